"""An independent estimate of what a log identifies: ``mujoco.sysid``, the pinned MuJoCo's
system-identification toolbox (Gauss–Newton on MuJoCo rollouts, s²(JᵀJ)⁻¹ intervals), on the same
IMU and motor log as the log-grounded posterior (:mod:`.inference`).

The model is the project's own MJCF (``assets/quadrotor.xml``) with MuJoCo's actuator dynamics in
place of the simulator's rotor lag: each thrust actuator filters its control u_i = clip(s_cmd,i, 0,
1)² with τ_m (``filterexact``), gain η_i k_t Ω_max², its gear carrying the yaw torque κ; three more
actuators at the IMU site, with a constant control of 1, carry the external torque τ_ext. MuJoCo
lags u = s², the simulator s (the same to first order around a trim). The unknowns are the twelve
visible coordinates v of :mod:`.coords` (the hidden ones held at the paper vehicle's values: no
IMU log changes with them) and the accelerometer's z bias.

A long open-loop rollout of a closed-loop flight diverges, so the log is cut into short chunks
(multiple shooting), each started from the log's state at its start — attitude, velocity and
position as an estimator would give them (here the flight's own), the body rates as the gyro's
mean over five samples, the rotor filters as the candidate's τ_m makes them of the commands before
the chunk (``custom_rollout``). The residuals are gyro x/y/z and accelerometer z, each divided by
the channel's white-noise level from the log's second differences (:func:`.logdata.noise_statistics`)
with a floor; the first steps of each chunk are dropped, and the gyro residuals' mean per chunk and axis
(an error in the start's rates, to first order) is profiled out (``modify_residual``) in a second
Gauss–Newton run from the first's optimum (the first, without it, converges from further away).

Intervals: :func:`mujoco.sysid.calculate_intervals` at the optimum (s² from the residuals, (JᵀJ)⁻¹
by eigen-decomposition, Student-t quantile), mapped to the :data:`.coords.LOG_NAMES` quantities by
the delta method (the log-scaled coordinates: exp of the interval's ends). Needs the toolbox's
dependencies (``pip install "mjxsysid[sysid]"``: tabulate, colorama, pyyaml); imported lazily.
"""
from __future__ import annotations

import contextlib
import dataclasses
import io
import time

import numpy as np
import scipy.special

from mjxsysid import theta as P
from mjxsysid.identify import logspace as L
from mjxsysid.identify.coords import PHYSICAL_PRIOR, PhysicalPrior, hidden_from_theta, theta_from, visible_from_theta
from mjxsysid.identify.logspace import N_V, V_NAMES

RHO4 = L.LOG_NAMES.index("relative_effectiveness[3]")
"""ρ_4's place among the quantities: its band comes from the covariance of ρ_1..3."""

CHUNK_STEPS = 50
"""Steps per multiple-shooting chunk (0.1 s at 500 Hz)."""
SKIP_STEPS = 5
"""First steps of each chunk left out of the residual (the state's estimate settles)."""
MAX_CHUNKS = 48
"""At most this many chunks, spread evenly over the log (the Jacobian's cost grows with them)."""
HISTORY_STEPS = 150
"""Commands before a chunk that set its rotor filters' start (0.3 s: > 3 τ_m for all but the slowest)."""
SHIFT = 0
"""MuJoCo's rollout row k against the log's row k + SHIFT: a chunk starts from the state its first IMU
row belongs to, and MuJoCo records each step's sensors at the state it starts from (measured: with the
true θ on a clean simulator log the gyro residual is 1e-5–5e-5 rad/s at 0, 4e-4 at ±1)."""
FLOOR = np.array([2e-3, 2e-3, 2e-3, 2e-2])
"""Residual scale floor per channel (rad/s, rad/s, rad/s, m/s²): a clean log's rollout error."""


def _require_sysid():
    """mujoco.sysid's toolbox as one namespace. Its modules are imported directly: the package's
    ``__init__`` also imports its HTML report (plotly, 64 MB), which this never uses, and swallows
    the ImportError of any missing dependency."""
    import types
    try:
        from mujoco.sysid._src import (
            optimize,
            parameter,
            residual,
            timeseries,
            trajectory,
        )
    except ImportError as e:                                  # pragma: no cover - depends on the install
        raise ImportError(f'mujoco.sysid needs its dependencies ({e}): pip install "mjxsysid[sysid]" '
                          '(tabulate, colorama, pyyaml; mujoco[sysid] adds its HTML report\'s plotly)') from e
    return types.SimpleNamespace(
        optimize=optimize.optimize, calculate_intervals=optimize.calculate_intervals, Parameter=parameter.Parameter,
        ParameterDict=parameter.ParameterDict, model_residual=residual.model_residual,
        TimeSeries=timeseries.TimeSeries, SystemTrajectory=trajectory.SystemTrajectory,
        create_initial_state=trajectory.create_initial_state, sysid_rollout=trajectory.sysid_rollout)


