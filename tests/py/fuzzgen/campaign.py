"""One fuzz session end to end (draw, generate with indgen, oracle, `g1viz diagnose`, score) and
the campaign over many seeds: results as JSON lines while it runs, then a summary JSON, a CSV
of every effect and claim, and a recall-vs-detectability figure."""
import json
import os
import subprocess
import time
from multiprocessing import Pool

import numpy as np

from . import grammar, oracle, score

GATE = 0.05  # the detectability gate for the recall goal (held-out RMSE gain)


def generate(base, seed, minutes):
    """Write base.mcap, base.truth.json (indgen's, with a `fuzz` section) and return the truth."""
    from indgen.session import generate as indgen_generate
    effects = grammar.draw_session(seed)
    phys = grammar.Physics(effects, seed, duration_s=minutes * 60.0)
    payload = [e for e in effects if e.get("mechanism") == "payload"]
    truth = indgen_generate(base, seed, hours=minutes / 60.0, effects=["payload"] if payload else [],
                            overrides={"payload.mass_kg": payload[0]["magnitude"]} if payload else None,
                            hook=phys)
    table = phys.table()
    gains, rmse, rms = oracle.detectability(table, truth, len(effects))
    known_window = oracle.detectability_net(table, truth, len(effects), window_free=False)
    for e, g, r, (gn, gr, gx), (_, _, gw) in zip(effects, gains, rms, oracle.detectability_net(
            table, truth, len(effects)), known_window):
        # `detectability`: the yardstick the data allow (net and rest rows, the drift fitted, the
        # sensor window estimated); `detectability_known_window`: the same with the true window
        # known (the yardstick before stop 54; it differs for main-board lags and window drifts);
        # `detectability_abs`: the first oracle's (absolute power, one intercept), kept comparable
        e.update(detectability=round(gx, 5), detectability_net=round(gn, 5), detectability_rest=round(gr, 5),
                 detectability_known_window=round(gw, 5), detectability_abs=round(g, 5),
                 reading_rms_W=round(r, 4))
        if e.get("mechanism") == "payload":
            g, r = phys.payload_detectability()
            e.update(detectability=round(g, 5), detectability_abs=round(g, 5), level="torque",
                     torque_rms_Nm=round(r, 4))
            for k in ("reading_rms_W", "detectability_net", "detectability_rest", "detectability_known_window"):
                del e[k]
    own = [e["mechanism"] if e["kind"] == "library" else None for e in effects]
    for e, d in zip(effects, oracle.distinguishability(table, truth, len(effects), own)):
        if d is not None:  # the least held-out gain of knowing it beside another library mechanism
            # (at most its detectability: the share of what the data see that no rival fits)
            e.update(distinguishability=round(min(max(d[0], 0.0), e["detectability"]), 5), closest_rival=d[1])
    truth["fuzz"] = {"seed": seed, "effects": effects, "oracle_rmse_W": rmse,
                     "hidden_mode_switch_s": phys.mode_t}
    with open(base + ".truth.json", "w") as f:
        json.dump(truth, f, indent=1)
    return truth


def diagnose(binary, mcap, out_json, limit_s=600):
    t0 = time.time()
    p = subprocess.run([binary, "diagnose", mcap, "--json", out_json], capture_output=True, text=True,
                       timeout=limit_s)
    if p.returncode != 0:
        raise RuntimeError(f"g1viz diagnose {mcap} failed ({p.returncode}): {p.stderr[-2000:]}")
    with open(out_json) as f:
        return json.load(f), time.time() - t0, p.stdout


