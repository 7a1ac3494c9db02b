"""θ in the coordinates a flight log sees, and the stated physical prior of the log-grounded posterior.

An IMU log of specific force and body rates, with the motor commands, obeys (DESIGN §3, the
simulator's own equations; η_i = η̄ ρ_i, ρ the effectiveness relative to the mean η̄)::

    acc_z        = (g / 4) · TWᵉ · Σ_i ρ_i s_i²                          (+ drag, + bias)
    ω̇_x          = Aᵉ_x Σ_i ρ_i y_i s̄_i² + c_x + (J_y − J_z)/J_x · ω_y ω_z
    ω̇_y          = Aᵉ_y Σ_i ρ_i (−x_i) s̄_i² + c_y + (J_z − J_x)/J_y · ω_z ω_x
    ω̇_z          = Yᵉ Σ_i ρ_i σ_i s̄_i² + c_z + (J_x − J_y)/J_z · ω_x ω_y

with s_i = Ω_i / Ω_max the rotor speed the first-order lag τ_m makes of the command, (x_i, y_i)
the rotor directions, σ_i the spin signs, and

- TWᵉ = 4 η̄ k_t Ω_max² / (m g): the thrust-to-weight of all four rotors at full speed, the one
  every report gives (``thrust_to_weight``; ``nominal_thrust_to_weight`` is it at η = 1, not seen);
- Aᵉ = η̄ l k_t Ω_max² / J: the angular authorities (``angular_authority`` × η̄); the inertia
  ratios of the gyroscopic terms are ratios of them (J_y / J_x = Aᵉ_x / Aᵉ_y);
- Yᵉ = η̄ κ k_t Ω_max² / J_z: the yaw authority (κ / l × Aᵉ_z);
- c = τ_ext / J: the constant angular acceleration of the external torque;
- ρ_i and τ_m themselves.

These twelve numbers are the *visible* coordinates v (their table, with h's, the nuisances' and the
reported quantities': [logspace][mjxsysid.identify.logspace]). The other seven — mass, arm length,
Ω_max, η̄ and the three drag coefficients — are *hidden*: no IMU log without position or
velocity changes with them while v is held (scale: mass against thrust coefficient, arm length
against inertia; drag acts through the velocity a log of IMU and motors does not carry).
``theta_from(v, h)`` and ``visible/hidden_from_theta`` are exact inverses.

The prior of the log-grounded posterior is stated in these coordinates, independent between v
and h, so the posterior is exactly p(v | log) p(h): the hidden directions come out as broad as
the prior says, by construction. :data:`PHYSICAL_PRIOR` is wider than every training prior of
the decoders (checked in the tests against the training priors' draws), so a vehicle outside
them is still identified.
"""
from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from mjxsysid import theta as P
from mjxsysid.identify import logspace as L
from mjxsysid.identify.logspace import H_NAMES, LOG_NAMES, LOG_UNITS, N_H, N_V, V_NAMES  # noqa: F401 (the room's names)
from mjxsysid.theta import xp_of


def _rho4(v):
    """ρ_4 = 4 − ρ_1 − ρ_2 − ρ_3 of v (..., 12)."""
    rho = v[..., L.RHO]
    return 4.0 - rho[..., 0] - rho[..., 1] - rho[..., 2]


def visible_from_theta(theta):
    """θ (..., 19) -> v (..., 12) (module doc); NumPy in, NumPy out (:func:`xp_of`)."""
    xp = xp_of(theta)
    t = xp.asarray(theta, xp.float32)
    eta = t[..., P.ETA]
    eb = eta.mean(-1)
    auth = P.angular_authority(t) * eb[..., None]
    yaw = t[..., P.KTAU] / t[..., P.KT] / t[..., P.ARM] * auth[..., 2]
    rho = eta / eb[..., None]
    return L.pack(L.V_FIELDS, log_thrust_to_weight=xp.log(P.thrust_to_weight(t)), rel_effectiveness=rho[..., :3],
                  log_motor_time_constant=xp.log(t[..., P.TAU_M]), log_authority=xp.log(auth),
                  log_yaw_authority=xp.log(yaw), ext_acc=t[..., P.TAU_EXT] / t[..., P.INERTIA])


