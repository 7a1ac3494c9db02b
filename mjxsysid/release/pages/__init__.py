"""The generated docs pages: [fair][mjxsysid.release.pages.fair] (docs/fair_comparisons.md),
[noise][mjxsysid.release.pages.noise] (docs/noise.md's tables) and [results][mjxsysid.release.pages.results]
(docs/results.md and README.md's results table) and [runs_index][mjxsysid.release.pages.runs_index]
(docs/runs/README.md), each a pure function of a
checkout's root and, optionally, a release's tree laid over it; [check][mjxsysid.release.pages.check]
tells which pages of a checkout differ from what its run files give."""
from __future__ import annotations

from pathlib import Path


def generate(root, overlay=None) -> dict[str, str]:
    """Each generated page's text (path relative to the checkout's root → Markdown)."""
    from mjxsysid.release.pages import fair, noise, results, runs_index
    return {fair.PAGE: fair.page(root, overlay), noise.PAGE: noise.page(root, overlay),
            results.PAGE: results.page(root, overlay), results.README: results.readme(root, overlay),
            runs_index.PAGE: runs_index.page(root)}


def check(root) -> list[str]:
    """The generated pages of the checkout at ``root`` that differ from what its run files give
    (empty: all current)."""
    root = Path(root)
    return [p for p, text in generate(root).items()
            if not (root / p).is_file() or (root / p).read_text() != text]
