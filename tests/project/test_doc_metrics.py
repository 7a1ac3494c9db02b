"""The pages a reader scans first stay scannable (tools/doc_metrics.py): README.md, docs/status.md,
docs/identify.md and BENCHMARKS.md keep a median sentence of at most 25 words, status bullets of at most 60 words,
the first table within 40 lines (status.md's bullets link to theirs) and no ``issue N``."""
import importlib.util
import sys

from support.paths import ROOT

PAGES = ("README.md", "docs/status.md", "docs/identify.md", "BENCHMARKS.md")


def _tool():
    spec = importlib.util.spec_from_file_location("doc_metrics", ROOT / "tools" / "doc_metrics.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod                  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


def test_scanned_pages_meet_their_targets():
    tool = _tool()
    for page in PAGES:
        m = tool.measure(ROOT / page, page)
        assert tool.failures(m) == [], (page, tool.failures(m))
        assert m.median <= 25 and not m.issues, page
    status = tool.measure(ROOT / "docs" / "status.md")
    assert status.bullets and status.longest_bullet <= 60
    assert tool.main(["--check", "--root", str(ROOT)]) == 0


def test_benchmarks_opens_with_its_summary_table():
    """BENCHMARKS.md: at most 400 lines, a summary table (metric | value | target | met | command, at most
    25 rows) before its first section."""
    lines = (ROOT / "BENCHMARKS.md").read_text().splitlines()
    assert len(lines) <= 400, len(lines)
    first_section = next(i for i, ln in enumerate(lines) if ln.startswith("## "))
    head = [ln for ln in lines[:first_section] if ln.startswith("|")]
    assert head and head[0].replace(" ", "") == "|metric|value|target|met|command|", head[:1]
    assert 1 <= len(head) - 2 <= 25


def test_the_checker_catches_what_it_should(tmp_path):
    tool = _tool()
    page = tmp_path / "page.md"
    long = " ".join(["word"] * 45) + "."
    page.write_text("# Title\n\n" + "\n".join(["Intro line."] * 45) + f"\n\n{long}\n\n| a | b |\n|---|---|\n"
                    "\nSee issue 12 and [a link](http://x.y/z).\n\n```\n" + long + "\n```\n")
    m = tool.measure(page)
    assert m.first_table == 51 and [hit for _, hit in m.issues] == ["issue 12"]
    assert max(m.sentences) == 45 and m.sentences.count(45) == 1       # the code block is not text
    fails = tool.failures(m)
    assert any("first table" in f for f in fails) and any("issue 12" in f for f in fails)
    status = tmp_path / "status.md"
    status.write_text("# Status\n\n- **One.** " + " ".join(["w"] * 61) + "\n  (link).\n- Two short.\n")
    s = tool.measure(status)
    assert s.bullets == [63, 2] and any("bullet" in f for f in tool.failures(s))
