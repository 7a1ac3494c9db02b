import atexit
import contextlib
import gc
import os
import sys
from pathlib import Path

import jax
import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

# Compiles dominate CPU test time (about 80 %). The tier compiles with XLA's optimisations off
# (JAX_DISABLE_MOST_OPTIMIZATIONS: about 20 % less CPU; the tests check behaviour, thresholds and
# equalities between two compiled paths, never bits of an optimised build). Set it to 0 to run
# the tier as users' code runs. Exported here, so the CLI subprocesses and notebook kernels that
# tests start compile the same way.
os.environ.setdefault("JAX_DISABLE_MOST_OPTIMIZATIONS", "1")
_XLA_OPTIMISATIONS_OFF = os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] not in ("0", "false", "False")
jax.config.update("jax_disable_most_optimizations", _XLA_OPTIMISATIONS_OFF)
# ...and keep them across runs.


@contextlib.contextmanager
def xla_optimised():
    """Compile with XLA's optimisations inside (for the few tests whose time is spent running a
    long training loop rather than compiling it: unoptimised, they would run 2-3x slower)."""
    jax.config.update("jax_disable_most_optimizations", False)
    try:
        yield
    finally:
        jax.config.update("jax_disable_most_optimizations", _XLA_OPTIMISATIONS_OFF)


@pytest.fixture
def xla_optimised_test():
    """:func:`xla_optimised` for a whole test (``@pytest.mark.usefixtures("xla_optimised_test")``)."""
    with xla_optimised():
        yield
# The suite's cache, also for the `mjxsysid` commands the tests run as subprocesses (the CLI's own
# default is ~/.cache/mjxsysid/jax).
os.environ.setdefault("MJXSYSID_JAX_CACHE", str(ROOT / ".jax_cache"))
jax.config.update("jax_compilation_cache_dir", os.environ["MJXSYSID_JAX_CACHE"])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
# Python's cyclic garbage collector: a worker's heap (JAX's traces, jaxprs and caches) makes every
# full collection cost up to 0.35 s, and the default thresholds ran 16 of them in 52 s of
# test_api/test_notebooks/test_decode (-n 0); with these, 3 (the collector's time there 4.4 -> 2.3 s,
# 1.6 s of it the notebooks' own resets, now skipped: _reset_shell). Memory stays bounded (the
# collector still runs; the tier's peak 4.4-4.6 GB against 4.3 GB before).
gc.set_threshold(10_000, 20, 100)


# The default tier runs on two pytest-xdist workers (pyproject addopts: -n 2 --dist loadgroup).
# A worker keeps its compiled functions, so tests that fly the same shapes or share session
# fixtures run in one worker (a group); every other file is a group of its own. Groups are
# queued longest first (measured CPU time), so the two workers finish together.
XDIST_GROUPS = {
    # the 2 s / 1.5 s policy flights, decoders and the released policy's recording, then the
    # notebooks, whose cells run in-process and fly those shapes again
    "policy-flights": ("test_api", "test_decode", "test_envs", "test_interface", "test_notebooks", "test_replay"),
    # the tiny Trainer, and the collect run of conftest.collected_pairs
    "policy-training": ("test_policy", "test_sequence"),
}
_GROUP_OF = {f: g for g, files in XDIST_GROUPS.items() for f in files}
# Queue order, longest first (seconds of the default tier, `pytest --durations=0`, 2026-11-26), so
# that the short files come last and fill in; files not listed after them.
_QUEUE = ("policy-training", "policy-flights", "test_control", "test_sim", "test_tune", "test_experiments_robustness",
          "test_cfm", "test_distributed", "test_resume", "test_logcheck", "test_references", "test_render",
          "test_export", "test_train_options", "test_docs_generated", "test_focus", "test_heldout", "test_inputs",
          "test_sensor_randomization", "test_params", "test_widened_control")


def pytest_configure(config):
    config.addinivalue_line("markers", "xdist_group(name): run in the xdist worker of that group")


# tryfirst: xdist's worker adds the group to each test's id in its own collection hook, which
# must see these markers (without it, every test was scheduled on its own and groups split).
@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    rank = {g: i for i, g in enumerate(_QUEUE)}
    for item in items:
        stem = item.path.stem
        item.add_marker(pytest.mark.xdist_group(_GROUP_OF.get(stem, stem)))
    # stable: the order of the tests within a file (and of the files within a group) is kept
    items.sort(key=lambda it: rank.get(_GROUP_OF.get(it.path.stem, it.path.stem), len(rank)))


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


def require_xadap(*modules: str) -> Path:
    """XADAP_DIR, or skip the test when the released files or the ``modules`` are missing."""
    if not XADAP_DIR.is_dir():
        pytest.skip(f"Xadap policy files not found at {XADAP_DIR} (set MJXSYSID_XADAP_DIR)")
    for mod in modules:
        if not have(mod):
            pytest.skip(f"{mod} not installed (pip install {mod})")
    return XADAP_DIR


@pytest.fixture(scope="module")
def xadap_weights():
    require_xadap("onnx")
    from mjxsysid.policy.xadap import load_xadap
    return load_xadap(XADAP_DIR)


