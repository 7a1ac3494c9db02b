"""XLA's flags: the faster compiling added to XLA_FLAGS by the CLI and the test tier, the tier's one Eigen
thread per worker, and the flags each command adds."""
import os
import subprocess
import sys

from mjxsysid.runtime.xla_flags import (
    FAST_CPU_COMPILE,
    GPU_LOOP_GRAPHS,
    ONE_EIGEN_THREAD,
    QUICK_FIRST_RUN,
    use_fast_cpu_compile,
    use_xla_flags,
    with_fast_cpu_compile,
)


def test_fast_cpu_compile_adds_its_flags_and_keeps_the_users():
    assert with_fast_cpu_compile("") == " ".join(FAST_CPU_COMPILE)
    kept = "--xla_force_host_platform_device_count=2"
    assert with_fast_cpu_compile(kept).split() == [kept, *FAST_CPU_COMPILE]
    # a user who sets the flag (to any value) keeps it, once
    mine = "--xla_cpu_use_fusion_emitters=true"
    assert with_fast_cpu_compile(mine) == mine
    assert with_fast_cpu_compile(with_fast_cpu_compile("")) == with_fast_cpu_compile("")


def test_the_flags_go_into_the_environment(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=1")
    use_fast_cpu_compile()          # what the CLI's main does first
    assert os.environ["XLA_FLAGS"].split() == ["--xla_force_host_platform_device_count=1", *FAST_CPU_COMPILE]
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=true")
    use_xla_flags(FAST_CPU_COMPILE + ONE_EIGEN_THREAD)   # what the tier does: the user's own value stays
    assert os.environ["XLA_FLAGS"].split() == ["--xla_cpu_multi_thread_eigen=true", *FAST_CPU_COMPILE]
    # the tier's own environment carries both (tests/support/jax_setup.py), for the subprocesses it starts
    monkeypatch.undo()
    assert set(FAST_CPU_COMPILE + ONE_EIGEN_THREAD) <= set(os.environ.get("XLA_FLAGS", "").split()) or \
        os.environ.get("JAX_DISABLE_MOST_OPTIMIZATIONS") in ("0", "false", "False")


def test_the_tiers_optimised_compiles_run_llvm_at_level_1():
    """support.jax_setup.xla_optimised: XLA's optimisations on and LLVM at level 1 inside (through
    JAX's private compile options, wrapped by the suite: this fails if JAX renames them); outside,
    no level forced."""
    from jax._src import compiler
    from support.jax_setup import xla_optimised

    def level():
        opts = compiler.get_compile_options(num_replicas=1, num_partitions=1)
        return opts.executable_build_options.debug_options.xla_backend_optimization_level

    with xla_optimised():
        assert level() == 1
    assert level() != 1


def test_flags_a_newer_jaxlib_removed_are_not_added(monkeypatch):
    """XLA exits on a flag it does not know: the fusion-emitter flag is left out from jaxlib 0.11 on
    (the GPU machine's), kept before it."""
    from mjxsysid.runtime.xla_flags import known_flags
    assert known_flags(FAST_CPU_COMPILE + ONE_EIGEN_THREAD, (0, 10)) == FAST_CPU_COMPILE + ONE_EIGEN_THREAD
    assert known_flags(FAST_CPU_COMPILE + ONE_EIGEN_THREAD, (0, 11)) == ONE_EIGEN_THREAD
    monkeypatch.setattr("mjxsysid.runtime.xla_flags._jaxlib_version", lambda: (0, 11))
    monkeypatch.setenv("XLA_FLAGS", "")
    use_fast_cpu_compile()
    assert "fusion_emitters" not in os.environ["XLA_FLAGS"]


def test_the_demo_alone_compiles_with_llvm_at_level_1(monkeypatch):
    """`mjxsysid demo` (a first run, mostly compiling) adds QUICK_FIRST_RUN to XLA_FLAGS before anything
    computes; another command does not (nothing is flown here: the handlers are replaced)."""
    import mjxsysid.cli.flights as F
    from mjxsysid.cli import main
    from mjxsysid.runtime.xla_flags import QUICK_FIRST_RUN
    seen = []
    monkeypatch.setattr(F, "cmd_demo", lambda args: seen.append(os.environ["XLA_FLAGS"]) or 0)
    monkeypatch.setattr(F, "cmd_fly", lambda args: seen.append(os.environ["XLA_FLAGS"]) or 0)
    monkeypatch.setenv("XLA_FLAGS", "")
    assert main(["fly", "--out", "x"]) == 0
    assert not set(QUICK_FIRST_RUN) & set(seen[-1].split())
    assert main(["demo"]) == 0
    assert set(QUICK_FIRST_RUN) <= set(seen[-1].split())


def test_the_posteriors_commands_add_cuda_graphs_of_loops_which_a_cpu_accepts():
    """GPU_LOOP_GRAPHS goes with `decode` and `calibrate-posterior` (commands the CLI has) and no other; the demo
    adds its quick first run, every other command nothing. XLA exits on a flag it does not know: a CPU process
    with the flag computes."""
    from mjxsysid.cli import POSTERIOR_COMMANDS, build_parser, command_xla_flags
    commands = set(next(a for a in build_parser()._actions if a.dest == "command").choices)   # as test_api's
    assert set(POSTERIOR_COMMANDS) == {"decode", "calibrate-posterior"} <= commands
    assert {c for c in commands if command_xla_flags(c) == GPU_LOOP_GRAPHS} == {"decode", "calibrate-posterior"}
    assert command_xla_flags("demo") == QUICK_FIRST_RUN
    assert {c for c in commands if command_xla_flags(c) == ()} == commands - {"decode", "calibrate-posterior", "demo"}
    env = dict(os.environ, XLA_FLAGS=" ".join(GPU_LOOP_GRAPHS), JAX_PLATFORMS="cpu")
    r = subprocess.run([sys.executable, "-c", "import jax.numpy as jnp; print(float(jnp.arange(4.0).sum()))"],
                       env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "6.0", r.stderr[-2000:]
