"""``mjxsysid export``: write mjxsysid's trained policy as ONNX files
(:mod:`mjxsysid.policy.export.graph`: one 500 Hz step, memory in and out), then check them in
onnxruntime against the JAX controller on the inputs of a recorded closed-loop flight, and time
them (:func:`run_export`).
"""
from __future__ import annotations

import dataclasses
import datetime
import platform
import time
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid import theta as P
from mjxsysid.control.low_level import Command
from mjxsysid.policy.adaptive import networks as N
from mjxsysid.policy.export.graph import (
    MOTOR_ORDER,
    OBS_FIELDS,
    OPSET,
    normalisation,
    to_onnx_model,
)
from mjxsysid.rollout.flight import fly_vehicles, one_flight, seen_imu


@dataclasses.dataclass(frozen=True)
class ExportConfig:
    """flight_seconds: closed-loop flight of the paper vehicle whose inputs check the files;
    reference/period: its reference; latency_calls: onnxruntime calls per timing (median);
    threads: onnxruntime intra-op threads (1: one core, as on an embedded computer);
    tolerance: parity target (max abs difference to the JAX controller)."""
    flight_seconds: float = 0.5
    reference: str = "lemniscate"
    period: float = 10.0
    latency_calls: int = 2000
    threads: int = 1
    tolerance: float = 1e-5
    opset: int = OPSET


def paths_for(out) -> dict:
    """``--out DIR/NAME.onnx`` -> the files written: fixed batch 1 (``NAME.onnx``), dynamic batch
    (``NAME_dynamic.onnx``), the description (``NAME.onnx.json``), the test vectors
    (``NAME_testvectors.npz``)."""
    out = Path(out)
    stem = out.with_suffix("")
    return {"fixed": out, "dynamic": stem.with_name(stem.name + "_dynamic.onnx"),
            "json": out.with_name(out.name + ".json"),
            "testvectors": stem.with_name(stem.name + "_testvectors.npz")}


def check_out(out) -> Path:
    """Validate ``--out`` before any work: a ``.onnx`` file name whose folder exists or can be
    made, not a folder itself. Raises ValueError naming the path."""
    out = Path(out)
    if out.suffix != ".onnx":
        raise ValueError(f"--out must be a file name ending in .onnx, got {out}")
    if out.is_dir():
        raise ValueError(f"--out {out} is a folder; give a file name ending in .onnx")
    parent = out.parent
    for p in (parent, *parent.parents):
        if p.exists():
            if not p.is_dir():
                raise ValueError(f"--out {out}: {p} exists and is not a folder")
            break
    return out


class Recording(NamedTuple):
    """Inputs of every step of a recorded flight (T steps) and the JAX controller's state and
    outputs there: imu (T, 6), command (T, 4), reset (T,), refresh (T,), history (T, 100, 14)
    and latent (T, 8) before the step; motor (T, 4), latent_next (T, 8), history_next (T, 100, 14)
    after; flown_motor (T, 4), flown_latent (T, 8) as the closed-loop flight recorded them."""
    imu: np.ndarray
    command: np.ndarray
    reset: np.ndarray
    refresh: np.ndarray
    history: np.ndarray
    latent: np.ndarray
    motor: np.ndarray
    latent_next: np.ndarray
    history_next: np.ndarray
    flown_motor: np.ndarray
    flown_latent: np.ndarray


def controller_steps(ctrl, imu, command):
    """Run :class:`PolicyController` step by step on given inputs from its initial state:
    imu (T, 6), command (T, 4) -> dict of its state before (history, latent, started) and its
    outputs after each step (motor, latent_next, history_next), each with leading axis T."""

    def body(carry, x):
        i, u, c = x
        new, motor = ctrl.step_at(carry, u, Command(c[0], c[1:4]), i)
        return new, dict(history=carry.history, latent=carry.zhat, started=carry.started,
                         motor=motor, latent_next=new.zhat, history_next=new.history)

    t = imu.shape[0]
    xs = (jnp.arange(t), jnp.asarray(imu, jnp.float32), jnp.asarray(command, jnp.float32))
    out = jax.jit(lambda xs: jax.lax.scan(body, ctrl.init(), xs)[1])(xs)
    return {k: np.asarray(v) for k, v in out.items()}


