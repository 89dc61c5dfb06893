import sys, json, os
sys.path.insert(0, "/work/wt/diag20/docs/campaign/paired-diag18")
import paired
from multiprocessing import Pool
seeds=[int(x) for x in sys.argv[1].split(',')]
bins=dict(x.split("=",1) for x in sys.argv[3:])
out=sys.argv[2]; os.makedirs(out, exist_ok=True); os.makedirs(out+"/work", exist_ok=True)
with Pool(2) as p:
    for r in p.imap_unordered(paired.one, [(s, 15.0, out+"/work", bins) for s in seeds]):
        for name, rec in r.items():
            open(f"{out}/{name}.jsonl","a").write(json.dumps(rec)+"\n")
        print(" || ".join(f"{n}: {rec.get('seed')} " + (rec.get('error','')[:80] or ", ".join(f"{c['id'] or c['name'][:50]}={c['result']}" for c in rec['claims']) or 'none') + " eff=" + ",".join(f"{e['mechanism']}/{e['form']}:{e['detectability']:.2f}:{e['result']}" for e in rec.get('effects',[])) for n, rec in r.items()), flush=True)
