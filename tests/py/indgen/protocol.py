"""Trial protocol (README 'Protocol'): routes, speeds, phase timing, cubic smooth-step segments."""
import itertools

import numpy as np

ID_SPEEDS = [0.5, 1.0, 1.5, 2.0, 2.5]
PRE_IDLE, POST_IDLE, RETURN_SPEED = 2.0, 2.0, 0.5
GAP = (0.1, 0.6)
SHORT = ["sh_pitch", "sh_roll", "sh_yaw", "elbow", "wr_roll", "wr_pitch", "wr_yaw"]
# waypoint ranges [rad]: inside the URDF limits, arm away from the body (left shoulder roll >= 0
# moves the arm outwards, elbow mostly flexed forward)
RANGE = np.array([[-1.6, 0.8], [0.05, 1.4], [-1.2, 1.2], [-0.6, 1.6], [-1.4, 1.4], [-1.2, 1.2], [-1.2, 1.2]])


def seg_duration(dq_max, speed):
    return max(0.3, 1.5 * dq_max / speed)


def make_routes(rng):
    """Route library: single-joint sweeps (7 x 6), all 21 pairs (x 3), 35 triples, 25 of the
    35 4-joint sets, and 15 larger sets (5, 6, 7 joints); 3-5 waypoints each."""
    combos = []
    for j in range(7):
        combos += [("single", (j,))] * 6
    for c in itertools.combinations(range(7), 2):
        combos += [("pair", c)] * 3
    combos += [("triple", c) for c in itertools.combinations(range(7), 3)]
    quads = list(itertools.combinations(range(7), 4))
    for i in rng.choice(len(quads), 25, replace=False):
        combos.append(("quad", quads[i]))
    for size in (5, 6, 7):
        big = list(itertools.combinations(range(7), size))
        n = {5: 8, 6: 5, 7: 2}[size]
        for i in rng.choice(len(big), min(n, len(big)), replace=False):
            combos.append((f"multi{size}", big[i]))
    routes = []
    count = {}
    for kind, joints in combos:
        n_wp = int(rng.integers(3, 6))
        wps = []
        prev = np.zeros(7)
        for _ in range(n_wp):
            for _try in range(50):
                w = np.zeros(7)
                for j in joints:
                    w[j] = rng.uniform(*RANGE[j])
                if np.abs(w - prev).max() >= 0.35 and np.abs(w).max() >= 0.25:
                    break
            wps.append(np.round(w, 6))
            prev = w
        key = "_".join(str(j) for j in joints)
        count[key] = count.get(key, 0) + 1
        rid = f"{'s' if kind == 'single' else 'm'}{key}_{count[key] - 1}"
        routes.append({"route_id": rid, "route_kind": kind, "joints": list(joints), "waypoints": np.array(wps)})
    return routes


def schedule(rng, routes, hours=None, n_trials=None, t0=3.0):
    """Trials one after another from t0 [s]: (route, speed) pairs in shuffled order, all speeds of
    the library before any repeats. Returns trials (dicts, times in s) and segment arrays."""
    pairs = [(r, s) for r in range(len(routes)) for s in ID_SPEEDS]
    order = []
    trials = []
    seg_s, seg_d, seg_q0, seg_q1 = [], [], [], []
    t = t0
    q = np.zeros(7)
    limit = None if hours is None else hours * 3600.0
    while True:
        if n_trials is not None and len(trials) >= n_trials:
            break
        if not order:
            order = [pairs[i] for i in rng.permutation(len(pairs))]
        ri, speed = order.pop()
        r = routes[ri]
        start = t
        ts = t + PRE_IDLE
        tt = ts
        q = np.zeros(7)
        for w in r["waypoints"]:
            d = seg_duration(np.abs(w - q).max(), speed)
            seg_s.append(tt); seg_d.append(d); seg_q0.append(q); seg_q1.append(w)
            tt += d
            q = w
        te = tt
        tp = te + POST_IDLE
        d = seg_duration(np.abs(q).max(), RETURN_SPEED)
        seg_s.append(tp); seg_d.append(d); seg_q0.append(q); seg_q1.append(np.zeros(7))
        tr = tp + d
        if limit is not None and n_trials is None and tr > limit and trials:
            seg_s, seg_d, seg_q0, seg_q1 = seg_s[:-len(r["waypoints"]) - 1], seg_d[:-len(r["waypoints"]) - 1], \
                seg_q0[:-len(r["waypoints"]) - 1], seg_q1[:-len(r["waypoints"]) - 1]
            break
        trials.append({"index": len(trials), "route_id": r["route_id"], "route_kind": r["route_kind"],
                       "joints_moved": r["joints"], "joints_moved_names": [SHORT[j] for j in r["joints"]],
                       "qdot_max": speed, "waypoints_rad": r["waypoints"].tolist(),
                       "t_start": start, "t_traj_start": ts, "t_traj_end": te, "t_post_idle_end": tp,
                       "t_return_end": tr})
        t = tr + rng.uniform(*GAP)
    segs = (np.array(seg_s), np.array(seg_d), np.array(seg_q0).reshape(-1, 7), np.array(seg_q1).reshape(-1, 7))
    return trials, segs, t


def evaluate(segs, t):
    """Reference q, qd, qdd (N,7) at times t from the segment list (holds between segments)."""
    S, D, Q0, Q1 = segs
    i = np.searchsorted(S, t, side="right") - 1
    before = i < 0
    i = np.maximum(i, 0)
    tau = np.clip((t - S[i]) / D[i], 0.0, 1.0)
    moving = (tau > 0.0) & (tau < 1.0)
    dq = Q1[i] - Q0[i]
    s = tau * tau * (3.0 - 2.0 * tau)
    q = Q0[i] + dq * s[:, None]
    sd = np.where(moving, 6.0 * tau * (1.0 - tau) / D[i], 0.0)
    sdd = np.where(moving, (6.0 - 12.0 * tau) / D[i] ** 2, 0.0)
    qd = dq * sd[:, None]
    qdd = dq * sdd[:, None]
    q[before] = 0.0
    qd[before] = 0.0
    qdd[before] = 0.0
    return q, qd, qdd