@pytest.fixture(scope="session")
def xadap_paper_recording():
    """The released policy flying the paper vehicle 2 s on a 10 s lemniscate, recorded as
    action replay needs it (IMU the policy acted on, commands, motor commands, latents). 2 s:
    the shape of notebook 01's Xadap flight, whose kernel then loads this compile from the cache."""
    from mjxsysid import theta as P
    from mjxsysid.rollout.flight import fly_vehicles, one_flight, seen_imu
    from mjxsysid.policy.interface import resolve_policy
    ref = resolve_policy("xadap", require_xadap("onnx"))
    fl, _, _ = fly_vehicles(P.PAPER_HARDWARE, controller="policy", policy=ref, reference="lemniscate",
                            period=10.0, duration=2.0)
    f = one_flight(fl)
    return ref, {"time": f.time, "imu": seen_imu(f.frame.imu), "imu_after": f.frame.imu,
                 "a_cmd": f.a_cmd, "omega_cmd": f.omega_cmd, "motor_cmd": f.frame.motor_cmd,
                 "latent": f.latent}


NOTEBOOKS = ROOT / "notebooks"


def run_notebook(name: str, cwd: Path, monkeypatch, *, kernel: bool = False, env: dict | None = None):
    """Execute every code cell of notebooks/``name`` with ``cwd`` as working directory and
    ``env`` set; return (the text the cells printed, their rich display outputs: dicts of
    MIME type -> data).

    ``kernel=False`` (the default tier): the cells run in this interpreter, in a fresh IPython
    namespace, so the notebooks share the jit caches of the tests (flights of the same shapes
    are traced once); an exception in any cell fails the test. ``kernel=True`` (slow tier):
    a Jupyter kernel in its own process executes the notebook as a user's would."""
    nbformat = pytest.importorskip("nbformat")
    pytest.importorskip("IPython")
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    for k, v in (env or {}).items():
        monkeypatch.setenv(k, v)
    if kernel:
        nbclient = pytest.importorskip("nbclient")
        pytest.importorskip("ipykernel")
        # The kernel imports this checkout and shares the suite's persistent compilation cache.
        monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
        monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", os.environ.get("MJXSYSID_JAX_CACHE", str(ROOT / ".jax_cache")))
        monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
        monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
        nbclient.NotebookClient(nb, timeout=900, kernel_name="python3",
                                resources={"metadata": {"path": str(cwd)}}).execute()
        outs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
        return "".join(o.get("text", "") for o in outs), [o["data"] for o in outs if "data" in o]
    import matplotlib
    from IPython.core.interactiveshell import InteractiveShell
    from IPython.utils.capture import capture_output
    monkeypatch.chdir(cwd)
    backend = matplotlib.get_backend()
    shell = InteractiveShell.instance()
    _reset_shell(shell)
    text, rich = [], []
    try:
        for i, cell in enumerate(c for c in nb.cells if c.cell_type == "code"):
            with capture_output() as cap:
                res = shell.run_cell(cell.source, store_history=False, silent=False)
            text.append(cap.stdout + cap.stderr)
            rich += [o.data for o in cap.outputs]
            if not res.success:
                raise AssertionError(f"{name}: code cell {i} failed: {res.error_before_exec or res.error_in_exec!r}\n"
                                     f"{cap.stdout[-3000:]}{cap.stderr[-3000:]}")
    finally:
        _reset_shell(shell)
        matplotlib.use(backend)
    return "".join(text), rich


def _reset_shell(shell):
    """A fresh namespace for the next notebook: ``shell.reset`` without the full garbage
    collection its display hook runs (0.2-0.5 s on a worker's heap, twice a notebook)."""
    collect = gc.collect
    gc.collect = lambda *a, **k: 0
    try:
        shell.reset(new_session=False)
    finally:
        gc.collect = collect


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    """An xdist worker ends here, its results sent (``workerfinished``, at session finish) and
    every plugin unconfigured: ``os._exit`` after closing the in-process notebooks' IPython shell.
    A normal exit spent about 9 s tearing down what the worker holds (JAX's atexit hook clears
    every jit cache one by one, IPython's resets the shell with a full garbage collection, then
    the interpreter frees thousands of traced and compiled programs), and the tier waited for it.
    ``MJXSYSID_TESTS_FULL_EXIT=1`` keeps the normal exit (e.g. for a coverage run, whose data a
    worker writes at exit)."""
    mod = sys.modules.get("IPython.core.interactiveshell")
    if mod is not None and mod.InteractiveShell.initialized():
        shell = mod.InteractiveShell.instance()
        atexit.unregister(shell.atexit_operations)
        if shell.history_manager is not None:
            shell.history_manager.end_session()
            shell.history_manager.close()
            shell.history_manager = None
    if os.environ.get("PYTEST_XDIST_WORKER") and not os.environ.get("MJXSYSID_TESTS_FULL_EXIT"):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)


@pytest.fixture(scope="session")
def collected_pairs(tmp_path_factory):
    """`mjxsysid collect` on tiny sizes with the shipped policy, run once for the tests that read
    its pairs (tests/test_policy.py) and latent trajectories (tests/test_sequence.py)."""
    from mjxsysid.cli import main
    from mjxsysid.policy.controller import PRETRAINED
    if not PRETRAINED.exists():
        pytest.skip("no shipped policy weights")
    out = tmp_path_factory.mktemp("collect")
    assert main(["collect", "--out", str(out), "--train", "6", "--test", "2", "--batch", "8"]) == 0
    return out
