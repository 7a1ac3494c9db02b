"""(θ, ẑ) datasets for the decoder: θ from a prior, ẑ from a frozen policy's adaptation
module in closed-loop flight under excitation (paper §IV-A: 20,000 training pairs).

Each vehicle flies ``steps`` control steps (default 1.5 s, so the 0.2 s history has long
filled) under the baseline cascade tracking a random 3-D lemniscate (period 5–15 s, size up to
1.5 × 1.5 × 0.3 m, yaw weave) with a random Gaussian world force (σ up to 0.1 m g per axis);
ẑ is read at the last step. Failed flights are kept but flagged (``failed``) and left out of
training by the decoder. Works with any low-level controller that has ``latent(carry)``.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid import distributed
from mjxsysid import params as P
from mjxsysid.analysis.flight import broadcast, make_low_level
from mjxsysid.analysis.harness import Disturbance, failure_mask, fly_batch
from mjxsysid.control.high_level import Cascade
from mjxsysid.control.references import Lemniscate
from mjxsysid.sim import Quadrotor


def random_lemniscates(key, n: int):
    """n random excitation references, stacked (leaves (n, ...))."""
    ks = jax.random.split(key, 4)
    u = lambda k, lo, hi, shape=(n,): jax.random.uniform(k, shape, jnp.float32, lo, hi)
    return Lemniscate(center=jnp.tile(jnp.array([0.0, 0.0, 1.0]), (n, 1)),
                      size=u(ks[0], 0.0, 1.0, (n, 3)) * jnp.array([1.5, 1.5, 0.3]),
                      period=u(ks[1], 5.0, 15.0), yaw=jnp.zeros(n),
                      yaw_amplitude=u(ks[2], -0.5, 0.5), duration=jnp.full((n,), jnp.inf))


def latents_in_flight(policy, theta, key, *, weights=None, steps: int = 750, sim=None):
    """Fly θ (n, 19) with a latent policy (a name, path or PolicyRef; see
    :func:`~mjxsysid.policy.interface.resolve_policy`) under excitation.
    Returns (ẑ at the last step (n, 8), failed (n,))."""
    from mjxsysid.policy.interface import resolve_policy
    theta = np.asarray(theta, np.float32)
    n = len(theta)
    sim = sim or Quadrotor()
    k_ref, k_force, k_fly = jax.random.split(key, 3)
    low = resolve_policy(policy, weights).batched(n)
    sigma = jax.random.uniform(k_force, (n, 1), minval=0.0, maxval=0.1) * theta[:, P.MASS, None] * P.GRAVITY
    dist = broadcast(Disturbance.make(), n).replace(sigma=jnp.broadcast_to(sigma, (n, 3)))
    fl = fly_batch(sim, theta, low, broadcast(Cascade.make("baseline"), n), random_lemniscates(k_ref, n),
                   dist, k_fly, steps)
    failed = np.asarray(jax.vmap(failure_mask)(fl))[:, -1]
    return np.asarray(fl.latent[:, -1]), failed


def collect(out, *, policy="mjxsysid", weights=None, n_train: int = 20_000,
            n_test: int = 2_000, prior: str | None = None, seed: int = 0, batch: int = 2_000,
            steps: int = 750, log=print) -> Path:
    """Write ``out/pairs.npz``: theta_train (n_train, 19), zhat_train (n_train, 8), failed_train,
    and the same for the held-out test split, plus metadata (policy weights hash, prior, seed).
    ``prior`` defaults to the policy's own training prior ('default' for mjxsysid's policy,
    'xadap' for the released one)."""
    from mjxsysid.policy.interface import resolve_policy
    if n_train < 1 or n_test < 1 or batch < 1:
        raise ValueError("n_train, n_test and batch must be >= 1")
    ref = resolve_policy(policy, weights)
    prior = prior or ref.prior
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    from mjxsysid.progress import tee
    log = tee(log, out / "collect_log.txt")
    total = n_train + n_test
    nb = -(-total // batch)
    theta = np.asarray(P.get_prior(prior).sample(jax.random.PRNGKey(seed), nb * batch))
    sim = Quadrotor()
    zs, fs = [], []
    t0 = time.time()
    from mjxsysid.progress import progress
    for i in progress(range(nb), desc="collect", unit="batch"):
        z, f = latents_in_flight(ref, theta[i * batch:(i + 1) * batch],
                                 jax.random.fold_in(jax.random.PRNGKey(seed + 1), i),
                                 steps=steps, sim=sim)
        zs.append(z)
        fs.append(f)
        done = (i + 1) * batch
        log(f"  {min(done, total)}/{total} vehicles, {done * steps / (time.time() - t0) / 1e6:.2f} M steps/s, "
            f"failed so far {int(np.sum(np.concatenate(fs)))}")
    z = np.concatenate(zs)[:total]
    f = np.concatenate(fs)[:total]
    theta = theta[:total]
    meta = {**ref.to_dict(), "prior": prior, "seed": seed, "steps": steps, "excitation": __doc__.split("\n\n")[1],
            "n_train": n_train, "n_test": n_test, "wall_s": time.time() - t0,
            "device": str(jax.devices()[0]), "devices": distributed.device_count()}
    path = out / "pairs.npz"
    np.savez_compressed(path, theta_train=theta[:n_train], zhat_train=z[:n_train], failed_train=f[:n_train],
                        theta_test=theta[n_train:], zhat_test=z[n_train:], failed_test=f[n_train:],
                        meta_json=np.frombuffer(json.dumps(meta).encode(), np.uint8))
    return path


def load_pairs(path) -> tuple[dict, dict]:
    """Read a pairs.npz -> (arrays dict, meta dict)."""
    path = Path(path)
    if path.is_dir():
        path = path / "pairs.npz"
    if not path.is_file():
        raise FileNotFoundError(f"dataset not found: {path}")
    from mjxsysid.policy.checkpoint import open_npz
    with open_npz(path, "pairs file") as f:
        need = {"theta_train", "zhat_train", "theta_test", "zhat_test"}
        missing = need - set(f.files)
        if missing:
            raise ValueError(f"{path}: missing arrays {sorted(missing)} (not a mjxsysid pairs file?)")
        arrays = {k: f[k] for k in f.files if k != "meta_json"}
        meta = json.loads(bytes(f["meta_json"]).decode()) if "meta_json" in f.files else {}
    for split in ("train", "test"):
        th, z = arrays[f"theta_{split}"], arrays[f"zhat_{split}"]
        if th.ndim != 2 or th.shape[1] != P.N_PARAMS or z.ndim != 2 or len(z) != len(th):
            raise ValueError(f"{path}: theta_{split} {th.shape} and zhat_{split} {z.shape} must be "
                             f"(n, {P.N_PARAMS}) and (n, latent)")
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: meta_json is not a JSON object")
    return arrays, meta
