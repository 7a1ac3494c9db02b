"""The released Extreme-Adaptation ("Xadap") quadrotor policy's networks in pure JAX.

The released policy (``encoder.onnx``, ``mlp.onnx``, ``mean.csv``, ``var.csv``; see the
README next to the files) is read once with ``onnx`` into an :class:`XAdapWeights` pytree
(:func:`mjxsysid.policy.xadap.onnx_import.load_xadap`); everything here is plain ``jax.numpy``
and works under ``jit``/``vmap``/``grad`` without ``onnx`` installed (use :func:`save_npz` /
:func:`load_npz` to carry converted weights).

The JAX functions follow the ONNX node lists exactly (opset 11, exported by PyTorch 2.1.2);
``load_xadap`` refuses any graph whose node list, attributes or weight shapes differ.

``encoder.onnx`` — adaptation module φ, input ``(1, 1200)`` → latent ``(1, 8)``::

    Reshape(x, [100, -1])                  (1, 1200) -> (100, 12)   row-major, no transpose
    Gemm(transB=1) encoder.0 (32, 12)      (100, 12) -> (100, 32)
    Tanh
    Reshape(h, [1, -1, 100])               (100, 32) -> (1, 32, 100) PLAIN reshape: channel c,
                                           time t reads h.ravel()[100 c + t] (not h.T)
    Conv conv_layers.0 (32, 32, 8), stride 4, no padding   -> (1, 32, 24)
    LeakyRelu(alpha=0.01)
    Conv conv_layers.2 (32, 32, 5), stride 1, no padding   -> (1, 32, 20)
    LeakyRelu(alpha=0.01)
    Conv conv_layers.4 (32, 32, 5), stride 1, no padding   -> (1, 32, 16)
    LeakyRelu(alpha=0.01)
    Flatten(axis=1)                        (1, 32, 16) -> (1, 512)  channel-major
    Gemm(transB=1) linear_output.0 (8, 512)                -> (1, 8)
    Tanh

``mlp.onnx`` — policy π, input ``(1, 20)`` → raw action ``(1, 4)``::

    Slice(x, starts=0, ends=-8, axis=1)    -> o (1, 12)   normalised [s, last r]
    Gemm shared_net.0 (128, 12), Tanh, Gemm shared_net.2 (128, 128), Tanh,
    Gemm shared_net.4 (8, 128), Tanh                      -> f (1, 8)
    Slice(x, starts=-8, ends=INT64_MAX, axis=1) -> z (1, 8)   latent
    Concat([f, z], axis=1)                                -> (1, 16)
    Gemm policy_net.0 (256, 16), Tanh, Gemm policy_net.2 (256, 256), Tanh,
    Gemm action_net.0 (4, 256), Tanh                      -> mean (1, 4)
    Exp(log_std), Mul, Shape, ConstantOfShape, Add, Add, Shape, Expand(mean, ...)
                                           output = Expand(mean): the mean head; the
                                           log-std branch only feeds a Shape (dead value)

All Gemm nodes have alpha = beta = 1, transB = 1 (y = x Wᵀ + b). Matrix products and
convolutions run with ``Precision.HIGHEST`` so that float32 results match onnxruntime on
accelerators that would otherwise use TF32/bf16 passes.

Input conventions (README, checked against the published wrapper ``Xadap_NN_control.py``):

* state s (8): ω (3, rad/s), filtered specific force along body z (1, m/s²), ω_cmd (3),
  mass-normalised collective thrust command (1, m/s²);
* action r (4): raw network output in [−1, 1] (motor speed = (0.5 r + 0.5) Ω_max), network
  motor order 0 front-right, 1 back-left, 2 back-right, 3 front-left;
* policy input (20) = [normalize_state([s, r_last]) (12), ẑ (8)];
* adaptation input (1200) = [normalised s history (100 × 8, oldest first, flattened),
  normalised r history (100 × 4, oldest first, flattened)], states normalised with
  ``mean[:8]``/``var[:8]``, actions with ``mean[8:12]``/``var[8:12]``, tiled over time.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.runtime.checkpoint import open_npz

__all__ = [
    "XAdapWeights",
    "xadap_encoder",
    "xadap_policy",
    "normalize_state",
    "build_history_input",
    "save_npz",
    "load_npz",
    "HISTORY_LEN",
    "STATE_DIM",
    "ACTION_DIM",
    "OBS_DIM",
    "LATENT_DIM",
    "HISTORY_DIM",
    "POLICY_INPUT_DIM",
    "N_STATS",
    "NORM_EPS",
]

HISTORY_LEN = 100
STATE_DIM = 8
ACTION_DIM = 4
OBS_DIM = STATE_DIM + ACTION_DIM  # 12: normalised policy observation [s, last r]
LATENT_DIM = 8
HISTORY_DIM = HISTORY_LEN * OBS_DIM  # 1200
POLICY_INPUT_DIM = OBS_DIM + LATENT_DIM  # 20
N_STATS = 46  # 12 policy-input entries + 34 privileged parameters
NORM_EPS = 1e-8
LEAKY_ALPHA = np.float32(0.01)  # stored in the graph as float32 0.009999999776482582
_HIGHEST = jax.lax.Precision.HIGHEST
PRECISIONS = ("highest", "default")
_NPZ_FORMAT = "mjxsysid.xadap/1"

# Weight field name -> (ONNX initializer name, shape). Encoder first, then policy.
ENCODER_WEIGHTS: dict[str, tuple[str, tuple[int, ...]]] = {
    "enc_in_w": ("encoder.0.weight", (32, OBS_DIM)),
    "enc_in_b": ("encoder.0.bias", (32,)),
    "enc_conv0_w": ("conv_layers.0.weight", (32, 32, 8)),
    "enc_conv0_b": ("conv_layers.0.bias", (32,)),
    "enc_conv1_w": ("conv_layers.2.weight", (32, 32, 5)),
    "enc_conv1_b": ("conv_layers.2.bias", (32,)),
    "enc_conv2_w": ("conv_layers.4.weight", (32, 32, 5)),
    "enc_conv2_b": ("conv_layers.4.bias", (32,)),
    "enc_out_w": ("linear_output.0.weight", (LATENT_DIM, 512)),
    "enc_out_b": ("linear_output.0.bias", (LATENT_DIM,)),
}
POLICY_WEIGHTS: dict[str, tuple[str, tuple[int, ...]]] = {
    "pi_feat0_w": ("mlp_extractor.shared_net.0.weight", (128, OBS_DIM)),
    "pi_feat0_b": ("mlp_extractor.shared_net.0.bias", (128,)),
    "pi_feat1_w": ("mlp_extractor.shared_net.2.weight", (128, 128)),
    "pi_feat1_b": ("mlp_extractor.shared_net.2.bias", (128,)),
    "pi_feat2_w": ("mlp_extractor.shared_net.4.weight", (8, 128)),
    "pi_feat2_b": ("mlp_extractor.shared_net.4.bias", (8,)),
    "pi_h0_w": ("mlp_extractor.policy_net.0.weight", (256, 16)),
    "pi_h0_b": ("mlp_extractor.policy_net.0.bias", (256,)),
    "pi_h1_w": ("mlp_extractor.policy_net.2.weight", (256, 256)),
    "pi_h1_b": ("mlp_extractor.policy_net.2.bias", (256,)),
    "pi_out_w": ("action_net.0.weight", (ACTION_DIM, 256)),
    "pi_out_b": ("action_net.0.bias", (ACTION_DIM,)),
    "log_std": ("log_std", (ACTION_DIM,)),
}
_STAT_SHAPES: dict[str, tuple[int, ...]] = {
    "obs_mean": (OBS_DIM,),
    "obs_var": (OBS_DIM,),
    "mean": (N_STATS,),
    "var": (N_STATS,),
}


@flax.struct.dataclass
class XAdapWeights:
    """Converted Xadap weights and normalisation statistics (a frozen JAX pytree).

    Network weights are float32 arrays with the PyTorch/ONNX layouts: linear weights
    ``(out, in)`` (applied as ``x @ W.T + b``), conv weights ``(out_ch, in_ch, kernel)``.
    Statistics are float64 as read from the CSV files (cast to the input dtype on use):
    ``mean``/``var`` are the full 46-vectors (12 policy-input entries, then 34 privileged
    parameters), ``obs_mean``/``obs_var`` their first 12 entries (8 state, 4 action).
    ``log_std`` (4,) is the policy's (unused) Gaussian log-std head, kept for completeness.
    """

    # adaptation module φ
    enc_in_w: Any  # (32, 12)
    enc_in_b: Any  # (32,)
    enc_conv0_w: Any  # (32, 32, 8), stride 4
    enc_conv0_b: Any  # (32,)
    enc_conv1_w: Any  # (32, 32, 5), stride 1
    enc_conv1_b: Any  # (32,)
    enc_conv2_w: Any  # (32, 32, 5), stride 1
    enc_conv2_b: Any  # (32,)
    enc_out_w: Any  # (8, 512)
    enc_out_b: Any  # (8,)
    # policy π
    pi_feat0_w: Any  # (128, 12)
    pi_feat0_b: Any  # (128,)
    pi_feat1_w: Any  # (128, 128)
    pi_feat1_b: Any  # (128,)
    pi_feat2_w: Any  # (8, 128)
    pi_feat2_b: Any  # (8,)
    pi_h0_w: Any  # (256, 16)
    pi_h0_b: Any  # (256,)
    pi_h1_w: Any  # (256, 256)
    pi_h1_b: Any  # (256,)
    pi_out_w: Any  # (4, 256)
    pi_out_b: Any  # (4,)
    log_std: Any  # (4,)
    # normalisation statistics
    obs_mean: Any  # (12,)
    obs_var: Any  # (12,)
    mean: Any  # (46,)
    var: Any  # (46,)


FIELDS: tuple[str, ...] = tuple(ENCODER_WEIGHTS) + tuple(POLICY_WEIGHTS) + tuple(_STAT_SHAPES)
_EXPECTED_SHAPES: dict[str, tuple[int, ...]] = {
    **{k: v[1] for k, v in ENCODER_WEIGHTS.items()},
    **{k: v[1] for k, v in POLICY_WEIGHTS.items()},
    **_STAT_SHAPES,
}
assert set(FIELDS) == {f.name for f in XAdapWeights.__dataclass_fields__.values()}


# --------------------------------------------------------------------------------------
# Pure JAX forward passes
# --------------------------------------------------------------------------------------


def _as_float(x) -> jax.Array:
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.float32)
    return x


def _check_last_dim(x: jax.Array, n: int, what: str) -> None:
    if x.ndim < 1 or x.shape[-1] != n:
        raise ValueError(f"{what}: expected shape (..., {n}), got {tuple(x.shape)}")


def _precision(name: str):
    if name not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {name!r}")
    return jax.lax.Precision.HIGHEST if name == "highest" else jax.lax.Precision.DEFAULT


def _gemm(x: jax.Array, w, b, precision=_HIGHEST) -> jax.Array:
    """ONNX Gemm(alpha=1, beta=1, transB=1): x @ Wᵀ + b."""
    w = jnp.asarray(w, x.dtype)
    return jnp.matmul(x, w.T, precision=precision) + jnp.asarray(b, x.dtype)


def _conv1d(x: jax.Array, w, b, stride: int, precision=_HIGHEST) -> jax.Array:
    """ONNX Conv, NCW layout, no padding, dilation 1, group 1."""
    w = jnp.asarray(w, x.dtype)
    y = jax.lax.conv_general_dilated(
        x, w, window_strides=(stride,), padding="VALID",
        dimension_numbers=("NCH", "OIH", "NCH"), precision=precision,
    )
    return y + jnp.asarray(b, x.dtype)[None, :, None]


def _leaky_relu(x: jax.Array) -> jax.Array:
    return jnp.where(x >= 0, x, jnp.asarray(LEAKY_ALPHA, x.dtype) * x)


def _encoder_batched(w: XAdapWeights, x: jax.Array, pr=_HIGHEST) -> jax.Array:
    """(B, 1200) -> (B, 8); per sample, exactly the node list of encoder.onnx."""
    bsz = x.shape[0]
    h = x.reshape(bsz, HISTORY_LEN, OBS_DIM)  # Reshape [100, -1]
    h = jnp.tanh(_gemm(h, w.enc_in_w, w.enc_in_b, pr))  # (B, 100, 32)
    h = h.reshape(bsz, -1, HISTORY_LEN)  # Reshape [1, -1, 100]: plain reshape, NOT a transpose
    h = _leaky_relu(_conv1d(h, w.enc_conv0_w, w.enc_conv0_b, 4, pr))  # (B, 32, 24)
    h = _leaky_relu(_conv1d(h, w.enc_conv1_w, w.enc_conv1_b, 1, pr))  # (B, 32, 20)
    h = _leaky_relu(_conv1d(h, w.enc_conv2_w, w.enc_conv2_b, 1, pr))  # (B, 32, 16)
    h = h.reshape(bsz, -1)  # Flatten(axis=1), channel-major -> (B, 512)
    return jnp.tanh(_gemm(h, w.enc_out_w, w.enc_out_b, pr))


def xadap_encoder(w: XAdapWeights, history_flat, precision: str = "highest") -> jax.Array:
    """Adaptation module φ: normalised history ``(1200,)`` -> latent ẑ ``(8,)`` in (−1, 1).

    ``history_flat`` is the output of :func:`build_history_input` (already normalised).
    Leading batch dimensions ``(..., 1200) -> (..., 8)`` are also accepted; the function is
    pure and works under ``jax.jit`` / ``jax.vmap``. ``precision``: "highest" (float32
    products, matches onnxruntime to < 1e-6) or "default" (the backend's fast path, e.g. TF32
    on NVIDIA GPUs: about 1e-3 from onnxruntime).
    """
    x = _as_float(history_flat)
    _check_last_dim(x, HISTORY_DIM, "xadap_encoder history_flat")
    lead = x.shape[:-1]
    out = _encoder_batched(w, x.reshape(-1, HISTORY_DIM), _precision(precision))
    return out.reshape(*lead, LATENT_DIM)


def xadap_policy(w: XAdapWeights, policy_input, precision: str = "highest") -> jax.Array:
    """Policy π (mean head): ``(20,) -> (4,)`` raw action r in (−1, 1).

    ``policy_input = [normalize_state(w, [s, r_last]) (12), ẑ (8)]``. Normalised motor speed
    is ``0.5 r + 0.5`` (network motor order: 0 front-right, 1 back-left, 2 back-right,
    3 front-left). Leading batch dimensions ``(..., 20) -> (..., 4)`` are also accepted.
    """
    x = _as_float(policy_input)
    _check_last_dim(x, POLICY_INPUT_DIM, "xadap_policy policy_input")
    pr = _precision(precision)
    obs = x[..., :-LATENT_DIM]  # Slice [0:-8]
    z = x[..., -LATENT_DIM:]  # Slice [-8:]
    f = jnp.tanh(_gemm(obs, w.pi_feat0_w, w.pi_feat0_b, pr))
    f = jnp.tanh(_gemm(f, w.pi_feat1_w, w.pi_feat1_b, pr))
    f = jnp.tanh(_gemm(f, w.pi_feat2_w, w.pi_feat2_b, pr))
    h = jnp.concatenate([f, z], axis=-1)  # Concat(axis=1): [features, latent]
    h = jnp.tanh(_gemm(h, w.pi_h0_w, w.pi_h0_b, pr))
    h = jnp.tanh(_gemm(h, w.pi_h1_w, w.pi_h1_b, pr))
    return jnp.tanh(_gemm(h, w.pi_out_w, w.pi_out_b, pr))


def normalize_state(w: XAdapWeights, s12) -> jax.Array:
    """``(x − mean[:12]) / sqrt(var[:12] + 1e-8)`` for ``s12 = [s (8), r_last (4)]``.

    Shape ``(..., 12) -> (..., 12)``; computed in the input's float dtype.
    """
    x = _as_float(s12)
    _check_last_dim(x, OBS_DIM, "normalize_state s12")
    mean = jnp.asarray(w.obs_mean, x.dtype)
    var = jnp.asarray(w.obs_var, x.dtype)
    return (x - mean) / jnp.sqrt(var + NORM_EPS)


def build_history_input(w: XAdapWeights, states, actions) -> jax.Array:
    """Normalised adaptation input ``(1200,)`` from ``states (100, 8)``, ``actions (100, 4)``.

    Rows are time steps, oldest first (row 99 is the most recent). Layout, as in the
    published wrapper: ``[((states − mean[:8]) / sqrt(var[:8] + 1e-8)).ravel() (800),
    ((actions − mean[8:12]) / sqrt(var[8:12] + 1e-8)).ravel() (400)]``; i.e. NOT interleaved
    per time step (the encoder's first Reshape(100, 12) then cuts this vector into rows of
    12 consecutive entries, which is how the weights were trained). Leading batch
    dimensions ``(..., 100, 8), (..., 100, 4) -> (..., 1200)`` are also accepted.
    """
    s = _as_float(states)
    a = _as_float(actions)
    if s.ndim < 2 or s.shape[-2:] != (HISTORY_LEN, STATE_DIM):
        raise ValueError(f"build_history_input states: expected (..., {HISTORY_LEN}, "
                         f"{STATE_DIM}), got {tuple(s.shape)}")
    if a.ndim < 2 or a.shape[-2:] != (HISTORY_LEN, ACTION_DIM):
        raise ValueError(f"build_history_input actions: expected (..., {HISTORY_LEN}, "
                         f"{ACTION_DIM}), got {tuple(a.shape)}")
    dt = jnp.result_type(s.dtype, a.dtype)
    s = s.astype(dt)
    a = a.astype(dt)
    mean = jnp.asarray(w.obs_mean, dt)
    std = jnp.sqrt(jnp.asarray(w.obs_var, dt) + NORM_EPS)
    s_n = (s - mean[:STATE_DIM]) / std[:STATE_DIM]
    a_n = (a - mean[STATE_DIM:]) / std[STATE_DIM:]
    lead = jnp.broadcast_shapes(s.shape[:-2], a.shape[:-2])
    s_n = jnp.broadcast_to(s_n, lead + s_n.shape[-2:]).reshape(*lead, HISTORY_LEN * STATE_DIM)
    a_n = jnp.broadcast_to(a_n, lead + a_n.shape[-2:]).reshape(*lead, HISTORY_LEN * ACTION_DIM)
    return jnp.concatenate([s_n, a_n], axis=-1)


# --------------------------------------------------------------------------------------
# Compact converted copy (.npz, no pickle)
# --------------------------------------------------------------------------------------


def save_npz(w: XAdapWeights, path) -> None:
    """Save converted weights to ``path`` with ``np.savez`` (numpy appends ``.npz`` if absent).

    Arrays keep their dtypes (float32 weights, float64 statistics); no pickled objects.
    """
    arrays = {k: np.asarray(getattr(w, k)) for k in FIELDS}
    np.savez(path, __format__=np.array(_NPZ_FORMAT), **arrays)


def load_npz(path) -> XAdapWeights:
    """Load weights written by :func:`save_npz` (``allow_pickle=False``); checks keys/shapes."""
    p = Path(path).expanduser()
    if not p.is_file() and p.suffix != ".npz" and p.with_name(p.name + ".npz").is_file():
        p = p.with_name(p.name + ".npz")
    if not p.is_file():
        raise FileNotFoundError(f"Xadap weights file not found: {str(p)!r}")
    with open_npz(p, "Xadap weights file") as z:
        keys = set(z.files)
        fmt = str(z["__format__"]) if "__format__" in keys else None
        if fmt != _NPZ_FORMAT:
            raise ValueError(f"{p.name}: not an Xadap weights file (format {fmt!r}, "
                             f"expected {_NPZ_FORMAT!r})")
        missing = [k for k in FIELDS if k not in keys]
        if missing:
            raise ValueError(f"{p.name}: missing arrays {missing}")
        arrays = {k: np.array(z[k]) for k in FIELDS}
    for k, a in arrays.items():
        if a.shape != _EXPECTED_SHAPES[k]:
            raise ValueError(f"{p.name}: array {k!r} has shape {a.shape}, expected "
                             f"{_EXPECTED_SHAPES[k]}")
        if np.issubdtype(a.dtype, np.floating) and not np.all(np.isfinite(a)):
            raise ValueError(f"{p.name}: array {k!r} has non-finite values (NaN/inf)")
    return XAdapWeights(**arrays)
