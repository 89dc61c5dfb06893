"""The oracle: how detectable each concealed effect is in a session's readings.

It knows the truth: per MBS reading it has the paper's 49 regressors (window-averaged true
states) and each effect's true contribution. It refits the base model on the readings (numpy):
an intercept and the 49 parameters by ridge regression toward the true θ (λ = 0.1·n on
standardised regressors — a short session holds some joint pairs in one trial only, and a free
fit's held-out prediction of that trial is off by tens of watts), 5-fold
cross-validated by trial, after subtracting the effects' true contributions (their coefficient is
known, so a slow effect cannot soak up the rest-power drift), and records for each effect the
held-out RMSE gain of knowing it: 1 - RMSE(all subtracted) / RMSE(all but this one subtracted). Readings of trials with balance sway or an outlier
step (both truth-file flags) are left out, as a diagnoser would reject them.

A payload in the hand is in the recorded joint torques, so the power regressors carry it; its
detectability is taken at the torque level instead (`grammar.Physics.payload_detectability`).
"""
import numpy as np


def readings_mask_and_folds(t, truth):
    """Per reading: kept (not in a contaminated/outlier trial) and its fold (trial index % 5)."""
    s0 = truth["session"]["start_ns"]
    starts = np.array([(tr["t_trial_start_ns"] - s0) / 1e9 for tr in truth["trials"]])
    bad = np.array([tr["contaminated"] or tr["outlier"] for tr in truth["trials"]])
    ti = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(starts) - 1)
    keep = ~bad[ti] & (t >= starts[0])
    return keep, ti % 5


RIDGE = 0.1


def cv_rmse(F49, y, folds, theta):
    """Held-out RMSE of y by intercept + θ·F49, θ shrunk toward `theta`, 5 folds."""
    r = y - F49 @ theta
    s = F49.std(0)
    s[s == 0] = 1.0
    X = np.column_stack([np.ones(len(y)), F49 / s])
    err = np.empty(len(y))
    for f in range(5):
        te = folds == f
        A = X[~te]
        R = RIDGE * len(A) * np.eye(A.shape[1])
        R[0, 0] = 0.0
        beta = np.linalg.solve(A.T @ A + R, A.T @ r[~te])
        err[te] = r[te] - X[te] @ beta
    return float(np.sqrt(np.mean(err * err)))


def detectability(table, truth, n_effects):
    """[gain per effect], base RMSE, effect RMS per reading [W] (de-meaned)."""
    t, y = table[:, 0], table[:, 1]
    keep, folds = readings_mask_and_folds(t, truth)
    t, y, F, folds = t[keep], y[keep], table[keep, 2:], folds[keep]
    theta = np.array(truth["theta"]["vector"], float)
    base = F[:, :49]
    E = F[:, 49:49 + n_effects]
    r_full = cv_rmse(base, y - E.sum(1), folds, theta)
    gains, rms = [], []
    for i in range(n_effects):
        r_wo = cv_rmse(base, y - E.sum(1) + E[:, i], folds, theta)
        gains.append(1.0 - r_full / r_wo)
        rms.append(float(np.std(E[:, i])))
    return gains, r_full, rms


# ---- the yardstick the data allow (net rows and rest rows, the rail's drift fitted) -------------
#
# The diagnoser never sees absolute power: it fits each reading of a trial's trajectory window net
# of the mean of the trial's pre-idle readings (its rest level), and it explains the trials' rest
# levels separately (the rest-power stage). And the rail drifts (indgen: OU σ 0.3 W, τ 300 s), so
# a slow change of the rest level is only evidence where a drift cannot make it. `detectability`
# measures that: the held-out RMSE gain of knowing the effect's true contribution beside a drift
# (a linear spline in session time, knots every KNOT_S) on
#   * net rows: each trajectory reading minus its trial's pre-idle mean, base = the 49 regressors
#     (also net, ridge toward θ as above) + the spline; folds by trial as above;
#   * rest rows: each trial's pre-idle mean, base = the spline; folds are contiguous blocks of
#     trials, as the rest-power stage's, since neighbouring trials share the drift;
# and takes the larger (the data allow finding it at either level). The other effects are taken off
# with their known contributions.

KNOT_S = 150.0  # the drift spline's knot spacing: half the rail drift's time constant


def drift_basis(t, t0, t1):
    """Hat functions (linear B-spline) in session time, knots every KNOT_S over [t0, t1]."""
    knots = np.linspace(t0, t1, max(2, int(np.ceil((t1 - t0) / KNOT_S)) + 1))
    eye = np.eye(len(knots))
    return np.column_stack([np.interp(t, knots, eye[k]) for k in range(len(knots))])


