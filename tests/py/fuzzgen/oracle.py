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
