"""CLI: python3 -m fuzzgen {draw,session,campaign,summarise,selftest} (PYTHONPATH=tests/py)."""
import argparse
import json
import os
import sys


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python3 -m fuzzgen", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("draw", help="print the concealed physics a seed draws (JSON)")
    d.add_argument("seed", type=int)
    s = sub.add_parser("session", help="generate, diagnose and score one seed; prints the record (JSON)")
    s.add_argument("seed", type=int)
    s.add_argument("--minutes", type=float, default=30.0)
    s.add_argument("--work", default="/tmp/fuzzgen")
    s.add_argument("--g1viz", default="target/debug/g1viz")
    s.add_argument("--keep", action="store_true", help="keep the .mcap")
    c = sub.add_parser("campaign", help="N sessions (2 processes at most); results in --out")
    c.add_argument("--sessions", type=int, required=True)
    c.add_argument("--seed", type=int, required=True)
    c.add_argument("--minutes", type=float, default=30.0)
    c.add_argument("--out", default="docs/campaign")
    c.add_argument("--work", default="/tmp/fuzzgen")
    c.add_argument("--g1viz", default="target/debug/g1viz")
    c.add_argument("--jobs", type=int, default=2)
    sub.add_parser("selftest", help="grammar coverage, scorer rules, oracle on synthetic readings")
    m = sub.add_parser("summarise", help="rewrite results.json/csv/png from --out/sessions.jsonl")
    m.add_argument("--out", default="docs/campaign")
    m.add_argument("--planned", type=int, required=True)
    m.add_argument("--seed", type=int, required=True)
    m.add_argument("--minutes", type=float, default=30.0)
    m.add_argument("--g1viz", default="target/debug/g1viz")
    a = ap.parse_args(argv)
    from . import campaign, grammar
    if a.cmd == "selftest":
        from .selftest import main as st
        st()
    elif a.cmd == "draw":
        print(json.dumps(grammar.draw_session(a.seed), indent=1))
    elif a.cmd == "session":
        os.makedirs(a.work, exist_ok=True)
        r = campaign.run_session((a.seed, a.minutes, a.work, os.path.abspath(a.g1viz), a.keep))
        print(json.dumps(r, ensure_ascii=False))
        return 1 if "error" in r else 0
    elif a.cmd == "campaign":
        r = campaign.campaign(a.sessions, a.seed, a.minutes, a.out, os.path.abspath(a.g1viz), a.work, a.jobs)
        print(json.dumps({k: v for k, v in r.items() if k not in ("wrong_claims",)}, indent=1, ensure_ascii=False))
    else:
        r = campaign.summarise(a.out, a.planned, a.seed, a.minutes, a.g1viz)
        print(json.dumps({k: v for k, v in r.items() if k not in ("wrong_claims",)}, indent=1, ensure_ascii=False))
        print(campaign.doc_table(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
