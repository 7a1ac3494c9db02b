"""A command's start-up: the compilation cache's folder (per CPU), kept when the process set one."""
import re
from pathlib import Path


def test_compilation_cache(monkeypatch, tmp_path):
    """The CLI turns on JAX's persistent compilation cache in MJXSYSID_JAX_CACHE (0: off) and keeps
    one the process already set (the suite's, here)."""
    import jax

    from mjxsysid.runtime.startup import compilation_cache
    suite = jax.config.jax_compilation_cache_dir
    suite_min = jax.config.jax_persistent_cache_min_compile_time_secs
    assert suite
    monkeypatch.setenv("MJXSYSID_JAX_CACHE", str(tmp_path / "c"))
    compilation_cache()
    assert jax.config.jax_compilation_cache_dir == suite          # kept
    try:
        jax.config.update("jax_compilation_cache_dir", None)
        monkeypatch.setenv("MJXSYSID_JAX_CACHE", "0")
        compilation_cache()
        assert jax.config.jax_compilation_cache_dir is None      # off
        monkeypatch.setenv("MJXSYSID_JAX_CACHE", str(tmp_path / "c"))
        compilation_cache()
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "c")
        assert jax.config.jax_persistent_cache_min_compile_time_secs == 0.0      # small programs kept too
        # the default: a folder per CPU (a home folder shared by two machines must not mix their programs)
        jax.config.update("jax_compilation_cache_dir", None)
        monkeypatch.delenv("MJXSYSID_JAX_CACHE")
        monkeypatch.setenv("HOME", str(tmp_path / "home"))
        compilation_cache()
        where = Path(jax.config.jax_compilation_cache_dir)
        assert where.parent == tmp_path / "home" / ".cache" / "mjxsysid" / "jax"
        assert re.fullmatch(r"cpu-[0-9a-f]{10}", where.name), where
    finally:
        jax.config.update("jax_compilation_cache_dir", suite)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", suite_min)
