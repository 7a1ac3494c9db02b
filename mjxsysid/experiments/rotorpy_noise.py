"""Sim-to-sim under IMU noise (issue 29): the shipped policy flies the paper vehicle with one worn
motor in RotorPy 3.0 (aerodynamics on), a 10 s lemniscate, with white noise and a per-flight bias
added to the IMU the policy reads and the log records, at multiples of the project's hardware-like
levels (gyro 0.01 rad/s and accelerometer 0.1 m/s² per 2 ms sample, biases 0.005 rad/s and
0.05 m/s²: mjxsysid.studies.noise.LEVELS); each flight is written as a flight log and decoded as
``mjxsysid decode --log LOG --truth VEHICLE.json`` does (seed 0, 100 samples, the flight-level
posterior). Reported per level: the tracking RMSE and how many of the 24 quantities (19 parameters
and 5 identifiable combinations) have their truth inside the decoded 5–95 % interval.

    .venv/bin/pip install rotorpy==3.0.0          # not a dependency of mjxsysid
    mjxsysid experiment rotorpy-noise --out docs/runs/measurements/rotorpy-noise
    mjxsysid experiment rotorpy-noise --quick --out /tmp/rotorpy_quick   # 2 s, two levels: a smoke run

The mapping of θ onto RotorPy: mass, inertia, arm (RotorPy's rotor order front-left, front-right,
back-right, back-left; written to the log in mjxsysid's order), k_t -> k_eta, k_τ -> k_m (yaw signs
as mjxsysid's), Ω_max -> rotor_speed_max, τ_m -> tau_m. Motor effectiveness η_i (RotorPy has one
k_eta) is a motor that reaches √η_i of its commanded speed: thrust and yaw torque η_i k Ω_cmd², as
in mjxsysid. Drag: mjxsysid's linear D is RotorPy's rotor drag (H force, ∝ Ω v) with k_d, k_z set so
that it equals D at the nominal hover speed; RotorPy's parasitic drag and translational lift are
the hummingbird's (aerodynamics mjxsysid does not model). The position/attitude cascade
(mjxsysid's baseline gains) sees RotorPy's true state; the IMU is RotorPy's ideal one at the
centre of mass (specific force and body rates, FLU) plus the level's noise.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid import theta as P
from mjxsysid.control.high_level import Cascade, Estimate
from mjxsysid.control.references import Lemniscate
from mjxsysid.experiments.common import write_results
from mjxsysid.logs.csvlog import LOG_DT, write_log
from mjxsysid.policy.adaptive.controller import PolicyController
from mjxsysid.policy.interface import PRETRAINED_DIR, file_sha256
from mjxsysid.studies.decode import run_decode
from mjxsysid.studies.noise import LEVELS as NOISE_LEVELS

LEVELS = ("clean", "x1", "x5_bias", "x5_white", "x20")
LABELS = {"clean": "clean", "x1": "× 1 (white + bias)", "x5_bias": "× 5 bias only",
          "x5_white": "× 5 white only", "x20": "× 20 (white + bias)"}
ROTORPY_ORDER = (1, 0, 3, 2)   # mjxsysid's rotor i is RotorPy's rotor ROTORPY_ORDER[i] (and back: the same)
PIP = ".venv/bin/pip install rotorpy==3.0.0  (or the wheel: .venv/bin/pip install rotorpy-3.0.0-py3-none-any.whl)"


def import_rotorpy():
    try:
        from rotorpy.sensors.imu import Imu
        from rotorpy.vehicles.multirotor import Multirotor
    except ImportError as e:
        sys.exit(f"error: RotorPy is not installed ({e}); install it with\n    {PIP}")
    return Multirotor, Imu


def worn_vehicle(motor: int, eta: float) -> np.ndarray:
    """The paper vehicle with motor ``motor`` (1–4, mjxsysid's order) at effectiveness ``eta``."""
    theta = P.paper_hardware()
    theta[P.ETA.start + motor - 1] = eta
    return P.validate_theta(theta, what="vehicle")


def rotorpy_params(theta) -> dict:
    """RotorPy quad_params for θ (19,) (see the module docstring); rotors in RotorPy's order."""
    m, arm, kt, ktau = (float(theta[i]) for i in (P.MASS, P.ARM, P.KT, P.KTAU))
    jxx, jyy, jzz = (float(j) for j in theta[P.INERTIA])
    dxx, _, dzz = (float(d) for d in theta[P.DRAG])
    hover = np.sqrt(m * P.GRAVITY / (4 * kt))          # nominal hover rotor speed, rad/s
    xy = arm * P.ROTOR_DIRECTIONS[list(ROTORPY_ORDER)]   # FL, FR, BR, BL
    return {"mass": m, "Ixx": jxx, "Iyy": jyy, "Izz": jzz, "Ixy": 0.0, "Iyz": 0.0, "Ixz": 0.0,
            "num_rotors": 4, "rotor_radius": 0.10,
            "rotor_pos": {f"r{i + 1}": np.array([x, y, 0.0]) for i, (x, y) in enumerate(xy)},
            "rotor_directions": P.YAW_SIGNS[list(ROTORPY_ORDER)].astype(int), "rI": np.zeros(3),
            "c_Dx": 0.5e-2, "c_Dy": 0.5e-2, "c_Dz": 1e-2,                   # hummingbird parasitic drag
            "k_eta": kt, "k_m": ktau, "k_d": dxx / (4 * hover), "k_z": dzz / (4 * hover),
            "k_h": 3.39e-3, "k_flap": 0.0,                                  # hummingbird translational lift
            "tau_m": float(theta[P.TAU_M]), "rotor_speed_min": 0.0,
            "rotor_speed_max": float(theta[P.OMEGA_MAX]), "motor_noise_std": 0.0}


@jax.jit
def _control(ctrl, high, ref, hc, lc, pos, vel, quat, omega, imu, i):
    """One 2 ms step of the cascade and the policy (as mjxsysid.rollout.harness.run_loop does)."""
    r = ref.at(i.astype(jnp.float32) * LOG_DT)
    hc, cmd = high.step(hc, Estimate(pos, vel, quat, omega), r, LOG_DT)
    lc, u = ctrl.step_at(lc, imu, cmd, i)
    return hc, lc, cmd.a_cmd, cmd.omega_cmd, u, r.pos


def fly(theta, seconds: float, noise: dict, white, bias, ctrl) -> dict:
    """Fly θ in RotorPy for ``seconds`` on the 10 s lemniscate; the IMU the policy reads is
    RotorPy's plus ``bias`` (6,) and ``white`` (T, 6) standard normals scaled by the level's stds.
    Returns the log's arrays (row k: what the policy saw and did at step k) and the position error."""
    Multirotor, Imu = import_rotorpy()
    steps = int(round(seconds / LOG_DT))
    ref = Lemniscate.make(period=10.0)
    high = Cascade.make("baseline")
    sq_eta = np.sqrt(np.asarray(theta[P.ETA], np.float64))
    omega_max = float(theta[P.OMEGA_MAX])
    hover = np.sqrt(theta[P.MASS] * P.GRAVITY / (4 * theta[P.KT]))
    state = {"x": np.asarray(ref.at(0.0).pos, np.float64), "v": np.zeros(3), "q": np.array([0.0, 0, 0, 1]),
             "w": np.zeros(3), "wind": np.zeros(3), "rotor_speeds": np.full(4, hover, np.float64)}
    vehicle = Multirotor(rotorpy_params(theta), initial_state=state, control_abstraction="cmd_motor_speeds",
                         aero=True)
    imu_model = Imu()
    sd = np.array([noise["gyro_noise"]] * 3 + [noise["accel_noise"]] * 3)
    sb = np.array([noise["gyro_bias"]] * 3 + [noise["accel_bias"]] * 3)
    true = np.array([0.0, 0, 0, 0, 0, P.GRAVITY])   # at rest before the first step
    hc, lc = high.init(), ctrl.init()
    rec = {k: [] for k in ("imu", "a_cmd", "omega_cmd", "motor", "err")}
    for i in range(steps):
        imu = true + sb * bias + sd * white[i]
        x, v, q, w = state["x"], state["v"], state["q"], state["w"]
        hc, lc, a_cmd, w_cmd, u, ref_pos = _control(
            ctrl, high, ref, hc, lc, jnp.asarray(x, jnp.float32), jnp.asarray(v, jnp.float32),
            jnp.asarray(np.r_[q[3], q[:3]], jnp.float32), jnp.asarray(w, jnp.float32),
            jnp.asarray(imu, jnp.float32), jnp.int32(i))
        u = np.clip(np.asarray(u, np.float64), 0.0, 1.0)
        control = {"cmd_motor_speeds": (sq_eta * u * omega_max)[list(ROTORPY_ORDER)]}
        state = vehicle.step(state, control, LOG_DT)
        meas = imu_model.measurement(state, vehicle.statedot(state, control, LOG_DT), with_noise=False)
        true = np.r_[meas["gyro"], meas["accel"]]
        for k, val in (("imu", imu), ("a_cmd", float(a_cmd)), ("omega_cmd", np.asarray(w_cmd)), ("motor", u),
                       ("err", state["x"] - np.asarray(ref_pos))):
            rec[k].append(val)
        if np.linalg.norm(rec["err"][-1]) > 3.0 or state["x"][2] < 0 or not np.all(np.isfinite(state["x"])):
            break   # lost (the project's failure test: 3 m from the reference or below the ground)
    rec = {k: np.asarray(v) for k, v in rec.items()}
    rec["t"] = LOG_DT * np.arange(len(rec["a_cmd"]))
    rec["lost"] = len(rec["t"]) < steps
    return rec


FULL = {"levels": ",".join(LEVELS), "seconds": 10.0, "samples": 100, "worn_motor": 1, "eta": 0.8}
"""The committed run's settings: ``samples`` decoded (decode's default), ``worn_motor`` mjxsysid's
rotor number (1–4), ``eta`` its effectiveness."""
QUICK = {**FULL, "seconds": 2.0, "samples": 20, "levels": "clean,x5_white"}


def run(out, *, quick=False, policy=None, seed=0, progress=True) -> dict:
    """The RotorPy flights and their decoding (see the module doc) into OUT/results.json,
    results.md (the table) and OUT/logs/ (the logs, truth.json and decode outputs). ``seed``: the
    IMU noise draws and decoding (decode's --seed). The shipped policy and decoders fly and decode
    (``policy`` is not used)."""
    from types import SimpleNamespace
    a = SimpleNamespace(**(QUICK if quick else FULL), seed=seed, out=Path(out), logs=Path(out) / "logs")
    levels = a.levels.split(",")
    import_rotorpy()
    import rotorpy
    t0 = time.time()
    theta = worn_vehicle(a.worn_motor, a.eta)
    ctrl = PolicyController.load()
    rng = np.random.default_rng(a.seed)
    steps = int(round(a.seconds / LOG_DT))
    white, bias = rng.standard_normal((steps, 6)), rng.standard_normal(6)   # the same draws at every level
    work = Path(a.logs) if a.logs else Path(tempfile.mkdtemp(prefix="rotorpy_noise_"))
    work.mkdir(parents=True, exist_ok=True)
    truth = P.save_vehicle(theta, work / "truth.json")
    names = list(P.PARAM_NAMES) + list(P.IDENTIFIABLE_NAMES)
    res = {"command": f"mjxsysid experiment rotorpy-noise{' --quick' if quick else ''} --seed {seed} --out {out}",
           "rotorpy": getattr(rotorpy, "__version__", None) or _dist_version("rotorpy"),
           "vehicle": P.theta_to_dict(theta), "worn_motor": a.worn_motor, "eta": a.eta, "seconds": a.seconds,
           "reference": "lemniscate, period 10 s, size (1, 1, 0.3) m", "samples": a.samples, "seed": a.seed,
           "weights_sha256": {f: file_sha256(PRETRAINED_DIR / f)[:16]
                              for f in ("policy.npz", "cfm_seq.npz", "cfm.npz", "regression.npz")},
           "levels": {}}
    for lv in levels:
        t1 = time.time()
        rec = fly(theta, a.seconds, NOISE_LEVELS[lv], white, bias, ctrl)
        rmse = float(np.sqrt(np.mean(np.sum(rec["err"] ** 2, -1))))
        row = {"label": LABELS.get(lv, lv), "imu": NOISE_LEVELS[lv], "rmse_m": rmse, "lost": bool(rec["lost"]),
               "flown_s": float(rec["t"][-1] + LOG_DT)}
        print(f"[{lv}] flown {row['flown_s']:.1f} s, RMSE {100 * rmse:.2f} cm ({time.time() - t1:.0f} s)", file=sys.stderr)
        log = write_log(work / f"{lv}.csv", rec["t"], rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"])
        try:
            s = run_decode(work / lv, log=log, truth=P.load_vehicle(truth), samples=a.samples, seed=a.seed,
                           echo=lambda m: None, warn=lambda f, lv=lv: print(f"[{lv}] {f}", file=sys.stderr))
        except ValueError as e:   # a log the checks refuse
            row["decode_error"] = str(e)
            res["levels"][lv] = row
            print(f"[{lv}] decode refused: {e}", file=sys.stderr)
            continue
        row["inside"] = sum(bool(s[n]["inside"]) for n in names)
        row["failing"] = [n for n in names if not s[n]["inside"]]
        row["quantities"] = {n: {k: s[n][k] for k in ("mean", "q05", "q95", "true", "inside")} for n in names}
        row["checks"] = s["_checks"]
        row["window"] = s["_window"]
        row["wall_s"] = time.time() - t1
        res["levels"][lv] = row
        print(f"[{lv}] truth inside for {row['inside']}/24; outside: {', '.join(row['failing']) or '-'}", file=sys.stderr)
    res["wall_s"] = time.time() - t0
    res["headline"] = {f"{lv}_inside": r.get("inside") for lv, r in res["levels"].items()}
    return write_results(a.out, "rotorpy-noise", config={"quick": quick, **{k: v for k, v in vars(a).items()
                                                                            if k not in ("out", "logs")}},
                         seeds={"seed": seed}, numbers=res, table_md=table(res), t0=t0)


def _dist_version(name):
    from importlib.metadata import version
    return version(name)


def table(res) -> str:
    lines = [f"RotorPy {res['rotorpy']} (aerodynamics on), the paper vehicle with motor {res['worn_motor']} at "
             f"η {res['eta']}, {res['seconds']:g} s of the 10 s lemniscate, decoded as `decode --log … --truth` "
             f"(flight-level, {res['samples']} samples, seed {res['seed']}), the shipped policy and decoders "
             f"(sha256 {', '.join(f'{k} {v}' for k, v in res['weights_sha256'].items())}). "
             f"`{res['command']}`, {res['wall_s']:.0f} s.", "",
             "| IMU | tracking RMSE | truth inside 5–95 % (of 24) | outside | log warnings |", "|---|---|---|---|---|"]
    for lv, r in res["levels"].items():
        rmse = f"{100 * r['rmse_m']:.1f} cm" + (f" (lost at {r['flown_s']:.1f} s)" if r["lost"] else "")
        if "decode_error" in r:
            lines.append(f"| {r['label']} | {rmse} | refused | {r['decode_error'][:120]} | |")
            continue
        warns = len(r["checks"]["warnings"]) + len(r["checks"]["out_of_prior"])
        lines.append(f"| {r['label']} | {rmse} | {r['inside']} | {', '.join(r['failing']) or '–'} | {warns} |")
    return "\n".join(lines) + "\n"
