"""Old import paths of moved modules: they still import, for one release, with a FutureWarning
that names the new path.

:data:`MOVED` maps each old module name to the new one; :func:`install` puts a finder first on
``sys.meta_path`` that answers an old name with the new module itself (one module object, so
state and ``isinstance`` checks agree), and :func:`moved_attribute` serves ``mjxsysid.<old>``.
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

_DECODE = {"posterior": "posteriors", "run": "command", "checks": "checking", "windows": "windows",
           "fleet": "fleet"}
MOVED: dict[str, str] = {
    "mjxsysid.studies": "mjxsysid.uses",
    "mjxsysid.studies.decode": "mjxsysid.decoding",
    **{f"mjxsysid.studies.decode.{a}": f"mjxsysid.decoding.{b}" for a, b in _DECODE.items()},
    "mjxsysid.studies.demo": "mjxsysid.decoding.demo",
    "mjxsysid.studies.noise": "mjxsysid.uses.imu_noise",
    **{f"mjxsysid.studies.{m}": f"mjxsysid.uses.{m}" for m in ("fidelity", "replay", "robustness")},
    "mjxsysid.experiments.replay": "mjxsysid.experiments.action_replay",
    "mjxsysid.experiments.robustness": "mjxsysid.experiments.robustness_envelopes",
    "mjxsysid.logs.checks.replay": "mjxsysid.logs.checks.policy_replay",
    "mjxsysid.envs.quadrotor": "mjxsysid.envs.dm_quadrotor",
    "mjxsysid._quiet": "mjxsysid.runtime.quiet",
    **{f"mjxsysid.{m}": f"mjxsysid.runtime.{m}"
       for m in ("xla_flags", "profiling", "distributed", "progress", "checkpoint", "jsonout")},
}
"""old module name -> new module name."""


def _warn(old: str, new: str, stacklevel: int) -> None:
    warnings.warn(f"{old} moved to {new}; import it from there (the old path goes in the next release)",
                  FutureWarning, stacklevel=stacklevel)


class _Alias(importlib.abc.Loader):
    def __init__(self, new: str):
        self.new = new

    def create_module(self, spec):
        return importlib.import_module(self.new)

    def exec_module(self, module):
        pass


class _MovedFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        new = MOVED.get(fullname)
        if new is None:
            return None
        _warn(fullname, new, 3)
        return importlib.util.spec_from_loader(fullname, _Alias(new))


def install() -> None:
    """Put the old paths' finder first on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _MovedFinder())


def moved_attribute(name: str):
    """``mjxsysid.<name>`` for a moved top-level module (with the warning), else None."""
    new = MOVED.get(f"mjxsysid.{name}")
    if new is None:
        return None
    _warn(f"mjxsysid.{name}", new, 4)
    return importlib.import_module(new)
