"""Networks of the unified latent-conditioned adaptive policy (paper §III-A, DESIGN §5).

Observation (per control step, 500 Hz), :func:`observation`, 10 entries, fixed scaling::

    gyro (3) / 4 rad/s, (specific force (3) − [0, 0, g]) / 10 m/s², (a_cmd − g) / 10 m/s²,
    ω_cmd (3) / 4 rad/s

Action r ∈ [−1, 1]⁴ (raw), motor command Ω_norm = (r + 1) / 2 in mjxsysid's rotor order.
Policy state s_t = [obs_t (10), r_{t−1} (4)] (14). History H_t = the last ``HISTORY`` = 100
steps of [obs, r] (100, 14), oldest first, *before* step t's action (so φ sees steps ≤ t − 1).

- μ   privileged encoder  θ_norm (19)  → z^θ (8), MLP 128-128, tanh
- φ   adaptation module   H (100, 14)  → ẑ (8): per-step Linear→32 + tanh, Conv1d 32 (k 8, s 4),
                                           Conv1d 32 (k 5), Conv1d 32 (k 5), LeakyReLU(0.01),
                                           flatten (512), Linear → 8, tanh (after XAdap)
- π   policy              (s (14), z (8)) → mean of r (4): state MLP 128-128-8 (tanh), concat z,
                                           MLP 256-256 → 4, tanh; Gaussian with learned log-std
- V   critic (training only) (s, θ_norm, z) → value, MLP 256-256 (asymmetric: sees θ)
- aux decoder             z (8)        → θ_norm (19), MLP 64-64
"""
from __future__ import annotations

import dataclasses
import functools

import flax.linen as nn
import jax
import jax.numpy as jnp

from mjxsysid.theta import GRAVITY, N_PARAMS

LATENT = 8
OBS = 10
ACT = 4
STATE = OBS + ACT
HISTORY = 100


def observation(imu, a_cmd, omega_cmd):
    """IMU (..., 6) [gyro, specific force], a_cmd (...), ω_cmd (..., 3) -> obs (..., 10)."""
    gyro = imu[..., 0:3] / 4.0
    f = (imu[..., 3:6] - jnp.array([0.0, 0.0, GRAVITY])) / 10.0
    a = ((a_cmd - GRAVITY) / 10.0)[..., None]
    return jnp.concatenate([gyro, f, a, omega_cmd / 4.0], -1)


def push_history(history, obs, raw_action):
    """Append one step [obs (10), r (4)] to history (100, 14), dropping the oldest."""
    row = jnp.concatenate([obs, raw_action], -1)[..., None, :]
    return jnp.concatenate([history[..., 1:, :], row], -2)


def initial_history(obs):
    """History at the start of a flight: the first observation repeated, zero actions."""
    row = jnp.concatenate([obs, jnp.zeros(obs.shape[:-1] + (ACT,), obs.dtype)], -1)
    return jnp.broadcast_to(row[..., None, :], obs.shape[:-1] + (HISTORY, STATE))


def to_motor(raw):
    """Raw action r ∈ [−1, 1] -> normalised motor command in [0, 1]."""
    return jnp.clip(0.5 * raw + 0.5, 0.0, 1.0)


class MLP(nn.Module):
    features: tuple[int, ...]
    act: str = "tanh"
    final_act: str | None = None

    @nn.compact
    def __call__(self, x):
        f = {"tanh": jnp.tanh, "elu": nn.elu, "silu": nn.silu}
        for i, n in enumerate(self.features):
            x = nn.Dense(n)(x)
            last = i == len(self.features) - 1
            if not last:
                x = f[self.act](x)
            elif self.final_act:
                x = f[self.final_act](x)
        return x


class Encoder(nn.Module):
    """μ: θ_norm (..., 19) -> z^θ (..., 8)."""
    @nn.compact
    def __call__(self, theta_norm):
        return MLP((128, 128, LATENT), final_act="tanh")(theta_norm)


class Adaptation(nn.Module):
    """φ: history (..., 100, 14) -> ẑ (..., 8)."""
    @nn.compact
    def __call__(self, history):
        x = jnp.tanh(nn.Dense(32)(history))                      # (..., 100, 32)
        x = nn.leaky_relu(nn.Conv(32, (8,), strides=(4,), padding="VALID")(x), 0.01)  # (..., 24, 32)
        x = nn.leaky_relu(nn.Conv(32, (5,), padding="VALID")(x), 0.01)  # (..., 20, 32)
        x = nn.leaky_relu(nn.Conv(32, (5,), padding="VALID")(x), 0.01)  # (..., 16, 32)
        x = x.reshape(x.shape[:-2] + (-1,))                        # (..., 512)
        return jnp.tanh(nn.Dense(LATENT)(x))


class Actor(nn.Module):
    """π: (s (..., 14), z (..., 8)) -> (mean of r (..., 4), log-std (4,))."""
    init_log_std: float = -1.6

    @nn.compact
    def __call__(self, state, z):
        h = MLP((128, 128, 8), final_act="tanh")(state)
        mean = MLP((256, 256, ACT), final_act="tanh")(jnp.concatenate([h, z], -1))
        log_std = self.param("log_std", nn.initializers.constant(self.init_log_std), (ACT,))
        return mean, log_std


class Critic(nn.Module):
    """V: (s, θ_norm, z) -> value (...)."""
    @nn.compact
    def __call__(self, state, theta_norm, z):
        return MLP((256, 256, 1), act="elu")(jnp.concatenate([state, theta_norm, z], -1))[..., 0]


class AuxDecoder(nn.Module):
    """z (..., 8) -> θ_norm (..., 19)."""
    @nn.compact
    def __call__(self, z):
        return MLP((64, 64, N_PARAMS), act="elu")(z)


@dataclasses.dataclass(frozen=True)
class Networks:
    """The five modules; parameters live in a dict {'mu', 'phi', 'pi', 'v', 'aux'}."""
    mu: Encoder = Encoder()
    phi: Adaptation = Adaptation()
    pi: Actor = Actor()
    v: Critic = Critic()
    aux: AuxDecoder = AuxDecoder()

    @functools.partial(jax.jit, static_argnums=0)
    def init(self, key) -> dict:
        """Fresh parameters {'mu', 'phi', 'pi', 'v', 'aux'} (compiled once per architecture)."""
        k = jax.random.split(key, 5)
        s = jnp.zeros((STATE,))
        th = jnp.zeros((N_PARAMS,))
        z = jnp.zeros((LATENT,))
        return {"mu": self.mu.init(k[0], th)["params"],
                "phi": self.phi.init(k[1], jnp.zeros((HISTORY, STATE)))["params"],
                "pi": self.pi.init(k[2], s, z)["params"],
                "v": self.v.init(k[3], s, th, z)["params"],
                "aux": self.aux.init(k[4], z)["params"]}

    def encode(self, params, theta_norm):
        return self.mu.apply({"params": params["mu"]}, theta_norm)

    def adapt(self, params, history):
        return self.phi.apply({"params": params["phi"]}, history)

    def act(self, params, state, z):
        return self.pi.apply({"params": params["pi"]}, state, z)

    def value(self, params, state, theta_norm, z):
        return self.v.apply({"params": params["v"]}, state, theta_norm, z)

    def decode(self, params, z):
        return self.aux.apply({"params": params["aux"]}, z)


def count_params(tree) -> int:
    return int(sum(x.size for x in jax.tree.leaves(tree)))
