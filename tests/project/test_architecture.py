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
    """A module past 500 lines holds more than one concept (split it by what each part is)."""
    long = {str(p.relative_to(ROOT)): n for p in (ROOT / "mjxsysid").rglob("*.py")
            if (n := len(p.read_text().splitlines())) > 500}
    assert long == {}


def test_docs_runs_stays_under_12_5_mb():
    """docs/runs/ holds the run files the docs quote (superseded ones leave the tree, git keeps them):
    the clone stays light. 12.5 MB: the rows the shipped calibration tables and the window check's threshold
    were fitted on are their provenance (NUTS's min-snap rows without velocity, 80 paths, carry R̂ and the
    motor-map check's features: 190 KB)."""
    size = sum(p.stat().st_size for p in (ROOT / "docs" / "runs").rglob("*") if p.is_file())
    assert size < 12.5e6, f"docs/runs/ holds {size / 1e6:.1f} MB"


def test_no_compiled_program_is_tracked():
    """JAX's compilation cache and the exported programs (``<cache>/exported``) are per machine and JAX version:
    none is committed, wherever a run wrote them."""
    import re
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    if not files:
        import pytest
        pytest.skip("not a git checkout")
    cached = [f for f in files if re.search(r"(^|/)exported/[^/]+\.bin$|(^|/)jit_[^/]*-cache$", f)]
    assert cached == [], cached[:5]


PER_ALGORITHM = {"networks.py", "train.py", "controller.py"}
"""Module names the field repeats per algorithm (the adaptive policy's, the released policy's, the decoders')."""
MIRRORS = {"cli", "release", "render"}
"""Rooms that mirror the others on purpose (a command group, a release stage or a figure module per room)."""


def test_top_level_holds_only_init_and_api():
    """Every module lives in a room: the package's top level is its face only."""
    top = sorted(p.name for p in (ROOT / "mjxsysid").glob("*.py"))
    assert set(top) <= {"__init__.py", "__main__.py", "api.py"}, top


def test_no_module_name_in_two_rooms():
    """A module's name says what it is once: `replay.py` in two rooms would be two concepts under one name."""
    seen: dict[str, list[str]] = {}
    for p in (ROOT / "mjxsysid").rglob("*.py"):
        rel = p.relative_to(ROOT / "mjxsysid")
        if p.name.startswith("__") or rel.parts[0] in MIRRORS or p.name in PER_ALGORITHM or len(rel.parts) < 2:
            continue
        seen.setdefault(p.name, []).append(str(rel))
    assert {k: v for k, v in seen.items() if len(v) > 1} == {}


def test_every_room_is_in_the_layer_contract():
    """A new room is placed among the layers (pyproject.toml) before it lands, so ARCHITECTURE.md names it."""
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import architecture
    finally:
        sys.path.pop(0)
    placed = {n for layer in architecture.layers() for n in layer}
    assert set(architecture.rooms()) == placed
