"""Where the suite finds the checkout and the released XAdap policy (not shipped), and skips without them."""
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
"""The checkout."""
DATA = ROOT / "tests" / "data"
"""The suite's data files (the CLI help golden file)."""

SHARED_DATA = ROOT.parent / "shared" / "data"
"""Logs gathered from elsewhere (never committed to the project): absent in a user's clone."""
PX4_SAMPLE = SHARED_DATA / "ulog" / "sample_px4_events.ulg"
"""PX4's sample ULog (pyulog's test data: jMAVSim's Iris, ../shared/data/ulog/README.md)."""


def require_shared(path: Path) -> Path:
    """``path`` under :data:`SHARED_DATA`, or skip the test where it is absent."""
    if not Path(path).is_file():
        pytest.skip(f"{path} not found (logs from elsewhere live in ../shared, absent in a clone)")
    return Path(path)

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
