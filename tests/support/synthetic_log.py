"""A quadrotor flight made in numpy for the log tests (no JAX, no MuJoCo): rotor speeds lag their
commands (first order), thrust ∝ Σ Ω², Euler's equation with the X layout's torque basis, a rate
controller closing the loop, optional ground time before take-off and after landing."""
import numpy as np

from mjxsysid import theta as P
from mjxsysid.logs.checks.signals import torque_basis

DT = 0.002


def synthetic_flight(seconds: float = 12.0, *, twr: float = 2.4, tau: float = 0.03, ground_s=(0.0, 0.0),
                     gains=(400.0, 400.0, 60.0), gyro_noise: float = 0.002, acc_noise: float = 0.02,
                     seed: int = 0) -> dict:
    """``seconds`` of flight between ``ground_s`` (before, after) seconds with the rotors stopped ->
    dict t (T,) s, imu (T, 6) gyro rad/s and specific force m/s² (FLU), a_cmd (T,) m/s²,
    omega_cmd (T, 3) rad/s, motor (T, 4) Ω_cmd/Ω_max and rotor_speed (T, 4) Ω/Ω_max in mjxsysid's
    rotor order; ``twr`` thrust-to-weight, ``tau`` the rotors' time constant (s), ``gains`` the
    angular acceleration (rad/s²) per unit of the torque basis · Ω²; ``airborne`` (t0, t1) s."""
    rng = np.random.default_rng(seed)
    g0, g1 = (int(round(s / DT)) for s in ground_s)
    n = int(round(seconds / DT))
    T = g0 + n + g1
    t = DT * np.arange(T)
    basis = torque_basis()                                   # (3, 4)
    mix = np.linalg.pinv(basis)                              # (4, 3): torque -> per-rotor Ω² change
    k = np.asarray(gains)
    # a smooth rate command: sums of sines of 0.3–3 Hz
    f = rng.uniform(0.3, 3.0, (3, 4))
    ph = rng.uniform(0, 2 * np.pi, (3, 4))
    tt = DT * np.arange(n)
    w_cmd = 1.2 * np.stack([np.sin(2 * np.pi * f[a, :, None] * tt + ph[a, :, None]).sum(0) / 2 for a in range(3)], -1)
    w_cmd[:, 2] *= 0.5
    coll = 1.0 + 0.15 * np.sin(2 * np.pi * 0.7 * tt) + 0.08 * np.sin(2 * np.pi * 2.3 * tt + 1.0)
    hover2 = 4.0 / twr / 4.0                                 # Ω² per rotor at hover
    a_flt = np.exp(-DT / tau)
    w = np.full(4, np.sqrt(hover2))
    om = np.zeros(3)
    u_out, w_out, om_out, acc_z = (np.zeros((n, 4)), np.zeros((n, 4)), np.zeros((n, 3)), np.zeros(n))
    for i in range(n):
        want = 8.0 * (w_cmd[i] - om) / k                     # the torque basis · Ω² the controller asks for
        u2 = np.clip(hover2 * coll[i] + mix @ want, 0.0, 1.0)
        u = np.sqrt(u2)
        w = a_flt * w + (1 - a_flt) * u
        om = om + DT * k * (basis @ (w * w))
        u_out[i], w_out[i], om_out[i] = u, w, om
        acc_z[i] = twr * P.GRAVITY / 4.0 * float(np.sum(w * w))
    imu = np.zeros((T, 6))
    imu[:, 5] = P.GRAVITY
    imu[g0:g0 + n, :3] = om_out
    imu[g0:g0 + n, 5] = acc_z
    imu[:, :3] += gyro_noise * rng.standard_normal((T, 3))
    imu[:, 3:] += acc_noise * rng.standard_normal((T, 3))
    motor, speed = np.zeros((T, 4)), np.zeros((T, 4))
    motor[g0:g0 + n], speed[g0:g0 + n] = u_out, w_out
    a_cmd, omega_cmd = np.zeros(T), np.zeros((T, 3))
    a_cmd[g0:g0 + n], omega_cmd[g0:g0 + n] = P.GRAVITY * coll, w_cmd
    return {"t": t, "imu": imu, "a_cmd": a_cmd, "omega_cmd": omega_cmd, "motor": motor, "rotor_speed": speed,
            "airborne": (float(t[g0]) if g0 else 0.0, float(t[g0 + n - 1]))}
