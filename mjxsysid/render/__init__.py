"""Offscreen rendering and plots of quadrotor rollouts (host side, never inside ``jax.jit``).

Lazy: importing :mod:`mjxsysid.render` imports neither mujoco, mediapy nor matplotlib; each
public function loads its module on first use. Scripts that render headless call
:func:`headless_env` before anything imports mujoco.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "ensure_gl": "gl",
    "headless_env": "gl",
    "vehicle_model": "scene",
    "render_rollout": "video",
    "render_frame": "video",
    "read_video": "video",
    "plot_trajectory": "plots",
    "plot_prior_marginals": "plots",
    "plot_marginals": "posterior",
    "plot_decoded_over_time": "posterior",
    "plot_rank_histograms": "posterior",
    "plot_gains": "tuning",
    "plot_tracking": "tuning",
    "plot_replay": "replay",
    "plot_summary": "replay",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
