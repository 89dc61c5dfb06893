#!/usr/bin/env python3
"""Make a large fleet from a simulated one: K copies of every robot under new names, for
measuring `g1viz fleet` at a million rows without simulating thousands of sessions.

    cargo run --example bench_fleet -- /tmp/fleet                    # 20 robots × 30 days
    python3 examples/fleet_replicate.py /tmp/fleet /tmp/fleet10 10   # 200 robots, ≈ 1.07 M rows
    cargo run --example bench_fleet -- --fit /tmp/fleet10 30          # one fit of all 30 days

Copy k of robot R is robot `R_ck`: its rows (the `robot` column, and the robot's name in the
`session` column) renamed, everything else as written, one file per robot and day as in the
source (`R_ck/dayNNN.parquet`, zstd). Each copy is a separate robot to the fit: its groups,
trials and drifts are its original's, so a fit finds each introduced drift once per copy.
Needs pyarrow. The source is only read.
"""

import os
import sys

import pyarrow as pa
import pyarrow.parquet as pq


def relabel(table, old, new):
    """The table with robot `old` renamed `new` in the robot and session columns."""
    for name, values in (
        ("robot", [new] * table.num_rows),
        ("session", [s.replace(old + "_", new + "_") for s in table.column("session").to_pylist()]),
    ):
        i = table.schema.get_field_index(name)
        table = table.set_column(i, name, pa.array(values, table.schema.field(name).type))
    return table


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    src, dst, copies = sys.argv[1], sys.argv[2], int(sys.argv[3])
    robots = sorted(d for d in os.listdir(src) if os.path.isdir(os.path.join(src, d)))
    if not robots:
        sys.exit(f"{src}: no robot folders (ROBOT/dayNNN.parquet)")
    files = 0
    for k in range(copies):
        for robot in robots:
            name = f"{robot}_c{k}"
            os.makedirs(os.path.join(dst, name), exist_ok=True)
            for f in sorted(os.listdir(os.path.join(src, robot))):
                if not f.endswith(".parquet"):
                    continue
                table = relabel(pq.read_table(os.path.join(src, robot, f)), robot, name)
                pq.write_table(table, os.path.join(dst, name, f), compression="zstd")
                files += 1
    print(f"{files} files of {copies * len(robots)} robots in {dst}")


if __name__ == "__main__":
    main()
