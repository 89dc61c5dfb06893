#!/usr/bin/env python3
"""Run the SQL `g1viz fleet --save-sql DIR` wrote, unchanged, on other engines and compare
their results with the embedded engine's (DataFusion) CSVs beside each query.

    g1viz fleet ROWS_DIR --by robot,week --save-sql sql/
    python3 examples/fleet_sql_crosscheck.py sql/ ROWS_DIR            # DuckDB
    python3 examples/fleet_sql_crosscheck.py sql/ ROWS_DIR --spark    # + Spark SQL

Needs `pip install duckdb` (and `pyspark` with Java 17 for --spark). Spark runs as a
multi-process cluster on this machine, `local-cluster[2,1,1024]`: a master, two worker JVMs of
one core and 1 GB each, the query's tasks scheduled across them by Spark (set
G1VIZ_SPARK_MASTER to another master URL, e.g. spark://host:7077, to use a real cluster). The
only engine-specific line is the registration of the Parquet files as the view `rows`; the
queries are the files' text. Each result row is matched by its key columns (robot, session, day, week, trial_*); every
number must agree to 1e-9 relative (sums in another order round differently).
"""

import csv
import glob
import math
import os
import sys

NUMERIC_PREFIXES = ("n", "sy", "yy", "sigma_omega", "t_min", "t_max")


def is_value_column(name):
    return name in NUMERIC_PREFIXES or name[:2] in ("h_", "g_", "s_")


def load_expected(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return rows


def compare(name, columns, got_rows, expected):
    keys = [c for c in columns if not is_value_column(c)]
    index = {tuple(str(r[k]) for k in keys): r for r in expected}
    assert len(got_rows) == len(expected), f"{name}: {len(got_rows)} rows, DataFusion {len(expected)}"
    worst = 0.0
    for row in got_rows:
        row = dict(zip(columns, row))
        key = tuple(str(row[k]) for k in keys)
        assert key in index, f"{name}: group {key} not in DataFusion's result"
        want = index[key]
        for c in columns:
            if not is_value_column(c):
                continue
            a, b = float(row[c]), float(want[c])
            err = abs(a - b) / max(abs(a), abs(b), 1e-300)
            worst = max(worst, err if not (a == 0 and b == 0) else 0.0)
            assert err <= 1e-9 or abs(a - b) < 1e-12, f"{name} {key} {c}: {a} vs {b}"
    return worst


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    sql_dir, rows_dir = sys.argv[1], sys.argv[2]
    files = sorted(glob.glob(os.path.join(sql_dir, "*.sql")))
    if not files:
        sys.exit(f"{sql_dir}: no .sql files (write them with g1viz fleet --save-sql)")
    parquet = glob.glob(os.path.join(rows_dir, "**", "*.parquet"), recursive=True)
    if os.path.isfile(rows_dir):
        parquet = [rows_dir]
    engines = []

    import duckdb

    con = duckdb.connect()
    con.execute(f"CREATE VIEW rows AS SELECT * FROM read_parquet({parquet!r})")

    def run_duckdb(q):
        cur = con.execute(q)
        return [d[0] for d in cur.description], cur.fetchall()

    engines.append(("DuckDB " + duckdb.__version__, run_duckdb))

    if "--spark" in sys.argv:
        from pyspark.sql import SparkSession

        spark = (
            SparkSession.builder.master(os.environ.get("G1VIZ_SPARK_MASTER", "local-cluster[2,1,1024]"))
            .appName("g1viz-fleet-crosscheck")
            .config("spark.ui.enabled", "false")
            .getOrCreate()
        )
        spark.sparkContext.setLogLevel("ERROR")
        spark.read.parquet(*parquet).createOrReplaceTempView("rows")

        def run_spark(q):
            df = spark.sql(q)
            return df.columns, [tuple(r) for r in df.collect()]

        engines.append(("Spark " + spark.version + " " + spark.sparkContext.master, run_spark))

    for engine, run in engines:
        for path in files:
            q = open(path).read()
            name = os.path.basename(path)
            columns, rows = run(q)
            expected = load_expected(path[: -len(".sql")] + ".csv")
            worst = compare(name, columns, rows, expected)
            print(f"{engine}: {name}: {len(rows)} rows, {len(columns)} columns, "
                  f"largest relative difference {worst:.1e}")
    print("all results agree")


if __name__ == "__main__":
    main()
