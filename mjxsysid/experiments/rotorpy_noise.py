"""Sim-to-sim under IMU noise: the shipped policy flies two vehicles in RotorPy 3.0 (aerodynamics on),
a 10 s lemniscate, with white noise, a per-flight bias or rotor vibration added to the IMU the policy
reads and the log records, at multiples of the project's hardware-like levels (gyro 0.01 rad/s and
accelerometer 0.1 m/s² per 2 ms sample, biases 0.005 rad/s and 0.05 m/s², vibration as the
simulator's: mjxsysid.uses.imu_noise.LEVELS); each flight is written as a flight log and decoded as
``mjxsysid decode --log LOG --truth VEHICLE.json`` does (seed 0, 100 samples). Reported per vehicle
and level: the tracking RMSE and how many of the 24 quantities (19 parameters and the 5 derived
quantities of decode's summary) have their truth inside the 5–95 % interval of the log-grounded posterior (decode's
default, :mod:`mjxsysid.identify`) and of the decoders alone (the flight-level posterior, ``--decoder-only``).
The vehicles (:data:`VEHICLES`): the paper vehicle with motor 1 worn to η 0.8, and a vehicle of the
policy's training prior (``default``, drawn with seed 1).

    .venv/bin/pip install rotorpy==3.0.0          # not a dependency of mjxsysid
    mjxsysid experiment rotorpy-noise --out docs/runs/measurements/rotorpy-noise
    mjxsysid experiment rotorpy-noise --quick --out /tmp/rotorpy_quick   # 2 s, two levels: a smoke run

The mapping of θ onto RotorPy: mass, inertia, arm (RotorPy's rotor order front-left, front-right,
back-right, back-left; written to the log in mjxsysid's order), k_t -> k_eta, k_τ -> k_m (yaw signs
as mjxsysid's), Ω_max -> rotor_speed_max, τ_m -> tau_m. Motor effectiveness η_i (RotorPy has one
k_eta) is a motor that reaches √η_i of its commanded speed: thrust and yaw torque η_i k Ω_cmd², as
in mjxsysid. Drag: mjxsysid's linear D is RotorPy's rotor drag (H force, ∝ Ω v) with k_d, k_z set so
that it equals D at the nominal hover speed; RotorPy's parasitic drag and translational lift are
the hummingbird's (aerodynamics mjxsysid does not model). The external torque τ_ext (RotorPy has none) is
added to RotorPy's body moment (:func:`with_external_torque`). The position/attitude cascade
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
from mjxsysid.logs.grid import world_to_body
from mjxsysid.policy.adaptive.controller import PolicyController
from mjxsysid.policy.interface import PRETRAINED_DIR, file_sha256
from mjxsysid.sim.quadrotor import aliased_hz, vibration_step
from mjxsysid.decoding import run_decode
from mjxsysid.uses.imu_noise import LEVELS as NOISE_LEVELS

LEVELS = ("clean", "x1", "x5_bias", "x5_white", "x5_vibration", "x20")
LABELS = {"clean": "clean", "x1": "× 1 (white + bias)", "x5_bias": "× 5 bias only",
          "x5_white": "× 5 white only", "x5_vibration": "× 5 rotor vibration only", "x20": "× 20 (white + bias)"}
VIBRATION_BANDWIDTH_HZ = 20.0   # the simulator's default (SimConfig.vibration_bandwidth_hz)
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


def prior_vehicle(seed: int = 1) -> np.ndarray:
    """A vehicle of the shipped policy's training prior (``default``), drawn with ``seed``."""
    return P.validate_theta(np.asarray(P.get_prior("default").sample(jax.random.PRNGKey(seed), 1)[0], np.float64),
                            what="vehicle")


VEHICLES = {"worn_motor": lambda: worn_vehicle(1, 0.8), "prior_seed1": lambda: prior_vehicle(1)}
"""The experiment's vehicles by name: the paper vehicle with motor 1 at η 0.8, and a
vehicle of the policy's prior."""


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


def with_external_torque(multirotor_cls, torque):
    """RotorPy's Multirotor with the constant body torque ``torque`` (3,) N m added to its wrench
    (mjxsysid's τ_ext; RotorPy models none)."""
    torque = np.asarray(torque, np.float64)

    class WithTorque(multirotor_cls):
        def compute_body_wrench(self, *args, **kwargs):
            force, moment = super().compute_body_wrench(*args, **kwargs)
            return force, moment + torque

    return WithTorque


