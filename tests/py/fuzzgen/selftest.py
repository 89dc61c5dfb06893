"""`python3 -m fuzzgen selftest`: the grammar covers what it claims to, the scorer classifies
hand-written claims as the rules say, and the oracle gives ~0 for no effect and a large gain for
a large one (synthetic readings, numpy only)."""
import numpy as np

from . import grammar, oracle, score


def check_grammar(n=2000):
    draws = [grammar.draw_session(s) for s in range(n)]
    effects = [e for d in draws for e in d]
    nulls = sum(not d for d in draws) / n
    seen = {(e["kind"], e["mechanism"]) for e in effects}
    lib = {m for k, m in seen if k == "library"}
    forms = {e["form"] for e in effects if e["kind"] in ("load", "modulated")}
    states = {e["state"] for e in effects if "state" in e}
    meters = {(e["meter"], e["artefact"]) for e in effects if e["kind"] == "meter"}
    mags = [abs(e["magnitude"]) for e in effects if e.get("unit") == "W"]
    # the cap on a modulated term's change: a 5 W draw on a 0.1 W term is drawn again below
    # 0.1 W (same sign); a 0.05 W draw on it is kept
    ph = grammar.Physics([], 7, 900.0)
    big, small = {"magnitude": -5.0}, {"magnitude": 0.05}
    ph._cap(0, big, 0.1)
    ph._cap(1, small, 0.1)
    checks = {
        "cap: a draw above it is redrawn below it": -0.1 <= big["magnitude"] < 0 and big["magnitude_drawn"] == -5.0,
        "cap: a draw below it is kept": small == {"magnitude": 0.05},
        "every power mechanism of the library has a physical limit":
            set(grammar.LIMITS) == set(grammar.LIBRARY) - {"latency", "payload"},
        "nulls >= 20 %": nulls >= 0.2,
        "every library mechanism": lib == set(grammar.LIBRARY),
        "every form": set(grammar.FORMS_SHAPE) <= forms,
        "every state": set(grammar.STATES) <= states,
        "both meters x 4 artefacts": len(meters) == 8,
        "magnitudes span > 2 decades": max(mags) / min(mags) > 100,
        "at most 2 effects": max(len(d) for d in draws) <= 2,
    }
    return checks, {"null_fraction": nulls, "effects": len(effects)}


