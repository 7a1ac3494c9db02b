"""Online predictive tuning of the high-level controller on decoded model ensembles (CEM).

:mod:`~mjxsysid.tune.cem` is the optimiser (pure, over a bounded log-scaled gain space);
:mod:`~mjxsysid.tune.rotor_state` the rotor state the rollouts start from;
:mod:`~mjxsysid.tune.tuner` the predictive rollouts, the cost, one jitted batched update and a
flight with the tuner in the loop; :mod:`~mjxsysid.tune.compare` the user-facing comparison of
methods behind ``mjxsysid tune``.
"""
from mjxsysid.tune.cem import CEMConfig, CEMState, cem_init, cem_minimize, from_search, mean_gains, to_search
from mjxsysid.tune.rotor_state import ROTOR_STATES, CommandHistory, estimate_rotor_speed
from mjxsysid.tune.tuner import (CEM_METHODS, METHOD_LABELS, METHODS, CostWeights,
                                 OnlineTuner, TunedFlight, TunerConfig, fly_tuned, predict,
                                 rollout_cost, tuner_update)

__all__ = ["CEMConfig", "CEMState", "cem_init", "cem_minimize", "from_search", "mean_gains", "to_search",
           "CEM_METHODS", "METHOD_LABELS", "METHODS", "CostWeights", "OnlineTuner", "TunedFlight",
           "TunerConfig", "fly_tuned", "predict", "rollout_cost", "tuner_update", "ROTOR_STATES", "CommandHistory",
           "estimate_rotor_speed"]
