"""PX4 ULog flight logs -> the arrays of :func:`~mjxsysid.logs.csvlog.read_log` (docs/px4.md).

:func:`read_ulog` picks the topics a PX4 log carries, converts them to mjxsysid's log contract
(body frame FLU, SI units, normalised rotor-speed commands Ω_cmd/Ω_max in mjxsysid's rotor order,
a 2 ms grid), cuts the armed, airborne segment and says what it did: ``rec["source"]`` (topics,
native rates, the segment and why, every conversion as a sentence), ``rec["resampled"]`` (how each
column group was brought to 2 ms) and ``rec["native"]`` (the samples before resampling, for the
checks that must not read interpolated values: :mod:`mjxsysid.logs.checks`).

pyulog is an optional dependency (``pip install mjxsysid[px4]``), imported when a log is read.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mjxsysid import theta as P
from mjxsysid.logs import ulog_fast
from mjxsysid.logs.record import rate_hz, rate_text
from mjxsysid.logs.grid import DT, MIN_ROWS, cut, hold, interp_linear, segment_grid, user_segment
from mjxsysid.logs.grid import parse_segment, world_to_body  # noqa: F401  (importable here too, their first home)

PX4_QUADX_ORDER = (0, 2, 1, 3)
"""PX4's default quad-X outputs (front-right, back-left, front-left, back-right): the mjxsysid
rotor (0 front-right, 1 front-left, 2 back-left, 3 back-right) each PX4 motor drives."""

QUAD_MAV_TYPES = {2: "quadrotor"}
OTHER_MAV_TYPES = {1: "fixed wing", 3: "coaxial helicopter", 4: "helicopter", 13: "hexarotor", 14: "octorotor",
                   15: "tricopter", 19: "VTOL tailsitter duo", 20: "VTOL tailsitter quad", 21: "VTOL tiltrotor",
                   22: "VTOL fixed rotor"}


def _import_pyulog():
    try:
        from pyulog import ULog
    except ImportError:
        raise ImportError("reading PX4 ULog files needs pyulog: pip install mjxsysid[px4] "
                          "(or pip install pyulog==1.3.0)") from None
    return ULog


def rotor_order_from_params(params: dict):
    """The mjxsysid rotor each PX4 motor 0..3 drives, from the control allocation's rotor geometry
    (CA_ROTORi_PX/PY, FRD) -> (order (4,), sentence); PX4's default quad-X order when the log has
    no geometry. ValueError: not four rotors in the four quadrants, or spun unlike an X."""
    if not all(f"CA_ROTOR{i}_PX" in params and f"CA_ROTOR{i}_PY" in params for i in range(4)):
        return PX4_QUADX_ORDER, ("rotor order: the log has no rotor geometry (CA_ROTORi_PX/PY); PX4's default "
                                 "quad-X order assumed (front-right, back-left, front-left, back-right)")
    quad = {(True, True): 0, (True, False): 1, (False, False): 2, (False, True): 3}   # (front, right) -> rotor
    order, km = [], []
    for i in range(4):
        px, py = float(params[f"CA_ROTOR{i}_PX"]), float(params[f"CA_ROTOR{i}_PY"])
        if px == 0 or py == 0:
            raise ValueError(f"CA_ROTOR{i} at ({px:g}, {py:g}) m: not on a diagonal; mjxsysid models a quad-X only")
        order.append(quad[(px > 0, py > 0)])
        km.append(float(params.get(f"CA_ROTOR{i}_KM", 0.0)))
    if sorted(order) != [0, 1, 2, 3]:
        raise ValueError(f"CA_ROTOR0..3 positions put two rotors in the same quadrant (rotors {order}): "
                         f"not a quad-X; mjxsysid models a quad-X only")
    yaw = np.asarray(P.YAW_SIGNS, np.float64)
    if all(k != 0 for k in km):
        # PX4's KM > 0 turns the body about FRD z (down) the way mjxsysid's yaw sign −1 does about FLU z
        agree = [np.sign(-k) == yaw[o] for k, o in zip(km, order)]
        if not all(agree):
            raise ValueError("CA_ROTORi_KM: the rotors spin opposite to mjxsysid's quad-X (front-right and "
                             "back-left one way, front-left and back-right the other, as PX4's default quad-X); "
                             "this layout is not supported")
    names = ", ".join(P.ROTOR_NAMES[o] for o in order)
    return tuple(order), f"rotor order: PX4 motors 1..4 are {names} (CA_ROTORi_PX/PY); reordered to mjxsysid's"


def check_airframe(params: dict) -> list[str]:
    """ValueError for a log of an airframe other than a quad-X multirotor (CA_AIRFRAME,
    CA_ROTOR_COUNT, MAV_TYPE) -> the sentences saying what was checked."""
    said = []
    af = params.get("CA_AIRFRAME")
    if af is not None and int(af) != 0:
        raise ValueError(f"CA_AIRFRAME = {int(af)}: not a multirotor (0); mjxsysid models a quad-X only")
    n = params.get("CA_ROTOR_COUNT")
    if n is not None and int(n) != 4:
        raise ValueError(f"CA_ROTOR_COUNT = {int(n)}: mjxsysid models a quad-X (four rotors) only")
    mt = params.get("MAV_TYPE")
    if mt is not None and int(mt) not in QUAD_MAV_TYPES:
        what = OTHER_MAV_TYPES.get(int(mt), f"type {int(mt)}")
        raise ValueError(f"MAV_TYPE = {int(mt)} ({what}): mjxsysid models a quad-X only")
    said.append("airframe: " + ", ".join(f"{k} {int(params[k])}" for k in ("CA_AIRFRAME", "CA_ROTOR_COUNT", "MAV_TYPE")
                                          if params.get(k) is not None) + " (a quadrotor)")
    return said


def throttle_to_rotor_speed(u, f: float):
    """Ω_cmd/Ω_max of a rotor whose ESC is driven at throttle ``u`` ∈ [0, 1] under PX4's thrust
    model thrust ∝ (1 − f) u + f u² (THR_MDL_FAC ``f``): thrust ∝ Ω², so Ω/Ω_max = √((1 − f) u + f u²)
    (1 at u = 1; f = 0: √u)."""
    u = np.clip(np.asarray(u, np.float64), 0.0, 1.0)
    return np.sqrt(np.clip((1.0 - f) * u + f * u * u, 0.0, 1.0))


def drop_interleaved_rows(x):
    """Rows of ``x`` (N, k) a second publisher wrote into the same topic: every channel at one
    constant value c (e.g. 1500), interleaved with the real outputs, c not the idle (lowest)
    value -> (keep mask (N,), c or None)."""
    x = np.asarray(x, np.float64)
    keep = np.ones(len(x), bool)
    flat = np.all(x == x[:, :1], axis=1)
    if flat.sum() < 3:
        return keep, None
    vals, counts = np.unique(x[flat, 0], return_counts=True)
    low = float(np.min(x))
    cand = [(c, v) for v, c in zip(vals, counts) if v > low]
    if not cand:
        return keep, None
    _, c = max(cand)
    rows = flat & (x[:, 0] == c)
    # interleaved: the rows of c alternate with others (many short runs), not one block
    switches = int(np.sum(rows[1:] != rows[:-1]))
    if rows.sum() >= 3 and switches >= rows.sum() and (~rows).sum() >= 3:
        return ~rows, float(c)
    return keep, None


def _segment(ulog, params, t_imu, start_us, segment, path=""):
    """(t0, t1, why) in seconds since the log's start; ValueError for a log never armed (naming ``path``)."""
    lo, hi = float(t_imu[0]), float(t_imu[-1])
    given = user_segment(path, segment, lo, hi)
    if given is not None:
        return given
    mask = np.ones(len(t_imu), bool)
    why = []
    armed = _topic(ulog, "actuator_armed")
    if armed is not None and "armed" in armed:
        mask &= hold(_seconds(armed["timestamp"], start_us), armed["armed"], t_imu) > 0.5
        why.append("armed (actuator_armed)")
    land = _topic(ulog, "vehicle_land_detected")
    if land is not None and "landed" in land:
        flags = [k for k in ("landed", "maybe_landed", "ground_contact") if k in land]
        on_ground = np.any([np.asarray(land[k], np.float64) > 0.5 for k in flags], axis=0)
        mask &= hold(_seconds(land["timestamp"], start_us), on_ground, t_imu) < 0.5
        why.append(f"airborne (vehicle_land_detected: none of {', '.join(flags)})")
    tk = _topic(ulog, "takeoff_status")
    if tk is not None and "takeoff_state" in tk:
        # PX4's takeoff state machine: 5 = flight (after the spool-up and the ramp-up on the ground)
        mask &= hold(_seconds(tk["timestamp"], start_us), tk["takeoff_state"], t_imu) == 5
        why.append("in flight (takeoff_status: takeoff_state 5, past the ramp-up)")
    if armed is None or "armed" not in armed:
        st = _topic(ulog, "vehicle_status")
        if st is not None and "arming_state" in st:
            # PX4's arming states (old and new): 0 init, 1 standby, 2 armed
            mask &= hold(_seconds(st["timestamp"], start_us), st["arming_state"], t_imu) == 2
            why.insert(0, "armed (vehicle_status.arming_state)")
    if why and why[0].startswith("armed") and not mask.any():
        raise ValueError(f"{path}: never armed ({why[0].split(' (')[1][:-1]} never armed over the log's "
                         f"{hi - lo:.1f} s): a bench or disarmed log, the rotors never carried the vehicle, there is "
                         f"no flight to identify. Next step: log a flight (armed and airborne) and read that log; "
                         f"to check this one anyway, give --segment T0:T1")
    if not mask.any():
        return lo, hi, ("the whole log: never " + " and ".join(w.split(" (")[0] for w in why)
                        + " (a bench or disarmed log?)")
    # the longest contiguous run
    d = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
    k = int(np.argmax(ends - starts))
    t0, t1 = float(t_imu[starts[k]]), float(t_imu[ends[k]])
    if t1 - t0 < MIN_ROWS * DT:
        return lo, hi, f"the whole log: the longest {' and '.join(why)} stretch is {t1 - t0:.3g} s"
    more = f"; the longest of {len(starts)} such stretches" if len(starts) > 1 else ""
    return t0, t1, " and ".join(why) + more