def net_and_rest_rows(table, truth, W=0.3):
    """(net, rest): net = (t, trial, [y, features...]) per trajectory reading minus its trial's
    pre-idle mean; rest = (t, trial, [y, features...]) per trial, the mean of the readings whose
    window [t - W, t] lies in its pre-idle. Trials with sway or an outlier step, or without a
    pre-idle reading, are left out."""
    t, V = table[:, 0], table[:, 1:]
    s0 = truth["session"]["start_ns"]
    sec = lambda k: np.array([(tr[k] - s0) / 1e9 for tr in truth["trials"]])
    a, b, c = sec("t_trial_start_ns"), sec("t_traj_start_ns"), sec("t_post_idle_end_ns")
    bad = np.array([tr["contaminated"] or tr["outlier"] for tr in truth["trials"]])
    ti = np.clip(np.searchsorted(a, t, side="right") - 1, 0, len(a) - 1)
    ok = ~bad[ti] & (t >= a[0])
    pre = ok & (t - W >= a[ti]) & (t <= b[ti])
    traj = ok & (t >= b[ti]) & (t <= c[ti])
    n = np.bincount(ti[pre], minlength=len(a))
    sums = np.stack([np.bincount(ti[pre], V[pre, k], len(a)) for k in range(V.shape[1])], 1)
    tsum = np.bincount(ti[pre], t[pre], len(a))
    has = n > 0
    rest = sums[has] / n[has, None]
    traj &= has[ti]
    lvl = np.zeros_like(sums)
    lvl[has] = rest
    net = V[traj] - lvl[ti[traj]]
    idx = np.flatnonzero(has)
    return (t[traj], ti[traj], net), (tsum[has] / n[has], idx, rest)


def _cv(X, y, folds, ridge_cols):
    """Held-out residuals of y on X, 5 folds; `ridge_cols` (bool per column) shrunk toward 0."""
    err = np.empty(len(y))
    for f in range(5):
        te = folds == f
        A = X[~te]
        R = np.diag(np.where(ridge_cols, RIDGE * len(A), 1e-9 * len(A)))
        beta = np.linalg.solve(A.T @ A + R, A.T @ y[~te])
        err[te] = y[te] - X[te] @ beta
    return float(np.sqrt(np.mean(err * err)))


def _gain(X, ridge_cols, y, e, folds):
    """1 - RMSE(y - e) / RMSE(y), each held out beside X: what knowing the effect (its true
    contribution e, coefficient known) adds to a model that has the drift. The coefficient is not
    refitted: a free one would let a slow state that follows the drift (the board temperature
    heats with the rail's power) be credited with the drift itself."""
    if len(y) < 10 or float(np.std(e)) < 1e-9 or len(np.unique(folds)) < 5:
        return 0.0
    base = _cv(X, y, folds, ridge_cols)
    return max(0.0, 1.0 - _cv(X, y - e, folds, ridge_cols) / base) if base > 0 else 0.0


