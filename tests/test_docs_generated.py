"""Pages whose numbers come from run files: regenerated, never typed by hand."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_fair_comparisons_page_matches_the_runs():
    """docs/fair_comparisons.md is what tools/fair_tables.py builds from docs/runs/ and
    docs/runs/fair/ (a hand edit, or a re-run without regenerating, fails here)."""
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "fair_tables.py"), "--check"],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    text = (ROOT / "docs" / "fair_comparisons.md").read_text()
    for heading in ("## 1. Nominal+CEM", "## 2. Action replay", "## 3. Regression", "## 5. Closed-loop",
                    "## 6a. tune-lemniscate", "## 6b. Robustness"):
        assert heading in text
