"""The adaptive policy's weight files (``policy.npz``, the shipped format of
:mod:`mjxsysid.runtime.checkpoint`): the deployable modules μ, φ, π and the auxiliary decoder, with the
training run's metadata (config, θ normaliser, final statistics) beside them.
"""
from __future__ import annotations

from pathlib import Path

import jax
import numpy as np

from mjxsysid.runtime.checkpoint import load_meta, load_tree, save_tree
from mjxsysid.policy.adaptive import networks as N

PRETRAINED_DIR = Path(__file__).resolve().parents[2] / "pretrained"
"""The shipped weights: the policy's ``policy.npz`` and its decoders (the released XAdap policy's in
``xadap/``)."""
POLICY_MODULES = ("mu", "phi", "pi", "aux")
"""The parameter groups a policy file holds (the critic ``v`` stays with training)."""


def save_policy_params(params, path, meta: dict) -> Path:
    """Ship the deployable part (μ, φ, π, aux decoder) of ``params`` with its metadata."""
    return save_tree(path, {k: params[k] for k in POLICY_MODULES}, meta)


def load_policy_params(path):
    """Read shipped policy weights -> (params dict {'mu','phi','pi','aux'}, meta)."""
    template = jax.eval_shape(lambda: N.Networks().init(jax.random.PRNGKey(0)))   # shapes only
    params = load_tree(path, {k: template[k] for k in POLICY_MODULES}, finite=True)
    return params, load_meta(path)


def same_normalizer(a: dict, b: dict) -> bool:
    """Two normalisers' dicts (:meth:`mjxsysid.theta.Normalizer.to_dict`: lists of numbers) alike:
    the same keys and shapes, numbers equal to float32 rounding (a normaliser fitted on another
    device or with other XLA optimisations differs in the last bits of its reductions)."""
    if set(a) != set(b):
        return False
    for k in a:
        x, y = np.asarray(a[k], np.float64), np.asarray(b[k], np.float64)
        if x.shape != y.shape or not np.allclose(x, y, rtol=1e-5, atol=1e-6):
            return False
    return True

