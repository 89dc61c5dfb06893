"""CLI: python3 -m indgen {generate,suite,selftest} (PYTHONPATH=tests/py)."""
import argparse
import json
import os
import sys
import time

SUITE = [
    ("null", 1), ("null", 2), ("null", 3), ("thermal", 4), ("braking", 5), ("latency", 6), ("payload", 7),
    ("thermal,braking", 8), ("bus_power", 9), ("bus_power,latency", 10), ("electronics_nm", 11),
    ("gear_friction", 12), ("grease", 13), ("rail_load", 14),
]
# The physical 0.1 Ohm supply path of sessions 09/10 adds ~0.006 W per trial, below anything 1 Hz
# readings can show; these two repeat them with an effective 5 Ohm (~0.3 W per trial: a supply
# path with a lossy input filter or DC/DC stage) so that the bus loss's form can be told at all.
VISIBLE_BUS = ["bus_power.R_bus_ohm=5"]
SUITE_EXTRA = [("bus_power", 15, VISIBLE_BUS, "bus_power5ohm"),
               ("bus_power,latency", 16, VISIBLE_BUS, "bus_power5ohm+latency")]


def suite_entries():
    """(index, file stem, effects, seed, --set overrides) of every suite session."""
    out = []
    for i, (eff, seed) in enumerate(SUITE, 1):
        out.append((i, f"{i:02d}_{eff.replace(',', '+')}", eff, seed, []))
    for eff, seed, sets, label in SUITE_EXTRA:
        i = len(out) + 1
        out.append((i, f"{i:02d}_{label}", eff, seed, sets))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python3 -m indgen", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    g = sub.add_parser("generate", help="one session: DIR/NAME.mcap + DIR/NAME.truth.json")
    g.add_argument("--out", required=True, help="DIR/NAME (no extension)")
    g.add_argument("--seed", type=int, default=1)
    g.add_argument("--hours", type=float, default=None, help="session length (default 0.5 h)")
    g.add_argument("--trials", type=int, default=None, help="exact number of trials instead of --hours")
    g.add_argument("--effects", default="", help="comma list: thermal,braking,latency,payload,bus_power,"
                                                  "electronics_nm,gear_friction,grease,rail_load (or null)")
    g.add_argument("--zstd-level", type=int, default=1)
    g.add_argument("--expect", action="store_true", help="also write NAME.expect.json for `check`")
    g.add_argument("--set", action="append", default=[], metavar="EFFECT.PARAM=VALUE",
                   help="override an effect parameter, e.g. bus_power.R_bus_ohm=0.05 (recorded in the truth)")
    k = sub.add_parser("check", help="read DIR/NAME.mcap back with mcap_ros2 and compare")
    k.add_argument("base", nargs="+", help="DIR/NAME (no extension)")
    k.add_argument("--full", action="store_true", help="walk every message (order, sequence, CRC)")
    s = sub.add_parser("suite", help="the 16-session suite NN_<effects>.mcap")
    s.add_argument("--out", required=True)
    s.add_argument("--only", type=int, action="append", default=[], metavar="N",
                   help="only session N (1-based; repeatable)")
    s.add_argument("--list", action="store_true", help="print the sessions (index, stem) and exit")
    s.add_argument("--hours", type=float, default=4.4)
    s.add_argument("--zstd-level", type=int, default=1)
    s.add_argument("--expect", action="store_true")
    sub.add_parser("selftest", help="RNEA / energy / CDR checks")
    a = ap.parse_args(argv)
    from .session import generate
    if a.cmd == "selftest":
        from .selftest import main as st
        st()
    elif a.cmd == "check":
        from .check import check
        ok = all([check(b.removesuffix(".mcap"), full=a.full) for b in a.base])
        return 0 if ok else 1
    elif a.cmd == "generate":
        eff = [x for x in a.effects.replace("+", ",").split(",") if x and x != "null"]
        t0 = time.time()
        tr = generate(a.out, a.seed, hours=a.hours, effects=eff, n_trials=a.trials, zstd_level=a.zstd_level,
                      expect=a.expect, overrides={k: json.loads(v) for k, v in (x.split("=", 1) for x in a.set)})
        print(f"{a.out}.mcap: {tr['session']['n_trials']} trials, {tr['session']['duration_s']:.0f} s, "
              f"{sum(tr['message_counts'].values())} messages, effects={list(tr['effects']) or 'none'}, "
              f"{time.time() - t0:.1f} s ({json.dumps(tr['timings_s'])})")
    elif a.cmd == "suite" and a.list:
        for i, name, eff, seed, sets in suite_entries():
            print(i, name, seed, " ".join(sets))
    elif a.cmd == "suite":
        os.makedirs(a.out, exist_ok=True)
        for i, name, eff, seed, sets in suite_entries():
            if a.only and i not in a.only:
                continue
            effs = [] if eff == "null" else eff.split(",")
            t0 = time.time()
            tr = generate(os.path.join(a.out, name), seed, hours=a.hours, effects=effs, zstd_level=a.zstd_level,
                          preset="suite", expect=a.expect,
                          overrides={k: json.loads(v) for k, v in (x.split("=", 1) for x in sets)})
            print(f"{name}: seed {seed}, {tr['session']['n_trials']} trials, {tr['session']['duration_s']:.0f} s, "
                  f"{time.time() - t0:.1f} s", flush=True)


if __name__ == "__main__":
    sys.exit(main())
