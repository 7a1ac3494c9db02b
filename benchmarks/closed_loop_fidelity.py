"""Closed-loop fidelity of decoded models (issue 5 item 4) on a few vehicles, CPU-sized:
hover, constant [1, 1, 0] N force from 0.5 s, 4 s; 16 decoded models vs 16 ±20 % perturbations.

    python benchmarks/closed_loop_fidelity.py
"""
import json, time, jax, numpy as np
from mjxsysid import params as P
from mjxsysid.analysis.fidelity import closed_loop_fidelity
th = np.concatenate([P.PAPER_HARDWARE[None], np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(7), 3))])
t=time.time()
r = closed_loop_fidelity(th, n_models=16, reference="hover", duration=4.0, force_step=(1.0, 1.0, 0.0))
print(json.dumps(r["mean"]), time.time()-t)
for o in r["per_vehicle"]: print({k: round(v,3) for k,v in o.items()})
