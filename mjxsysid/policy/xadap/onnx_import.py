"""Reading the released Xadap policy's files (``encoder.onnx``, ``mlp.onnx``, ``mean.csv``,
``var.csv``) into :class:`~mjxsysid.policy.xadap.network.XAdapWeights`, validating every ONNX node,
attribute and weight shape against the node lists that :mod:`mjxsysid.policy.xadap.network`
computes (its module docstring). Needs the optional ``onnx`` package (imported lazily).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mjxsysid.policy.xadap.network import (
    ACTION_DIM,
    ENCODER_WEIGHTS,
    FIELDS,
    HISTORY_DIM,
    HISTORY_LEN,
    LATENT_DIM,
    LEAKY_ALPHA,
    N_STATS,
    OBS_DIM,
    POLICY_INPUT_DIM,
    POLICY_WEIGHTS,
    XAdapWeights,
)

__all__ = ["load_xadap"]


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
    a = float(LEAKY_ALPHA)
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
    return {k: g.weight(name, shape) for k, (name, shape) in ENCODER_WEIGHTS.items()}


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
    return {k: g.weight(name, shape) for k, (name, shape) in POLICY_WEIGHTS.items()}


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
    return XAdapWeights(**{k: np.array(arrays[k]) for k in FIELDS})
