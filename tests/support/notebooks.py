"""Running a notebook of notebooks/ inside a test: in this interpreter (default tier) or in a kernel."""
import gc
import os
from pathlib import Path

import pytest

from support.paths import ROOT

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
        monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", os.environ["MJXSYSID_JAX_CACHE"])
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
