"""Every relative link of the Markdown pages (docs/*.md, README.md, BENCHMARKS.md, ARCHITECTURE.md)
and every path `docs/runs/...` they name points at a file or folder that exists; docs/runs/README.md
is what :func:`mjxsysid.release.pages.runs_index.page` writes of today's docs/runs/."""
import re
from pathlib import Path

import pytest
from support.paths import ROOT

PAGES = sorted([*(ROOT / "docs").glob("*.md"), ROOT / "README.md", ROOT / "BENCHMARKS.md", ROOT / "ARCHITECTURE.md"])
LINK = re.compile(r"\]\(([^)\s]+)\)")
RUNS_PATH = re.compile(r"docs/runs/[A-Za-z0-9_.\-/]*[A-Za-z0-9_\-/]")


def broken_links(page: Path) -> list[str]:
    """The relative links and docs/runs/ paths of ``page`` that point at nothing."""
    text = page.read_text()
    bad = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z]+:", target) or target.startswith("#"):
            continue
        path = target.split("#", 1)[0]
        if path and not (page.parent / path).exists():
            bad.append(target)
    for m in RUNS_PATH.finditer(text):
        if text[m.end():m.end() + 1] in ("*", "{", "<") or m.group(0).endswith(".npz"):
            continue     # a pattern (`seed*`, `{a,b}`, `<kind>`), or weights docs/runs never holds (their _meta.json stays)
        if re.search(r"git show [0-9a-f]{7,40}:$", text[max(0, m.start() - 60):m.start()]):
            continue     # a file of an earlier commit (superseded runs leave the tree; history keeps them)
        if not (ROOT / m.group(0)).exists():
            bad.append(m.group(0))
    return bad


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_links_point_at_files(page):
    assert broken_links(page) == []


def test_runs_index_describes_every_folder(tmp_path):
    """docs/runs/README.md is checked current with the other generated pages (tools/fair_tables.py
    --check, tests/project/test_docs_generated.py); a folder nobody described is named as such."""
    from mjxsysid.release.pages.runs_index import page
    assert "(not described" not in page(ROOT)
    (tmp_path / "docs" / "runs" / "measurements" / "new-thing").mkdir(parents=True)
    assert "`new-thing/`" in page(tmp_path) and "(not described: add it to MEASUREMENTS)" in page(tmp_path)


def test_docs_runs_holds_no_weights():
    """Weights live in mjxsysid/pretrained/ only; docs/runs/ keeps an unshipped file's NAME_meta.json."""
    assert sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs" / "runs").rglob("*.npz")) == []
