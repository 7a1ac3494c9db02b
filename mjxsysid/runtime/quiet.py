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


# XLA:CPU's loader of persistent-cache entries logs two E-level lines per program it loads on CPUs
# whose LLVM tuning flags (+prefer-no-gather, +prefer-no-scatter) it mistakes for ISA features
# (jax-ml/jax#38445, openxla/xla#44565): the entry still loads (checked: a 27 s compile read back in
# 0.3 s), but each line is ~2,500 characters of feature lists. The C++ logger writes straight to file
# descriptor 2, so Python cannot filter it; :func:`filter_native_stderr` puts a small process between
# fd 2 and the terminal that drops exactly those lines.
_AOT_LINE = (rb"^E\d{4} [\d:.]+ +\d+ cpu_aot_loader\.cc:\d+\] Loading XLA:CPU AOT result\. "
             rb"Target machine feature \+prefer-no-(gather|scatter) is not +supported on the host machine\.")

_FILTER = r'''
import os, re, sys
drop = re.compile(%r)
out = sys.stdout.buffer
held = b""
while True:
    try:
        chunk = os.read(0, 65536)
    except OSError:
        break
    if not chunk:
        break
    lines = (held + chunk).split(b"\n")
    held = lines.pop()
    for ln in lines:
        if not drop.match(ln):
            out.write(ln + b"\n")
    # a partial line goes out at once (progress bars redraw with "\r") unless it may be a C++
    # logger's E-line still arriving
    if held and not (held[:1] == b"E" and len(held) < 65536 and b"\r" not in held):
        out.write(held)
        held = b""
    out.flush()
if held and not drop.match(held):
    out.write(held)
out.flush()
''' % _AOT_LINE


def is_aot_loader_line(line: bytes) -> bool:
    """True for exactly the XLA:CPU loader's spurious feature-mismatch lines (see above)."""
    return bool(re.match(_AOT_LINE, line))


def filter_native_stderr() -> bool:
    """Route this process's file descriptor 2 through a child process that drops the XLA:CPU
    loader's spurious lines and passes everything else on unchanged (Python's own stderr included).
    The child outlives a crash of this process (it reads to the pipe's end), so a crash's message
    still shows. Only where stderr is a file or terminal we own: not under pytest's capture, not when
    ``MJXSYSID_RAW_STDERR=1``. Returns whether the filter was installed."""
    import atexit
    import os
    import subprocess
    if os.environ.get("MJXSYSID_RAW_STDERR") == "1" or "pytest" in sys.modules:
        return False
    try:
        sys.stderr.flush()
        child = subprocess.Popen([sys.executable, "-c", _FILTER], stdin=subprocess.PIPE, stdout=2,
                                 stderr=subprocess.DEVNULL, close_fds=True)
    except OSError:
        return False
    if os.isatty(2):     # the progress bars look at stderr, now a pipe: they are still wanted
        os.environ.setdefault("MJXSYSID_PROGRESS", "1")
    saved = os.dup(2)
    os.dup2(child.stdin.fileno(), 2)
    child.stdin.close()

    def restore():
        try:
            sys.stderr.flush()
        except (OSError, ValueError):
            pass
        os.dup2(saved, 2)        # the pipe's last writer closes: the child drains it and ends
        os.close(saved)
        try:
            child.wait(timeout=5)
        except subprocess.TimeoutExpired:
            child.kill()

    atexit.register(restore)
    return True
