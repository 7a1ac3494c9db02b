"""Notebooks run end to end on fast settings."""
import os
from pathlib import Path

import pytest
from conftest import XADAP_DIR, have

ROOT = Path(__file__).resolve().parent.parent


def _share_compilation_cache(monkeypatch):
    """The kernel imports this checkout and shares the suite's persistent compilation cache
    (conftest.py): the notebooks' flights have the shapes of flights the tests compiled before
    (tests/test_decode.py, test_api.py, conftest.xadap_paper_recording), so a kernel loads them."""
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", os.environ.get("MJXSYSID_JAX_CACHE", str(ROOT / ".jax_cache")))
    monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
    monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")


CHECKS = {
    "01_decode_latents.ipynb": lambda out, d: "inside=" in out and (d / "decoded_marginals.png").exists(),
    "02_tuning.ipynb": lambda out, d: "cfm_tuned: position RMSE" in out and (d / "tuning_gains.png").exists(),
}


@pytest.mark.parametrize("name", sorted(CHECKS))
def test_notebook_executes(name, tmp_path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    if not (ROOT / "mjxsysid" / "pretrained" / "cfm.npz").exists():
        pytest.skip("no shipped decoder")
    nb = nbformat.read(ROOT / "notebooks" / name, as_version=4)
    os.environ["MJXSYSID_NOTEBOOK_FAST"] = "1"
    with_xadap = XADAP_DIR.is_dir() and have("onnx")
    if with_xadap:
        os.environ["MJXSYSID_XADAP_DIR"] = str(XADAP_DIR)
    _share_compilation_cache(monkeypatch)
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []))
    assert CHECKS[name](outputs, tmp_path), outputs[-2000:]
    if with_xadap and name.startswith("01"):  # the released policy's section ran: decoded, plotted, replayed
        assert "Xadap: position RMSE" in outputs and (tmp_path / "xadap_marginals.png").exists()
        assert "CFM (mean action)" in outputs


@pytest.mark.parametrize("name,expect,figure", [
    ("00_quickstart.ipynb", "inside=", "quickstart_marginals.png"),
    ("04_your_vehicle_and_log.ipynb", "posterior/prior width", "posterior_vs_prior.png"),
])
def test_newcomer_notebook_executes(name, expect, figure, tmp_path, monkeypatch):
    """The newcomer notebooks (Python API) run end to end on fast settings."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    if not (ROOT / "mjxsysid" / "pretrained" / "cfm.npz").exists():
        pytest.skip("no shipped decoder")
    nb = nbformat.read(ROOT / "notebooks" / name, as_version=4)
    monkeypatch.setenv("MJXSYSID_NOTEBOOK_FAST", "1")
    _share_compilation_cache(monkeypatch)
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []))
    assert expect in outputs and (tmp_path / figure).exists()
    assert "Failed to import" not in outputs and "Traceback" not in outputs
    if name.startswith("04"):
        assert "refused: heavy.json: cannot hover" in outputs and (tmp_path / "my_flight.csv").exists()
