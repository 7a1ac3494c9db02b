"""What the flight shows: the log-grounded posterior of a vehicle (DESIGN §11).

:mod:`.coords` (θ in the coordinates an IMU log sees, the stated physical prior),
:mod:`.likelihood` (the IMU given the motor commands, windowed equation error),
:mod:`.inference` (the decoded ensemble as proposal, BFGS + Laplace importance sampling, tempered
SMC), :mod:`.gap` (the information gap between the decoders and the log).
"""
from mjxsysid.identify.coords import LOG_NAMES, PHYSICAL_PRIOR, PhysicalPrior, log_quantities
from mjxsysid.identify.inference import log_grounded_posterior

__all__ = ["LOG_NAMES", "PHYSICAL_PRIOR", "PhysicalPrior", "log_quantities", "log_grounded_posterior"]