def hidden_from_theta(theta):
    """θ (..., 19) -> h (..., 7) (module doc)."""
    xp = xp_of(theta)
    t = xp.asarray(theta, xp.float32)
    return L.pack(L.H_FIELDS, log_mass=xp.log(t[..., P.MASS]), log_arm_length=xp.log(t[..., P.ARM]),
                  log_max_rotor_speed=xp.log(t[..., P.OMEGA_MAX]), mean_effectiveness=t[..., P.ETA].mean(-1),
                  log_drag=xp.log(t[..., P.DRAG]))


def theta_from(v, h, dtype=None):
    """v (..., 12), h (..., 7) -> θ (..., 19): the inverse of the two maps above. ``dtype``: float32
    by default (float64 for a NumPy caller that differentiates it by finite differences)."""
    xp = xp_of(v, h)
    dtype = xp.float32 if dtype is None else dtype
    v, h = xp.asarray(v, dtype), xp.asarray(h, dtype)
    m, arm, wmax, eb = xp.exp(h[..., L.LOG_MASS]), xp.exp(h[..., L.LOG_ARM]), xp.exp(h[..., L.LOG_OMEGA_MAX]), \
        h[..., L.ETA_MEAN]
    rho = xp.concatenate([v[..., L.RHO], _rho4(v)[..., None]], -1)
    twr = xp.exp(v[..., L.LOG_TW]) / eb
    kt = twr * m * P.GRAVITY / (4.0 * wmax**2)
    auth = xp.exp(v[..., L.LOG_AUTH]) / eb[..., None]
    inertia = (arm * kt * wmax**2)[..., None] / auth
    kappa = arm * xp.exp(v[..., L.LOG_YAW]) / xp.exp(v[..., L.LOG_AUTH_Z])
    tau_ext = v[..., L.EXT_ACC] * inertia
    return xp.concatenate([m[..., None], arm[..., None], kt[..., None], (kappa * kt)[..., None], inertia,
                           xp.exp(h[..., L.LOG_DRAG]), wmax[..., None], eb[..., None] * rho,
                           xp.exp(v[..., L.LOG_TAU_M])[..., None], tau_ext], -1)


def with_mass(theta, mass_kg) -> np.ndarray:
    """θ (..., 19) with its mass set to ``mass_kg`` and every visible coordinate kept (thrust-to-weight,
    the authorities, τ_m, ρ, τ_ext / J: the thrust coefficient and inertia scale with it). Draws of the
    log-grounded posterior, whose hidden coordinates are independent of the visible ones, become draws
    of the posterior given a weighed vehicle."""
    v, h = visible_from_theta(np.asarray(theta, np.float32)), hidden_from_theta(np.asarray(theta, np.float32))
    h = np.array(h)
    h[..., L.LOG_MASS] = np.log(np.float32(mass_kg))
    return np.asarray(theta_from(v, h))


def log_quantities(theta) -> np.ndarray:
    """θ (..., 19) -> the :data:`LOG_NAMES` quantities (..., 13) in physical units."""
    return L.quantities_of_v(visible_from_theta(theta))


