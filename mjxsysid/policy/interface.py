"""One interface for every frozen latent-conditioned policy, and the names that select them.

A *latent policy* is a low-level controller (:mod:`mjxsysid.control.low_level`) that also
exposes its latent. Both mjxsysid's own trained policy
(:class:`~mjxsysid.policy.adaptive.controller.PolicyController`) and the released Extreme-Adaptation
policy (:class:`~mjxsysid.policy.xadap.controller.XAdapController`) implement it:

=====================  ===================================================================
``init(key)``          empty per-episode memory (history buffer, last action, ẑ, counters)
``step(carry, imu,     observation from the IMU (gyro, specific force) and the high-level
command)``             command; push to the history; ẑ = φ(history) at the policy's own
                       schedule; π(observation, ẑ) -> normalised motor speeds Ω/Ω_max (4,)
                       in mjxsysid's rotor order (its motor-order mapping applied inside)
``latent(carry)``      the current ẑ (8,)
``rate_hz``            policy rate (the simulator runs at 500 Hz; the command is held)
``batched(n)``         n vehicles sharing the weights, for ``fly_batch``
``batch_axes()``       vmap axes of such a batch (weights shared: None)
``replay(imu, a_cmd,   ẑ after every step (T, 8) with the history rebuilt from a recorded
omega_cmd, motor)``    flight (the logged motor commands stand in for the policy's actions)
=====================  ===================================================================

Policies are named on the command line and in code by :func:`resolve_policy`:
``"mjxsysid"`` (alias ``"policy"``: the shipped weights, or ``weights=`` a policy.npz / run
folder), ``"xadap"`` (``weights=`` a folder of the released files or a converted .npz; the
``MJXSYSID_XADAP_DIR`` environment variable is the fallback), or a path, whose kind is
recognised from its contents. The result, a :class:`PolicyRef`, knows where that policy's
decoders ship and which prior is its in-distribution test set.
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
from pathlib import Path
from typing import Protocol, runtime_checkable

import jax
import numpy as np

from mjxsysid.runtime.checkpoint import open_npz
from mjxsysid.policy.adaptive.controller import PolicyController
from mjxsysid.policy.adaptive.weights import PRETRAINED_DIR
from mjxsysid.policy.xadap.controller import XAdapController
from mjxsysid.policy.xadap.network import FIELDS, load_npz
from mjxsysid.policy.xadap.onnx_import import load_xadap

POLICY_NAMES = ("mjxsysid", "xadap")
XADAP_ENV = "MJXSYSID_XADAP_DIR"
XADAP_FILES = ("encoder.onnx", "mlp.onnx", "mean.csv", "var.csv")


@runtime_checkable
class LatentPolicy(Protocol):
    """What downstream tools (fly, collect, decode, replay, experiments) rely on."""

    rate_hz: float

    def init(self, key=None): ...

    def step(self, carry, imu: jax.Array, command) -> tuple[object, jax.Array]: ...

    def latent(self, carry) -> jax.Array: ...

    def batched(self, n: int): ...

    def batch_axes(self): ...

    def replay(self, imu, a_cmd, omega_cmd, motor) -> np.ndarray: ...


@dataclasses.dataclass(frozen=True)
class PolicyRef:
    """A resolved policy: ``kind`` ('mjxsysid' | 'xadap') and the weights path it loads."""
    kind: str
    weights: Path

    @property
    def label(self) -> str:
        shipped = self.kind == "mjxsysid" and self.weights == PRETRAINED_DIR / "policy.npz"
        return "mjxsysid (shipped)" if shipped else f"{self.kind} ({self.weights})"

    def load(self) -> LatentPolicy:
        """The unbatched controller."""
        if self.kind == "mjxsysid":
            return PolicyController.load(self.weights)
        return XAdapController.load(self.weights)

    def batched(self, n: int) -> LatentPolicy:
        """n vehicles sharing the weights (for ``fly_batch``)."""
        return self.load().batched(int(n))

    @property
    def decoders_dir(self) -> Path:
        """Where this policy's shipped decoders (cfm.npz, regression.npz) live."""
        return PRETRAINED_DIR if self.kind == "mjxsysid" else PRETRAINED_DIR / "xadap"

    @property
    def prior(self) -> str:
        """Name of the prior this policy was trained on (its in-distribution vehicles)."""
        return "default" if self.kind == "mjxsysid" else "xadap"

    @property
    def decoder_prior(self) -> str:
        """Name of the prior its shipped decoders are trained on (``collect``'s default): for
        mjxsysid's policy the default vehicles with τ_m over the default and the slow-actuator
        range ('wide_actuators', so slow motors can be decoded); for Xadap its own prior."""
        return "wide_actuators" if self.kind == "mjxsysid" else "xadap"

    def sha256(self) -> str:
        """Digest of the weights. Xadap: of the converted arrays, so the released folder and a
        converted .npz of it agree; mjxsysid: of the file."""
        return _xadap_digest(self.weights) if self.kind == "xadap" else file_sha256(self.weights)

    def to_dict(self) -> dict:
        return {"policy": self.kind, "weights": str(self.weights), "weights_sha256": self.sha256()}


