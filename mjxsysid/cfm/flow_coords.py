"""The coordinates a decoder's flow learns in: a normaliser with an optional linear map on top.

A decoder samples v = y @ flow_map + flow_offset, y the normalised θ
([Normalizer][mjxsysid.theta.normalize.Normalizer]); ``"theta"`` coordinates learn y itself,
``"identifiable"`` coordinates put log thrust-to-weight and the log angular authorities on their
own axes ([identifiable_flow_map][mjxsysid.cfm.flow_coords.identifiable_flow_map]).
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.theta import ARM, ETA, INERTIA, KT, MASS, N_PARAMS, OMEGA_MAX, SizeFactorPrior
from mjxsysid.theta.normalize import Normalizer, prior_samples_for_normalizer

DECODER_COORDS = ("theta", "identifiable")
"""Coordinates a decoder can learn in: the normalised θ entries, or a log-linear
reparametrisation whose axes are the identifiable combinations
([identifiable_flow_map][mjxsysid.cfm.flow_coords.identifiable_flow_map])."""


@jax.tree_util.register_pytree_node_class
@dataclasses.dataclass(frozen=True)
class FlowNormalizer(Normalizer):
    """A [Normalizer][mjxsysid.theta.normalize.Normalizer] with the decoder's flow coordinates.

    ``flow_map`` (19, 19) and ``flow_offset`` (19,), optional: v = y @ flow_map + flow_offset
    ([to_flow][mjxsysid.cfm.flow_coords.FlowNormalizer.to_flow],
    [from_flow][mjxsysid.cfm.flow_coords.FlowNormalizer.from_flow]); None: v = y. ``normalize`` /
    ``denormalize`` never apply it: decoders return samples in the standard y space whatever
    their flow coordinates."""
    flow_map: jax.Array | None = None
    flow_offset: jax.Array | None = None

    def tree_flatten(self):
        return (self.shift, self.scale, self.flow_map, self.flow_offset), None

    @classmethod
    def of(cls, norm):
        """A plain [Normalizer][mjxsysid.theta.normalize.Normalizer] as a FlowNormalizer without a
        flow map; anything else (a FlowNormalizer, None) as it is."""
        if not isinstance(norm, Normalizer) or isinstance(norm, cls):
            return norm
        return cls(norm.shift, norm.scale)

    @jax.jit
    def to_flow(self, y):
        """Normalised y (..., 19) -> the decoder's flow coordinates v (..., 19)."""
        if self.flow_map is None:
            return jnp.asarray(y)
        return jnp.asarray(y) @ self.flow_map + self.flow_offset

    @jax.jit
    def from_flow(self, v):
        """Flow coordinates v (..., 19) -> normalised y (..., 19) (exact inverse of ``to_flow``)."""
        if self.flow_map is None:
            return jnp.asarray(v)
        return jnp.linalg.solve(self.flow_map.T, (jnp.asarray(v) - self.flow_offset)[..., None])[..., 0]

    def with_flow(self, flow_map, flow_offset) -> FlowNormalizer:
        return FlowNormalizer(self.shift, self.scale, jnp.asarray(flow_map, jnp.float32),
                              jnp.asarray(flow_offset, jnp.float32))

    def to_dict(self) -> dict:
        d = super().to_dict()
        if self.flow_map is not None:
            d["flow_map"] = np.asarray(self.flow_map).tolist()
            d["flow_offset"] = np.asarray(self.flow_offset).tolist()
        return d

    @classmethod
    def from_dict(cls, d) -> FlowNormalizer:
        norm = super().from_dict(d)
        if d.get("flow_map") is not None:
            fm, fo = np.asarray(d["flow_map"], np.float64), np.asarray(d.get("flow_offset"), np.float64)
            n = norm.shift.shape[-1]
            if fm.shape != (n, n) or fo.shape != (n,) or not (np.all(np.isfinite(fm)) and np.all(np.isfinite(fo))):
                raise ValueError(f"normalizer flow_map must be ({n}, {n}) and flow_offset ({n},) finite values, "
                                 f"got {fm.shape} and {fo.shape}")
            if not np.linalg.cond(fm) < 1e8:
                raise ValueError("normalizer flow_map is singular (condition number ≥ 1e8)")
            norm = norm.with_flow(fm, fo)
        return norm


def identifiable_log_matrix() -> np.ndarray:
    """M (19, 19): u = f(θ) @ M with f the normaliser's log/identity map, where u equals f except
    u[Ω_max] = log k_t + 2 log Ω_max − log m + mean(η) (log thrust-to-weight up to a constant; the
    mean η as the linearisation of log mean η) and u[J_a] = log l + log k_t + 2 log Ω_max − log J_a
    (log angular authority a). Invertible (each replaced coordinate keeps its own entry with a
    non-zero weight)."""
    m = np.eye(N_PARAMS)
    tw = np.zeros(N_PARAMS)
    tw[KT], tw[OMEGA_MAX], tw[MASS] = 1.0, 2.0, -1.0
    tw[ETA] = 0.25
    m[:, OMEGA_MAX] = tw
    for a in range(3):
        col = np.zeros(N_PARAMS)
        col[ARM], col[KT], col[OMEGA_MAX], col[INERTIA.start + a] = 1.0, 1.0, 2.0, -1.0
        m[:, INERTIA.start + a] = col
    return m


def identifiable_flow_map(norm: Normalizer, theta) -> FlowNormalizer:
    """``norm`` with the flow coordinates of
    [identifiable_log_matrix][mjxsysid.cfm.flow_coords.identifiable_log_matrix], standardised over
    the samples θ (n, 19) (e.g. those ``norm`` was fitted to): v = y @ A + c has zero mean and
    unit std per axis; the axes of Ω_max and J are log thrust-to-weight and log angular
    authorities, the others the normalised θ entries."""
    y = np.asarray(norm.normalize(theta), np.float64)
    a0 = np.diag(np.asarray(norm.scale, np.float64)) @ identifiable_log_matrix()   # y -> u up to a constant
    v0 = y @ a0
    std = np.maximum(v0.std(0), 1e-6)
    a = a0 / std
    c = -(v0 / std).mean(0)
    return FlowNormalizer.of(norm).with_flow(a, c)


def decoder_normalizer(prior: str | SizeFactorPrior = "default", n: int = 100_000, seed: int = 0,
                       coords: str = "theta") -> FlowNormalizer:
    """Normaliser fitted to ``n`` samples of a prior (seeded, deterministic; the same as
    [prior_normalizer][mjxsysid.theta.normalize.prior_normalizer]) with the flow coordinates
    ``coords`` ("theta" | "identifiable", [DECODER_COORDS][mjxsysid.cfm.flow_coords.DECODER_COORDS])."""
    if coords not in DECODER_COORDS:
        raise ValueError(f"unknown decoder coordinates {coords!r}; choose from {DECODER_COORDS}")
    theta = prior_samples_for_normalizer(prior, n, seed)
    norm = FlowNormalizer.fit(theta)
    return identifiable_flow_map(norm, theta) if coords == "identifiable" else norm
