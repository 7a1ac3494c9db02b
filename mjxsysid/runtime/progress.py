"""Progress bars and progress messages for long commands, in one place.

Every long loop in mjxsysid goes through :func:`progress` (a ``tqdm`` bar on stderr) and every
progress message through :func:`echo`, so one switch governs both:

- ``set_quiet(True)`` (the CLI's ``--quiet``, or ``MJXSYSID_QUIET=1``): no bars, no progress
  messages (results, warnings and errors are still printed; run folders still get their logs);
- otherwise bars are shown when stderr is a terminal (``MJXSYSID_PROGRESS=1`` forces them on,
  e.g. in CI logs; ``=0`` off).

Bars advance *between* jitted chunks (a training iteration, an epoch, a batch of flights): never
from inside a scan.
"""
from __future__ import annotations

import os
import sys

from tqdm import tqdm

_QUIET: bool | None = None


def set_quiet(quiet: bool | None = True) -> None:
    """Turn bars and progress messages off (``True``), on (``False``), or back to the default
    (``None``: ``MJXSYSID_QUIET``)."""
    global _QUIET
    _QUIET = None if quiet is None else bool(quiet)


def quiet() -> bool:
    """Whether bars and progress messages are off."""
    if _QUIET is not None:
        return _QUIET
    return os.environ.get("MJXSYSID_QUIET", "") not in ("", "0")


def bars_enabled(enabled: bool | None = None) -> bool:
    """Whether a bar is drawn: ``enabled`` if given, else not quiet and (MJXSYSID_PROGRESS or
    stderr is a terminal)."""
    if quiet():
        return False
    if enabled is not None:
        return bool(enabled)
    force = os.environ.get("MJXSYSID_PROGRESS")
    if force is not None and force != "":
        return force != "0"
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def progress(iterable=None, *, total: int | None = None, desc: str | None = None,
             enabled: bool | None = None, unit: str = "it", initial: int = 0, leave: bool = True):
    """A tqdm bar on stderr over ``iterable`` (or a manual one: ``total`` with ``.update()``).
    Disabled bars cost nothing and still iterate. ``bar.set_postfix(...)`` shows metrics."""
    return tqdm(iterable, total=total, desc=desc, unit=unit, initial=initial, leave=leave,
                disable=not bars_enabled(enabled), file=sys.stderr, dynamic_ncols=True,
                mininterval=0.5)


def stages(labels, *, desc: str, enabled: bool | None = None) -> "Stages":
    """A bar over named stages: ``st = stages(["fly", "decode"], desc="demo")``, then
    ``st.start("fly")`` before each and ``st.close()`` at the end."""
    return Stages(list(labels), desc, enabled)


class Stages:
    """See :func:`stages`."""

    def __init__(self, labels, desc, enabled):
        self.labels = labels
        self.bar = progress(total=len(labels), desc=desc, enabled=enabled, unit="stage")
        self._started = False

    def start(self, label: str) -> None:
        if self._started:
            self.bar.update(1)
        self._started = True
        self.bar.set_postfix_str(label)

    def close(self) -> None:
        if self._started:
            self.bar.update(1)
        self.bar.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if exc[0] is None:
            self.close()
        else:
            self.bar.close()


def echo(msg: str, *, file=None) -> None:
    """Print a progress message (stdout by default) without breaking a bar; nothing when quiet."""
    if quiet():
        return
    tqdm.write(str(msg), file=file or sys.stdout)
    (file or sys.stdout).flush()


def tee(log, path):
    """``log`` (a callable or None) that also appends each message to the file ``path`` (a run
    folder's log, written even when the terminal is quiet)."""
    def both(msg):
        with open(path, "a") as f:
            f.write(f"{msg}\n")
        if log is not None:
            log(msg)
    return both
