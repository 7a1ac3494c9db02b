"""Physical plausibility of a flight log, before anything is decoded.

A log can pass every check of its format (columns, numbers, 500 Hz, motor commands in [0, 1])
and still be wrong in a way only physics sees: the accelerometer in g, the gyro in deg/s, the
motor columns in another autopilot's rotor order, a command column that is not what the policy
was given. Each check here rests on what every multirotor obeys, not on numbers fitted to
mjxsysid's own logs:

- **specific force against gravity.** Over a flight that does not end in a fall, the
  accelerometer (specific force, body frame) averages to gravity's magnitude in the world frame,
  so its mean norm is at least about g; at hover it reads +g on the body z axis (FLU: thrust up).
- **gyro scale.** A MEMS gyro's full-scale range is at most 2000 °/s (34.9 rad/s); a rate
  controller follows its body-rate command, so gyro ≈ omega_cmd (gain 1, not 180/π).
- **rotor order.** Euler's equation J ω̇ = τ: the angular acceleration the gyro shows must follow
  the torque the motor commands imply through the rotor layout (roll from the left–right
  difference of Ω², pitch from back–front, yaw from the spin directions), with a positive gain
  on every axis. Every one of the 24 orders is fitted; a clearly better one is named.
- **motor columns.** Normalised rotor-speed commands lie in [0, 1] (checked on reading); values
  that do not drive the angular acceleration under any rotor order are not rotor commands.
- **the policy on its own inputs.** For a log flown by the policy being decoded, the policy
  replayed on the logged IMU and commands must output the logged motor commands.
- **IMU noise.** A rigid body's rates and specific force change smoothly from one 2 ms sample to
  the next (rotors lag their commands), so the second difference of a clean IMU is tiny and that
  of a noisy one is the noise's: its robust spread estimates the white-noise level per sample
  (:func:`estimate_imu_noise`). Past what the decoders were calibrated under
  (:data:`IMU_NOISE_LIMIT`), high-frequency noise reads as a smaller, quicker vehicle.

:func:`check_log` returns :class:`Finding` s: ``error`` where the log cannot be right (the CLI
exits 2), ``warning`` where it is suspicious. :func:`prior_check` estimates, from the log alone,
what the decoders cannot be trusted beyond: thrust-to-weight (specific force per unit Σ u²),
the motor time constant (the lag of specific force behind the commands) and the weakest
motor's effectiveness (the hover balance), each against the decoders' training prior.
"""
from mjxsysid.logs.checks.findings import Finding, LogError, warn
from mjxsysid.logs.checks.mistakes import MISTAKES, make_mistake
from mjxsysid.logs.checks.noise import IMU_NOISE_LIMIT, check_imu_noise, estimate_imu_noise, imu_noise_limit
from mjxsysid.logs.checks.plausibility import check_log
from mjxsysid.logs.checks.prior import estimate_vehicle, motor_time_constant, prior_bounds, prior_check
from mjxsysid.logs.checks.rates import check_resampled, column_rates, detect_resampled
from mjxsysid.logs.checks.policy_replay import check_replay
from mjxsysid.logs.checks.rotors import estimate_thrust_lag, rotor_order_fit, thrust_model_fit
from mjxsysid.logs.checks.signals import DT, KNOWN_ORDERS, fit_rows, order_name

__all__ = ["DT", "IMU_NOISE_LIMIT", "KNOWN_ORDERS", "MISTAKES", "Finding", "LogError", "check_imu_noise", "check_log",
           "check_replay", "check_resampled", "column_rates", "detect_resampled", "estimate_imu_noise",

           "estimate_thrust_lag", "estimate_vehicle", "fit_rows", "imu_noise_limit", "make_mistake",
           "motor_time_constant", "order_name", "prior_bounds", "prior_check", "rotor_order_fit", "thrust_model_fit",
           "warn"]