def detectability_net(table, truth, n_effects, W=0.3, window_free=True):
    """[gain per effect] on the rows the diagnoser fits, the drift fitted: (net, rest, max).

    With `window_free`, an effect is credited only with what a sensor window estimated from the
    data cannot absorb: a main-board lag beside the window of the same centre read at no lag, a
    window drift beside the session's mean window (the table's last k columns, `Physics.table`).
    The part a window absorbs is taken off with the other effects. Without it (or for a table
    without those columns), the true window is known, as in the first yardstick."""
    k = n_effects
    q0 = _remainder_column(table, k)
    window_free = window_free and q0 is not None
    (tn, tin, N), (tr, tir, Rr) = net_and_rest_rows(table, truth, W)
    theta = np.array(truth["theta"]["vector"], float)
    t0, t1 = float(table[0, 0]), float(table[-1, 0])
    yn, Fn, En = N[:, 0] - N[:, 1:50] @ theta, N[:, 1:50], N[:, 50:50 + k]
    # the remainder a window cannot absorb (the contribution itself where nothing can)
    Qn = N[:, q0 - 1:q0 - 1 + k] if window_free else En
    sd = Fn.std(0)
    sd[sd == 0] = 1.0
    Xn = np.column_stack([drift_basis(tn, t0, t1), Fn / sd])
    rn = np.r_[np.zeros(Xn.shape[1] - 49, bool), np.ones(49, bool)]
    yr, Er = Rr[:, 0] - Rr[:, 1:50] @ theta, Rr[:, 50:50 + k]
    Qr = Rr[:, q0 - 1:q0 - 1 + k] if window_free else Er
    Xr = drift_basis(tr, t0, t1)
    block = max(4, min(20, len(yr) // 10))
    fr = (np.arange(len(yr)) // block) % 5
    out = []
    for i in range(n_effects):
        others = [j for j in range(n_effects) if j != i]
        # the data less the other effects and the part of this one a window absorbs
        y_n = yn - En[:, others].sum(1) - (En[:, i] - Qn[:, i])
        y_r = yr - Er[:, others].sum(1) - (Er[:, i] - Qr[:, i])
        g_net = _gain(Xn, rn, y_n, Qn[:, i], tin % 5)
        g_rest = _gain(Xr, np.zeros(Xr.shape[1], bool), y_r, Qr[:, i], fr)
        out.append((g_net, g_rest, max(g_net, g_rest)))
    return out


def _remainder_column(table, k):
    """The first window-free remainder column of a `Physics.table` (None for a bare
    [t, y, 49 regressors, k contributions] table, as the self-test builds)."""
    from .grammar import N_RIVAL_COLS
    return 51 + k + N_RIVAL_COLS if table.shape[1] == 51 + 2 * k + N_RIVAL_COLS else None


# ---- could another mechanism be it? --------------------------------------------------------------
#
# Detectability says the data see an effect; it does not say they can tell *which* mechanism it is.
# A gear friction k|τq̇| is k·τq̇ + 2k·max(−τq̇, 0): with each joint's efficiency refitted (the paper's
# a ≥ 1, the plant's a = 1) it *is* a braking asymmetry of 2k, whatever the diagnoser does — while a
# braking asymmetry is not a gear friction (that would need a < 1). `distinguishability` is the
# held-out gain of knowing a library effect's true contribution beside the base model (each joint's
# efficiency free to rise, as a refit under a ≥ 1 has it) and, in turn, each *other* library
# mechanism in its linear form (per joint where it is per joint, coefficients ≥ 0: a loss): the
# smallest over those rivals. Near 0, another mechanism fits the effect as well as its own — the
# most a diagnosis can then say is "X or Y".


def _bounded_cv(X, y, folds, ridge_cols, lower):
    """As `_cv`, the coefficients with `lower` (bool per column) held ≥ 0 (projected coordinate
    descent on the normal equations, from the unbounded solution clipped)."""
    err = np.empty(len(y))
    for f in range(5):
        te = folds == f
        A = X[~te]
        G = A.T @ A + np.diag(np.where(ridge_cols, RIDGE * len(A), 1e-9 * len(A)))
        h = A.T @ y[~te]
        b = np.linalg.solve(G, h)
        b[lower] = np.maximum(b[lower], 0.0)
        for _ in range(300):
            moved = 0.0
            for j in range(len(b)):
                bj = b[j] + (h[j] - G[j] @ b) / G[j, j]
                if lower[j]:
                    bj = max(bj, 0.0)
                moved = max(moved, abs(bj - b[j]) * np.sqrt(G[j, j]))
                b[j] = bj
            if moved < 1e-9 * np.sqrt(h @ h / len(A) + 1e-300):
                break
        err[te] = y[te] - X[te] @ b
    return float(np.sqrt(np.mean(err * err)))


def distinguishability(table, truth, n_effects, own, W=0.3):
    """Per effect: (smallest gain over the rivals, that rival) on net rows, for effects whose
    `own[i]` is a library mechanism of `grammar.RIVALS`; None for the others."""
    from .grammar import RIVALS
    k = n_effects
    q0 = _remainder_column(table, k)
    if q0 is None:
        return [None] * k
    (tn, tin, N), _ = net_and_rest_rows(table, truth, W)
    theta = np.array(truth["theta"]["vector"], float)
    t0, t1 = float(table[0, 0]), float(table[-1, 0])
    yn, Fn, En = N[:, 0] - N[:, 1:50] @ theta, N[:, 1:50], N[:, 50:50 + k]
    Qn = N[:, q0 - 1:q0 - 1 + k]
    cols, start = {}, 50 + k
    for m, n in RIVALS:
        cols[m] = N[:, start:start + n]
        start += n

    def scaled(X):
        sd = X.std(0)
        sd[sd == 0] = 1.0
        return X / sd

    D = drift_basis(tn, t0, t1)
    out = []
    for i in range(k):
        if own[i] not in cols:
            out.append(None)
            continue
        others = [j for j in range(k) if j != i]
        y = yn - En[:, others].sum(1) - (En[:, i] - Qn[:, i])
        best = (np.inf, None)
        for m, R in cols.items():
            if m == own[i] or float(np.abs(R).max(initial=0.0)) == 0.0:
                continue
            X = np.column_stack([D, scaled(Fn), scaled(R)])
            # the drift free; each joint's efficiency (the first 7 regressors) free to rise; the
            # other 42 shrunk toward θ as in `detectability_net`; the rival a loss (≥ 0)
            nd, nr = D.shape[1], R.shape[1]
            ridge = np.r_[np.zeros(nd + 7, bool), np.ones(42, bool), np.zeros(nr, bool)]
            lower = np.r_[np.zeros(nd, bool), np.ones(7, bool), np.zeros(42, bool), np.ones(nr, bool)]
            base = _bounded_cv(X, y, tin % 5, ridge, lower)
            g = max(0.0, 1.0 - _bounded_cv(X, y - Qn[:, i], tin % 5, ridge, lower) / base) if base > 0 else 0.0
            if g < best[0]:
                best = (g, m)
        out.append(best if best[1] is not None else None)
    return out
