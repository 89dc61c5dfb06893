import glob, sys, collections
import numpy as np
files = sys.argv[1:]
rows = []
for f in files:
    for l in open(f):
        a = l.split()
        rows.append((int(a[1]), float(a[2]), float(a[3]), float(a[4])))
r = np.array(rows)
print(f"{len(files)} sessions, {len(r)} discovery candidates")
for qsel, name in ((None, "all"), (1, "q=1"), (2, "q=2"), (3, "q>=3")):
    m = np.ones(len(r), bool) if qsel is None else (r[:, 0] == qsel if qsel < 3 else r[:, 0] >= 3)
    if not m.any(): continue
    out = [f"{name} n={m.sum()}"]
    for k, lab in ((1, "score"), (2, "λ0"), (3, "λ¼")):
        out.append(lab + " " + " ".join(f"{(r[m, k] < a).mean() / a:.2f}" for a in (1e-2, 1e-3, 1e-4)) + f" min {r[m, k].min():.1e}")
    print(" | ".join(out))