def quadrotor_spec(dt: float = 0.002):
    """The project's MJCF as an ``MjSpec`` with filtered thrust actuators and three external-torque
    actuators (module doc); visuals removed."""
    import mujoco

    from mjxsysid.sim.quadrotor import ASSET
    spec = mujoco.MjSpec.from_file(str(ASSET))
    spec.option.timestep = dt
    spec.compiler.balanceinertia = True     # a candidate off J's triangle inequality: MuJoCo moves it onto it
    for i in range(1, 5):
        a = spec.actuator(f"thrust{i}")
        a.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
        a.dynprm[0] = 0.05
    body = spec.body("quadrotor")
    for k, axis in enumerate("xyz"):
        site = body.add_site(name=f"torque_{axis}", pos=[0, 0, 0])
        a = spec.add_actuator(name=f"tau_ext_{axis}", trntype=mujoco.mjtTrn.mjTRN_SITE, target=site.name)
        gear = [0.0] * 6
        gear[3 + k] = 1.0
        a.gear = gear
    for g in list(body.geoms):
        spec.delete(g)
    return spec


def apply_theta(spec, theta) -> None:
    """Write θ (19,) into ``spec`` (in place): mass, inertia, rotor sites, thrust gains and lag,
    yaw gear, external torque."""
    t = np.asarray(theta, np.float64)
    body = spec.body("quadrotor")
    body.mass = t[P.MASS]
    body.inertia = t[P.INERTIA]
    pos = np.concatenate([t[P.ARM] * np.asarray(P.ROTOR_DIRECTIONS, np.float64), np.zeros((4, 1))], 1)
    kappa = t[P.KTAU] / t[P.KT]
    for i in range(4):
        spec.site(f"rotor{i + 1}").pos = pos[i]
        a = spec.actuator(f"thrust{i + 1}")
        a.gainprm[0] = t[P.ETA][i] * t[P.KT] * t[P.OMEGA_MAX] ** 2
        a.dynprm[0] = t[P.TAU_M]
        a.gear = [0.0, 0.0, 1.0, 0.0, 0.0, float(P.YAW_SIGNS[i]) * kappa]
    for k, axis in enumerate("xyz"):
        spec.actuator(f"tau_ext_{axis}").gainprm[0] = t[P.TAU_EXT][k]


@dataclasses.dataclass
class SysidResult:
    """v (12,) at the optimum, its interval half-widths (12,) (inf where JᵀJ is singular along it) and
    ρ_4's, the accelerometer's z bias, the residual's s², seconds, the chunks used."""
    v: np.ndarray
    half_width: np.ndarray
    half_rho4: float
    acc_bias: float
    s2: float
    seconds: float
    chunks: int

    def quantities(self) -> dict:
        """The :data:`.coords.LOG_NAMES` quantities: estimate, 5 % and 95 % (13,) each."""
        est = L.quantities_of_v(self.v)
        lo, hi = L.quantities_of_v(self.v - self.half_width), L.quantities_of_v(self.v + self.half_width)
        lo[RHO4], hi[RHO4] = est[RHO4] - self.half_rho4, est[RHO4] + self.half_rho4
        return {"estimate": est, "q05": lo, "q95": hi}


def _chunk_starts(n: int, chunk: int, history: int, max_chunks: int) -> np.ndarray:
    starts = np.arange(history, n - chunk, chunk)
    if len(starts) > max_chunks:
        starts = starts[np.linspace(0, len(starts) - 1, max_chunks).round().astype(int)]
    return starts


def _lagged_square(cmd_hist, tau: float, dt: float) -> np.ndarray:
    """MuJoCo's filterexact state after the commands ``cmd_hist`` (H, 4) (normalised), from their
    first value: the filtered u = s²."""
    u = np.clip(cmd_hist, 0.0, 1.0) ** 2
    a = np.exp(-dt / max(tau, 1e-6))
    x = u[0].copy()
    for row in u[1:]:
        x = row + (x - row) * a
    return x