@jax.jit
def _vibration(prev, noise, rotor_speeds):
    """One 2 ms step of the simulator's rotor vibration (unit std, (2, 6) last two outputs), centred
    on the mean rotor speed aliased into the IMU's band, as :class:`mjxsysid.sim.Quadrotor` draws it."""
    f = aliased_hz(jnp.mean(rotor_speeds) / (2 * jnp.pi), LOG_DT)
    return vibration_step(prev, noise, f, VIBRATION_BANDWIDTH_HZ, LOG_DT)


@jax.jit
def _control(ctrl, high, ref, hc, lc, pos, vel, quat, omega, imu, i):
    """One 2 ms step of the cascade and the policy (as mjxsysid.rollout.harness.run_loop does)."""
    r = ref.at(i.astype(jnp.float32) * LOG_DT)
    hc, cmd = high.step(hc, Estimate(pos, vel, quat, omega), r, LOG_DT)
    lc, u = ctrl.step_at(lc, imu, cmd, i)
    return hc, lc, cmd.a_cmd, cmd.omega_cmd, u, r.pos


def fly(theta, seconds: float, noise: dict, white, bias, ctrl, vib_white=None) -> dict:
    """Fly θ in RotorPy for ``seconds`` on the 10 s lemniscate; the IMU the policy reads is
    RotorPy's plus ``bias`` (6,) and ``white`` (T, 6) standard normals scaled by the level's stds,
    and, where the level has rotor vibration, the simulator's narrow-band vibration
    (:func:`mjxsysid.sim.quadrotor.vibration_step`, centred on RotorPy's mean rotor speed aliased into
    the IMU's band, driven by ``vib_white`` (T, 6) standard normals) at the level's stds.
    Returns the log's arrays (row k: what the policy saw and did at step k, and the body-frame velocity
    at its start, as a state estimate gives it) and the position error."""
    Multirotor, Imu = import_rotorpy()
    steps = int(round(seconds / LOG_DT))
    ref = Lemniscate.make(period=10.0)
    high = Cascade.make("baseline")
    sq_eta = np.sqrt(np.asarray(theta[P.ETA], np.float64))
    omega_max = float(theta[P.OMEGA_MAX])
    hover = np.sqrt(theta[P.MASS] * P.GRAVITY / (4 * theta[P.KT]))
    state = {"x": np.asarray(ref.at(0.0).pos, np.float64), "v": np.zeros(3), "q": np.array([0.0, 0, 0, 1]),
             "w": np.zeros(3), "wind": np.zeros(3), "rotor_speeds": np.full(4, hover, np.float64)}
    vehicle = with_external_torque(Multirotor, theta[P.TAU_EXT])(
        rotorpy_params(theta), initial_state=state, control_abstraction="cmd_motor_speeds", aero=True)
    imu_model = Imu()
    sd = np.array([noise["gyro_noise"]] * 3 + [noise["accel_noise"]] * 3)
    sb = np.array([noise["gyro_bias"]] * 3 + [noise["accel_bias"]] * 3)
    sv = np.array([noise.get("gyro_vibration", 0.0)] * 3 + [noise.get("accel_vibration", 0.0)] * 3)
    vib = np.zeros((2, 6), np.float32)                 # the resonator's last two outputs (unit std)
    true = np.array([0.0, 0, 0, 0, 0, P.GRAVITY])   # at rest before the first step
    hc, lc = high.init(), ctrl.init()
    rec = {k: [] for k in ("imu", "a_cmd", "omega_cmd", "motor", "err", "quat", "vel")}
    for i in range(steps):
        imu = true + sb * bias + sd * white[i]
        if sv.any():
            vib = np.asarray(_vibration(vib, np.float32(vib_white[i]), np.float32(state["rotor_speeds"])))
            imu = imu + sv * vib[1]
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
                       ("err", state["x"] - np.asarray(ref_pos)), ("quat", np.r_[q[3], q[:3]]), ("vel", v)):
            rec[k].append(val)
        if np.linalg.norm(rec["err"][-1]) > 3.0 or state["x"][2] < 0 or not np.all(np.isfinite(state["x"])):
            break   # lost (the project's failure test: 3 m from the reference or below the ground)
    rec = {k: np.asarray(v) for k, v in rec.items()}
    rec["velocity_body"] = world_to_body(rec.pop("quat"), rec.pop("vel"))   # at each step's start, wxyz
    rec["t"] = LOG_DT * np.arange(len(rec["a_cmd"]))
    rec["lost"] = len(rec["t"]) < steps
    return rec


FULL = {"levels": "clean,x1,x5_white,x5_vibration,x20", "vehicles": ",".join(VEHICLES), "seconds": 10.0,
        "samples": 100}