def record_flight(ref, cfg: ExportConfig = ExportConfig(), seed: int = 0) -> Recording:
    """Fly the paper vehicle with the policy ``ref`` (a PolicyRef) in the closed loop, then
    rebuild the inputs the controller saw at every step and its state there."""
    fl, _, _ = fly_vehicles(P.PAPER_HARDWARE, controller="policy", policy=ref, reference=cfg.reference,
                            period=cfg.period, duration=cfg.flight_seconds, seed=seed)
    f = one_flight(fl)
    imu = seen_imu(f.frame.imu)
    command = np.concatenate([np.asarray(f.a_cmd)[:, None], np.asarray(f.omega_cmd)], -1).astype(np.float32)
    ctrl = ref.load()
    s = controller_steps(ctrl, imu, command)
    t = np.arange(imu.shape[0])
    return Recording(imu=imu, command=command, reset=~s["started"], refresh=(t + 1) % ctrl.phi_every == 0,
                     history=s["history"], latent=s["latent"], motor=s["motor"],
                     latent_next=s["latent_next"], history_next=s["history_next"],
                     flown_motor=np.asarray(f.frame.motor_cmd), flown_latent=np.asarray(f.latent))


def session(path, threads: int = 1):
    """An onnxruntime CPU session with ``threads`` intra-op threads."""
    import onnxruntime as ort
    so = ort.SessionOptions()
    so.intra_op_num_threads = int(threads)
    so.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])


def feeds(rec: Recording, idx, refresh: bool | None = None) -> dict:
    """Input dict for the steps ``idx`` (an index array: a batch of teacher-forced steps) of a
    recording; ``refresh`` as recorded (the steps must then share it) unless given."""
    idx = np.atleast_1d(idx)
    if refresh is None:
        if rec.refresh[idx].min() != rec.refresh[idx].max():
            raise ValueError("steps of one batch must share refresh")
        refresh = rec.refresh[idx][0]
    return {"imu": rec.imu[idx], "command": rec.command[idx], "history": rec.history[idx],
            "latent": rec.latent[idx], "reset": rec.reset[idx], "refresh": np.array(bool(refresh))}


def run_chain(sess, rec: Recording):
    """Run a batch-1 session over the whole recording from reset, feeding its own outputs back
    (free running, as on the robot). Returns motor (T, 4), latent_next (T, 8)."""
    history = np.zeros((1, N.HISTORY, N.STATE), np.float32)
    latent = np.zeros((1, N.LATENT), np.float32)
    motors, latents = [], []
    for t in range(rec.imu.shape[0]):
        motor, latent, history = sess.run(None, {
            "imu": rec.imu[t:t + 1], "command": rec.command[t:t + 1], "history": history,
            "latent": latent, "reset": np.array([t == 0]), "refresh": np.array(bool(rec.refresh[t]))})
        motors.append(motor[0])
        latents.append(latent[0])
    return np.stack(motors), np.stack(latents)


def _maxabs(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64))))


def parity(fixed, dynamic, rec: Recording, params) -> dict:
    """Max abs differences of the ONNX sessions to the JAX controller on a recording.

    teacher_forced: the batch-1 file fed the controller's own state at every step;
    free_running: the batch-1 file feeding its outputs back over the whole flight;
    dynamic_batch: the dynamic file on all steps at once (refresh false: motor and history;
    refresh true: latent against φ(history_next) of every step);
    rebuild_vs_flight: the controller re-run on the rebuilt inputs vs the motor commands and
    latents the closed-loop flight recorded (checks the rebuild, not ONNX).
    """
    t = rec.imu.shape[0]
    m = np.zeros((t, N.ACT), np.float32)
    z = np.zeros((t, N.LATENT), np.float32)
    h = np.zeros((t, N.HISTORY, N.STATE), np.float32)
    for i in range(t):
        m[i], z[i], h[i] = (o[0] for o in fixed.run(None, feeds(rec, i)))
    tf = {"motor": _maxabs(m, rec.motor), "latent": _maxabs(z, rec.latent_next),
          "history": _maxabs(h, rec.history_next)}
    fm, fz = run_chain(fixed, rec)
    fr = {"motor": _maxabs(fm, rec.motor), "latent": _maxabs(fz, rec.latent_next)}
    f = feeds(rec, np.arange(t), refresh=False)
    dm, dz0, dh = dynamic.run(None, f)
    _, dz1, _ = dynamic.run(None, f | {"refresh": np.array(True)})
    phi = np.asarray(jax.jit(N.Networks().adapt)(params, jnp.asarray(rec.history_next)))
    db = {"batch": t, "motor": _maxabs(dm, rec.motor), "history": _maxabs(dh, rec.history_next),
          "latent_held": _maxabs(dz0, rec.latent), "latent_phi": _maxabs(dz1, phi)}
    rb = {"motor": _maxabs(rec.motor, rec.flown_motor), "latent": _maxabs(rec.latent_next, rec.flown_latent)}
    worst = max(*tf.values(), *fr.values(), *(v for k, v in db.items() if k != "batch"))
    return {"steps": t, "refresh_steps": int(rec.refresh.sum()), "teacher_forced": tf, "free_running": fr,
            "dynamic_batch": db, "rebuild_vs_flight": rb, "max_abs_diff": worst}


