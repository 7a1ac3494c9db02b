"""An exact-model flight log for the log-grounded posterior's tests: a forward model written for
them (NumPy, step by step: the rotor lag, Euler's equation, the specific force), independent of the
likelihood's windowed sums, so that inference is checked where the model is exact."""
import numpy as np

from mjxsysid import theta as P

DT = 0.002


def synthetic_log(theta, seconds=6.0, gyro_noise=0.0, acc_noise=0.0, seed=0, closed_loop=False, drag=None,
                  speed_noise=None, motor_delay=0, rotor_gain=None, rotor_offset=None, gyro_vibration=0.0,
                  torque_noise=0.0, motor_map=None):
    """Fly θ (19,) open loop around hover with a rate damper and chirp excitation -> imu, motor.
    ``closed_loop``: instead, a rate P controller on the *measured* (noisy) rates tracking a slow
    sinusoid: the commands react to the gyro's noise, the feedback that biases an equation error.
    ``drag`` (1/s): a body-z velocity 0.8 + 0.7 sin(0.9 t) m/s (a forward flight's, tilted) whose drag
    −drag · v_z enters the specific force, and the log's ``velocity_body``. ``speed_noise`` (rad/s): the
    log carries the true rotor speeds (``rotor_speed`` (T, 4), row k the speed at its time) with this white
    noise. ``motor_delay`` (steps): the motors act on each logged command that many steps late (they hold
    the hover command before). ``rotor_gain`` (4,), ``rotor_offset`` (4,) rad/s: each rotor's speed is
    Ω_i = rotor_gain_i · Ω_max · s_i + rotor_offset_i (s_i its command through the lag; default 1 and 0), the
    thrust η k_T Ω_i², and each rotor's hover command gives the hover speed (the vehicle trimmed).
    ``gyro_vibration`` (rad/s): the std of a rotor vibration on each gyro axis, as the simulator's
    (:func:`mjxsysid.sim.quadrotor.vibration_step`): a two-pole resonator driven by white noise, 20 Hz wide,
    at the rotors' mean speed / 2π aliased into the 250 Hz band.
    ``torque_noise`` (rad/s²): a disturbance's angular acceleration the model lacks, an Ornstein–Uhlenbeck
    process (0.1 s correlation) of this standard deviation per axis, that a closed loop answers within a
    rate window. ``motor_map``: a command→speed share map (a callable on (4,) commands in [0, 1], increasing):
    the rotors lag toward Ω_max · motor_map(u) instead of Ω_max · u (the simulator's ``motor_idle`` and
    ``motor_kappa``), the hover command its inverse at the hover speed; the log keeps the commands."""
    rng = np.random.default_rng(seed)
    t = np.asarray(theta, np.float64)
    eta, tau, wmax = t[P.ETA], t[P.TAU_M], t[P.OMEGA_MAX]
    kt, m, arm, J = t[P.KT], t[P.MASS], t[P.ARM], t[P.INERTIA]
    kap = t[P.KTAU] / kt
    d = P.ROTOR_DIRECTIONS.astype(np.float64)
    n = int(seconds / DT)
    gain = wmax * (np.ones(4) if rotor_gain is None else np.asarray(rotor_gain, np.float64))
    off = np.zeros(4) if rotor_offset is None else np.asarray(rotor_offset, np.float64)
    hover = (np.sqrt(m * P.GRAVITY / (4 * kt * eta)) - off) / gain
    s = hover.copy()
    if motor_map is not None:               # the command whose mapped share is the hover speed's (bisection)
        lo_u, hi_u = np.zeros(4), np.ones(4)
        for _ in range(60):
            mid = 0.5 * (lo_u + hi_u)
            below = motor_map(mid) < hover
            lo_u, hi_u = np.where(below, mid, lo_u), np.where(below, hi_u, mid)
        hover = 0.5 * (lo_u + hi_u)
    w, meas = np.zeros(3), np.zeros(3)
    imu, mot, speed = np.zeros((n, 6)), np.zeros((n, 4)), np.zeros((n, 4))
    imu[0, 5] = P.GRAVITY
    a = np.exp(-DT / tau)
    vib = np.zeros((2, 3))
    rv = np.exp(-np.pi * 20.0 * DT)
    dist, rho_d = np.zeros(3), np.exp(-DT / 0.1)
    for k in range(n):
        tt = k * DT
        if closed_loop:
            ref = 2.0 * np.array([np.sin(3 * tt), np.sin(2.3 * tt + 1), 0.5 * np.sin(1.7 * tt + 2)])
            cmd = 0.15 * (ref - meas) * np.array([1.0, 1.0, 2.0])
        else:
            exc = 0.08 * np.array([np.sin(7 * tt), np.sin(5 * tt + 1), np.sin(3 * tt + 2)]) + 0.03 * rng.standard_normal(3)
            cmd = -0.02 * w + exc                                   # roll, pitch, yaw effort
        u = np.clip(hover * (1 + 0.05 * np.sin(2 * tt) + d[:, 1] * cmd[0] - d[:, 0] * cmd[1]
                             + P.YAW_SIGNS * cmd[2]), 0, 1)
        mot[k] = u
        u = mot[k - motor_delay] if k >= motor_delay else hover
        if motor_map is not None:
            u = motor_map(u)
        speed[k] = gain * s + off
        d0 = s - u
        ms = u * u + 2 * u * d0 * tau / DT * (1 - a) + d0 * d0 * tau / (2 * DT) * (1 - a * a)
        m1 = u + d0 * tau / DT * (1 - a)                        # the mean of s over the step
        s = u + d0 * a
        T = eta * kt * (gain * gain * ms + 2 * gain * off * m1 + off * off)
        tq = np.array([arm * d[:, 1] @ T, -arm * d[:, 0] @ T, kap * P.YAW_SIGNS @ T]) + t[P.TAU_EXT]
        if torque_noise:        # (drawn only then: the other logs keep their noise draws)
            dist = rho_d * dist + torque_noise * np.sqrt(1 - rho_d ** 2) * rng.standard_normal(3)
        w = w + DT * ((tq - np.cross(w, J * w)) / J + dist)
        if k + 1 < n:
            sf = (eta * kt * (gain * s + off) ** 2).sum() / m
            if drag is not None:
                sf -= drag * (0.8 + 0.7 * np.sin(0.9 * (k + 1) * DT))
            meas = w + gyro_noise * rng.standard_normal(3)
            if gyro_vibration:
                f = np.mean(gain * s + off) / (2 * np.pi)
                phi1, phi2 = 2 * rv * np.cos(2 * np.pi * abs((f + 250.0) % 500.0 - 250.0) * DT), -rv * rv
                g = np.sqrt((1 + phi2) * ((1 - phi2) ** 2 - phi1 ** 2) / (1 - phi2))     # unit variance
                vib = np.stack([vib[1], phi1 * vib[1] + phi2 * vib[0] + g * rng.standard_normal(3)])
                meas = meas + gyro_vibration * vib[1]
            imu[k + 1] = np.concatenate([meas,
                                         [acc_noise * rng.standard_normal(), acc_noise * rng.standard_normal(),
                                          sf + acc_noise * rng.standard_normal()]])
    rec = {"imu": imu, "motor": mot}
    if speed_noise is not None:
        rec["rotor_speed"] = speed + speed_noise * rng.standard_normal(speed.shape)
    if drag is not None:
        vz = 0.8 + 0.7 * np.sin(0.9 * np.arange(n) * DT)
        rec["velocity_body"] = np.stack([np.zeros(n), np.zeros(n), vz], -1)
    return rec


