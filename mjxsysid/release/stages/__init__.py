"""The stages of a release, registered in release order by the modules of this package
([registry][mjxsysid.release.stages.registry]): policy, decoders, measurements, the posterior calibration, shipping.

Each stage imports what it runs when it runs: importing the stages (``--list``, the plan checks)
imports no JAX.
"""
from mjxsysid.release.stages.registry import STAGES, Stage, StageResult

# isort: off
# the modules register their stages when imported: this order is the release order
from mjxsysid.release.stages import policy  # noqa: F401
from mjxsysid.release.stages import decoders  # noqa: F401
from mjxsysid.release.stages import measurements  # noqa: F401
from mjxsysid.release.stages import calibration  # noqa: F401
from mjxsysid.release.stages import ship  # noqa: F401
# isort: on

__all__ = ["STAGES", "Stage", "StageResult"]
