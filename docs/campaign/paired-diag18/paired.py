"""Paired fuzz slice: each session generated once, diagnosed by two binaries, scored; two
campaign directories (sessions.jsonl + summary) in the campaign module's format."""
import json, os, sys, time
from multiprocessing import Pool
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "../../../tests/py"))
from fuzzgen import campaign as C, score

def one(args):
    seed, minutes, work, bins = args
    base = os.path.join(work, f"fuzz_{seed}")
    out = {}
    try:
        t0 = time.time()
        if os.path.exists(base + ".mcap") and os.path.exists(base + ".truth.json"):
            truth = json.load(open(base + ".truth.json"))
        else:
            truth = C.generate(base, seed, minutes)
        t_gen = time.time() - t0
        effects = truth["fuzz"]["effects"]
        for name, b in bins.items():
            try:
                d, t_diag, _ = C.diagnose(b, base + ".mcap", f"{base}.{name}.diagnosis.json")
            except Exception as ex:
                out[name] = {"seed": seed, "error": str(ex)[-3000:]}
                continue
            cl, loc = score.claims(d), score.locations(d)
            cs, es = score.score(effects, [e["detectability"] for e in effects], cl, located=loc)
            out[name] = {"seed": seed, "minutes": minutes, "n_trials": d.get("n_trials"), "gen_s": round(t_gen, 1),
                         "diagnose_s": round(t_diag, 1),
                         "effects": [{k: v for k, v in e.items() if k != "expect"} | {"expect": e["expect"], "result": s}
                                     for e, s in zip(effects, es)],
                         "claims": [c | {"result": s} for c, s in zip(cl, cs)], "locations": loc}
    except Exception as ex:
        for name in bins:
            out.setdefault(name, {"seed": seed, "error": str(ex)[-3000:]})
    finally:
        if os.path.exists(base + ".mcap") and not os.environ.get("KEEP"):
            os.remove(base + ".mcap")
    return out

if __name__ == "__main__":
    n, seed, minutes, outroot, work = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), sys.argv[4], sys.argv[5]
    bins = dict(x.split("=", 1) for x in sys.argv[6:])
    os.makedirs(work, exist_ok=True)
    for name in bins:
        os.makedirs(os.path.join(outroot, name), exist_ok=True)
    done = {}
    for name in bins:
        p0 = os.path.join(outroot, name, "sessions.jsonl")
        done[name] = {json.loads(x)["seed"] for x in open(p0) if x.strip()} if os.path.exists(p0) else set()
    todo = [(s, minutes, work, {k: v for k, v in bins.items() if s not in done[k]}) for s in C.seeds_for(seed, n)]
    todo = [t for t in todo if t[3]]
    t0 = time.time()
    with Pool(2) as pool:
        for k, r in enumerate(pool.imap_unordered(one, todo), 1):
            for name, rec in r.items():
                with open(os.path.join(outroot, name, "sessions.jsonl"), "a") as f:
                    f.write(json.dumps(rec) + "\n")
            print(f"[{k}/{len(todo)} {time.time()-t0:.0f}s] " + " || ".join(
                f"{name}: " + (rec.get("error", "")[:100] or ", ".join(f"{c['id'] or c['name'][:50]}={c['result']}" for c in rec["claims"]) or "none")
                for name, rec in r.items()), flush=True)
    for name, b in bins.items():
        C.summarise(os.path.join(outroot, name), planned=n, campaign_seed=seed, minutes=minutes, binary=b)
