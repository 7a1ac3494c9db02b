"""CFM decoder speed: sampling latency (50 Euler steps) for 100 / 1,000 / 10,000 samples of one
latent, and training steps/s at batch 256, with the shipped (paper-size, 5.2 M parameter) model.

    python benchmarks/cfm_benchmark.py [--train-steps 50]
"""
import argparse
import json
import time

import jax
import numpy as np


def best(fn, repeats=5):
    jax.block_until_ready(fn())
    t = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        t.append(time.perf_counter() - t0)
    return min(t)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--train-steps", type=int, default=50)
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 10000])
    args = ap.parse_args()
    from mjxsysid.policy.interface import PRETRAINED_DIR
    from mjxsysid.cfm.sample import Decoder, sample
    from mjxsysid.cfm.train import CFMConfig, train_cfm
    dec = Decoder.load(PRETRAINED_DIR / "cfm.npz")
    z = np.zeros((1, 8), np.float32)
    dev = str(jax.devices()[0].device_kind if hasattr(jax.devices()[0], "device_kind") else jax.devices()[0])
    for n in args.sizes:
        s = best(lambda: sample(dec.params, dec.cfg, z, jax.random.PRNGKey(0), n, 50, "euler"))
        print(json.dumps({"what": "sample", "samples": n, "euler_steps": 50, "seconds": s, "device": dev}))
    if args.train_steps:
        rng = np.random.default_rng(0)
        n = 256 * args.train_steps
        cfg = CFMConfig(epochs=2)
        _, hist = train_cfm(rng.normal(size=(n, 19)).astype(np.float32), rng.normal(size=(n, 8)).astype(np.float32) * 0.1,
                            cfg, log=None)
        print(json.dumps({"what": "train", "batch": 256, "steps_per_s": hist["steps_per_s"][-1], "device": dev}))


if __name__ == "__main__":
    main()