def check_scorer():
    lib = {"kind": "library", "mechanism": "braking", "expect": {"ids": ["braking"], "fields": [], "terms": []}}
    visc = {"kind": "modulated", "mechanism": "viscous_x_state", "expect": {
        "ids": [], "fields": ["/lowstate.motor_state[18].temperature[1]"], "terms": grammar.TERMS["viscous"]}}
    load = {"kind": "load", "mechanism": "rail_load", "expect": {
        "ids": [], "fields": ["/lf/mainboardstate.fan_state[0]", "/lf/mainboardstate.fan_state[1]"], "terms": []}}
    gain = {"kind": "meter", "mechanism": "meter_gain", "expect": {
        "ids": [], "fields": ["/lf/mainboardstate.temperature[0]"], "terms": [], "meter": "mbs",
        "meter_words": grammar.METER_WORDS}}
    rng = __import__("numpy").random.default_rng(28)
    thermal = next(e for e in iter(lambda: grammar.draw_effect(rng), None) if e.get("mechanism") == "thermal")
    L = lambda i: {"kind": "library", "id": i, "name": i, "fields": []}
    F = lambda name, *f: {"kind": "found", "id": None, "name": name, "fields": list(f)}
    cases = [
        ([lib], [L("braking")], ["right"], ["named"]),
        ([], [L("latency")], ["spurious"], []),
        ([lib], [L("braking"), L("gear_friction")], ["right", "spurious"], ["named"]),
        ([lib], [L("gear_friction")], ["wrong"], ["missed"]),
        ([visc], [F("the viscous friction loss q̇² falls as it rises",
                    "/lowstate.motor_state[18].temperature[1]")], ["right"], ["named"]),
        ([visc], [F("the viscous friction loss q̇² falls as it rises",
                    "/lowstate.motor_state[19].temperature[1]")], ["located"], ["located"]),
        ([visc], [F("a load on the power rail", "/lowstate.motor_state[18].temperature[1]")],
         ["located"], ["located"]),
        ([load], [F("a load on the power rail that rises with it", "/lf/mainboardstate.fan_state[1]")],
         ["right"], ["named"]),
        ([gain], [F("a load on the power rail that rises with it", "/lf/mainboardstate.temperature[0]")],
         ["located"], ["located"]),
        ([gain], [F("a gain error of the main-board meter", "/lf/mainboardstate.temperature[0]")],
         ["right"], ["named"]),
        ([gain, lib], [L("stribeck")], ["wrong"], ["missed", "missed"]),
        # a found term on a winding temperature locates a thermal drift (another loss named)
        ([thermal], [F("the drive-electronics loss per Nm of the driving joints rises with it",
                       "/lowstate.motor_state[17].temperature[0]")], ["located"], ["located"]),
        ([thermal], [F("the drive-electronics loss per Nm of the driving joints rises with it",
                       "/lowstate.motor_state[17].temperature[1]")], ["wrong"], ["missed"]),
        # a meter artefact is right only on the meter it is on
        ([gain], [{"kind": "meter", "id": None, "fields": [], "name": "an artefact of the battery meter: "
                   "its reading changes, which the main-board meter does not show"}], ["wrong"], ["missed"]),
        ([gain], [{"kind": "meter", "id": None, "fields": [], "name": "an artefact of the main-board meter: "
                   "its reading changes, which the battery meter does not show"}], ["right"], ["named"]),
    ]
    bad = []
    for effs, cl, want_c, want_e in cases:
        got_c, got_e = score.score(effs, [1.0] * len(effs), cl)
        if got_c != want_c or got_e != want_e:
            bad.append((effs and effs[0]["mechanism"], [c["id"] or c["name"] for c in cl], got_c, got_e))
    # diagnosis.json's rest-power stage is one object (or null), its found terms claims
    rest = {"discovery": {"accepted": [], "rest": {"found": [
        {"name": "the rail's rest power rises with it", "field": "/lf/mainboardstate.fan_state[1]", "tied": []}]}}}
    if [c["fields"] for c in score.claims(rest)] != [["/lf/mainboardstate.fan_state[1]"]]:
        bad.append(("rest object", score.claims(rest)))
    # a form located at an implausible size makes its effect located, and is no claim
    d = {"hypotheses": [{"id": "braking", "verdict": "rejected: parameter outside its physically plausible range"},
                        {"id": "stribeck", "verdict": "rejected: held-out improvement not significant"}]}
    loc = score.locations(d)
    if score.claims(d) or score.score([lib], [1.0], [], located=loc) != ([], ["located"]) \
            or score.score([lib], [1.0], [], located=loc[1:]) != ([], ["missed"]):
        bad.append(("implausible form", loc))
    # a meter change the other meter cannot tell from a load locates that meter's artefact only
    d = {"discovery": {"meter_located": {"name": "the main-board meter's rest reading: its reading changes by "
                                                 "+1.97 W; the battery meter cannot tell — located, not claimed"}}}
    loc = score.locations(d)
    if score.claims(d) or score.score([gain], [1.0], [], located=loc) != ([], ["located"]) \
            or score.score([load], [1.0], [], located=loc) != ([], ["missed"]):
        bad.append(("meter located", loc))
    # ... and a load on a field it names as what the rest power follows
    d["discovery"]["meter_located"]["fields"] = ["/lf/bmsstate.soc", "/lf/mainboardstate.fan_state[1]"]
    if score.score([load], [1.0], [], located=score.locations(d)) != ([], ["located"]):
        bad.append(("meter located on a field", score.locations(d)))
    # a lag the held-out trials cannot tell from a longer window locates a latency, and is no claim
    d = {"summary": "Located: the readings' timing — a latency of 0.050 s behind a 0.300 s window, or a "
                    "0.375 s window at no lag; the data do not tell them apart (in-sample ΔBIC = -40.5, held out p = 3.7e-1); "
                    "neither is claimed."}
    lat = {"kind": "library", "mechanism": "latency", "expect": {"ids": ["latency"], "fields": [], "terms": []}}
    loc = score.locations(d)
    if score.claims(d) or score.score([lat], [1.0], [], located=loc) != ([], ["located"]) \
            or score.score([lib], [1.0], [], located=loc) != ([], ["missed"]):
        bad.append(("timing located", loc))
    # two lags of the main-board meter are one delay: one latency claim names both
    lag_claim = [{"kind": "library", "id": "latency", "name": "power-sensor latency", "fields": []}]
    mlag = {"kind": "meter", "mechanism": "meter_lag", "meter": "mbs",
            "expect": {"ids": ["latency"], "fields": [], "terms": [], "meter": "mbs", "meter_words": ["meter"]}}
    if score.score([lat, mlag], [1.0, 0.5], lag_claim) != (["right"], ["named", "named"]):
        bad.append(("one delay", score.score([lat, mlag], [1.0, 0.5], lag_claim)))
    # one claim that fits two drawn forms of a mechanism names the one the data show most
    if score.score([lib, dict(lib)], [0.0, 0.28], [L("braking")]) != (["right"], ["missed", "named"]):
        bad.append(("two forms, one claim", score.score([lib, dict(lib)], [0.0, 0.28], [L("braking")])))
    if score.claims({"discovery": {"rest": None}}):
        bad.append(("rest null", "claims"))
    return {"scorer cases": not bad}, {"scorer_failures": bad}


