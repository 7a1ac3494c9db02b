"""Notebooks run end to end on fast settings.

Default tier: the code cells run in this interpreter (support.notebooks.run_notebook), sharing the jit
caches of the tests whose flights have the notebooks' shapes (tests/decoding/test_decode.py,
test_api.py, conftest.xadap_paper_recording; notebook 02 runs in tests/tune/test_tune.py, beside
the tuner's flights). Slow tier: the same notebooks and checks in a Jupyter kernel of their own,
as a user runs them."""
import pytest
from support.paths import ROOT, XADAP_DIR, have
from support.notebooks import run_notebook

KERNEL = [pytest.param(False, id="inprocess"), pytest.param(True, id="kernel", marks=pytest.mark.slow)]

CHECKS = {
    "01_decode_latents.ipynb": lambda out, d: "inside=" in out and (d / "decoded_marginals.png").exists(),
}


def _need_decoder():
    if not (ROOT / "mjxsysid" / "pretrained" / "cfm.npz").exists():
        pytest.skip("no shipped decoder")


@pytest.mark.parametrize("kernel", KERNEL)
@pytest.mark.parametrize("name", sorted(CHECKS))
def test_notebook_executes(name, kernel, tmp_path, monkeypatch):
    _need_decoder()
    env = {"MJXSYSID_NOTEBOOK_FAST": "1"}
    with_xadap = XADAP_DIR.is_dir() and have("onnx")
    if with_xadap:
        env["MJXSYSID_XADAP_DIR"] = str(XADAP_DIR)
    outputs, _ = run_notebook(name, tmp_path, monkeypatch, kernel=kernel, env=env)
    assert CHECKS[name](outputs, tmp_path), outputs[-2000:]
    if with_xadap and name.startswith("01"):  # the released policy's section ran: decoded, plotted, replayed
        assert "Xadap: position RMSE" in outputs and (tmp_path / "xadap_marginals.png").exists()
        assert "CFM (mean action)" in outputs


@pytest.mark.parametrize("kernel", KERNEL)
@pytest.mark.parametrize("name,expect,figure", [
    ("00_quickstart.ipynb", "inside=", "quickstart_marginals.png"),
    ("04_your_vehicle_and_log.ipynb", "posterior/prior width", "posterior_vs_prior.png"),
])
def test_newcomer_notebook_executes(name, expect, figure, kernel, tmp_path, monkeypatch):
    """The newcomer notebooks (Python API) run end to end on fast settings."""
    _need_decoder()
    outputs, _ = run_notebook(name, tmp_path, monkeypatch, kernel=kernel, env={"MJXSYSID_NOTEBOOK_FAST": "1"})
    assert expect in outputs and (tmp_path / figure).exists()
    assert "Failed to import" not in outputs and "Traceback" not in outputs
    if name.startswith("04"):
        assert "refused: heavy.json: cannot hover" in outputs and (tmp_path / "my_flight.csv").exists()
