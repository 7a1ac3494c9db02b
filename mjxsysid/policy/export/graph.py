"""The ONNX graph of mjxsysid's trained policy, for a robot (``mjxsysid export``).

The exported graph is **one 500 Hz step** of :class:`~mjxsysid.policy.adaptive.controller.PolicyController`,
with the policy's memory passed in and out explicitly (like an RNN cell), so the robot keeps two
arrays and nothing else::

    inputs   imu (B, 6)            gyro [rad/s] (3), specific force [m/s²] (3), body frame FLU
             command (B, 4)        a_cmd [m/s², collective thrust / mass], ω_cmd [rad/s] (3)
             history (B, 100, 14)  policy memory (feed back ``history_next``; zeros with reset)
             latent (B, 8)         held ẑ (feed back ``latent_next``; zeros at the start)
             reset (B,) bool       first step of a flight: history := first observation repeated
             refresh () bool       ẑ := φ(history_next) after this step (every ``phi_every``-th)
    outputs  motor (B, 4)          Ω_cmd/Ω_max ∈ [0, 1], mjxsysid's rotor order
             latent_next (B, 8)    φ(history_next) if refresh else latent
             history_next (B, 100, 14)

Inside: observation = fixed affine scaling of [imu, command] (:func:`normalisation`), policy
state s = [obs, previous raw action] (the previous action is the last row of ``history``),
r = π(s, latent) (deterministic mean), motor = clip((r + 1)/2, 0, 1), history push, then φ under
an ONNX ``If`` on ``refresh``, so φ costs nothing on the other steps.

Why one graph with ẑ in and out rather than φ and π as separate files: the controller's timing
(π at step t uses the ẑ refreshed after step t − 1 at the latest; φ reads the history *after* the
push) is then reproduced exactly by a loop that only feeds outputs back and sets ``refresh`` on
every ``phi_every``-th step; the robot never builds the history or scales an observation itself,
and still pays for φ only when it runs.

The conversion uses jax2onnx (the same :mod:`mjxsysid.policy.adaptive.networks` functions the controller
runs, weights as initializers); :func:`mjxsysid.policy.export.run.run_export` then checks the files in onnxruntime against
the JAX controller on inputs recorded in a closed-loop flight, and times them.
"""
from __future__ import annotations

import logging

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.policy.adaptive import networks as N

INPUTS = ("imu", "command", "history", "latent", "reset", "refresh")
OUTPUTS = ("motor", "latent_next", "history_next")
OPSET = 17  # TensorRT 8.5+ (JetPack 5), onnxruntime ≥ 1.13
OBS_FIELDS = ("gyro_x", "gyro_y", "gyro_z", "specific_force_x", "specific_force_y", "specific_force_z",
              "a_cmd", "omega_cmd_x", "omega_cmd_y", "omega_cmd_z")
MOTOR_ORDER = ("1 front-right (CCW)", "2 front-left (CW)", "3 back-left (CCW)", "4 back-right (CW)")


def policy_step(params, imu, command, history, latent, reset, refresh):
    """One step of the policy on a batch (the exported graph).

    params: {'phi', 'pi', ...} of :class:`~mjxsysid.policy.adaptive.networks.Networks`; imu (B, 6);
    command (B, 4) [a_cmd, ω_cmd]; history (B, 100, 14); latent (B, 8); reset (B,) bool;
    refresh () bool. Returns motor (B, 4), latent_next (B, 8), history_next (B, 100, 14).
    Equal to :meth:`PolicyController.step_at` with carry (history, last_raw = history[-1, 10:],
    zhat = latent, started = ~reset) and refresh = (index + 1) % phi_every == 0.
    """
    nets = N.Networks()
    obs = N.observation(imu, command[..., 0], command[..., 1:4])
    history = jnp.where(reset[..., None, None], N.initial_history(obs), history)
    s = jnp.concatenate([obs, history[..., -1, N.OBS:]], -1)
    raw, _ = nets.act(params, s, latent)
    history = N.push_history(history, obs, raw)
    latent = jax.lax.cond(refresh, lambda h: nets.adapt(params, h), lambda h: latent, history)
    return N.to_motor(raw), latent, history


def normalisation() -> dict:
    """The observation's affine scaling, read off :func:`networks.observation`:
    obs = (x − shift) / scale, x = [gyro (3), specific force (3), a_cmd, ω_cmd (3)]."""
    def obs(x):
        return np.asarray(N.observation(x[:6], x[6], x[7:10]), np.float64)
    x0 = np.zeros(N.OBS, np.float32)
    o0 = obs(x0)
    jac = np.stack([obs(np.eye(N.OBS, dtype=np.float32)[i]) - o0 for i in range(N.OBS)], 1)
    if not np.allclose(jac, np.diag(np.diag(jac)), atol=1e-7):
        raise AssertionError("observation scaling is not per-field")
    scale = 1.0 / np.diag(jac)
    shift = -o0 * scale
    return {"fields": list(OBS_FIELDS), "shift": [round(float(v), 5) + 0.0 for v in shift],
            "scale": [round(float(v), 5) for v in scale],
            "formula": "obs = (x - shift) / scale; x = [imu, command]"}


def _if_subgraph_cleanup(model):
    """Drop initializers of If branches that no node reads (jax2onnx leaves shape constants
    there; onnxruntime warns about each)."""
    def used(graph) -> set:
        names = set()
        for node in graph.node:
            names.update(node.input)
            for a in node.attribute:
                for g in ([a.g] if a.HasField("g") else []) + list(a.graphs):
                    names |= used(g)
        names.update(o.name for o in graph.output)
        return names

    def clean(graph):
        for node in graph.node:
            for a in node.attribute:
                for g in ([a.g] if a.HasField("g") else []) + list(a.graphs):
                    keep = [t for t in g.initializer if t.name in used(g)]
                    del g.initializer[:]
                    g.initializer.extend(keep)
                    clean(g)
    clean(model.graph)
    return model


def to_onnx_model(params, *, batch, opset: int = OPSET, metadata: dict | None = None):
    """The ONNX ModelProto of :func:`policy_step` with ``params`` as initializers; batch an int
    (fixed) or a name (dynamic axis)."""
    import types

    from jax2onnx import to_onnx
    params = jax.tree.map(lambda a: np.asarray(a, np.float32), params)

    def spec(shape, dtype=np.float32):
        return types.SimpleNamespace(shape=shape, dtype=np.dtype(dtype))

    b = batch
    # jax2onnx's IR logs a warning per intermediate value whose shape it leaves symbolic.
    quiet = logging.getLogger("onnx_ir.serde")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        model = to_onnx(lambda *a: policy_step(params, *a),
                        [spec((b, 6)), spec((b, 4)), spec((b, N.HISTORY, N.STATE)), spec((b, N.LATENT)),
                         spec((b,), bool), spec((), bool)],
                        model_name="mjxsysid_policy_step", opset=opset,
                        input_names=list(INPUTS), output_names=list(OUTPUTS))
    finally:
        quiet.setLevel(level)
    model = _if_subgraph_cleanup(model)
    model.doc_string = ("mjxsysid adaptive quadrotor policy, one 500 Hz step (adaptation module φ and "
                        "policy π); see the .onnx.json beside this file")
    for k, v in (metadata or {}).items():
        e = model.metadata_props.add()
        e.key, e.value = str(k), str(v)
    import onnx
    onnx.checker.check_model(model, full_check=True)
    return model
