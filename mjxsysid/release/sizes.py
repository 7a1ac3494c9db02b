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
class CalibrationSet:
    """One collection of posterior-calibration rows
    (:func:`mjxsysid.experiments.posterior_calibration.collect`): ``vehicles`` drawn with ``seed``,
    each flying ``flights`` ('lemniscate:PERIOD', 'minsnap:SECONDS', 'hover:SECONDS') at every
    level; ``controller`` 'oracle' or 'policy' (the release's); ``aero``: rotor aerodynamics on;
    ``velocity``: the logs keep their body velocity; ``motor_idle``, ``motor_kappa``: the simulator's
    static motor map (``SimConfig``'s; 0 and 1: the map θ describes); ``paths``: each flight and level's vehicles
    flown in this many groups, each drawing its own path where the reference is random (min-snap;
    :func:`mjxsysid.experiments.posterior_calibration.flights`)."""
    vehicles: int
    seed: int
    flights: tuple[str, ...]
    controller: str = "oracle"
    aero: bool = False
    velocity: bool = True
    motor_idle: float = 0.0
    motor_kappa: float = 1.0
    paths: int = 1

    def logs(self, levels: int) -> int:
        """The logs it flies at ``levels`` levels (before failed flights are dropped)."""
        return self.vehicles * len(self.flights) * levels


@dataclasses.dataclass(frozen=True)
class CalibrationSizes:
    """The posterior calibration stage: ``train`` and ``held_out`` sets (name → CalibrationSet),
    flown at ``train_levels`` and ``held_out_levels`` (:data:`mjxsysid.uses.imu_noise.LEVELS`), and
    ``misfit`` sets flown at ``train_levels``: a misspecification the table is not fitted on, evaluated apart;
    each set collected in ``shards`` pieces (every shards-th vehicle: a piece resumes on its own);
    the table's ``bins`` and ``min_group`` (:func:`mjxsysid.identify.calibration_fit.fit`), and the logs of a window of
    the tables fitted in windows (:data:`mjxsysid.identify.calibration_fit.WINDOWED`: NUTS's)."""
    train: Mapping[str, CalibrationSet]
    held_out: Mapping[str, CalibrationSet]
    train_levels: tuple[str, ...]
    held_out_levels: tuple[str, ...]
    shards: int
    bins: int
    min_group: int
    misfit: Mapping[str, CalibrationSet] = dataclasses.field(default_factory=_frozen)
    window_logs: int = 300

    def logs(self) -> tuple[int, int, int]:
        """(training logs, held-out logs, misfit logs) flown."""
        return (sum(s.logs(len(self.train_levels)) for s in self.train.values()),
                sum(s.logs(len(self.held_out_levels)) for s in self.held_out.values()),
                sum(s.logs(len(self.train_levels)) for s in self.misfit.values()))


_CAL = CalibrationSet
MINSNAP_PATHS = 4
"""Path draws per shard and level of the min-snap training set without velocity (thrust-to-weight's error there moves
with the path's drag exposure; one draw gave the set 20 paths, four give it 80: docs/identify.md). The held-out
min-snap set keeps one (its committed rows; minsnap-paths/ checks a path per vehicle)."""
FULL_CALIBRATION = CalibrationSizes(
    train=_frozen(vel_lem=_CAL(128, 5, ("lemniscate:10",)),
                  novel_lem=_CAL(128, 6, ("lemniscate:10",), velocity=False),
                  vel_ms=_CAL(128, 7, ("minsnap:10",)),
                  novel_ms=_CAL(128, 8, ("minsnap:10",), velocity=False, paths=MINSNAP_PATHS),
                  aero=_CAL(128, 9, ("lemniscate:10",), aero=True),
                  policy=_CAL(128, 10, ("lemniscate:10",), controller="policy"),
                  slow=_CAL(128, 11, ("lemniscate:20", "hover:8"))),
    held_out=_frozen(test_vel=_CAL(128, 71, ("lemniscate:10",)),
                     test_novel=_CAL(128, 72, ("minsnap:10",), velocity=False)),
    train_levels=("clean", "x1", "x5_white", "x5_vibration", "x20"),
    held_out_levels=("clean", "x1", "x2", "x5_white", "x5_vibration", "x10", "x20"),
    shards=4, bins=4, min_group=30,
    misfit=_frozen(motor=_CAL(128, 12, ("lemniscate:10", "hover:8"), motor_idle=0.1)))
"""The protocol of the release's table (docs/identify.md, "Calibration by simulation"): 7 training sets of 128 vehicles at
5 levels, 2 held-out sets at 7 (other seeds), 4 bins of at least 30 logs (the SMC's table), windows of 300 (NUTS's); ``motor`` (an idle offset of 0.1 Ω_max in the
static motor map) evaluated apart: fitting it widened every log's bands and still left its own logs uncovered."""


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
        calibration: the posterior calibration stage's sets and table.
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
    calibration: CalibrationSizes


FULL = Sizes(
    train=_frozen(), eval_vehicles=1000, heldout_vehicles=256, heldout_sets=None, heldout_period=10.0,
    pairs=PairSizes(20_000, 2_000, 2_000), seq_pairs=PairSizes(20_000, 2_000, 5_500), seq_seconds=10.0,
    cfm=_frozen(), seq_cfg=_frozen(epochs=100), eval_cases=1000, eval_samples=200, paper_flight=True,
    noise=NoiseSizes(vehicles=128, seconds=4.0, samples=100, levels=_frozen(**{
        "noise_sensitivity.json": None,   # None: the study's DEFAULT_LEVELS
        "noise_sensitivity_low.json": ("clean", "x0.5_white", "x1_white")})),
    quick=False, fidelity=FidelitySizes(vehicles=20, models=100, duration=4.0), calibration=FULL_CALIBRATION)

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
    quick=True, fidelity=FidelitySizes(vehicles=2, models=2, duration=1.0),
    # hover:2 leaves the 5 rate windows a log needs; logs without velocity (no velocity stratum to fill);
    # 4 training rows: a group of fewer than 19 has no finite conformal quantile (an infinite band). Every set
    # flies 2 vehicles: one flight program (the levels are data) serves them all
    calibration=CalibrationSizes(
        train=_frozen(train=_CAL(2, 5, ("hover:2",), velocity=False)),
        held_out=_frozen(test=_CAL(2, 71, ("hover:2",), velocity=False)),
        train_levels=("clean", "x1"), held_out_levels=("clean", "x1"), shards=1, bins=1, min_group=2,
        misfit=_frozen(motor=_CAL(2, 12, ("hover:2",), velocity=False, motor_idle=0.1)), window_logs=2))

SIZES = {"full": FULL, "tiny": TINY}
"""Per scale, its sizes."""
SCALES = tuple(SIZES)
