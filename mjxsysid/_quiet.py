"""Import MJX without its warp probe's message.

MJX 3.17 probes for NVIDIA Warp when ``mujoco.mjx`` is imported and *prints* (to stdout)
``Failed to import warp: No module named 'warp'`` and ``Failed to import mujoco_warp: …`` when
Warp is not installed. mjxsysid does not use Warp, so exactly those lines are dropped; any other
output of the import is passed on unchanged, and a failing import of MJX itself raises as usual.
"""
from __future__ import annotations

import contextlib
import importlib
import io
import re
import sys

_PROBE = re.compile(r"^Failed to import (warp|mujoco_warp): No module named '?warp'?\S*$")


def is_probe_line(line: str) -> bool:
    """True for exactly the lines MJX's warp probe prints when Warp is not installed."""
    return bool(_PROBE.match(line.strip()))


def quiet_import(name: str):
    """``importlib.import_module(name)`` with the warp probe's lines removed from its stdout;
    other output is printed afterwards, errors propagate."""
    if sys.modules.get(name) is not None:
        return sys.modules[name]
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf):
            return importlib.import_module(name)
    finally:
        rest = [ln for ln in buf.getvalue().splitlines() if not is_probe_line(ln)]
        if rest:
            print("\n".join(rest))


def import_mjx():
    """``from mujoco import mjx`` without the warp probe's message; returns the module."""
    return quiet_import("mujoco.mjx")
