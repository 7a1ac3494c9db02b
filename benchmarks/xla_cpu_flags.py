"""What XLA:CPU flags do to compile time, run time and results: one fresh process per flag set.

    python benchmarks/xla_cpu_flags.py                 # the default flags against mjxsysid.runtime.xla_flags'
    python benchmarks/xla_cpu_flags.py --repeat 3 --optimised

Each process, with an empty persistent cache, flies the oracle and the shipped policy on the paper
vehicle (2 vehicles, 2 s lemniscate: compiled, then run again from the in-memory cache) and
decodes the policy flight's last latent with the shipped decoder; it reports its CPU seconds, each
first (compile + run) and second (run) call, and the results (position RMSE, decoded mean) so that
a flag that changes what is computed shows. ``--optimised``: XLA's optimisations on (as users'
commands compile); by default off, as the test tier compiles.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

CHILD = r"""
import json, os, resource, time
import jax
jax.config.update("jax_disable_most_optimizations", os.environ["OPT_OFF"] == "1")
import numpy as np
from mjxsysid import theta as P
from mjxsysid.rollout.flight import fly_vehicles
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.cfm.sample import Decoder

out = {}
theta = np.stack([P.PAPER_HARDWARE] * 2)
policy = resolve_policy("mjxsysid")
for ctrl in ("oracle", "policy"):
    for k in ("first", "second"):
        t = time.perf_counter()
        fl, m, _ = fly_vehicles(theta, controller=ctrl, policy=policy if ctrl == "policy" else None,
                                reference="lemniscate", period=10.0, duration=2.0)
        out[f"{ctrl}_{k}_s"] = time.perf_counter() - t
    out[f"{ctrl}_rmse"] = float(np.asarray(m["pos_rmse_m"])[0])
dec = Decoder.load(policy.decoders_dir / "cfm.npz")
z = np.asarray(fl.latent)[:, -1]
for k in ("first", "second"):
    t = time.perf_counter()
    s = np.asarray(dec.sample_theta(z, jax.random.PRNGKey(0), 200))
    out[f"decode_{k}_s"] = time.perf_counter() - t
out["decoded_mean_mass"] = float(s[..., P.MASS].mean())
out["cpu_s"] = resource.getrusage(resource.RUSAGE_SELF).ru_utime
print("RESULT " + json.dumps(out))
"""


def run(flags: str, opt_off: bool) -> dict:
    env = dict(os.environ, XLA_FLAGS=flags, OPT_OFF="1" if opt_off else "0", JAX_PLATFORMS="cpu",
               JAX_COMPILATION_CACHE_DIR="", MJXSYSID_JAX_CACHE="0")
    with tempfile.TemporaryDirectory() as tmp:
        r = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, cwd=tmp, check=False)
    line = [x for x in r.stdout.splitlines() if x.startswith("RESULT ")]
    if r.returncode or not line:
        raise SystemExit(f"flags {flags!r} failed:\n{r.stderr[-2000:]}")
    return json.loads(line[0][7:])


def main() -> None:
    from mjxsysid.runtime.xla_flags import with_fast_cpu_compile
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2, help="processes per flag set (alternating)")
    ap.add_argument("--optimised", action="store_true", help="XLA's optimisations on (users' default)")
    ap.add_argument("--flags", nargs="*", default=None, help="flag sets to compare (default: '' and mjxsysid's)")
    a = ap.parse_args()
    sets = a.flags if a.flags is not None else ["", with_fast_cpu_compile("")]
    rows = {f: [] for f in sets}
    for _ in range(a.repeat):
        for f in sets:
            rows[f].append(run(f, not a.optimised))
    keys = ["cpu_s", "oracle_first_s", "oracle_second_s", "policy_first_s", "policy_second_s",
            "decode_first_s", "decode_second_s", "oracle_rmse", "policy_rmse", "decoded_mean_mass"]
    print(f"XLA optimisations {'on' if a.optimised else 'off'}; median of {a.repeat} processes")
    print("| flags | " + " | ".join(keys) + " |")
    print("|---" * (len(keys) + 1) + "|")
    for f, rs in rows.items():
        med = {k: sorted(r[k] for r in rs)[len(rs) // 2] for k in keys}
        print(f"| `{f or '(none)'}` | " + " | ".join(
            f"{med[k]:.6g}" if "rmse" in k or "mean" in k else f"{med[k]:.2f}" for k in keys) + " |")


if __name__ == "__main__":
    main()