def _seconds(ts, start_us):
    return (np.asarray(ts, np.float64) - float(start_us)) * 1e-6


def _topic(ulog, name, multi_id=0):
    for d in ulog.data_list:
        if d.name == name and d.multi_id == multi_id:
            return d.data
    return None


def read_ulog(path, segment=None) -> dict:
    """Read a PX4 ULog flight log -> the arrays of :func:`~mjxsysid.logs.csvlog.read_log`
    (t (T,) in s since the log's start, imu (T, 6), a_cmd (T,), omega_cmd (T, 3), motor (T, 4) on
    a 2 ms grid) over the armed, airborne segment (or ``segment``: 't0:t1' or (t0, t1), seconds
    since the log's start), plus ``native`` {group: (t (N,), values)} the samples before
    resampling, ``resampled`` {group: how it was brought to 2 ms} and ``source`` (topics, rates,
    segment, parameters, ``conversions``: one sentence each).

    Topics: IMU ``sensor_combined`` (else ``vehicle_angular_velocity`` + ``vehicle_acceleration``),
    motors ``actuator_motors`` (else ``actuator_outputs`` with the PWM limits and THR_MDL_FAC),
    ``vehicle_rates_setpoint`` (omega_cmd), ``vehicle_thrust_setpoint`` and
    ``hover_thrust_estimate`` (else MPC_THR_HOVER) for a_cmd; ``velocity_body`` (T, 3) m/s FLU from
    ``vehicle_local_position`` and ``vehicle_attitude`` where valid (else ``source["missing"]`` names it:
    :mod:`mjxsysid.logs.ulog_velocity`). ValueError: not a quad-X, a topic
    missing, a segment too short; ImportError without pyulog (``pip install mjxsysid[px4]``)."""
    ULog = _import_pyulog()
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"flight log not found: {path}")
    try:
        ulog = ulog_fast.load(ULog, str(path))
    except Exception as e:  # pyulog raises various errors on a file that is not ULog
        raise ValueError(f"{path}: not a readable PX4 ULog file ({type(e).__name__}: {e})") from None
    params = dict(ulog.initial_parameters)
    start = ulog.start_timestamp
    g = P.GRAVITY
    conv, topics, rates = [], {}, {}
    conv += check_airframe(params)

    # ---- IMU (native), FRD -> FLU
    sc = _topic(ulog, "sensor_combined")
    if sc is not None:
        t_g = _seconds(sc["timestamp"], start)
        rel = np.asarray(sc.get("accelerometer_timestamp_relative", np.zeros(len(t_g))), np.float64)
        rel = np.where(np.abs(rel) >= 2 ** 31 - 1, 0.0, rel)
        t_a = t_g + rel * 1e-6
        gyro = np.stack([sc[f"gyro_rad[{i}]"] for i in range(3)], -1)
        acc = np.stack([sc[f"accelerometer_m_s2[{i}]"] for i in range(3)], -1)
        topics["imu"] = "sensor_combined (gyro_rad, accelerometer_m_s2)"
    else:
        av, va = _topic(ulog, "vehicle_angular_velocity"), _topic(ulog, "vehicle_acceleration")
        if av is None or va is None:
            raise ValueError(f"{path}: no IMU topic: sensor_combined, or vehicle_angular_velocity and "
                             f"vehicle_acceleration, expected")
        t_g = _seconds(av.get("timestamp_sample", av["timestamp"]), start)
        t_a = _seconds(va.get("timestamp_sample", va["timestamp"]), start)
        gyro = np.stack([av[f"xyz[{i}]"] for i in range(3)], -1)
        acc = np.stack([va[f"xyz[{i}]"] for i in range(3)], -1)
        topics["imu"] = "vehicle_angular_velocity + vehicle_acceleration (xyz)"
    order_g, order_a = np.argsort(t_g, kind="stable"), np.argsort(t_a, kind="stable")
    t_g, gyro, t_a, acc = t_g[order_g], gyro[order_g], t_a[order_a], acc[order_a]
    frd = np.array([1.0, -1.0, -1.0])
    imu_native = np.concatenate([gyro * frd, interp_linear(t_a, acc, t_g) * frd], -1)
    rates["imu"] = rate_hz(t_g)
    conv.append("body frame: PX4's FRD (x forward, y right, z down) to FLU (x forward, y left, z up): "
                "gyro, accelerometer and rate setpoint y and z negated")

    t0, t1, why = _segment(ulog, params, t_g, start, segment, path)
    grid = segment_grid(path, t0, t1)

    # ---- motors
    order, said = rotor_order_from_params(params)
    f = float(params.get("THR_MDL_FAC", 0.0))
    am = _topic(ulog, "actuator_motors")
    if am is not None:
        t_m = _seconds(am["timestamp"], start)
        ctrl = np.stack([am[f"control[{i}]"] for i in range(4)], -1).astype(np.float64)
        extra = [i for i in range(4, 12) if f"control[{i}]" in am
                 and np.nanmax(np.abs(np.nan_to_num(am[f"control[{i}]"], nan=0.0))) > 0]
        if extra:
            raise ValueError(f"{path}: actuator_motors drives {4 + len(extra)} motors: mjxsysid models a quad-X only")
        off = ~np.isfinite(ctrl)
        thrust = np.clip(np.where(off, 0.0, ctrl), 0.0, 1.0)
        topics["motor"] = "actuator_motors (control[0..3])"
        conv.append("motor commands: actuator_motors is each rotor's normalised thrust in [0, 1] (PX4 applies "
                    f"THR_MDL_FAC = {f:g} after it, on the way to the ESC); thrust ∝ Ω², so "
                    "Ω_cmd/Ω_max = √control" + ("; NaN (motor off or disarmed) read as 0" if off.any() else ""))
        rotor = np.sqrt(thrust)
    else:
        ao = _topic(ulog, "actuator_outputs")
        if ao is None:
            raise ValueError(f"{path}: no motor topic: actuator_motors or actuator_outputs expected")
        chans = _motor_channels(params)
        t_m = _seconds(ao["timestamp"], start)
        pwm = np.stack([ao[f"output[{c}]"] for c in chans], -1).astype(np.float64)
        keep, c = drop_interleaved_rows(pwm)
        if c is not None:
            conv.append(f"actuator_outputs: {int((~keep).sum())} rows with every output at {c:g} interleaved with "
                        f"the motor outputs (a second publisher) dropped")
            t_m, pwm = t_m[keep], pwm[keep]
        lo_p, hi_p, said_pwm = pwm_limits(params, pwm, chans)
        conv.append(said_pwm)
        u = np.clip((pwm - lo_p) / (hi_p - lo_p), 0.0, 1.0)
        rotor = throttle_to_rotor_speed(u, f)
        topics["motor"] = f"actuator_outputs (output[{', '.join(str(ch) for ch in chans)}])"
        conv.append(f"motor commands: throttle u = (pwm − {lo_p:g}) / ({hi_p:g} − {lo_p:g}); PX4's thrust model "
                    f"thrust ∝ (1 − f) u + f u² with THR_MDL_FAC f = {f:g} and thrust ∝ Ω²: "
                    f"Ω_cmd/Ω_max = √((1 − f) u + f u²)" + (" = √u" if f == 0 else ""))
    conv.append(said)
    inv = [list(order).index(j) for j in range(4)]        # mjxsysid rotor j <- PX4 motor inv[j]
    rotor = rotor[:, inv]
    srt = np.argsort(t_m, kind="stable")
    t_m, rotor = t_m[srt], rotor[srt]
    rates["motor"] = rate_hz(t_m)

    # ---- commands
    rs = _topic(ulog, "vehicle_rates_setpoint")
    if rs is None:
        raise ValueError(f"{path}: no vehicle_rates_setpoint topic (omega_cmd)")
    t_w = _seconds(rs["timestamp"], start)
    w_cmd = np.stack([rs["roll"], rs["pitch"], rs["yaw"]], -1).astype(np.float64) * frd
    topics["omega_cmd"] = "vehicle_rates_setpoint (roll, pitch, yaw)"
    rates["omega_cmd"] = rate_hz(t_w)
    ts = _topic(ulog, "vehicle_thrust_setpoint")
    if ts is not None:
        t_T, thr = _seconds(ts["timestamp"], start), -np.asarray(ts["xyz[2]"], np.float64)
        topics["a_cmd"] = "vehicle_thrust_setpoint (xyz[2])"
    elif "thrust_body[2]" in rs:
        t_T, thr = t_w, -np.asarray(rs["thrust_body[2]"], np.float64)
        topics["a_cmd"] = "vehicle_rates_setpoint (thrust_body[2])"
    elif "thrust" in rs:      # PX4 ≤ 1.9: the collective thrust as a positive scalar
        t_T, thr = t_w, np.asarray(rs["thrust"], np.float64)
        topics["a_cmd"] = "vehicle_rates_setpoint (thrust, PX4 ≤ 1.9)"
    else:
        raise ValueError(f"{path}: no thrust setpoint (vehicle_thrust_setpoint, or vehicle_rates_setpoint.thrust_body "
                         f"or .thrust): a_cmd cannot be built; log vehicle_thrust_setpoint (PX4: SDLOG_PROFILE "
                         f"default topics) or convert the log to the CSV contract (docs/decoding.md)")
    thr = np.nan_to_num(thr, nan=0.0)
    hover, said_h = _hover_thrust(ulog, params, start, t0, t1)
    a_cmd = thr * g / hover
    rates["a_cmd"] = rate_hz(t_T)
    conv.append(f"a_cmd: PX4's normalised collective thrust setpoint (−xyz[2], FRD z down) × g / hover thrust "
                f"({said_h}): m/s², g at hover")

    native = {"imu": cut(t_g, imu_native, t0, t1), "motor": cut(t_m, rotor, t0, t1),
              "omega_cmd": cut(t_w, w_cmd, t0, t1), "a_cmd": cut(t_T, a_cmd, t0, t1)}
    rec = {"t": grid, "imu": interp_linear(*native["imu"], grid),
           "a_cmd": hold(*native["a_cmd"], grid), "omega_cmd": hold(*native["omega_cmd"], grid),
           "motor": hold(*native["motor"], grid)}
    hows = {"imu": "interpolated (linear)", "motor": "held (zero-order)", "omega_cmd": "held (zero-order)",
            "a_cmd": "held (zero-order)"}
    from mjxsysid.logs.ulog_velocity import ulog_velocity_body
    vel, said_v = ulog_velocity_body(_topic(ulog, "vehicle_local_position"), _topic(ulog, "vehicle_attitude"),
                                     start, t0, t1)
    conv.append(said_v)
    if vel is not None:
        native["velocity_body"], rec["velocity_body"] = vel, interp_linear(*vel, grid)
        hows["velocity_body"], rates["velocity_body"] = "interpolated (linear)", rate_hz(vel[0])
        topics["velocity_body"] = "vehicle_local_position (vx, vy, vz) + vehicle_attitude (q)"
    resampled = {}
    for k, how in hows.items():
        r = rates[k]
        resampled[k] = (f"{how} from {rate_text(r)}" if abs(r * DT - 1) > 0.05 else f"native ({rate_text(r)})")
    rec["native"] = native
    rec["resampled"] = resampled
    rec["source"] = {"format": "PX4 ULog", "path": str(path), "topics": topics,
                     "rates_hz": {k: round(v, 2) for k, v in rates.items()},
                     "segment": {"t0": float(t0), "t1": float(t1), "why": why,
                                 "clock": "seconds since the log's start"},
                     "log_start_us": int(start), "conversions": conv,
                     "missing": [] if vel is not None else ["velocity_body"],
                     "parameters": {k: float(params[k]) for k in ("THR_MDL_FAC", "MPC_THR_HOVER", "CA_ROTOR_COUNT",
                                                                  "MAV_TYPE", "SYS_AUTOSTART") if k in params}}
    return rec


