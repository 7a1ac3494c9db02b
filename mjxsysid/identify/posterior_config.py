"""How the log-grounded posterior is computed: one frozen object instead of module constants.

    from mjxsysid.identify import PosteriorConfig
    post = mjxsysid.identify("flight.ulg", config=PosteriorConfig(refine=False, samples=2000))

:data:`DEFAULT` is what a call that names no config uses (``decode --log``, the demo, the notebooks);
a process that wants other defaults replaces it with another :class:`PosteriorConfig` (the test
tier's lower resolution: tests/conftest.py). Keyword arguments of the posterior's functions override
single fields of the config they are given.
"""
from __future__ import annotations

import dataclasses
import numbers
from pathlib import Path
from typing import Any

from mjxsysid.identify.logdata import RATES


@dataclasses.dataclass(frozen=True)
class PosteriorConfig:
    """The log-grounded posterior's settings (:func:`~.inference.log_grounded_posteriors`).

    samples: draws returned per log. draws: importance draws per proposal. particles: SMC particles.
    n_mcmc: the SMC's moves per stage. max_stages: its tempering stages at most. starts: the mode's
    starting points. force_smc: run the SMC even where importance sampling passes. refine: the SMC's
    draws refined by NUTS (:mod:`.nuts`). rates: the likelihood's rate term, "windows" or
    "innovations". calibration: "shipped" (the table fitted on simulated logs), a table (dict) or a
    path to one, or None for the raw posterior. shared_maps: command→speed maps (ι, κ) of
    :data:`~.idlecheck.MAPS` that other flights of this vehicle showed (``decode --same-vehicle``): where the
    motor-map check flags the log, its bands hold their values under these too (:func:`~.idlecheck.run`)."""
    samples: int = 1000
    draws: int = 4096
    particles: int = 2048
    n_mcmc: int = 24
    max_stages: int = 200
    starts: int = 12
    force_smc: bool = False
    refine: bool = True
    rates: str = RATES
    calibration: Any = "shipped"
    shared_maps: tuple = ()

    def __post_init__(self):
        for name in ("samples", "draws", "particles", "n_mcmc", "max_stages", "starts"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < 1:
                raise ValueError(f"PosteriorConfig.{name} must be a positive integer, got {v!r}")
            object.__setattr__(self, name, int(v))          # a NumPy integer stored as an int
        if self.rates not in ("windows", "innovations"):
            raise ValueError(f"PosteriorConfig.rates must be 'windows' or 'innovations', got {self.rates!r}")
        if self.shared_maps:
            from mjxsysid.identify.idlecheck import MAPS
            maps = tuple(tuple(float(x) for x in m) for m in self.shared_maps)
            bad = [m for m in maps if m not in MAPS]
            if bad:
                raise ValueError(f"PosteriorConfig.shared_maps: {bad} not among the motor-map check's maps "
                                 "(idlecheck.MAPS)")
            object.__setattr__(self, "shared_maps", maps)
        c = self.calibration
        if not (c is None or c == "shipped" or isinstance(c, (dict, str, Path))):
            raise ValueError(f"PosteriorConfig.calibration must be 'shipped', a table (dict), a path or None, "
                             f"got {type(c).__name__}")

    def replace(self, **changes) -> "PosteriorConfig":
        """A copy with ``changes`` (field names; an unknown one is an error naming the fields)."""
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise TypeError(f"PosteriorConfig has no field {sorted(unknown)}; fields: "
                            f"{[f.name for f in dataclasses.fields(self)]}")
        return dataclasses.replace(self, **changes)


DEFAULT = PosteriorConfig()
"""The settings of a call that names no config."""

def resolve(config: PosteriorConfig | None = None, **overrides) -> PosteriorConfig:
    """``config`` (None: :data:`DEFAULT`, read at call time) with the overrides that are not None
    (calibration's None is one: the raw posterior)."""
    base = DEFAULT if config is None else config
    if not isinstance(base, PosteriorConfig):
        raise TypeError(f"config must be a PosteriorConfig, got {type(base).__name__}")
    return base.replace(**{k: v for k, v in overrides.items() if v is not None or k == "calibration"})