def file_sha256(path) -> str:
    """sha256 of a file, or of the files of a folder in name order."""
    h = hashlib.sha256()
    p = Path(path)
    for f in sorted(p.glob("*")) if p.is_dir() else [p]:
        if f.is_file():
            h.update(f.read_bytes())
    return h.hexdigest()


def _xadap_digest(path: Path) -> str:
    w = load_npz(path) if path.is_file() else load_xadap(path)
    h = hashlib.sha256()
    for k in FIELDS:
        h.update(np.ascontiguousarray(np.asarray(getattr(w, k))).tobytes())
    return h.hexdigest()


def _kind_of_path(p: Path) -> str | None:
    if p.is_dir():
        if all((p / f).is_file() for f in XADAP_FILES[:2]):
            return "xadap"
        if (p / "policy.npz").is_file():
            return "mjxsysid"
        return None
    if p.is_file() and p.suffix == ".npz":
        with open_npz(p, "policy weights file") as z:
            return "xadap" if "__format__" in z.files else "mjxsysid"
    return None


def resolve_policy(policy="mjxsysid", weights=None) -> PolicyRef:
    """A policy name ('mjxsysid' / 'policy', 'xadap') or a path (+ optional ``weights`` path)
    -> :class:`PolicyRef`. Errors name what is missing."""
    if isinstance(policy, PolicyRef):
        return policy
    name = str(policy)
    if name == "policy":
        name = "mjxsysid"
    if name == "mjxsysid":
        w = Path(weights).expanduser() if weights is not None else PRETRAINED_DIR / "policy.npz"
        if w.is_dir():
            w = w / "policy.npz"
        if not w.is_file():
            raise FileNotFoundError(f"policy weights not found: {w}")
        if _kind_of_path(w) != "mjxsysid":
            raise ValueError(f"{w}: not mjxsysid policy weights (an Xadap file? use --policy xadap)")
        return PolicyRef("mjxsysid", w)
    if name == "xadap":
        if weights is None:
            env = os.environ.get(XADAP_ENV)
            if not env:
                raise ValueError(f"--policy xadap needs --weights DIR (a copy of the released policy: "
                                 f"{', '.join(XADAP_FILES)}, or a converted .npz), or ${XADAP_ENV}")
            weights = env
        w = Path(weights).expanduser()
        if not w.exists():
            raise FileNotFoundError(f"Xadap weights not found: {w}")
        if _kind_of_path(w) != "xadap":
            raise ValueError(f"{w}: not the released Xadap policy (expected a folder with "
                             f"{', '.join(XADAP_FILES)} or a converted .npz)")
        return PolicyRef("xadap", w)
    p = Path(name).expanduser()
    if not p.exists():
        raise ValueError(f"unknown policy {name!r}: give one of {POLICY_NAMES} or a path to weights")
    if weights is not None:
        raise ValueError("give the policy either as a path or as a name with --weights, not both")
    kind = _kind_of_path(p)
    if kind is None:
        raise ValueError(f"{p}: not a policy (expected policy.npz, a run folder, an Xadap folder "
                         f"or a converted Xadap .npz)")
    return resolve_policy(kind, p)
