import numpy as np
from math import erfc, sqrt
rng=np.random.default_rng(7)
def sf(t): return 0.5*np.vectorize(erfc)(t/np.sqrt(2))
def run(lams,n=55,K=10,N=100000,p=1,b=0.0):
    f=np.arange(n)%K
    res={l:[] for l in lams}
    for chunk in range(N//25000):
        M=25000
        g=rng.standard_normal((M,n,p))+b   # per-trial score; true effect adds b (w_t=1)
        G=np.stack([g[:,f==k].sum(1) for k in range(K)],1)
        tot=G.sum(1,keepdims=True)
        W=np.array([(f!=k).sum() for k in range(K)])[None,:,None]
        beta=(tot-G)/W
        B=beta[:,f,:]
        S=(B*g).sum(2); Q=(B*B).sum(2)
        for l in lams:
            E=S-l*Q; m=E.mean(1); s=E.std(1,ddof=1)
            res[l].append(sf(m/(s/np.sqrt(n))))
    return {l:np.concatenate(v) for l,v in res.items()}
L=[0,0.25,0.375,0.5]
for p in (1,7):
    r=run(L,p=p)
    print("null p=%d"%p, {l:[round((v<a).mean()/a,2) for a in (1e-2,1e-3,1e-4)] for l,v in r.items()})
for b in (0.3,0.45):
    r=run(L,p=1,b=b,N=25000)
    print("alt b=%.2f"%b, {l:[round(float(np.median(v)),8), round(float((v<1e-5).mean()),3)] for l,v in r.items()})
