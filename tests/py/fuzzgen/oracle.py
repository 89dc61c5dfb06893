"""The oracle: how detectable each concealed effect is in a session's readings.

It knows the truth: per MBS reading it has the paper's 49 regressors (window-averaged true
states) and each effect's true contribution. It fits the readings by least squares (numpy) with
an intercept and the 49 regressors (the base model refitted, as the diagnoser does), 5-fold
cross-validated by trial, after subtracting the effects' true contributions (their coefficient is
known, so a slow effect cannot soak up the rest-power drift), and records for each effect the
held-out RMSE gain of knowing it: 1 - RMSE(all subtracted) / RMSE(all but this one subtracted). Readings of trials with balance sway or an outlier
step (both truth-file flags) are left out, as a diagnoser would reject them.
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


def cv_rmse(X, y, folds):
    err = np.empty(len(y))
    for f in range(5):
        te = folds == f
        tr = ~te
        beta, *_ = np.linalg.lstsq(X[tr], y[tr], rcond=None)
        err[te] = y[te] - X[te] @ beta
    return float(np.sqrt(np.mean(err * err)))


def detectability(table, truth, n_effects):
    """[gain per effect], base RMSE, effect RMS per reading [W] (de-meaned)."""
    t, y = table[:, 0], table[:, 1]
    keep, folds = readings_mask_and_folds(t, truth)
    t, y, F, folds = t[keep], y[keep], table[keep, 2:], folds[keep]
    base = np.column_stack([np.ones(len(y)), F[:, :49]])
    E = F[:, 49:49 + n_effects]
    r_full = cv_rmse(base, y - E.sum(1), folds)
    gains, rms = [], []
    for i in range(n_effects):
        r_wo = cv_rmse(base, y - E.sum(1) + E[:, i], folds)
        gains.append(1.0 - r_full / r_wo)
        rms.append(float(np.std(E[:, i])))
    return gains, r_full, rms
