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