def _motor_channels(params) -> list[int]:
    """actuator_outputs channels of motors 1..4: PWM_MAIN_FUNCn = 100 + k is motor k (PX4 ≥ 1.13),
    else channels 0..3."""
    chans = {}
    for key, v in params.items():
        if key.startswith("PWM_MAIN_FUNC") and key[13:].isdigit() and 101 <= int(v) <= 104:
            chans[int(v) - 101] = int(key[13:]) - 1
    if sorted(chans) == [0, 1, 2, 3]:
        return [chans[k] for k in range(4)]
    return [0, 1, 2, 3]


def pwm_limits(params, pwm, chans=(0, 1, 2, 3)):
    """Zero and full throttle in µs of the motor outputs ``pwm`` (N, 4): PWM_MAIN_MIN/MAX (or the
    per-channel PWM_MAIN_MINn/MAXn where set, −1 meaning unset; default 1000/2000); where the outputs idle below the minimum the
    parameters give (a disarmed value), zero throttle is taken at that idle value -> (lo, hi, sentence)."""
    def par(name, default):
        per = [params.get(f"{name}{c + 1}") for c in chans]
        if all(p is not None and p >= 0 for p in per):     # −1: unset, the global value applies
            return float(np.median(per)), f"{name}1..4"
        if name in params:
            return float(params[name]), name
        return default, f"{name} absent, default"
    lo, lo_from = par("PWM_MAIN_MIN", 1000.0)
    hi, hi_from = par("PWM_MAIN_MAX", 2000.0)
    idle = float(np.percentile(pwm, 1))
    said = f"PWM limits {lo:g}–{hi:g} µs ({lo_from}, {hi_from})"
    if idle < lo - 5:
        said += (f"; the outputs idle at {idle:g} µs, below {lo_from} = {lo:g}: zero throttle taken at "
                 f"{idle:g} µs (the ESC's calibrated zero, PX4's disarmed value)")
        lo = idle
    if not hi > lo:
        raise ValueError(f"PWM limits {lo:g}–{hi:g} µs: the maximum is not above the minimum; check the log's "
                         f"PWM_MAIN_MIN/MAX parameters, or convert the outputs to the CSV contract (docs/decoding.md)")
    return lo, hi, said


