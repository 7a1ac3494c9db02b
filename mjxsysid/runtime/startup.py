"""A command's start-up: JAX's persistent compilation cache in a folder per CPU model, and the
join of a multi-process run a cluster launcher started."""
from __future__ import annotations

from pathlib import Path


def start_processes(args) -> None:
    """Join a multi-process run if a cluster launcher started one (mjxsysid.runtime.distributed): every
    process computes the same gathered results; only process 0 writes ``--out`` (the others
    write to a scratch folder; train-policy guards its own writes and reads the shared run
    folder to resume)."""
    from mjxsysid.runtime import distributed
    if not distributed.maybe_initialize():
        return
    import jax
    if jax.process_index() > 0 and getattr(args, "out", None) is not None and args.command != "train-policy":
        import tempfile
        args.out = Path(tempfile.mkdtemp(prefix=f"mjxsysid_p{jax.process_index()}_"))


def cpu_fingerprint() -> str:
    """'cpu-' and 10 hex digits of the CPU's model name and feature flags (Linux: /proc/cpuinfo;
    elsewhere the platform's processor string)."""
    import hashlib
    import platform
    text = platform.machine() + platform.processor()
    try:
        with open("/proc/cpuinfo") as f:
            lines = [ln for ln in f if ln.startswith(("model name", "flags", "Features", "CPU part"))]
        text += "".join(sorted(set(lines)))
    except OSError:
        pass
    return "cpu-" + hashlib.sha256(text.encode()).hexdigest()[:10]


def compilation_cache() -> None:
    """JAX's persistent compilation cache for the command's programs: a command run again (another
    seed of the same config, an evaluation of another policy) loads what it compiled instead of
    compiling it again (a policy training's cold start on a GPU spends ~25 s compiling, BENCHMARKS.md).
    ``MJXSYSID_JAX_CACHE``: the folder (default ~/.cache/mjxsysid/jax/<this CPU's fingerprint>; ``0``:
    off). A cache the process already set (the tests' conftest) is kept.

    The default folder is per CPU model and instruction set: JAX's cache key does not hold the host's
    CPU features, so a home folder shared by two machines (a cluster's, a VM moved to another host)
    loaded CPU programs built for the other one — XLA then logs "Target machine feature ... is not
    supported on the host machine ... could lead to execution errors such as SIGILL"."""
    import os
    where = os.environ.get("MJXSYSID_JAX_CACHE",
                           str(Path.home() / ".cache" / "mjxsysid" / "jax" / cpu_fingerprint()))
    if where == "0":
        return
    import jax
    if jax.config.jax_compilation_cache_dir:
        return
    jax.config.update("jax_compilation_cache_dir", where)
    # every program: most of a command's compile in small ones (a 10 s log's decode: 95 builds of 0.2-0.7 s), which a
    # 1 s threshold left to be compiled again on every run (decode --log warm 26.2 -> 20.9 s, the demo 36.7 -> 30-32 s)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
