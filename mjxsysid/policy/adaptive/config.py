"""Configuration of the adaptive policy's training: the environment's settings
(:class:`EnvConfig`) and the training run's (:class:`TrainConfig`, which holds an EnvConfig), both
frozen dataclasses whose defaults reproduce the shipped weights; :func:`config_with_overrides`
reads a JSON file of overrides (``mjxsysid train-policy --config``).
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

IMU_FIELDS = ("gyro_noise", "accel_noise", "gyro_bias", "accel_bias", "gyro_vibration", "accel_vibration",
              "randomize_imu", "imu_clean_fraction")
"""The EnvConfig settings passed on to the simulator's IMU (:class:`~mjxsysid.sim.SimConfig`)."""


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Training-environment settings (static)."""
    prior: str = "default"
    episode_steps: int = 1000           # 2 s at 500 Hz
    phi_every: int = 10                 # ẑ refreshed every this many steps
    gyro_noise: float = 0.005           # rad/s per step
    accel_noise: float = 0.05           # m/s² per step
    gyro_bias: float = 0.0              # rad/s: std of a per-episode gyro bias
    accel_bias: float = 0.0             # m/s²: std of a per-episode accelerometer bias
    gyro_vibration: float = 0.0         # rad/s: std of rotor vibration (SimConfig)
    accel_vibration: float = 0.0        # m/s²
    randomize_imu: bool = False         # the IMU settings above are maxima, levels drawn per episode
    imu_clean_fraction: float = 0.0     # with randomize_imu: this share of episodes has a clean IMU
    force_sigma_max: float = 0.15       # × m g: per-episode σ of the random world force
    excite_rate: tuple = (2.0, 2.0, 1.0)  # max ω excitation (rad/s)
    excite_thrust: float = 2.0          # max a_cmd excitation (m/s²)
    excite_hold: float = 0.3            # mean hold time of an excitation level (s)
    period_range: tuple = (5.0, 15.0)   # lemniscate period (s)
    size_max: tuple = (1.5, 1.5, 0.3)   # lemniscate size (m)
    yaw_amplitude_max: float = 0.5      # rad
    tube: float = 3.0                   # m
    w_rate: float = 0.25
    w_thrust: float = 0.05
    w_smooth: float = 0.1
    w_sat: float = 0.2
    fail_penalty: float = -20.0
    focus_weight: float = 0.3           # with focus systems: the fraction of episodes flying one of them


PARAM_MODULES = ("mu", "phi", "pi", "v", "aux")   # the networks' parameter groups (Networks.init)


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Defaults reproduce the shipped weights (see mjxsysid/pretrained/policy.json)."""
    seed: int = 0
    num_envs: int = 4096
    unroll: int = 32
    iterations: int = 1500
    epochs: int = 4
    minibatches: int = 8
    learning_rate: float = 3e-4
    gamma: float = 0.98
    gae_lambda: float = 0.95
    clip: float = 0.2
    value_coef: float = 0.5
    entropy_coef: float = 0.0
    max_grad_norm: float = 1.0
    lambda1: float = 1.0
    lambda2: float = 1.0
    align_scale_invariant: bool = False   # True collapsed a latent dimension in a 2500-it trial
    var_coef: float = 1.0
    var_target: float = 0.1
    rec_coef: float = 0.1
    # Reconstruction of the identifiable combinations (log T/W, log angular authorities, log τ_m
    # and, with ident_yaw_authority, the yaw authority k_τ Ω_max²/J_zz in place of κ, which flight
    # does not reveal): what makes the latent carry T/W (probe R² 0.44 -> 0.92, docs/runs/archive/latent_trials/latent_trials.md).
    # 0.0 / False: the latent trials' control.
    rec_ident_coef: float = 1.0
    ident_yaw_authority: bool = True
    bc_coef: float = 2.0
    bc_final: float = 0.05
    bc_decay: float = 0.7          # fraction of training over which β decays to bc_final
    warmup: float = 0.2            # fraction with p = 0
    ramp: float = 0.3              # fraction over which p rises to p_max
    p_max: float = 0.5
    # Episode starts: False (the shipped policy's training) computes a fresh reset for every
    # environment at every step and keeps it where an episode ended; True draws one per
    # environment per unroll (``unroll`` × fewer resets; the rollout's largest cost after the
    # simulator step, docs/runs/measurements/benchmarks/train_profile.json).
    reset_per_unroll: bool = False
    # Speed options of policy training (off by default: the shipped policy's protocol). ``flat_optimizer``: Adam and
    # the gradient clip on one concatenated parameter vector (optax.flatten; the same update up to float
    # reassociation; no measurable speed-up on an H200, docs/runs/measurements/benchmarks/train_profile_16k_4x8_flat_*.json).
    # ``lr_decay``: the learning rate falls linearly to ``lr_final`` × learning_rate over the run's
    # gradient steps (what brought the fast configs to the shipped quality, BENCHMARKS.md).
    flat_optimizer: bool = False
    lr_decay: bool = False
    lr_final: float = 0.1
    # Modules (of :data:`PARAM_MODULES`) whose learning rate stays constant under ``lr_decay``: the
    # adaptation module φ learns only from the alignment loss, and Adam makes its step size the learning
    # rate whatever that loss's weight, so a short run with a decayed rate leaves ẑ short of z^θ.
    lr_constant: tuple[str, ...] = ()
    checkpoint_every: int = 50
    log_every: int = 10
    env: EnvConfig = EnvConfig()
    focus: str | None = None       # weak.npz of `mjxsysid probe`: its systems mixed into training (env.focus_weight)
    # Warm start: a policy.npz whose μ, φ, π and auxiliary decoder replace the fresh ones (the critic
    # and the optimiser start afresh; the schedules run from iteration 0): fine-tuning a trained policy.
    init_from: str | None = None

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        d = dict(d)
        env = EnvConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.pop("env", {}).items()})
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown training config key(s) {unknown}; known: {sorted(known)}")
        cfg = cls(**d, env=env)
        for k in ("num_envs", "unroll", "iterations", "epochs", "minibatches"):
            if getattr(cfg, k) < 1:
                raise ValueError(f"config {k} must be >= 1, got {getattr(cfg, k)}")
        if (cfg.num_envs * cfg.unroll) % cfg.minibatches or cfg.num_envs % cfg.minibatches:
            raise ValueError("num_envs and num_envs × unroll must be divisible by minibatches")
        if not 0.0 <= cfg.lr_final <= 1.0:
            raise ValueError(f"config lr_final must be in [0, 1] (a fraction of learning_rate), got {cfg.lr_final}")
        return cfg

    def __post_init__(self):
        if isinstance(self.lr_constant, list):    # JSON gives a list
            object.__setattr__(self, "lr_constant", tuple(self.lr_constant))
        bad = sorted(set(self.lr_constant) - set(PARAM_MODULES))
        if bad:
            raise ValueError(f"config lr_constant: unknown module(s) {bad}; modules: {list(PARAM_MODULES)}")
        if self.lr_constant and self.flat_optimizer:
            raise ValueError("config lr_constant needs flat_optimizer=false (one flat Adam has one learning rate)")
        if self.lr_constant and not self.lr_decay:
            raise ValueError("config lr_constant needs lr_decay=true (without the decay every rate is constant)")


def config_with_overrides(path=None) -> dict:
    """The default :class:`TrainConfig` as a dict, with the overrides of the JSON file ``path``
    (an object of TrainConfig keys, and an ``env`` object of EnvConfig keys) merged in; checked
    keys are left to :meth:`TrainConfig.from_dict`. A missing file is a FileNotFoundError, a file
    that is not such an object a ValueError, both naming the file."""
    cfg = TrainConfig().to_dict()
    if path is None:
        return cfg
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file not found: {path}")
    try:
        over = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(over, dict) or not isinstance(over.get("env", {}), dict):
        raise ValueError(f"{path}: expected a JSON object of TrainConfig keys (and an 'env' object)")
    env = dict(cfg["env"], **over.pop("env", {}))
    cfg.update(over)
    cfg["env"] = env
    return cfg