def exact_model_log(theta, seconds: float = 4.0, gyro_noise: float = 0.0, acc_noise: float = 0.0,
                    seed: int = 0) -> dict:
    """:func:`synthetic_log` open loop, without drag: {'imu' (T, 6), 'motor' (T, 4)}."""
    return synthetic_log(theta, seconds, gyro_noise, acc_noise, seed)


def likelihood_peaks(data, v, x0, span: float = 0.3, points: int = 31) -> tuple[float, float]:
    """Where the log target of ``data`` peaks along log τ_m and along the roll authority's log, each swept
    ±``span`` (the authority ±span/3) about the truth's visible coordinates ``v`` (12,) with the linear
    start ``x0``'s nuisances (σ, δ) -> (τ_m's offset, the roll authority's offset) from the truth, in log."""
    from mjxsysid.identify.inference import log_target
    steps = np.linspace(-span, span, points)
    y = np.concatenate([v, x0[12:16], [0.0]])[None].repeat(2 * points, 0)
    y[:points, 4] += steps
    y[points:, 5] += steps / 3
    lt = np.asarray(log_target(y.astype(np.float32), data, log_delta=x0[16:20]))
    assert not np.any(np.isnan(lt))          # -inf only outside the prior (J's triangle inequality)
    return float(steps[np.argmax(lt[:points])]), float(steps[np.argmax(lt[points:])] / 3)
