"""Null-rate table of the calibration log (G1VIZ_P_LOG): per stage and λ, the share of logged
candidate p-values below 1e-2 … 1e-5. Usage: python3 calibration.py plog_*.txt"""
import sys,collections
rows=collections.defaultdict(list); mins=collections.defaultdict(list)
files=sys.argv[1:]
L=["0","1/8","1/4","3/8","1/2 (old)"]
for f in files:
    per=collections.defaultdict(lambda:[1.0]*5)
    for l in open(f):
        x=l.split(); st=x[0]; v=[float(t) for t in x[1:6]]; rows[st].append(v)
        per[st]=[min(a,b) for a,b in zip(per[st],v)]
    for st,v in per.items(): mins[st].append(v)
print(f"{len(files)} sessions")
print("| stage | λ | candidates | < 1e-2 | < 1e-3 | < 1e-4 | < 1e-5 | smallest | sessions with min < 1e-4 |")
print("|---|---|---|---|---|---|---|---|---|")
for st in sorted(rows):
    v=rows[st]; n=len(v)
    for i,l in enumerate(L):
        r=lambda a: f"{sum(1 for x in v if x[i]<a)/n*100:.2f} %"
        print(f"| {st} | {l} | {n} | {r(1e-2)} | {r(1e-3)} | {r(1e-4)} | {r(1e-5)} | {min(x[i] for x in v):.1e} | {sum(1 for m in mins[st] if m[i]<1e-4)}/{len(mins[st])} |")
