"""Conditional flow-matching decoder p(θ | ẑ) (paper §III-B, §IV-A; DESIGN §6).

Works in the normalised θ space (``mjxsysid.theta.Normalizer``), conditioned on the policy
latent ẑ (8); physical units only at the :class:`Decoder` interface.

- :mod:`~mjxsysid.cfm.path`        GaussianSmoothedLinearPath (σ, τ_max)
- :mod:`~mjxsysid.cfm.networks`    VelocityNet, RegressionNet (FiLM residual, flax.linen)
- :mod:`~mjxsysid.cfm.train`       CFMConfig, train_cfm, train_regression, save/load_decoder
- :mod:`~mjxsysid.cfm.sample`      sample (euler / midpoint / heun), Decoder, random_baseline
- :mod:`~mjxsysid.cfm.calibration` coverage, SBC, C2ST, energy score (numpy / scipy)
- :mod:`~mjxsysid.cfm.sequence`    flight-level decoder p(θ | ẑ_1..ẑ_W): SeqCFMConfig,
                                   train_seq_cfm, SequenceDecoder

Submodules are imported lazily (``from mjxsysid.cfm import train_cfm`` works). The sampler
function shares its module's name, so import it from the module:
``from mjxsysid.cfm.sample import sample`` (``mjxsysid.cfm.sample`` is the module).
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "GaussianSmoothedLinearPath": "path",
    "VelocityNet": "networks", "RegressionNet": "networks", "count_params": "networks",
    "CFMConfig": "train", "train_cfm": "train", "train_regression": "train",
    "save_decoder": "train", "load_decoder": "train", "init_params": "train",
    "make_network": "train",
    "point": "sample", "Decoder": "sample", "random_baseline": "sample",
    "METHODS": "sample",
    "SeqCFMConfig": "sequence", "train_seq_cfm": "sequence", "SequenceDecoder": "sequence",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        mod = importlib.import_module(f"{__name__}.{_EXPORTS[name]}")
        return getattr(mod, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
