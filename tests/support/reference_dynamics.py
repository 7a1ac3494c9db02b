"""An independent NumPy reference for the quadrotor equations of DESIGN §3.

Written separately from mjxsysid.sim (no MuJoCo, no JAX): Newton–Euler rigid body with
quaternion attitude, rotor first-order speed dynamics as ODE states, quadratic thrust, yaw
reaction torque, body-frame linear drag, constant body torque, world force, gravity.
Integrated with classical RK4 at a small fixed step, float64.
"""
import numpy as np

G = 9.81
S = 1 / np.sqrt(2)
ARM_DIR = np.array([[S, -S], [S, S], [-S, S], [-S, -S]])  # FR, FL, BL, BR (x fwd, y left)
YAW = np.array([-1.0, 1.0, -1.0, 1.0])


def rotmat(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def deriv(x, theta, omega_cmd, force_world):
    m, l, kt, ktau = theta[0:4]
    J = theta[4:7]
    D = theta[7:10]
    eta = theta[11:15]
    tau_m = theta[15]
    tau_ext = theta[16:19]
    v, q, w, rot_speed = x[3:6], x[6:10], x[10:13], x[13:17]   # the position x[0:3] does not enter
    R = rotmat(q / np.linalg.norm(q))
    f = eta * kt * rot_speed**2  # per-rotor thrust
    rx, ry = (l * ARM_DIR).T  # rotor i at (rx, ry, 0) body: r × (0, 0, f) = (ry f, −rx f, 0)
    torque = np.array([ry @ f, -(rx @ f), np.sum(YAW * (ktau / kt) * f)]) + tau_ext
    v_body = R.T @ v
    acc = (R @ (np.array([0, 0, f.sum()]) - D * v_body) + force_world) / m + np.array([0, 0, -G])
    wdot = (torque - np.cross(w, J * w)) / J
    qw, qx, qy, qz = q
    ox, oy, oz = w
    qdot = 0.5 * np.array([-qx * ox - qy * oy - qz * oz,
                           qw * ox + qy * oz - qz * oy,
                           qw * oy - qx * oz + qz * ox,
                           qw * oz + qx * oy - qy * ox])
    sdot = (omega_cmd - rot_speed) / tau_m
    return np.concatenate([v, acc, qdot, wdot, sdot])


def simulate(theta, x0, motor_cmds, forces, dt=0.002, h=5e-4):
    """theta (19,), x0 (17,) = [p, v, q(wxyz), ω_body, Ω]; motor_cmds (T, 4) normalised held
    for dt; forces (T, 3). Returns states after each control step (T, 17)."""
    theta = np.asarray(theta, np.float64)
    x = np.asarray(x0, np.float64).copy()
    n = int(round(dt / h))
    out = []
    for u, fw in zip(np.asarray(motor_cmds, np.float64), np.asarray(forces, np.float64)):
        oc = np.clip(u, 0, 1) * theta[10]
        for _ in range(n):
            k1 = deriv(x, theta, oc, fw)
            k2 = deriv(x + h / 2 * k1, theta, oc, fw)
            k3 = deriv(x + h / 2 * k2, theta, oc, fw)
            k4 = deriv(x + h * k3, theta, oc, fw)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            x[6:10] /= np.linalg.norm(x[6:10])
        out.append(x.copy())
    return np.array(out)
