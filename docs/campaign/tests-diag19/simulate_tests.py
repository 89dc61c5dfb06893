"""Null calibration and power of four ways to test a candidate that extends a model, in the
abstraction of ../paired-diag18/simulate_null.py: trial t's score for the candidate's q columns
(residualised on the model) is g_t ~ N(b, I_q), independent across trials; a fit on a set of
trials estimates the coefficient by the mean of their scores.
  enc0   : 10 folds by trial, per-trial evidence β_fold(t)·g_t (λ = 0), one-sided t test
  enc1/4 : the same minus ¼|β|² (λ = ¼, the shipped test)
  xfit   : 2-fold cross-fit: half A's trials scored with half B's fit and vice versa (λ = 0);
           per half the one-sided t statistic (exactly t under the null given the other half),
           S = z_A + z_B, p from S's null law (q = 1: ½[1 − (1 − 2Φ̄(S/√2))²]; q > 1: the law of
           u_A·û_B + u_B·û_A, u ~ N(0, I_q), by Monte Carlo)
  score  : cluster-robust score test: Hotelling T² of the per-trial scores (q = 1: two-sided t)
Usage: python3 simulate_tests.py [N]   (seeded; prints rate/level at 1e-2, 1e-3, 1e-4 and power)."""
import sys
from math import erfc, exp, lgamma, log, sqrt

import numpy as np

rng = np.random.default_rng(19)
N = int(sys.argv[1]) if len(sys.argv) > 1 else 100000


def betacf(a, b, x):
    qab, qap, qam = a + b, a + 1, a - 1
    c, d = 1.0, 1 - qab * x / qap
    d = 1 / d if abs(d) > 1e-300 else 1e300
    h = d
    for m in range(1, 300):
        m2 = 2 * m
        for aa in (m * (b - m) * x / ((qam + m2) * (a + m2)), -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))):
            d = 1 + aa * d
            d = 1 / d if abs(d) > 1e-300 else 1e300
            c = 1 + aa / c if abs(c) > 1e-300 else 1e300
            h *= d * c
    return h


def ibeta(a, b, x):
    if x <= 0:
        return 0.0
    if x >= 1:
        return 1.0
    front = exp(lgamma(a + b) - lgamma(a) - lgamma(b) + a * log(x) + b * log(1 - x))
    return front * betacf(a, b, x) / a if x < (a + 1) / (a + b + 2) else 1 - front * betacf(b, a, 1 - x) / b


def t_sf(t, df):
    half = 0.5 * ibeta(0.5 * df, 0.5, df / (df + t * t))
    return half if t >= 0 else 1 - half


def f_sf(f, d1, d2):
    return ibeta(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * f)) if f > 0 else 1.0


def norm_sf(z):
    return 0.5 * erfc(z / sqrt(2))


def norm_isf(p):  # bisection is enough here
    lo, hi = -40.0, 40.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if norm_sf(mid) > p else (lo, mid)
    return 0.5 * (lo + hi)


def xfit_law(q, m=2_000_000):
    """Sorted null draws of S for q columns (ideal law)."""
    ua, ub = rng.standard_normal((2, m, q))
    na, nb = np.linalg.norm(ua, axis=1), np.linalg.norm(ub, axis=1)
    dot = (ua * ub).sum(1)
    return np.sort(dot / nb + dot / na)


def tstat(e):
    n = e.shape[1]
    return e.mean(1) / (e.std(1, ddof=1) / sqrt(n))


def run(n, q, b, M, K=10):
    f = np.arange(n) % K
    half = f % 2
    g = rng.standard_normal((M, n, q)) + b
    tot = g.sum(1, keepdims=True)
    G = np.stack([g[:, f == k].sum(1) for k in range(K)], 1)
    W = np.array([(f != k).sum() for k in range(K)])[None, :, None]
    B = ((tot - G) / W)[:, f, :]
    s, qq = (B * g).sum(2), (B * B).sum(2)
    out = {}
    for name, lam in (("enc0", 0.0), ("enc1/4", 0.25)):
        t = tstat(s - lam * qq)
        out[name] = np.array([t_sf(x, n - 1) for x in t])
    z = []
    for h in (0, 1):
        beta_other = g[:, half != h].mean(1)  # (M, q)
        e = (g[:, half == h] * beta_other[:, None, :]).sum(2)
        nh = e.shape[1]
        z.append(np.array([-norm_isf(t_sf(x, nh - 1)) * -1 for x in tstat(e)]))
    S = z[0] + z[1]
    if q == 1:
        out["xfit"] = np.array([0.5 * (1 - (1 - 2 * norm_sf(x / sqrt(2))) ** 2) if x > 0
                                else 1 - 0.5 * (1 - (1 - 2 * norm_sf(-x / sqrt(2))) ** 2) for x in S])
    else:
        law = LAW[q]
        out["xfit"] = 1 - np.searchsorted(law, S) / len(law)
    mean = g.mean(1)
    C = np.einsum("mni,mnj->mij", g - mean[:, None, :], g - mean[:, None, :]) / (n - 1)
    T2 = n * np.einsum("mi,mij,mj->m", mean, np.linalg.inv(C), mean)
    out["score"] = np.array([f_sf(x * (n - q) / (q * (n - 1)), q, n - q) for x in T2])
    return out


LAW = {q: xfit_law(q) for q in (2, 7)}
for q in (1, 2, 7):
    r = run(55, q, 0.0, N)
    print(f"null q={q} n=55 N={N}: rate/level at 1e-2, 1e-3, 1e-4 |",
          "; ".join(f"{k} " + " ".join(f"{(v < a).mean() / a:.2f}" for a in (1e-2, 1e-3, 1e-4)) for k, v in r.items()))
for q, b in ((1, 0.45), (1, 0.6), (2, 0.45), (7, 0.3)):
    r = run(55, q, b / sqrt(q), 20000)
    print(f"alt q={q} |b|={b}: median log10 p, share < 1e-5 |",
          "; ".join(f"{k} {np.log10(np.median(v)):.2f} {(v < 1e-5).mean():.3f}" for k, v in r.items()))
