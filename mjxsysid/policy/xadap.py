"""Importer for the released Extreme-Adaptation ("Xadap") quadrotor policy (ONNX → pure JAX).

The released policy (``encoder.onnx``, ``mlp.onnx``, ``mean.csv``, ``var.csv``; see the
README next to the files) is read once with ``onnx`` into an :class:`XAdapWeights` pytree;
everything after that is plain ``jax.numpy`` and works under ``jit``/``vmap``/``grad``
without ``onnx`` installed (use :func:`save_npz` / :func:`load_npz` to carry converted weights).

The JAX functions follow the ONNX node lists exactly (opset 11, exported by PyTorch 2.1.2);
:func:`load_xadap` refuses any graph whose node list, attributes or weight shapes differ.

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

from mjxsysid.checkpoint import open_npz

__all__ = [
    "XAdapWeights",
    "load_xadap",
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
_LEAKY_ALPHA = np.float32(0.01)  # stored in the graph as float32 0.009999999776482582
_HIGHEST = jax.lax.Precision.HIGHEST
PRECISIONS = ("highest", "default")
_NPZ_FORMAT = "mjxsysid.xadap/1"

# Weight field name -> (ONNX initializer name, shape). Encoder first, then policy.
_ENCODER_WEIGHTS: dict[str, tuple[str, tuple[int, ...]]] = {
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
_POLICY_WEIGHTS: dict[str, tuple[str, tuple[int, ...]]] = {
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


_FIELDS: tuple[str, ...] = tuple(_ENCODER_WEIGHTS) + tuple(_POLICY_WEIGHTS) + tuple(_STAT_SHAPES)
_EXPECTED_SHAPES: dict[str, tuple[int, ...]] = {
    **{k: v[1] for k, v in _ENCODER_WEIGHTS.items()},
    **{k: v[1] for k, v in _POLICY_WEIGHTS.items()},
    **_STAT_SHAPES,
}
assert set(_FIELDS) == {f.name for f in XAdapWeights.__dataclass_fields__.values()}


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
    return jnp.where(x >= 0, x, jnp.asarray(_LEAKY_ALPHA, x.dtype) * x)


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
# ONNX loading and graph validation
# --------------------------------------------------------------------------------------


class _Graph:
    """Minimal view of an ONNX graph for structure checks."""

    def __init__(self, onnx_mod, model, fname: str):
        from onnx import numpy_helper

        self.fname = fname
        g = model.graph
        self.inits = {t.name: numpy_helper.to_array(t) for t in g.initializer}
        self.consts: dict[str, np.ndarray] = {}
        self.nodes = []
        for n in g.node:
            attrs = {a.name: onnx_mod.helper.get_attribute_value(a) for a in n.attribute}
            if n.op_type == "Constant":
                if "value" not in attrs or len(n.output) != 1:
                    self.fail(f"unsupported Constant node {n.name!r}")
                self.consts[n.output[0]] = numpy_helper.to_array(attrs["value"])
                continue
            self.nodes.append((n.op_type, list(n.input), list(n.output), attrs))
        self.inputs = [i for i in g.input if i.name not in self.inits]
        self.outputs = list(g.output)

    def fail(self, msg: str):
        raise ValueError(f"{self.fname}: unexpected graph structure: {msg}")

    def io_shape(self, vi) -> tuple:
        return tuple(d.dim_value if d.HasField("dim_value") else d.dim_param
                     for d in vi.type.tensor_type.shape.dim)

    def check_io(self, in_shape: tuple, out_shape: tuple) -> tuple[str, str]:
        if len(self.inputs) != 1 or len(self.outputs) != 1:
            self.fail(f"expected 1 input and 1 output, got {len(self.inputs)} and "
                      f"{len(self.outputs)}")
        i, o = self.inputs[0], self.outputs[0]
        for vi, want, what in ((i, in_shape, "input"), (o, out_shape, "output")):
            if vi.type.tensor_type.elem_type != 1:  # TensorProto.FLOAT
                self.fail(f"{what} {vi.name!r} is not float32")
            got = self.io_shape(vi)
            if len(got) != len(want) or any(isinstance(g_, int) and g_ != w_
                                            for g_, w_ in zip(got, want)):
                self.fail(f"{what} {vi.name!r} has shape {got}, expected {want}")
        return i.name, o.name

    def check_ops(self, expected: list[str]) -> None:
        got = [n[0] for n in self.nodes]
        if got != expected:
            self.fail(f"non-Constant op sequence {got} != expected {expected}")

    def const(self, name: str, what: str) -> np.ndarray:
        if name in self.consts:
            return self.consts[name]
        if name in self.inits:
            return self.inits[name]
        self.fail(f"{what}: {name!r} is not a constant")

    def weight(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        if name not in self.inits:
            self.fail(f"missing initializer {name!r}")
        a = self.inits[name]
        if a.shape != shape or a.dtype != np.float32:
            self.fail(f"initializer {name!r} has shape {a.shape} / dtype {a.dtype}, "
                      f"expected {shape} / float32")
        return a

    def chain(self, start: int, x: str, spec: list[tuple]) -> str:
        """Check nodes[start:start+len(spec)] form a chain fed by ``x``; returns last output.

        spec entries: ("Gemm", W, b) | ("Tanh",) | ("LeakyRelu", alpha) | ("Flatten", axis)
        | ("Reshape", shape) | ("Conv", W, b, kernel, stride).
        """
        for k, item in enumerate(spec):
            op, ins, outs, attrs = self.nodes[start + k]
            where = f"node {start + k} ({op})"
            if op != item[0]:
                self.fail(f"{where}: expected {item[0]}")
            if not ins or ins[0] != x:
                self.fail(f"{where}: data input {ins[:1]} is not {x!r}")
            if len(outs) != 1:
                self.fail(f"{where}: expected one output")
            if op == "Gemm":
                ok = (ins[1:] == [item[1], item[2]]
                      and float(attrs.get("alpha", 1.0)) == 1.0
                      and float(attrs.get("beta", 1.0)) == 1.0
                      and int(attrs.get("transA", 0)) == 0
                      and int(attrs.get("transB", 0)) == 1)
                if not ok:
                    self.fail(f"{where}: expected Gemm(x, {item[1]}, {item[2]}, alpha=1, "
                              f"beta=1, transB=1), got inputs {ins}, attrs {attrs}")
            elif op == "Tanh":
                if len(ins) != 1:
                    self.fail(f"{where}: unexpected inputs {ins}")
            elif op == "LeakyRelu":
                if abs(float(attrs.get("alpha", 0.01)) - item[1]) > 1e-7:
                    self.fail(f"{where}: alpha {attrs.get('alpha')} != {item[1]}")
            elif op == "Flatten":
                if int(attrs.get("axis", 1)) != item[1]:
                    self.fail(f"{where}: axis {attrs.get('axis')} != {item[1]}")
            elif op == "Reshape":
                shape = self.const(ins[1], where).tolist()
                if shape != list(item[1]) or int(attrs.get("allowzero", 0)) != 0:
                    self.fail(f"{where}: target shape {shape} != {list(item[1])}")
            elif op == "Conv":
                _, w_name, b_name, kernel, stride = item
                ok = (ins[1:] == [w_name, b_name]
                      and list(attrs.get("kernel_shape", [kernel])) == [kernel]
                      and list(attrs.get("strides", [1])) == [stride]
                      and list(attrs.get("pads", [0, 0])) == [0, 0]
                      and list(attrs.get("dilations", [1])) == [1]
                      and int(attrs.get("group", 1)) == 1
                      and attrs.get("auto_pad", b"NOTSET") in (b"NOTSET", "NOTSET"))
                if not ok:
                    self.fail(f"{where}: expected Conv({w_name}, kernel {kernel}, stride "
                              f"{stride}, no padding), got inputs {ins}, attrs {attrs}")
            else:  # pragma: no cover - spec error
                raise AssertionError(op)
            x = outs[0]
        return x

    def check_slice(self, idx: int, x: str, start: int, end_pred, what: str) -> str:
        op, ins, outs, _ = self.nodes[idx]
        if op != "Slice" or len(ins) < 3 or ins[0] != x:
            self.fail(f"node {idx}: expected Slice of {x!r} ({what})")
        starts = self.const(ins[1], what).tolist()
        ends = self.const(ins[2], what).tolist()
        axes = self.const(ins[3], what).tolist() if len(ins) > 3 and ins[3] else [0]
        steps = self.const(ins[4], what).tolist() if len(ins) > 4 and ins[4] else [1]
        if not (starts == [start] and len(ends) == 1 and end_pred(ends[0])
                and axes in ([1], [-1]) and steps == [1]):
            self.fail(f"node {idx}: {what} Slice starts={starts} ends={ends} axes={axes} "
                      f"steps={steps}")
        return outs[0]


def _import_onnx():
    try:
        import onnx
    except ImportError as e:  # pragma: no cover - depends on environment
        raise ImportError(
            "load_xadap needs the optional 'onnx' package to read encoder.onnx/mlp.onnx: "
            "pip install onnx  (or pip install 'mjxsysid[dev]'); converted weights saved "
            "with save_npz() load without it via load_npz()."
        ) from e
    return onnx


def _read_encoder(onnx_mod, path: Path) -> dict[str, np.ndarray]:
    g = _Graph(onnx_mod, onnx_mod.load(str(path)), path.name)
    x, y = g.check_io((1, HISTORY_DIM), (1, LATENT_DIM))
    g.check_ops(["Reshape", "Gemm", "Tanh", "Reshape", "Conv", "LeakyRelu", "Conv",
                 "LeakyRelu", "Conv", "LeakyRelu", "Flatten", "Gemm", "Tanh"])
    a = float(_LEAKY_ALPHA)
    out = g.chain(0, x, [
        ("Reshape", (HISTORY_LEN, -1)),
        ("Gemm", "encoder.0.weight", "encoder.0.bias"),
        ("Tanh",),
        ("Reshape", (1, -1, HISTORY_LEN)),
        ("Conv", "conv_layers.0.weight", "conv_layers.0.bias", 8, 4),
        ("LeakyRelu", a),
        ("Conv", "conv_layers.2.weight", "conv_layers.2.bias", 5, 1),
        ("LeakyRelu", a),
        ("Conv", "conv_layers.4.weight", "conv_layers.4.bias", 5, 1),
        ("LeakyRelu", a),
        ("Flatten", 1),
        ("Gemm", "linear_output.0.weight", "linear_output.0.bias"),
        ("Tanh",),
    ])
    if out != y:
        g.fail(f"final Tanh output {out!r} is not the graph output {y!r}")
    return {k: g.weight(name, shape) for k, (name, shape) in _ENCODER_WEIGHTS.items()}


def _read_policy(onnx_mod, path: Path) -> dict[str, np.ndarray]:
    g = _Graph(onnx_mod, onnx_mod.load(str(path)), path.name)
    x, y = g.check_io((1, POLICY_INPUT_DIM), (1, ACTION_DIM))
    g.check_ops(["Slice", "Gemm", "Tanh", "Gemm", "Tanh", "Gemm", "Tanh", "Slice", "Concat",
                 "Gemm", "Tanh", "Gemm", "Tanh", "Gemm", "Tanh",
                 "Exp", "Mul", "Shape", "ConstantOfShape", "Add", "Add", "Shape", "Expand"])
    obs = g.check_slice(0, x, 0, lambda e: e == -LATENT_DIM, "observation")
    feat = g.chain(1, obs, [
        ("Gemm", "mlp_extractor.shared_net.0.weight", "mlp_extractor.shared_net.0.bias"),
        ("Tanh",),
        ("Gemm", "mlp_extractor.shared_net.2.weight", "mlp_extractor.shared_net.2.bias"),
        ("Tanh",),
        ("Gemm", "mlp_extractor.shared_net.4.weight", "mlp_extractor.shared_net.4.bias"),
        ("Tanh",),
    ])
    lat = g.check_slice(7, x, -LATENT_DIM, lambda e: e >= 2**31 - 1, "latent")
    op, ins, outs, attrs = g.nodes[8]
    if ins != [feat, lat] or int(attrs.get("axis", 0)) not in (1, -1):
        g.fail(f"node 8: expected Concat([{feat!r}, {lat!r}], axis=1), got {ins}, {attrs}")
    mean = g.chain(9, outs[0], [
        ("Gemm", "mlp_extractor.policy_net.0.weight", "mlp_extractor.policy_net.0.bias"),
        ("Tanh",),
        ("Gemm", "mlp_extractor.policy_net.2.weight", "mlp_extractor.policy_net.2.bias"),
        ("Tanh",),
        ("Gemm", "action_net.0.weight", "action_net.0.bias"),
        ("Tanh",),
    ])
    # Tail: Exp(log_std) ... Expand(mean, Shape(...)). The graph output must be the
    # Expand of the mean head (the log-std branch only provides a shape).
    if g.nodes[15][1] != ["log_std"]:
        g.fail(f"node 15: expected Exp(log_std), got inputs {g.nodes[15][1]}")
    op, ins, outs, _ = g.nodes[-1]
    if ins[0] != mean or outs[0] != y:
        g.fail(f"graph output {y!r} is not Expand of the mean head {mean!r} "
               f"(Expand inputs {ins}, outputs {outs})")
    return {k: g.weight(name, shape) for k, (name, shape) in _POLICY_WEIGHTS.items()}


def _read_stats(path: Path) -> np.ndarray:
    try:
        a = np.loadtxt(path, dtype=np.float64, delimiter=None, ndmin=1).reshape(-1)
    except ValueError as e:
        raise ValueError(f"{path.name}: cannot parse as whitespace-separated numbers: {e}") from e
    if a.shape != (N_STATS,):
        raise ValueError(f"{path.name}: expected {N_STATS} values, got {a.size}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{path.name}: contains non-finite values")
    return a


def load_xadap(path) -> XAdapWeights:
    """Read ``encoder.onnx``, ``mlp.onnx``, ``mean.csv``, ``var.csv`` from directory ``path``.

    Checks every node, attribute and weight shape against the known graphs (see module
    docstring) and raises ``ValueError`` naming the file on any mismatch;
    ``FileNotFoundError`` names a missing directory or file. Needs ``onnx`` (imported
    lazily; ``ImportError`` otherwise).
    """
    d = Path(path).expanduser()
    if not d.is_dir():
        raise FileNotFoundError(
            f"Xadap policy directory not found: {str(d)!r} (expected encoder.onnx, mlp.onnx, "
            "mean.csv, var.csv)")
    files = {n: d / n for n in ("encoder.onnx", "mlp.onnx", "mean.csv", "var.csv")}
    for n, p in files.items():
        if not p.is_file():
            raise FileNotFoundError(f"Xadap policy file missing: {str(p)!r} ({n})")
    onnx_mod = _import_onnx()
    arrays: dict[str, np.ndarray] = {}
    arrays.update(_read_encoder(onnx_mod, files["encoder.onnx"]))
    arrays.update(_read_policy(onnx_mod, files["mlp.onnx"]))
    mean = _read_stats(files["mean.csv"])
    var = _read_stats(files["var.csv"])
    if np.any(var < 0):
        raise ValueError("var.csv: contains negative variances")
    arrays.update(mean=mean, var=var, obs_mean=mean[:OBS_DIM].copy(),
                  obs_var=var[:OBS_DIM].copy())
    return XAdapWeights(**{k: np.array(arrays[k]) for k in _FIELDS})


# --------------------------------------------------------------------------------------
# Compact converted copy (.npz, no pickle)
# --------------------------------------------------------------------------------------


def save_npz(w: XAdapWeights, path) -> None:
    """Save converted weights to ``path`` with ``np.savez`` (numpy appends ``.npz`` if absent).

    Arrays keep their dtypes (float32 weights, float64 statistics); no pickled objects.
    """
    arrays = {k: np.asarray(getattr(w, k)) for k in _FIELDS}
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
        missing = [k for k in _FIELDS if k not in keys]
        if missing:
            raise ValueError(f"{p.name}: missing arrays {missing}")
        arrays = {k: np.array(z[k]) for k in _FIELDS}
    for k, a in arrays.items():
        if a.shape != _EXPECTED_SHAPES[k]:
            raise ValueError(f"{p.name}: array {k!r} has shape {a.shape}, expected "
                             f"{_EXPECTED_SHAPES[k]}")
        if np.issubdtype(a.dtype, np.floating) and not np.all(np.isfinite(a)):
            raise ValueError(f"{p.name}: array {k!r} has non-finite values (NaN/inf)")
    return XAdapWeights(**arrays)