def _body_z_velocity(quat, vel) -> np.ndarray:
    """quat (T, 4) wxyz, world velocity (T, 3) -> the velocity along body z (T,)."""
    w, x, y, z = quat.T
    zb = np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], -1)   # R[:, 2]
    return (zb * vel).sum(-1)


def identify(imu, motor, qpos, qvel, *, dt: float = 0.002, start_theta=None, prior: PhysicalPrior = PHYSICAL_PRIOR,
             chunk_steps: int = CHUNK_STEPS, max_chunks: int = MAX_CHUNKS, max_iters: int = 60,
             alpha: float = 0.10) -> SysidResult:
    """mujoco.sysid's estimate of the visible coordinates from a log (module doc).

    imu (T, 6) [gyro, specific force] as the controller saw it (:func:`mjxsysid.rollout.flight.seen_imu`),
    motor (T, 4) normalised commands, qpos (T, 7) [position, quaternion wxyz] and qvel (T, 6)
    [world velocity, body rates] the state estimate at each step (the body rates are replaced by the
    gyro's mean). ``start_theta`` (19,): the optimiser's start (default: the paper vehicle); its
    hidden coordinates are the ones the model holds. ``alpha``: 0.10 gives 90 % intervals.
    """
    from mujoco import minimize
    sysid = _require_sysid()

    from mjxsysid.identify.logdata import noise_statistics
    imu, motor = np.asarray(imu, np.float64), np.asarray(motor, np.float64)
    qpos, qvel = np.asarray(qpos, np.float64), np.asarray(qvel, np.float64)
    n = len(imu)
    for name, a, d in (("motor", motor, 4), ("qpos", qpos, 7), ("qvel", qvel, 6)):
        if a.shape != (n, d):
            raise ValueError(f"{name} must be ({n}, {d}) like imu ({n}, 6), got {a.shape}")
    starts = _chunk_starts(n, chunk_steps, HISTORY_STEPS, max_chunks)
    if len(starts) < 4:
        raise ValueError(f"log too short for mujoco.sysid: {n} steps give {len(starts)} chunks of {chunk_steps} "
                         f"after {HISTORY_STEPS} steps of history (need 4)")
    start_theta = np.asarray(P.paper_hardware() if start_theta is None else start_theta, np.float32)
    h0 = np.asarray(hidden_from_theta(start_theta), np.float64)
    v0 = np.asarray(visible_from_theta(start_theta), np.float64)

    count, ssq, _ = noise_statistics({"imu": imu})
    sigma = np.sqrt(ssq / np.maximum(count, 1) / 6.0)
    scale = np.sqrt(sigma ** 2 + FLOOR ** 2)

    spec = quadrotor_spec(dt)
    lo, hi = prior.v_bounds()
    params = sysid.ParameterDict()
    for k, name in enumerate(V_NAMES):
        params.add(sysid.Parameter(name, nominal=float(np.clip(v0[k], lo[k], hi[k])),
                                   min_value=float(lo[k]), max_value=float(hi[k])))
    params.add(sysid.Parameter("acc_bias_z", nominal=0.0, min_value=-3.0, max_value=3.0))
    params.add(sysid.Parameter("drag_z_per_mass", nominal=0.1, min_value=0.0, max_value=60.0))

    def v_of(p):
        return np.array([p[name].value[0] for name in V_NAMES], np.float64)

    def build_model(p, s=spec):
        v = v_of(p)
        v[L.RHO] = np.clip(v[L.RHO], 0.05, None)
        rho4 = 4.0 - v[L.RHO].sum()
        if rho4 < 0.05:                                     # keep the vehicle valid
            v[L.RHO] *= 3.95 / v[L.RHO].sum()
        apply_theta(s, theta_from(v, h0, np.float64))
        return s.compile()

    model0 = build_model(params)
    ctrl = np.concatenate([np.clip(motor, 0.0, 1.0) ** 2, np.ones((n, 3))], 1)
    chunks = []
    for s0 in starts:
        sl = slice(s0, s0 + chunk_steps)
        w0 = imu[max(s0 - 2, 0):s0 + 3, :3].mean(0)
        q0 = np.concatenate([qvel[s0, :3], w0])
        state0 = sysid.create_initial_state(model0, qpos[s0], q0, np.zeros(model0.na))
        times = dt * np.arange(chunk_steps)
        chunks.append(sysid.SystemTrajectory(
            model=model0, control=sysid.TimeSeries(times, ctrl[sl]),
            sensordata=sysid.TimeSeries.from_names(times, imu[sl], model0),
            initial_state=state0, state=None))
    act_slice = slice(1 + model0.nq + model0.nv, 1 + model0.nq + model0.nv + model0.na)

    def rollout(models, datas, control_signal, initial_states, param_dicts, **kw):
        """mujoco.sysid's rollout with each chunk's rotor filters started by the candidate's τ_m."""
        states = []
        for j, st in enumerate(initial_states):         # FD column j // chunks, chunk j % chunks
            s0, pd = starts[j % len(starts)], param_dicts[j // len(starts)]
            tau = float(np.exp(pd["log_motor_time_constant"].value[0]))
            st = np.array(st)
            st[act_slice][:4] = _lagged_square(motor[s0 - HISTORY_STEPS:s0], tau, dt)
            states.append(st)
        return sysid.sysid_rollout(models, datas, control_signal, states, **kw)

    chans = np.array([0, 1, 2, 5])

    profile = [False]      # stage 1 without the rate offsets' profile (it converges from further away)

    def modify_residual(p, pred, meas, model, return_pred_all, state=None):
        pd_, md = np.asarray(pred.data), np.asarray(meas.data)
        k = min(len(pd_), len(md) - SHIFT)
        pd_, md, st = pd_[SKIP_STEPS:k, chans], md[SKIP_STEPS + SHIFT:k + SHIFT], np.asarray(state)[SKIP_STEPS:k]
        # the body-z drag, −(d_z / m) v_body,z, from the rollout's own velocity (MuJoCo's fluid model
        # is not the simulator's linear drag), and the accelerometer's bias
        v_bz = _body_z_velocity(st[:, 4:8], st[:, 8:11])
        pd_[:, 3] += p["acc_bias_z"].value[0] - p["drag_z_per_mass"].value[0] * v_bz
        res = (md[:, chans] - pd_) / scale
        # the start's body rates are a nuisance (the gyro's mean carries its noise): profiled out as a
        # constant rate offset per chunk and axis (to first order what an error in them does)
        if profile[0]:
            res[:, :3] -= res[:, :3].mean(0)
        res = res.ravel()
        # one mapping object for both (the library compares the mappings, whose values are arrays)
        return res, sysid.TimeSeries(pred.times, pred.data, meas.signal_mapping), meas

    def residual_fn(x, p):
        r, preds, meas = sysid.model_residual(x, p, build_model, chunks, modify_residual=modify_residual,
                                        custom_rollout=rollout, n_threads=1)
        if np.ndim(x) == 2:    # columns per (FD column, chunk) -> one column per FD column
            r = np.asarray(r).T.reshape(np.shape(x)[1], -1).T
        return [r], preds, meas

    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):      # the backend prints every iteration
        opt, _ = sysid.optimize(params.move_off_bounds(fraction=0.002), residual_fn, optimizer="mujoco",
                                verbose=False, max_iters=max_iters)
        profile[0] = True   # stage 2: from stage 1's optimum, the start's rate errors profiled out
        opt, _ = sysid.optimize(opt.move_off_bounds(fraction=0.002), residual_fn, optimizer="mujoco",
                                verbose=False, max_iters=max_iters)
    # The Jacobian at the optimum for the intervals, by mujoco.minimize's finite differences with a
    # step the rollouts resolve (its default, √ε, is below the float32 of the IMU's data)
    x = opt.as_vector()
    r_star, _, _ = residual_fn(x, opt)
    jac, _ = minimize.jacobian_fd(lambda xx: residual_fn(xx, opt)[0][0], x.reshape(-1, 1),
                                  np.concatenate(r_star).reshape(-1, 1), 1e-5, 0, [b.reshape(-1, 1) for b in opt.get_bounds()])
    opt.update_from_vector(x)          # the finite differences moved the dict's values
    seconds = time.perf_counter() - t0
    sigma_x, half = sysid.calculate_intervals(r_star, jac, alpha=alpha)
    final = np.concatenate(r_star)
    dof = max(final.size - jac.shape[1], 1)
    s2 = float(final @ final / dof)
    # ρ_4 = 4 − ρ_1 − ρ_2 − ρ_3: its half-width from the covariance, with calculate_intervals' quantile
    half_rho4 = float(scipy.special.stdtrit(dof, 1 - alpha / 2)) * float(np.sqrt(max(sigma_x[L.RHO, L.RHO].sum(), 0.0)))
    return SysidResult(v=v_of(opt), half_width=np.asarray(half[:N_V], np.float64), half_rho4=half_rho4,
                       acc_bias=float(opt["acc_bias_z"].value[0]), s2=s2, seconds=seconds, chunks=len(starts))