"""The committed run's settings: the levels of the log-grounded posterior's calibration, both
:data:`VEHICLES`, ``samples`` decoded (decode's default)."""
QUICK = {**FULL, "seconds": 2.0, "samples": 20, "levels": "clean,x5_white", "vehicles": "worn_motor"}
NAMES = list(P.PARAM_NAMES) + list(P.DERIVED_NAMES)


def _inside(s: dict) -> tuple[int, list]:
    """(how many of the 24 quantities hold the truth, the ones that do not) of one summary table."""
    return sum(bool(s[n]["inside"]) for n in NAMES), [n for n in NAMES if not s[n]["inside"]]


def run(out, *, quick=False, policy=None, seed=0, progress=True, levels: str | None = None,
        vehicles: str | None = None, variant: str | None = None) -> dict:
    """The RotorPy flights and their decoding (see the module doc) into OUT/results.json,
    results.md (the table) and OUT/logs/VEHICLE/ (the logs, truth.json and decode outputs). ``seed``:
    the IMU noise draws and decoding (decode's --seed). ``levels``, ``vehicles``: comma-separated
    names of :data:`LEVELS` and :data:`VEHICLES` (default: FULL's or QUICK's). The shipped policy
    and decoders fly and decode (``policy`` is not used). ``variant`` "velocity": the logs carry the
    body velocity (the CSV's vel_body_* columns), so the posterior models the body drag."""
    if variant not in (None, "velocity"):
        raise ValueError(f"rotorpy-noise: unknown variant {variant!r}; the one known: velocity")
    from types import SimpleNamespace
    a = SimpleNamespace(**(QUICK if quick else FULL), seed=seed, out=Path(out), logs=Path(out) / "logs")
    a.levels, a.vehicles = levels or a.levels, vehicles or a.vehicles
    levels, vehicles = a.levels.split(","), a.vehicles.split(",")
    bad = [lv for lv in levels if lv not in LEVELS] + [v for v in vehicles if v not in VEHICLES]
    if bad:
        raise ValueError(f"unknown level(s) or vehicle(s) {bad}; levels: {', '.join(LEVELS)}; "
                         f"vehicles: {', '.join(VEHICLES)}")
    import_rotorpy()
    import rotorpy
    t0 = time.time()
    ctrl = PolicyController.load()
    rng = np.random.default_rng(a.seed)
    steps = int(round(a.seconds / LOG_DT))
    # the same draws at every level and vehicle
    white, bias, vib_white = rng.standard_normal((steps, 6)), rng.standard_normal(6), rng.standard_normal((steps, 6))
    res = {"command": f"mjxsysid experiment rotorpy-noise{' --quick' if quick else ''}"
                      f"{f' --variant {variant}' if variant else ''} --seed {seed} --out {out}", "variant": variant,
           "rotorpy": getattr(rotorpy, "__version__", None) or _dist_version("rotorpy"), "seconds": a.seconds,
           "reference": "lemniscate, period 10 s, size (1, 1, 0.3) m", "samples": a.samples, "seed": a.seed,
           "weights_sha256": {f: file_sha256(PRETRAINED_DIR / f)[:16]
                              for f in ("policy.npz", "cfm_seq.npz", "cfm.npz", "regression.npz")},
           "vehicles": {}}
    for vn in vehicles:
        theta = VEHICLES[vn]()
        work = Path(a.logs) / vn if a.logs else Path(tempfile.mkdtemp(prefix="rotorpy_noise_"))
        work.mkdir(parents=True, exist_ok=True)
        truth = P.save_vehicle(theta, work / "truth.json")
        vres = res["vehicles"][vn] = {"vehicle": P.theta_to_dict(theta), "levels": {}}
        for lv in levels:
            t1 = time.time()
            rec = fly(theta, a.seconds, NOISE_LEVELS[lv], white, bias, ctrl, vib_white)
            rmse = float(np.sqrt(np.mean(np.sum(rec["err"] ** 2, -1))))
            row = {"label": LABELS.get(lv, lv), "imu": NOISE_LEVELS[lv], "rmse_m": rmse, "lost": bool(rec["lost"]),
                   "flown_s": float(rec["t"][-1] + LOG_DT)}
            vres["levels"][lv] = row
            tag = f"[{vn} {lv}]"
            print(f"{tag} flown {row['flown_s']:.1f} s, RMSE {100 * rmse:.2f} cm ({time.time() - t1:.0f} s)", file=sys.stderr)
            log = write_log(work / f"{lv}.csv", rec["t"], rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"],
                            velocity_body=rec["velocity_body"] if variant == "velocity" else None)
            try:
                s = run_decode(work / lv, log=log, truth=P.load_vehicle(truth), samples=a.samples, seed=a.seed,
                               echo=lambda m: None, warn=lambda f, tag=tag: print(f"{tag} {f}", file=sys.stderr))
            except ValueError as e:   # a log the checks refuse
                row["decode_error"] = str(e)
                print(f"{tag} decode refused: {e}", file=sys.stderr)
                continue
            row["inside"], row["failing"] = _inside(s)
            row["inside_decoder_only"], row["failing_decoder_only"] = _inside(s["_decoder_only"])
            row["quantities"] = {n: {k: s[n][k] for k in ("mean", "q05", "q95", "true", "inside")} for n in NAMES}
            row["posterior"] = s.get("_posterior", "decoder-only")
            row["checks"] = s["_checks"]
            row["wall_s"] = time.time() - t1
            print(f"{tag} truth inside for {row['inside']}/24 (log-grounded; decoders alone "
                  f"{row['inside_decoder_only']}/24); outside: {', '.join(row['failing']) or '-'}", file=sys.stderr)
    res["wall_s"] = time.time() - t0
    res["headline"] = {f"{vn}_{lv}_inside": r.get("inside") for vn, v in res["vehicles"].items()
                       for lv, r in v["levels"].items()}
    plot_inside(res, Path(a.out) / "inside.png")
    return write_results(a.out, "rotorpy-noise", config={"quick": quick, **{k: v for k, v in vars(a).items()
                                                                            if k not in ("out", "logs")}},
                         seeds={"seed": seed}, numbers=res, table_md=table(res), t0=t0)