def latency(sess, inputs: dict, calls: int = 2000, warmup: int = 50) -> dict:
    """Median and 90th percentile (µs) of ``sess.run`` on ``inputs`` over ``calls`` calls."""
    for _ in range(warmup):
        sess.run(None, inputs)
    ts = np.empty(calls)
    for i in range(calls):
        t0 = time.perf_counter_ns()
        sess.run(None, inputs)
        ts[i] = time.perf_counter_ns() - t0
    return {"median_us": round(float(np.median(ts)) / 1e3, 2), "p90_us": round(float(np.percentile(ts, 90)) / 1e3, 2),
            "calls": int(calls)}


def step_latency(sess, rec: Recording, batch: int, calls: int, phi_every: int) -> dict:
    """Per-call latency of a session at ``batch`` on recorded steps: plain steps, steps with the
    ẑ refresh, and the mean over one refresh cycle ((phi_every − 1) plain + 1 refresh)."""
    idx = np.resize(np.flatnonzero(~rec.refresh & ~rec.reset), batch)
    f = feeds(rec, idx, refresh=False)
    plain = latency(sess, f, calls)
    refresh = latency(sess, f | {"refresh": np.array(True)}, calls)
    cycle = ((phi_every - 1) * plain["median_us"] + refresh["median_us"]) / phi_every
    return {"batch": batch, "step_us": plain, "refresh_step_us": refresh, "mean_per_step_us": round(cycle, 2)}


def describe(paths: dict, *, ref, phi_every: int, opset: int) -> dict:
    """The JSON written beside the .onnx (without the measured numbers)."""
    import importlib.metadata
    nz = normalisation()

    def io(name, shape, dtype, what):
        fixed = [1 if d == "B" else d for d in shape]
        return {"name": name, "shape": fixed, "dynamic_shape": list(shape), "dtype": dtype, "what": what}

    hist = f"(B, {N.HISTORY}, {N.STATE})"
    return {
        "what": "mjxsysid adaptive quadrotor policy: one 500 Hz step (adaptation module φ + policy π)",
        "files": {"fixed_batch_1": paths["fixed"].name, "dynamic_batch": paths["dynamic"].name,
                  "testvectors": paths["testvectors"].name},
        "inputs": [
            io("imu", ("B", 6), "float32", "gyro [rad/s] (3), specific force [m/s²] (3), body frame FLU "
                                           "(accelerometer: +9.81 on z at hover)"),
            io("command", ("B", 4), "float32", "a_cmd [m/s², commanded collective thrust / mass], "
                                               "ω_cmd [rad/s] (3), body frame"),
            io("history", ("B", N.HISTORY, N.STATE), "float32",
               f"policy memory {hist}: last {N.HISTORY} steps of [obs (10), raw action r (4)], oldest "
               "first; feed back history_next; anything (zeros) when reset"),
            io("latent", ("B", N.LATENT), "float32", "held ẑ; feed back latent_next; zeros at the start"),
            io("reset", ("B",), "bool", "true on the first step of a flight: history := the first "
                                        "observation repeated, zero actions"),
            io("refresh", (), "bool", f"true on steps t (from 0 at reset) with (t + 1) % {phi_every} == 0: "
                                      "latent_next := φ(history_next); shared by the batch"),
        ],
        "outputs": [
            io("motor", ("B", 4), "float32", "normalised rotor speed commands Ω_cmd/Ω_max in [0, 1], "
                                             "motor_order"),
            io("latent_next", ("B", N.LATENT), "float32", "φ(history_next) if refresh else latent"),
            io("history_next", ("B", N.HISTORY, N.STATE), "float32", "history with this step's "
                                                                     "[obs, r] appended"),
        ],
        "observation": nz,
        "history_row": list(OBS_FIELDS) + ["r_1", "r_2", "r_3", "r_4"],
        "raw_action": "r = tanh output in [-1, 1]; motor = clip((r + 1) / 2, 0, 1)",
        "motor_order": list(MOTOR_ORDER),
        "body_frame": "x forward, y left, z up (FLU)",
        "rate_hz": 500.0,
        "phi_every": phi_every,
        "history_len": N.HISTORY,
        "latent_dim": N.LATENT,
        "policy": ref.kind,
        "weights": str(ref.weights),
        "weights_sha256": ref.sha256(),
        "converter": f"jax2onnx {importlib.metadata.version('jax2onnx')}",
        "jax": jax.__version__,
        "opset": opset,
    }


