"""Latency of the exported policy step (``mjxsysid export``) in onnxruntime on the CPU.

Exports the shipped policy into a temporary folder (or ``--out``), flies the paper vehicle to
record inputs, then times ``session.run`` per 500 Hz step (median over ``--calls`` calls after a
warm-up) at batch 1 (the fixed file) and at the ``--batch`` sizes (the dynamic file): plain
steps, steps with the ẑ refresh (φ), and the mean over one refresh cycle (9 plain + 1 refresh).
For comparison, the same step as a jitted JAX function on the same CPU (batch 1).

    python benchmarks/export_latency.py --batch 64 --calls 5000 --threads 1

Prints one JSON line per configuration and a Markdown table.
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, nargs="+", default=[64])
    ap.add_argument("--calls", type=int, default=5000)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seconds", type=float, default=0.5, help="recorded flight (s)")
    ap.add_argument("--out", type=Path, default=None, help="NAME.onnx to write (default: a temporary folder)")
    args = ap.parse_args()

    import jax
    import jax.numpy as jnp

    from mjxsysid.policy.export import graph as G
    from mjxsysid.policy.export import run as E
    from mjxsysid.policy.interface import resolve_policy

    ref = resolve_policy("mjxsysid")
    out = args.out or Path(tempfile.mkdtemp()) / "policy.onnx"
    cfg = E.ExportConfig(flight_seconds=args.seconds, latency_calls=args.calls, threads=args.threads)
    rec = E.record_flight(ref, cfg)
    desc = E.run_export(ref, out, cfg, log=lambda m: None, rec=rec)
    import os
    print(f"parity max abs diff {desc['parity']['max_abs_diff']:.2e}; {desc['latency']['runtime']}; "
          f"{desc['latency']['machine']}; load average {os.getloadavg()[0]:.1f}")
    rows = [("onnxruntime, fixed file", desc["latency"]["batch_1"])]
    paths = E.paths_for(out)
    phi_every = desc["phi_every"]
    dyn = E.session(paths["dynamic"], args.threads)
    for b in [1, *args.batch]:
        rows.append(("onnxruntime, dynamic file", E.step_latency(dyn, rec, b, args.calls, phi_every)))

    # the same step in JAX (jit, CPU), batch 1
    params = ref.load().params
    step = jax.jit(lambda *a: G.policy_step(params, *a))
    f = E.feeds(rec, np.flatnonzero(~rec.refresh & ~rec.reset)[:1], refresh=False)
    jx = {}
    for name, refresh in (("step_us", False), ("refresh_step_us", True)):
        a = [jnp.asarray(v) for v in (f | {"refresh": np.array(refresh)}).values()]
        jax.block_until_ready(step(*a))
        ts = []
        for _ in range(args.calls):
            t0 = time.perf_counter_ns()
            jax.block_until_ready(step(*a))
            ts.append(time.perf_counter_ns() - t0)
        jx[name] = {"median_us": round(float(np.median(ts)) / 1e3, 2)}
    jx["batch"] = 1
    jx["mean_per_step_us"] = round(((phi_every - 1) * jx["step_us"]["median_us"]
                                    + jx["refresh_step_us"]["median_us"]) / phi_every, 2)
    rows.append((f"JAX {jax.__version__} jit (reference)", jx))

    print("\n| runtime | batch | step (µs, median) | step with ẑ refresh (µs) | mean per 500 Hz step (µs) |")
    print("|---|---|---|---|---|")
    for name, r in rows:
        print(f"| {name} | {r['batch']} | {r['step_us']['median_us']:.1f} | {r['refresh_step_us']['median_us']:.1f} "
              f"| {r['mean_per_step_us']:.1f} |")
    for name, r in rows:
        print(json.dumps({"runtime": name, **r}))


if __name__ == "__main__":
    main()
