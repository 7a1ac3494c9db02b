"""The sizes every stage of a release runs at: :data:`FULL` (the shipped protocols) and
:data:`TINY` (CPU seconds: what the tests run), one frozen dataclass per stage's knobs."""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any


def _frozen(**kw) -> Mapping[str, Any]:
    return MappingProxyType(dict(kw))


@dataclasses.dataclass(frozen=True)
class PairSizes:
    """(θ, ẑ) pairs to collect: ``train`` and ``test`` vehicles, flown ``batch`` at a time."""
    train: int
    test: int
    batch: int


@dataclasses.dataclass(frozen=True)
class NoiseSizes:
    """The noise stage's measurement (:func:`mjxsysid.uses.imu_noise.noise_sensitivity`):
    held-out ``vehicles``, flights of ``seconds``, posterior ``samples`` per flight, and the IMU
    ``levels`` of each result file (file name → level names)."""
    vehicles: int
    seconds: float
    samples: int
    levels: Mapping[str, tuple[str, ...]]

    def measurement(self) -> dict:
        """The keyword arguments of the measurement (without the levels)."""
        return {"vehicles": self.vehicles, "seconds": self.seconds, "samples": self.samples}


@dataclasses.dataclass(frozen=True)
class FidelitySizes:
    """Closed-loop fidelity (:func:`mjxsysid.uses.fidelity.fidelity_benchmark`): test
    ``vehicles``, decoded ``models`` per vehicle, flights of ``duration`` s."""
    vehicles: int
    models: int
    duration: float


@dataclasses.dataclass(frozen=True)
class Sizes:
    """What a release's stages run at.

    Attributes:
        train: TrainConfig overrides on top of the policy config (empty: the config's own sizes).
        eval_vehicles: vehicles of ``evaluate-policy``.
        heldout_vehicles: vehicles per held-out set; ``heldout_sets``: the sets (None: all of
            :data:`mjxsysid.experiments.heldout.SETS`); ``heldout_period``: lemniscate period (s).
        pairs, seq_pairs: single-latent pairs and latent trajectories of ``seq_seconds`` s.
        cfm: CFMConfig overrides of both decoder stages; ``seq_cfg``: the flight-level decoder's.
        eval_cases, eval_samples: ``evaluate-decoder``'s held-out cases and posterior samples;
            ``paper_flight``: also decode the paper vehicle's flight.
        noise, fidelity: those stages' sizes; ``quick``: the experiments' ``--quick`` protocol.
    """
    train: Mapping[str, Any]
    eval_vehicles: int
    heldout_vehicles: int
    heldout_sets: tuple[str, ...] | None
    heldout_period: float
    pairs: PairSizes
    seq_pairs: PairSizes
    seq_seconds: float
    cfm: Mapping[str, Any]
    seq_cfg: Mapping[str, Any]
    eval_cases: int
    eval_samples: int
    paper_flight: bool
    noise: NoiseSizes
    quick: bool
    fidelity: FidelitySizes


FULL = Sizes(
    train=_frozen(), eval_vehicles=1000, heldout_vehicles=256, heldout_sets=None, heldout_period=10.0,
    pairs=PairSizes(20_000, 2_000, 2_000), seq_pairs=PairSizes(20_000, 2_000, 5_500), seq_seconds=10.0,
    cfm=_frozen(), seq_cfg=_frozen(epochs=100), eval_cases=1000, eval_samples=200, paper_flight=True,
    noise=NoiseSizes(vehicles=128, seconds=4.0, samples=100, levels=_frozen(**{
        "noise_sensitivity.json": None,   # None: the study's DEFAULT_LEVELS
        "noise_sensitivity_low.json": ("clean", "x0.5_white", "x1_white")})),
    quick=False, fidelity=FidelitySizes(vehicles=20, models=100, duration=4.0))

TINY = Sizes(
    # tests/policy/test_policy.py's tiny trainer (4 iterations), warm-started from the shipped policy
    # (``init_from``) so that the tiny policy still flies and the later stages have flights to decode
    train=_frozen(num_envs=64, unroll=16, iterations=4, epochs=2, minibatches=4, log_every=1, checkpoint_every=2,
                  warmup=0.3, ramp=0.3),
    eval_vehicles=10, heldout_vehicles=2, heldout_sets=("default", "weak_motor"), heldout_period=5.0,
    pairs=PairSizes(32, 8, 40), seq_pairs=PairSizes(32, 8, 40), seq_seconds=2.0,
    cfm=_frozen(width=32, blocks=1, time_dim=16, epochs=2, batch=16),
    seq_cfg=_frozen(epochs=2, set_width=16, heads=2, cond_dim=8),
    eval_cases=8, eval_samples=20, paper_flight=False,
    noise=NoiseSizes(vehicles=4, seconds=1.0, samples=8, levels=_frozen(**{
        "noise_sensitivity.json": ("clean", "x1"), "noise_sensitivity_low.json": ("clean", "x1_white")})),
    quick=True, fidelity=FidelitySizes(vehicles=2, models=2, duration=1.0))

SIZES = {"full": FULL, "tiny": TINY}
"""Per scale, its sizes."""
SCALES = tuple(SIZES)
