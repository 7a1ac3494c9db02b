"""θ: the 19 physical parameters of a quadrotor, a float array (..., 19) in SI units.

- [layout][mjxsysid.theta.layout]: the field table (name, size, unit, positive, log-scaled) and
  every view of it: names, units, index constants, slices, masks, vehicle-file keys; the rotor
  geometry and the paper's vehicle.
- [derived][mjxsysid.theta.derived]: thrust-to-weight, the identifiable combinations, the derived
  quantities a summary reports, and flyability.
- [vehicles][mjxsysid.theta.vehicles]: validation, projection to valid θ, vehicle files.
- [priors][mjxsysid.theta.priors]: the priors over θ and the held-out families, by name.
- [normalize][mjxsysid.theta.normalize]: θ ↔ the standardised space everything learned works in.

The names below are the public API; ``from mjxsysid import theta as P`` then ``P.MASS``,
``P.get_prior("default")``, ``P.load_vehicle(path)``.
"""
from mjxsysid.theta.derived import (DERIVED_NAMES, IDENTIFIABLE_NAMES, angular_authority, derived, flyability,
                                    identifiable, nominal_thrust_to_weight, rotor_positions, thrust_to_weight,
                                    torque_ratio, xp_of)
from mjxsysid.theta.layout import (ARM, DRAG, ETA, FIELDS, GRAVITY, INDEX, INERTIA, KT, KTAU, LOG_MASK, LOG_OFFSET,
                                   MASS, N_PARAMS, NONNEGATIVE_MASK, OMEGA_MAX, PAPER_HARDWARE, PARAM_NAMES,
                                   PARAM_UNITS, POSITIVE_MASK, ROTOR_DIRECTIONS, ROTOR_NAMES, SLICES, TAU_EXT, TAU_M,
                                   VEHICLE_KEYS, YAW_SIGNS, Field)
from mjxsysid.theta.normalize import Normalizer, prior_normalizer
from mjxsysid.theta.priors import (DEFAULT_PRIOR, HELDOUT_FAMILIES, PRIORS, SLOW_ACTUATOR_PRIOR, STRESS_PRIOR,
                                   STRESS_WIDE_PRIOR, WIDE_ACTUATOR_PRIOR, XADAP_PRIOR, HeldOutFamily, Prior,
                                   SizeFactorPrior, XAdapPrior, get_prior, widened_prior, xadap_training_prior)
from mjxsysid.theta.vehicles import (as_batch, check_flyable, load_vehicle, paper_hardware, project_valid,
                                     project_valid_jax, save_vehicle, theta_from_dict, theta_to_dict, validate_theta,
                                     vehicle_path)

__all__ = ["ARM", "DEFAULT_PRIOR", "DERIVED_NAMES", "DRAG", "ETA", "FIELDS", "GRAVITY", "HELDOUT_FAMILIES",
           "IDENTIFIABLE_NAMES", "INDEX", "INERTIA", "KT", "KTAU", "LOG_MASK", "LOG_OFFSET", "MASS",
           "NONNEGATIVE_MASK", "N_PARAMS", "OMEGA_MAX", "PAPER_HARDWARE", "PARAM_NAMES", "PARAM_UNITS",
           "POSITIVE_MASK", "PRIORS", "ROTOR_DIRECTIONS", "ROTOR_NAMES", "SLICES", "SLOW_ACTUATOR_PRIOR",
           "STRESS_PRIOR", "STRESS_WIDE_PRIOR", "TAU_EXT", "TAU_M", "VEHICLE_KEYS", "WIDE_ACTUATOR_PRIOR",
           "XADAP_PRIOR", "YAW_SIGNS", "Field", "HeldOutFamily", "Normalizer", "Prior", "SizeFactorPrior",
           "XAdapPrior", "angular_authority", "as_batch", "check_flyable", "derived", "flyability", "get_prior",
           "identifiable", "load_vehicle", "nominal_thrust_to_weight", "paper_hardware", "prior_normalizer",
           "project_valid", "project_valid_jax", "rotor_positions", "save_vehicle", "theta_from_dict", "theta_to_dict",
           "thrust_to_weight", "torque_ratio", "validate_theta", "vehicle_path", "widened_prior",
           "xadap_training_prior", "xp_of"]