@dataclasses.dataclass(frozen=True)
class PhysicalPrior:
    """The stated prior of the log-grounded posterior, independent uniform in each coordinate
    (log-uniform for the positive quantities), truncated to valid vehicles: ρ_4 in ``rel_eff``
    and the triangle inequality of J (1/Aᵉ_z ≤ 1/Aᵉ_x + 1/Aᵉ_y). Every range is physical
    (units in the field names) and wider than the decoders' training priors."""
    name: str = "physical"
    thrust_to_weight: tuple[float, float] = (1.05, 15.0)
    rel_eff: tuple[float, float] = (0.25, 1.9)
    motor_time_constant_s: tuple[float, float] = (0.002, 0.3)
    authority_rad_s2: tuple[float, float] = (10.0, 10_000.0)
    yaw_authority_rad_s2: tuple[float, float] = (0.2, 3_000.0)
    ext_acc_rad_s2: tuple[float, float] = (-150.0, 150.0)
    mass_kg: tuple[float, float] = (0.02, 5.0)
    arm_length_m: tuple[float, float] = (0.02, 0.6)
    max_rotor_speed_rad_s: tuple[float, float] = (150.0, 20_000.0)
    mean_effectiveness: tuple[float, float] = (0.45, 1.35)
    drag_kg_s: tuple[float, float] = (0.001, 5.0)

    @property
    def thrust_to_weight_total(self) -> tuple[float, float]:
        """The old name of :attr:`thrust_to_weight` (a FutureWarning)."""
        warnings.warn("PhysicalPrior.thrust_to_weight_total is now PhysicalPrior.thrust_to_weight (the one "
                      "thrust-to-weight, 4 η̄ k_t Ω_max² / (m g)); the old name goes in the next release",
                      FutureWarning, stacklevel=2)
        return self.thrust_to_weight

    def _bounds(self, fields, ranges: dict) -> tuple[np.ndarray, np.ndarray]:
        """Per field of ``fields`` its (lo, hi), log for a field in log units -> lo, hi per entry."""
        rows = [np.log(ranges[f.name]) if f.unit.startswith("log(") else ranges[f.name]
                for f in fields for _ in range(f.size)]
        b = np.asarray(rows, np.float64)
        return b[:, 0], b[:, 1]

    def v_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Box of v (12,), (12,) (before the truncations)."""
        return self._bounds(L.V_FIELDS, {
            "log_thrust_to_weight": self.thrust_to_weight, "rel_effectiveness": self.rel_eff,
            "log_motor_time_constant": self.motor_time_constant_s, "log_authority": self.authority_rad_s2,
            "log_yaw_authority": self.yaw_authority_rad_s2, "ext_acc": self.ext_acc_rad_s2})

    def h_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Box of h (7,), (7,)."""
        return self._bounds(L.H_FIELDS, {
            "log_mass": self.mass_kg, "log_arm_length": self.arm_length_m,
            "log_max_rotor_speed": self.max_rotor_speed_rad_s, "mean_effectiveness": self.mean_effectiveness,
            "log_drag": self.drag_kg_s})

    def v_valid(self, v):
        """v (..., 12) -> (...) bool: inside the box, ρ_4 in range, J's triangle inequality."""
        lo, hi = self.v_bounds()
        xp = xp_of(v)
        v = xp.asarray(v)
        box = xp.all((v >= lo) & (v <= hi), -1)
        r4 = _rho4(v)
        inv = xp.exp(-v[..., L.LOG_AUTH])                    # ∝ J_x, J_y, J_z
        return box & (r4 >= self.rel_eff[0]) & (r4 <= self.rel_eff[1]) & (inv[..., 2] <= inv[..., 0] + inv[..., 1])

    def log_prob_v(self, v):
        """Unnormalised log density of v (..., 12): 0 inside, −inf outside (a uniform prior)."""
        xp = xp_of(v)
        return xp.where(self.v_valid(v), 0.0, -xp.inf)

    def sample_v(self, rng, n: int) -> np.ndarray:
        """n draws of v (n, 12) (rejection from the box); ``rng``: a NumPy generator or a seed."""
        lo, hi = self.v_bounds()
        rng = np.random.default_rng(rng)
        out, have = [], 0
        while have < n:
            x = rng.uniform(lo, hi, (4 * n, N_V)).astype(np.float32)
            x = x[self.v_valid(x)]
            out.append(x)
            have += len(x)
        return np.concatenate(out)[:n]

    def sample_h(self, rng, n: int) -> np.ndarray:
        """n draws of h (n, 7); ``rng``: a NumPy generator or a seed."""
        lo, hi = self.h_bounds()
        return np.random.default_rng(rng).uniform(lo, hi, (n, N_H)).astype(np.float32)

    def contains_theta(self, theta) -> np.ndarray:
        """θ (..., 19) -> (...) bool: inside this prior's support."""
        v, h = visible_from_theta(theta), hidden_from_theta(theta)
        lo, hi = self.h_bounds()
        hin = np.all((np.asarray(h) >= lo - 1e-6) & (np.asarray(h) <= hi + 1e-6), -1)
        return np.asarray(self.v_valid(v)) & hin


PHYSICAL_PRIOR = PhysicalPrior()