def run_session(args):
    """Generate, diagnose and score one seed; returns its result record (the mcap is deleted)."""
    seed, minutes, workdir, binary, keep = args
    base = os.path.join(workdir, f"fuzz_{seed}")
    t0 = time.time()
    try:
        truth = generate(base, seed, minutes)
        t_gen = time.time() - t0
        d, t_diag, _ = diagnose(binary, base + ".mcap", base + ".diagnosis.json")
    except Exception as ex:  # noqa: BLE001 - a failed session is a result, recorded with its seed
        return {"seed": seed, "error": str(ex)[-3000:]}
    finally:
        if not keep and os.path.exists(base + ".mcap"):
            os.remove(base + ".mcap")
    effects = truth["fuzz"]["effects"]
    cl, loc = score.claims(d), score.locations(d)
    cstate, estate = score.score(effects, [e["detectability"] for e in effects], cl, located=loc)
    return {"seed": seed, "minutes": minutes, "n_trials": d.get("n_trials"), "gen_s": round(t_gen, 1),
            "diagnose_s": round(t_diag, 1),
            "effects": [{k: v for k, v in e.items() if k != "expect"} | {"expect": e["expect"], "result": s}
                        for e, s in zip(effects, estate)],
            "claims": [c | {"result": s} for c, s in zip(cl, cstate)], "locations": loc}


def seeds_for(seed, n):
    """Session seeds of a campaign: deterministic in the campaign seed."""
    rng = np.random.default_rng([seed, 28])
    return [int(x) for x in rng.integers(1, 2 ** 31 - 1, n)]


def campaign(n, seed, minutes, out_dir, binary, workdir, jobs=2, keep=False):
    os.makedirs(out_dir, exist_ok=True)
    os.makedirs(workdir, exist_ok=True)
    lines = os.path.join(out_dir, "sessions.jsonl")
    done = set()
    if os.path.exists(lines):
        with open(lines) as f:
            done = {json.loads(x)["seed"] for x in f if x.strip()}
    wanted = seeds_for(seed, n)
    foreign = done - set(wanted)
    if foreign:
        # A resume continues the SAME campaign; records of another one would be summarised with it.
        raise SystemExit(f"{lines} holds {len(foreign)} session(s) not drawn by campaign seed {seed} "
                         f"(e.g. seed {min(foreign)}): give an empty --out, or the campaign seed and "
                         "--sessions it was started with to resume it")
    todo = [(s, minutes, workdir, binary, keep) for s in wanted if s not in done]
    t0 = time.time()
    with Pool(min(2, jobs)) as pool, open(lines, "a") as f:
        for k, r in enumerate(pool.imap_unordered(run_session, todo), 1):
            f.write(json.dumps(r) + "\n")
            f.flush()
            print(f"[{k}/{len(todo)} {time.time() - t0:.0f} s] seed {r['seed']}: "
                  + (r.get("error", "")[:200] or " ".join(
                      f"{e['mechanism']}({e['detectability']:.3f})->{e['result']}" for e in r["effects"])
                     + " | claims: " + (", ".join(f"{c['id'] or c['name'][:60]}={c['result']}" for c in r["claims"])
                                        or "none")), flush=True)
    return summarise(out_dir, planned=n, campaign_seed=seed, minutes=minutes, binary=binary)


def load(out_dir):
    """Every session record, re-scored with the current rules (claims are stored as printed)."""
    with open(os.path.join(out_dir, "sessions.jsonl")) as f:
        rs = [json.loads(x) for x in f if x.strip()]
    for r in rs:
        if "error" in r:
            continue
        for e in r["effects"]:  # a store from before the net oracle holds the first oracle's number only
            e.setdefault("detectability_abs", e["detectability"])
        cs, es = score.score(r["effects"], [e["detectability"] for e in r["effects"]], r["claims"],
                             located=r.get("locations", ()))
        for c, s in zip(r["claims"], cs):
            c["result"] = s
        for e, s in zip(r["effects"], es):
            e["result"] = s
    return rs


BINS = [0.0, 0.005, 0.02, 0.05, 0.1, 0.2, 1.01]


