"""The layering of ARCHITECTURE.md, enforced: import-linter's contracts (pyproject.toml,
[tool.importlinter]) and the diagram in ARCHITECTURE.md, generated from the import graph."""
import subprocess
import sys
from pathlib import Path
from support.paths import ROOT



def test_import_contracts_are_kept():
    """A layer importing one above it (a cycle in waiting), or the simulator / controllers /
    closed loop importing optax, matplotlib or mediapy, fails here with the import chain."""
    lint = Path(sys.executable).parent / "lint-imports"  # import-linter's CLI, in the dev extra
    r = subprocess.run([str(lint), "--config", str(ROOT / "pyproject.toml"), "--no-cache"],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    import tomllib
    n = len(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"])
    assert f"{n} kept, 0 broken" in r.stdout, r.stdout


def test_architecture_diagram_is_generated_from_the_code():
    """ARCHITECTURE.md's diagram is what tools/architecture.py draws from today's imports."""
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "architecture.py"), "--check"],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr


def test_no_module_over_500_lines():
    """Issue 40's bound: a module past 500 lines holds more than one room (split it by what each part is)."""
    long = {str(p.relative_to(ROOT)): n for p in (ROOT / "mjxsysid").rglob("*.py")
            if (n := len(p.read_text().splitlines())) > 500}
    assert long == {}


def test_docs_runs_stays_under_10_mb():
    """Issue 40's bound on docs/runs/ (run files the docs quote; superseded ones leave the tree, history
    keeps them): the clone stays light."""
    size = sum(p.stat().st_size for p in (ROOT / "docs" / "runs").rglob("*") if p.is_file())
    assert size < 10e6, f"docs/runs/ holds {size / 1e6:.1f} MB"