def check_oracle():
    rng = np.random.default_rng(0)
    n = 2000
    F = rng.normal(0, 1, (n, 49))
    theta = rng.uniform(0, 1, 49)
    E = rng.normal(0, 1, n)
    trials = [{"t_trial_start_ns": int(i * 10e9), "contaminated": False, "outlier": False} for i in range(n // 10)]
    truth = {"session": {"start_ns": 0}, "trials": trials, "theta": {"vector": theta.tolist()}}
    t = np.arange(n) + 0.5
    out = {}
    for k in (0.01, 1.0):
        y = 120 + F @ theta + rng.normal(0, 0.3, n) + k * E
        table = np.column_stack([t, y, F, k * E])
        out[k] = oracle.detectability(table, truth, 1)[0][0]
    # an effect of RMS 1 W over 0.3 W noise: 1 - 0.3/sqrt(0.3^2 + 1) = 0.71
    checks = {"oracle: 0.01 W over 0.3 W ~ 0": abs(out[0.01]) < 0.01,
              "oracle: 1 W over 0.3 W ~ 0.71": abs(out[1.0] - 0.71) < 0.03}
    info = {"oracle_gain_none": out[0.01], "oracle_gain_1W": out[1.0]}
    # the yardstick the data allow: trials of 10 s (2 s at rest, then 8 s of motion), one reading
    # a second; the rail flat, or drifting as indgen's (OU σ 0.3 W, τ 300 s)
    n_tr = 90
    t = np.arange(n_tr * 10) + 0.5
    moving = (t % 10) > 2.0
    F = rng.normal(0, 1, (len(t), 49)) * moving[:, None]
    trials = [{"t_trial_start_ns": int(i * 10e9), "t_traj_start_ns": int((i * 10 + 2) * 1e9),
               "t_post_idle_end_ns": int((i * 10 + 10) * 1e9), "contaminated": False, "outlier": False}
              for i in range(n_tr)]
    truth = {"session": {"start_ns": 0}, "trials": trials, "theta": {"vector": theta.tolist()}}
    a = np.exp(-1.0 / 300.0)
    ou = np.zeros(len(t))
    w = rng.normal(0, 0.3 * np.sqrt(1 - a * a), len(t))
    for i in range(1, len(t)):
        ou[i] = a * ou[i - 1] + w[i]
    # (the step off the spline's knots: at a knot the spline takes most of it on either rail)
    effects = {"slow load: 2 W step at 0.37 of the session": 2.0 * (t > 0.37 * t[-1]),
               "slow load: 2 W linear in time": 2.0 * t / t[-1],
               "arm effect: 1 W while moving": moving * rng.normal(0, 1.0, len(t))}
    got = {}
    for name, e in effects.items():
        for rail, d in (("flat", 0.0 * ou), ("drifting", ou)):
            y = 120 + d + F @ theta + rng.normal(0, 0.3, len(t)) + e
            table = np.column_stack([t, y, F, e])
            got[name, rail] = oracle.detectability_net(table, truth, 1)[0][2]
            info[f"oracle_net: {name}, {rail} rail"] = round(got[name, rail], 3)
    step, lin, arm = effects
    # could another mechanism be it? A gear friction k|τq̇| is a braking asymmetry of 2k once each
    # joint's efficiency may rise (a ≥ 1); a braking asymmetry is no gear friction (that needs a < 1)
    mech = F[:, :7]
    lib = {"braking": np.maximum(-mech, 0.0), "gear_friction": np.abs(mech)}
    for own in ("gear_friction", "braking"):
        e = 0.3 * lib[own].sum(1)
        riv = np.hstack([lib.get(m, np.zeros((len(t), n))) if n == 7 else np.zeros((len(t), 1))
                         for m, n in grammar.RIVALS])
        y = 120 + F @ theta + rng.normal(0, 0.3, len(t)) + e
        table = np.column_stack([t, y, F, e, riv, e])
        d = oracle.distinguishability(table, truth, 1, [own])[0]
        got[own] = d[0]
        info[f"oracle: distinguishability of a {own}"] = [round(d[0], 3), d[1]]
    # the window-free yardstick: what a lag leaves beside the best window read at no lag — nothing
    # on a rail linear in time (a window of the same centre averages it the same), something on a
    # rail that switches every second (the two windows' edges differ)
    dt, lag = 0.01, 0.05
    ts = np.arange(0.0, 120.0, dt)
    rest_rms = {}
    for rail_name, rail in (("linear", 100 + 1.0 * ts), ("switching", 100 + 5.0 * (np.floor(ts) % 2))):
        phys = grammar.Physics([{"kind": "library", "mechanism": "latency", "form": "lag",
                                 "magnitude": lag}], 1, duration_s=120.0)
        phys.cur = (ts, np.zeros((len(ts), 50 + grammar.N_RIVAL_COLS)))
        cs = np.concatenate([[0.0], np.cumsum(rail)])

        def avg(_m, at, lg, w, cs=cs):
            i1 = np.searchsorted(ts, at - lg, side="right")
            i0 = np.minimum(np.searchsorted(ts, at - lg - w, side="right"), i1 - 1)
            return (cs[i1] - cs[i0]) / (i1 - i0)

        mt = 3.0 + np.arange(110) * 1.037  # readings at every phase of the rail's seconds
        phys.meter(mt, mt, avg, avg("mbs", mt, 0.0, 0.3), avg("bms", mt, 0.0, 0.3))
        tab = phys.table()
        rms = lambda x: float(np.sqrt(np.mean(x * x)))
        rest_rms[rail_name] = (rms(tab[:, -1]), rms(tab[:, 51]))
        info[f"oracle: a 0.05 s lag's remainder / contribution, {rail_name} rail"] = [round(v, 3) for v in rest_rms[rail_name]]
    checks.update({
        "oracle: a longer window absorbs a lag on a smooth rail":
            rest_rms["linear"][0] < 0.05 * rest_rms["linear"][1],
        "oracle: a lag on a switching rail keeps a remainder":
            0.05 * rest_rms["switching"][1] < rest_rms["switching"][0] < rest_rms["switching"][1],
    })
    checks.update({
        "oracle_net: a slow load scores lower on a drifting rail": got[step, "drifting"] < got[step, "flat"] - 0.05,
        "oracle: a gear friction is a braking asymmetry (~0)": got["gear_friction"] < 0.02,
        "oracle: a braking asymmetry is no gear friction": got["braking"] > 0.2,
        "oracle_net: a load linear in time is a drift (~0)": got[lin, "flat"] < 0.02 and got[lin, "drifting"] < 0.02,
        "oracle_net: an arm effect scores the same on both":
            abs(got[arm, "drifting"] - got[arm, "flat"]) < 0.02 and got[arm, "flat"] > 0.5,
    })
    return checks, info


def main():
    checks, info = {}, {}
    for f in (check_grammar, check_scorer, check_oracle):
        c, i = f()
        checks.update(c)
        info.update(i)
    print(info)
    for k, v in checks.items():
        print(f"{k:32s} {'ok' if v else 'FAIL'}")
    if not all(checks.values()):
        raise SystemExit(1)
    print("selftest passed")
