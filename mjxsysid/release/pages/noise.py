"""docs/noise.md's generated tables: each block between ``<!-- BEGIN noise table RUN ... -->``
and ``<!-- END noise table -->`` is the table of the run file RUN
([replace_tables][mjxsysid.uses.imu_noise.replace_tables])."""
from __future__ import annotations

import re
from pathlib import Path

from mjxsysid.release.layout import DOCS
from mjxsysid.release.pages.runs import RunFiles

PAGE = f"{DOCS}/noise.md"
"""The page (relative to a checkout's root)."""


def marked_runs(text: str) -> list[str]:
    """The run files (paths relative to the checkout's root) named by the page's table markers."""
    return re.findall(r"<!-- BEGIN noise table (\S+)", text)


def page(root, overlay=None) -> str:
    """docs/noise.md of the checkout at ``root`` with its noise tables rewritten from the run
    files its markers name (read from ``overlay`` where it has them: a release's tree)."""
    from mjxsysid.uses.imu_noise import replace_tables
    runs = RunFiles(root, overlay)
    text = (Path(root) / PAGE).read_text()
    return replace_tables(text, {r: runs.load(r) for r in marked_runs(text)})