def _hover_thrust(ulog, params, start, t0, t1):
    """PX4's hover thrust (normalised collective thrust at hover) -> (value, sentence)."""
    h = _topic(ulog, "hover_thrust_estimate")
    if h is not None and "hover_thrust" in h:
        t = _seconds(h["timestamp"], start)
        v = np.asarray(h["hover_thrust"], np.float64)
        ok = np.asarray(h.get("valid", np.ones(len(v))), bool) & np.isfinite(v) & (v > 0.02) & (v < 1)
        seg = ok & (t >= t0) & (t <= t1)
        for m, where in ((seg, "in the segment"), (ok, "over the log")):
            if m.any():
                val = float(np.median(v[m]))
                return val, f"hover_thrust_estimate, median of {int(m.sum())} valid samples {where}: {val:.4g}"
    if "MPC_THR_HOVER" in params and 0 < float(params["MPC_THR_HOVER"]) < 1:
        val = float(params["MPC_THR_HOVER"])
        return val, f"MPC_THR_HOVER = {val:.4g} (no valid hover_thrust_estimate)"
    raise ValueError("no hover thrust: neither a valid hover_thrust_estimate nor MPC_THR_HOVER in the log "
                     "(a_cmd cannot be brought to m/s²)")


ULOG_MAGIC = b"ULog\x01\x12\x35"


def sniff(head: bytes) -> bool:
    """Is ``head`` (a file's first bytes) a ULog's header? (:mod:`mjxsysid.logs.formats`)"""
    return head[:7] == ULOG_MAGIC


read = read_ulog
