"""What the flight shows: the log-grounded posterior of a vehicle, calibrated by simulation.

The room is callable: ``mjxsysid.identify(log)`` is :func:`.logposterior.identify` (a
:class:`~.logposterior.LogPosterior`). :mod:`.logspace` (the log space's one table: v, h, the
nuisances, the vectors x, y, z and the reported quantities, by name), :mod:`.coords` (θ in the
coordinates an IMU log sees, the stated physical prior), :mod:`.likelihood` (the IMU given the motor
commands, windowed equation error), :mod:`.posterior_config` (how it is computed: :class:`~.posterior_config.PosteriorConfig`),
:mod:`.inference` (the decoded ensemble as proposal, Laplace
importance sampling, tempered SMC; one log or many at once) with :mod:`.target`, :mod:`.mode` and
:mod:`.smc`, :mod:`.calibrate` (the bands calibrated by simulation, the model
check), :mod:`.gap` (the information gap between the decoders and the log).
"""
import sys
import types

from mjxsysid.identify.posterior_config import PosteriorConfig
from mjxsysid.identify.coords import LOG_NAMES, PHYSICAL_PRIOR, PhysicalPrior, log_quantities
from mjxsysid.identify.inference import log_grounded_posterior, log_grounded_posteriors
from mjxsysid.identify.logposterior import LogPosterior, identify

__all__ = ["LOG_NAMES", "PHYSICAL_PRIOR", "PhysicalPrior", "LogPosterior", "PosteriorConfig", "identify", "log_quantities",
           "log_grounded_posterior", "log_grounded_posteriors"]


class _CallableRoom(types.ModuleType):
    """``mjxsysid.identify(log, ...)`` calls :func:`identify`; the room's modules stay importable."""

    def __call__(self, log, decoded_theta=None, **kw):
        return identify(log, decoded_theta, **kw)


sys.modules[__name__].__class__ = _CallableRoom