def run_export(ref, out, cfg: ExportConfig = ExportConfig(), log=print, rec: Recording | None = None) -> dict:
    """Write the fixed and dynamic-batch ONNX files, the test vectors and the JSON for the
    mjxsysid policy ``ref`` (a PolicyRef), check them in onnxruntime against the JAX controller
    on a recorded flight (``rec``, else :func:`record_flight`), time them. Returns the JSON dict
    (with ``parity`` and ``latency``)."""
    if ref.kind != "mjxsysid":
        raise ValueError(f"export writes mjxsysid's own policy; --policy {ref.kind} is not exportable "
                         "(the released Xadap policy already is ONNX: encoder.onnx, mlp.onnx)")
    import onnx

    paths = paths_for(check_out(out))
    paths["fixed"].parent.mkdir(parents=True, exist_ok=True)
    ctrl = ref.load()
    desc = describe(paths, ref=ref, phi_every=ctrl.phi_every, opset=cfg.opset)
    meta = {k: desc[k] for k in ("rate_hz", "phi_every", "weights_sha256")} | {
        "motor_order": ", ".join(MOTOR_ORDER), "io": "see " + paths["json"].name}
    t0 = time.time()
    for key, batch in (("fixed", 1), ("dynamic", "B")):
        onnx.save(to_onnx_model(ctrl.params, batch=batch, opset=cfg.opset, metadata=meta), paths[key])
        log(f"wrote {paths[key]} ({paths[key].stat().st_size / 1e3:.0f} kB)")
    desc["export_s"] = round(time.time() - t0, 1)

    if rec is None:
        log(f"flying the paper vehicle {cfg.flight_seconds} s ({cfg.reference}) to record inputs")
        rec = record_flight(ref, cfg)
    np.savez_compressed(paths["testvectors"], imu=rec.imu, command=rec.command, reset=rec.reset,
                        refresh=rec.refresh, motor=rec.motor, latent_next=rec.latent_next)
    fixed, dynamic = session(paths["fixed"], cfg.threads), session(paths["dynamic"], cfg.threads)
    par = parity(fixed, dynamic, rec, ctrl.params)
    par["tolerance"] = cfg.tolerance
    par["ok"] = bool(par["max_abs_diff"] <= cfg.tolerance)
    desc["parity"] = par
    import onnxruntime as ort
    desc["latency"] = {
        "runtime": f"onnxruntime {ort.__version__}, CPUExecutionProvider, {cfg.threads} intra-op thread(s)",
        "machine": _machine(), "date": datetime.date.today().isoformat(),
        "batch_1": step_latency(fixed, rec, 1, cfg.latency_calls, ctrl.phi_every)}
    desc["testvectors"] = {"file": paths["testvectors"].name,
                           "what": "a recorded flight's inputs (imu, command, reset, refresh per step) and "
                                   "the JAX controller's outputs (motor, latent_next): run the batch-1 file "
                                   "from reset, feeding history_next/latent_next back, and compare"}
    paths["json"].write_text(jsonout.dumps(desc, indent=2, ensure_ascii=False) + "\n")
    log(f"wrote {paths['json']}, {paths['testvectors']}")
    return desc


def _machine() -> str:
    import os
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores visible"
