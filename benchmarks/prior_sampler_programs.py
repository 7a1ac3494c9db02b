"""What one compiled prior sampler for every draw of 2 to 4,096 vehicles saves: a fresh process per way.

    python benchmarks/prior_sampler_programs.py [--sizes 2,12,13,16,64,100,200,1000,2000] [--optimised]

Each way draws the default prior and two held-out families at every size (the sizes of the project's
commands and tests), in a fresh process with an empty compilation cache, and reports its wall and CPU
seconds and the programs compiled. ``bucketed``: ``Prior.sample`` (one program per prior up to 4,096
vehicles, ``theta.priors.sample_bucket``); ``per size``: the sampler compiled for each n (as before).
The draws of the two ways are compared (to the last bit's rounding). By default XLA's optimisations are
off, as the test tier compiles; ``--optimised``: as users' commands compile.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

CHILD = r"""
import json, os, resource, sys, time
import jax
jax.config.update("jax_disable_most_optimizations", os.environ["OPT_OFF"] == "1")
import numpy as np
from mjxsysid import theta as P
from mjxsysid.theta.priors import _sampled
sizes = [int(s) for s in os.environ["SIZES"].split(",")]
priors = [P.DEFAULT_PRIOR, P.HELDOUT_FAMILIES["weak_motor"], P.HELDOUT_FAMILIES["slow_motors"]]
draw = (lambda p, k, n: p.sample(k, n)) if os.environ["WAY"] == "bucketed" else (lambda p, k, n: _sampled(p, k, n))
t, c = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF).ru_utime
out = {f"{p.name}/{n}": np.asarray(draw(p, jax.random.PRNGKey(n), n)).tolist() for p in priors for n in sizes}
print("RESULT " + json.dumps({"wall_s": time.perf_counter() - t, "cpu_s": resource.getrusage(resource.RUSAGE_SELF).ru_utime - c,
                              "programs": _sampled._cache_size(), "draws": out}))
"""


def run(way: str, sizes: str, opt_off: bool) -> dict:
    env = dict(os.environ, WAY=way, SIZES=sizes, OPT_OFF="1" if opt_off else "0", JAX_PLATFORMS="cpu",
               MJXSYSID_JAX_CACHE="0")
    with tempfile.TemporaryDirectory() as tmp:
        r = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, cwd=tmp, check=False)
    line = [x for x in r.stdout.splitlines() if x.startswith("RESULT ")]
    if r.returncode or not line:
        raise SystemExit(f"{way} failed:\n{r.stderr[-2000:]}")
    return json.loads(line[-1][7:])


def main(argv=None) -> None:
    import numpy as np
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="2,12,13,16,64,100,200,1000,2000")
    ap.add_argument("--optimised", action="store_true", help="XLA's optimisations on (as users' commands compile)")
    ap.add_argument("--out", default=None, help="write the result as JSON here")
    a = ap.parse_args(argv)
    res = {way: run(way, a.sizes, not a.optimised) for way in ("per size", "bucketed")}
    d0, d1 = res["per size"].pop("draws"), res["bucketed"].pop("draws")
    worst = max(float(np.max(np.abs(np.array(d0[k]) - np.array(d1[k])) / np.maximum(np.abs(np.array(d0[k])), 1e-30)))
                for k in d0)
    res["draws_max_relative_difference"] = worst
    res["sizes"], res["optimised"] = a.sizes, a.optimised
    for way in ("per size", "bucketed"):
        r = res[way]
        print(f"{way:9s}: {r['programs']:2d} programs, {r['wall_s']:5.1f} s wall, {r['cpu_s']:5.1f} s CPU")
    print(f"draws: largest relative difference {worst:.1e}")
    if a.out:
        with open(a.out, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