def summarise(out_dir, planned, campaign_seed, minutes, binary):
    rs = load(out_dir)
    ok = [r for r in rs if "error" not in r]
    claims = [(r["seed"], c) for r in ok for c in r["claims"]]
    effects = [(r["seed"], e) for r in ok for e in r["effects"]]
    count = lambda xs, k: sum(1 for _, x in xs if x["result"] == k)
    n_claims = len(claims)
    curve = []
    for lo, hi in zip(BINS[:-1], BINS[1:]):
        sel = [(s, e) for s, e in effects if lo <= e["detectability"] < hi]
        curve.append({"detectability_from": lo, "detectability_to": min(hi, 1.0), "effects": len(sel),
                      "named": count(sel, "named"), "located": count(sel, "located"), "missed": count(sel, "missed")})
    above = [(s, e) for s, e in effects if e["detectability"] >= GATE]
    above_abs = [(s, e) for s, e in effects if e["detectability_abs"] >= GATE]
    # library effects another library mechanism fits as well (`oracle.distinguishability` below the
    # gate) can at most be located ("X or Y"); the rest, with every non-library effect, are distinct
    distinct = [(s, e) for s, e in above if e.get("distinguishability", 1.0) >= GATE]
    rival_twins = [(s, e) for s, e in above if e.get("distinguishability", 1.0) < GATE]
    net = all("detectability_net" in e or e.get("level") == "torque" for _, e in effects)
    rate = lambda xs, ks: (sum(count(xs, k) for k in ks) / len(xs)) if xs else None
    summary = {
        "what": "physics-fuzz campaign: tests/py/fuzzgen (python3 -m fuzzgen campaign)",
        "complete": len(rs) >= planned, "sessions_planned": planned, "sessions_done": len(ok),
        "sessions_failed": [{"seed": r["seed"], "error": r["error"][:500]} for r in rs if "error" in r],
        "campaign_seed": campaign_seed, "minutes": minutes, "binary": binary,
        "null_sessions": sum(1 for r in ok if not r["effects"]),
        "claims": n_claims, "right": count(claims, "right"), "located": count(claims, "located"),
        "wrong": count(claims, "wrong"), "spurious": count(claims, "spurious"),
        "claim_precision": (count(claims, "right") / n_claims) if n_claims else None,
        "effects": len(effects), "named": count(effects, "named"), "effects_located": count(effects, "located"),
        "missed": count(effects, "missed"),
        "gate": GATE,
        "yardstick": "net and rest rows, the rail's drift fitted (oracle.detectability_net)" if net
        else "absolute power (the first oracle; this store predates the net one)",
        "effects_above_gate": len(above), "recall_above_gate": rate(above, ["named"]),
        "recall_or_located_above_gate": rate(above, ["named", "located"]),
        "effects_above_gate_abs": len(above_abs), "recall_above_gate_abs": rate(above_abs, ["named"]),
        "recall_or_located_above_gate_abs": rate(above_abs, ["named", "located"]),
        "effects_above_gate_distinct": len(distinct), "recall_above_gate_distinct": rate(distinct, ["named"]),
        "recall_or_located_above_gate_distinct": rate(distinct, ["named", "located"]),
        "effects_above_gate_rival_twins": len(rival_twins),
        "rival_twins_named_or_located": rate(rival_twins, ["named", "located"]),
        "recall_curve": curve,
        "wrong_claims": [{"seed": s, "claim": c["id"] or c["name"], "fields": c["fields"][:4], "result": c["result"],
                          "concealed": [f"{e['mechanism']}/{e.get('form')}/{e.get('state', e.get('meter', ''))}"
                                        f" d={e['detectability']:.3f}" for e in r["effects"]]}
                         for r in ok for c in r["claims"] if c["result"] in ("wrong", "spurious", "located")
                         for s in [r["seed"]]],
        "median_diagnose_s": float(np.median([r["diagnose_s"] for r in ok])) if ok else None,
    }
    with open(os.path.join(out_dir, "results.json"), "w") as f:
        json.dump(summary, f, indent=1, ensure_ascii=False)
    with open(os.path.join(out_dir, "results.csv"), "w") as f:
        f.write("seed,row,mechanism,form,state_or_meter,magnitude,detectability,result,detectability_abs,"
                "distinguishability,closest_rival\n")
        for r in ok:
            for e in r["effects"]:
                f.write(f"{r['seed']},effect,{e['mechanism']},{e.get('form')},{e.get('state', e.get('meter', ''))},"
                        f"{e.get('magnitude')},{e['detectability']},{e['result']},{e['detectability_abs']},"
                        f"{e.get('distinguishability', '')},{e.get('closest_rival', '')}\n")
            for c in r["claims"]:
                name = (c["id"] or c["name"]).replace(",", ";").replace("\n", " ")
                f.write(f"{r['seed']},claim,{name},,{'|'.join(c['fields'][:3])},,,{c['result']},,,\n")
    figure(summary, os.path.join(out_dir, "recall.png"))
    return summary