def plot_inside(res: dict, path) -> Path:
    """Bars: of the 24 quantities, how many hold the truth in their 5–95 % interval, per vehicle and
    IMU level, the log-grounded posterior beside the decoders alone; the dashed line is 90 % of 24."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = [(vn, lv, r) for vn, v in res["vehicles"].items() for lv, r in v["levels"].items() if "inside" in r]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(6.0, 0.75 * len(rows) + 2), 3.6))
    ax.bar(x - 0.2, [r["inside"] for *_, r in rows], 0.4, label="log-grounded (decode's default)")
    ax.bar(x + 0.2, [r["inside_decoder_only"] for *_, r in rows], 0.4, label="decoders alone (--decoder-only)")
    ax.axhline(0.9 * len(NAMES), color="k", ls="--", lw=1, label="90 % of 24")
    ax.set_xticks(x, [f"{vn}\n{lv}" for vn, lv, _ in rows], fontsize=7)
    ax.set_ylim(0, len(NAMES) + 0.5)
    ax.set_ylabel("truth inside 5–95 % (of 24)")
    ax.set_title(f"RotorPy {res['rotorpy']} (aero on), {res['seconds']:g} s lemniscate, shipped policy", fontsize=9)
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def _dist_version(name):
    from importlib.metadata import version
    return version(name)


def table(res) -> str:
    lines = [(f"RotorPy {res['rotorpy']} (aerodynamics on), {res['seconds']:g} s of the 10 s lemniscate flown by the "
             f"shipped policy, decoded as `decode --log … --truth` ({res['samples']} samples, seed {res['seed']}): "
             f"the log-grounded posterior (decode's default) and the decoders alone (flight-level, `--decoder-only`); "
             f"weights sha256 {', '.join(f'{k} {v}' for k, v in res['weights_sha256'].items())}. "
             f"`{res['command']}`, {res['wall_s']:.0f} s."), "",
             "| vehicle | IMU | tracking RMSE | log-grounded: truth inside (of 24) | outside | decoders alone: inside | log warnings |",
             "|---|---|---|---|---|---|---|"]
    for vn, v in res["vehicles"].items():
        for r in v["levels"].values():
            rmse = f"{100 * r['rmse_m']:.1f} cm" + (f" (lost at {r['flown_s']:.1f} s)" if r["lost"] else "")
            if "decode_error" in r:
                lines.append(f"| {vn} | {r['label']} | {rmse} | refused | {r['decode_error'][:120]} | | |")
                continue
            warns = len(r["checks"]["warnings"]) + len(r["checks"]["out_of_prior"])
            lines.append(f"| {vn} | {r['label']} | {rmse} | {r['inside']} | {', '.join(r['failing']) or '–'} | "
                         f"{r['inside_decoder_only']} | {warns} |")
    return "\n".join(lines) + "\n"
