"""Where the suite finds the checkout and the released XAdap policy (not shipped), and skips without them."""
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
"""The checkout."""
DATA = ROOT / "tests" / "data"
"""The suite's data files (a PX4 sample log, the CLI help golden file)."""

# The released XAdap policy (not shipped): located like the package does, skipped when absent.
XADAP_DIR = Path(os.environ.get("MJXSYSID_XADAP_DIR", ROOT.parent / "shared" / "external" / "xadap"))


def have(mod: str) -> bool:
    try:
        __import__(mod)
        return True
    except ImportError:
        return False


def require_xadap(*modules: str) -> Path:
    """XADAP_DIR, or skip the test when the released files or the ``modules`` are missing."""
    if not XADAP_DIR.is_dir():
        pytest.skip(f"Xadap policy files not found at {XADAP_DIR} (set MJXSYSID_XADAP_DIR)")
    for mod in modules:
        if not have(mod):
            pytest.skip(f"{mod} not installed (pip install {mod})")
    return XADAP_DIR
