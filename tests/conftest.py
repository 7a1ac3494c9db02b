import os
import sys
from pathlib import Path

import jax
import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

# Compiles dominate CPU test time: keep them across runs.
jax.config.update("jax_compilation_cache_dir", os.environ.get("MJXSYSID_JAX_CACHE", str(ROOT / ".jax_cache")))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


@pytest.fixture(scope="session")
def sim():
    from mjxsysid.sim import Quadrotor
    return Quadrotor()


# The released XAdap policy (not shipped): located like the package does, skipped when absent.
XADAP_DIR = Path(os.environ.get("MJXSYSID_XADAP_DIR", ROOT.parent / "shared" / "external" / "xadap"))


def have(mod: str) -> bool:
    try:
        __import__(mod)
        return True
    except ImportError:
        return False


@pytest.fixture(scope="module")
def xadap_weights():
    if not XADAP_DIR.is_dir():
        pytest.skip(f"Xadap policy files not found at {XADAP_DIR} (set MJXSYSID_XADAP_DIR)")
    if not have("onnx"):
        pytest.skip("onnx not installed (pip install onnx)")
    from mjxsysid.policy.xadap import load_xadap
    return load_xadap(XADAP_DIR)
