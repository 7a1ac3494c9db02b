"""Weak-system files (``weak.npz``): physical systems a probe found the policy weak on, which
training can mix into its vehicles (``TrainConfig.focus``, ``mjxsysid train-policy --focus``).

Format: an ``.npz`` with ``theta`` (n, 19) float32, physical θ (each a valid vehicle), and
optional ``zhat`` (n, 8) — the latents they were decoded from — plus ``meta_json`` (a JSON
string: what found them). No pickle.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid import theta as P


def save_weak(path, theta, zhat=None, meta: dict | None = None) -> Path:
    """Write weak systems θ (n, 19) (validated) [and the latents (n, 8)] to ``path``."""
    theta = _check_theta(np.asarray(theta, np.float32), str(path))
    arrays = {"theta": theta, "meta_json": np.asarray(jsonout.dumps(meta or {}))}
    if zhat is not None:
        zhat = np.asarray(zhat, np.float32)
        if zhat.shape != (len(theta), zhat.shape[-1]) or zhat.ndim != 2:
            raise ValueError(f"{path}: zhat must have shape ({len(theta)}, z_dim); got {zhat.shape}")
        arrays["zhat"] = zhat
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **arrays)
    return path


def load_weak(path) -> tuple[np.ndarray, dict]:
    """θ (n, 19) float32 and meta of a weak-system file; every problem is a ValueError naming it."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"weak-system file not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            if "theta" not in z.files:
                raise ValueError(f"{path}: no 'theta' array (a weak-system file from `mjxsysid probe`?)")
            theta = np.asarray(z["theta"], np.float32)
            meta = json.loads(str(z["meta_json"])) if "meta_json" in z.files else {}
    except (OSError, EOFError) as e:
        raise ValueError(f"{path}: not a readable .npz ({e})") from None
    return _check_theta(theta, str(path)), meta


def _check_theta(theta: np.ndarray, what: str) -> np.ndarray:
    if theta.ndim != 2 or theta.shape[1] != P.N_PARAMS:
        raise ValueError(f"{what}: theta must have shape (n, {P.N_PARAMS}); got {theta.shape}")
    if len(theta) == 0:
        raise ValueError(f"{what}: no weak systems (theta is empty)")
    return np.asarray(P.validate_theta(theta, what=f"{what}: theta"), np.float32)


def replay_resample(theta, weights, n: int, seed: int = 0) -> np.ndarray:
    """A replay buffer's systems θ (m, 19) drawn n times with replacement, each with probability
    ∝ its weight (m,) (e.g. how badly the current policy flies it) -> θ (n, 19), what a focus file
    holds (training draws its systems uniformly). Weights must be finite, ≥ 0 and not all 0."""
    theta = _check_theta(np.asarray(theta, np.float32), "replay buffer")
    w = np.asarray(weights, np.float64)
    if w.shape != (len(theta),):
        raise ValueError(f"replay weights must have shape ({len(theta)},) (one per system); got {w.shape}")
    if not np.isfinite(w).all() or (w < 0).any() or not w.sum() > 0:
        raise ValueError("replay weights must be finite, >= 0 and not all 0")
    if not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n (replay draws) must be a positive integer, got {n!r}")
    idx = np.random.default_rng(seed).choice(len(theta), size=int(n), p=w / w.sum())
    return theta[idx]
