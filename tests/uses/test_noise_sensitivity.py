"""docs/noise.md's table is what mjxsysid.uses.imu_noise makes of its committed run, and the
figure is drawn from it (the run itself takes minutes: `mjxsysid experiment noise-sensitivity`)."""
import json

import numpy as np
import pytest
from support.paths import ROOT



def test_docs_table_and_figure_come_from_the_run(tmp_path):
    from mjxsysid.uses import imu_noise as tool
    doc = (ROOT / "docs/noise.md").read_text()
    parts = doc.split("<!-- BEGIN noise table ")[1:]
    assert len(parts) == 2
    for part in parts:
        run, rest = part.split(" ", 1)
        res = json.loads((ROOT / run).read_text())
        body = rest.split("-->", 1)[1].split("<!-- END noise table -->")[0]
        assert body.strip() == tool.table(res).strip(), f"regenerate: mjxsysid.uses.imu_noise.replace_tables on {run}"
        for name, lv in res["levels"].items():
            assert lv["sim"] == tool.LEVELS[name], name     # the levels the tool defines today
    assert tool.figure(res, tmp_path / "f.png").stat().st_size > 10_000


def test_plot_checks_shapes(tmp_path):
    from mjxsysid.render.plots import plot_noise_sensitivity
    with pytest.raises(ValueError, match="must be"):
        plot_noise_sensitivity(["a", "b"], {"x": np.zeros((2, 3))}, {"x": np.zeros((2, 2))}, tmp_path / "f.png",
                               names=["p", "q", "r"])
    with pytest.raises(ValueError, match="same decoders"):
        plot_noise_sensitivity(["a"], {"x": np.zeros((1, 1))}, {}, tmp_path / "f.png", names=["p"])


def test_figure_names_whose_decoders_and_edge_coverages_count_as_calibrated():
    """The figure's title names a candidate's decoders (not "shipped"); a coverage of exactly
    0.850 of 1,000 flights counts as within ±5 points (float round-off), 0.849 does not."""
    from mjxsysid.cfm.pipeline import WITHIN_5_POINTS
    from mjxsysid.uses.imu_noise import _whose
    assert _whose({"decoders": "runs/release_clean/decoder_set"}) == "decoders of release_clean"
    assert _whose({"decoders": None}) == _whose({"decoders": "x/mjxsysid/pretrained"}) == "shipped decoders"
    assert abs(850 / 1000 - 0.9) <= WITHIN_5_POINTS and abs(950 / 1000 - 0.9) <= WITHIN_5_POINTS
    assert not abs(849 / 1000 - 0.9) <= WITHIN_5_POINTS