DOC_ROWS = [("sessions diagnosed", "sessions_done", 1, ""), ("null sessions", "null_sessions", 1, ""),
            ("claims", "claims", 1, ""), ("right claims", "right", 1, ""), ("located but misnamed", "located", 1, ""),
            ("wrong claims", "wrong", 1, ""), ("spurious claims", "spurious", 1, ""),
            ("claim precision", "claim_precision", 100, " %"), ("concealed effects", "effects", 1, ""),
            ("effects with detectability >= 5 %", "effects_above_gate", 1, ""),
            ("recall (named) above 5 %", "recall_above_gate", 100, " %"),
            ("recall (named or located) above 5 %", "recall_or_located_above_gate", 100, " %"),
            ("effects above 5 % no other library mechanism fits as well", "effects_above_gate_distinct", 1, ""),
            ("recall (named) above 5 % of those", "recall_above_gate_distinct", 100, " %"),
            ("effects with first-oracle detectability >= 5 %", "effects_above_gate_abs", 1, ""),
            ("recall (named) above 5 %, first oracle", "recall_above_gate_abs", 100, " %"),
            ("recall (named or located) above 5 %, first oracle", "recall_or_located_above_gate_abs", 100, " %")]


def doc_table(summary):
    """The figure table docs/campaign.md quotes (tests/campaign.rs checks it against results.json)."""
    rows = ["| figure | value | source |", "|---|---|---|"]
    for name, key, scale, unit in DOC_ROWS:
        v = summary[key]
        if v is None:
            continue
        val = f"{v * scale:.1f}" if scale != 1 else f"{v}"
        rows.append(f"| {name} | {val}{unit} | `results.json` {key}{' × 100' if scale != 1 else ''} |")
    return "\n".join(rows)


def figure(summary, path):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    cv = [b for b in summary["recall_curve"] if b["effects"]]
    if not cv:
        return
    x = np.arange(len(cv))
    named = [b["named"] / b["effects"] for b in cv]
    loc = [(b["named"] + b["located"]) / b["effects"] for b in cv]
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.bar(x, loc, color="#f0c36d", label="named or located")
    ax.bar(x, named, color="#3b7dd8", label="named (right mechanism)")
    for i, b in enumerate(cv):
        ax.text(i, loc[i] + 0.02, f"n={b['effects']}", ha="center", fontsize=8)
    ax.set_xticks(x, [f"{b['detectability_from']:g}–{b['detectability_to']:g}" for b in cv])
    ax.set_xlabel("oracle detectability (held-out RMSE gain of the true form)")
    ax.set_ylabel("recall")
    ax.set_ylim(0, 1.12)
    p = summary["claim_precision"]
    ax.set_title(f"fuzz campaign: {summary['sessions_done']} sessions, claim precision "
                 f"{'—' if p is None else f'{100 * p:.0f} %'} ({summary['claims']} claims)"
                 + ("" if summary["complete"] else " — PARTIAL"), fontsize=10)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
