"""`mjxsysid decode --no-refine`: the switch for the NUTS refinement reaches the log-grounded
posterior (run_decode, ground_in_log and mjxsysid.decode pass it on, and the vehicle's shared motor maps with it;
nothing is decoded here)."""
import numpy as np
import pytest

from mjxsysid.cli import main


def test_no_refine_reaches_run_decode(tmp_path, monkeypatch, capsys):
    import mjxsysid.decoding as D
    got = []

    def fake_run_decode(out, **kw):
        got.append(kw["refine"])
        raise ValueError("stopped before decoding")
    monkeypatch.setattr(D, "run_decode", fake_run_decode)
    log = tmp_path / "l.csv"
    log.write_text("t\n")
    out = str(tmp_path / "o")
    assert main(["decode", "--log", str(log), "--no-refine", "--out", out]) == 2
    assert main(["decode", "--log", str(log), "--out", out]) == 2
    assert got == [False, None]                     # None: the library's default (refined)
    capsys.readouterr()
    assert main(["decode", "--no-refine", "--out", out]) == 2
    assert "--no-refine needs --log" in capsys.readouterr().err
    assert main(["decode", "--log", str(log), "--no-refine", "--decoder-only", "--out", out]) == 2
    assert "not --decoder-only" in capsys.readouterr().err
    import mjxsysid
    with pytest.raises(ValueError, match="refine applies"):
        mjxsysid.decode(str(log), refine=False, decoder_only=True)
    with pytest.raises(ValueError, match="shared_maps applies"):
        mjxsysid.decode(str(log), shared_maps=[(0.1, 1.5)], decoder_only=True)


@pytest.mark.parametrize("refine", [False, True, None])
def test_ground_in_log_passes_refine_and_shared_maps_to_the_posterior(monkeypatch, refine):
    from mjxsysid.decoding import ground_in_log
    from mjxsysid.identify import inference
    from mjxsysid.identify.logdata import LogTooShort
    got = {}

    def fake_posterior(rec, decoded, **kw):
        got.update(kw)
        raise LogTooShort("stopped before the posterior")
    monkeypatch.setattr(inference, "log_grounded_posterior", fake_posterior)
    maps = ((0.1, 1.5),)
    summary = ground_in_log({"samples": np.zeros((1, 4, 19))}, {}, {}, seed=3, refine=refine, shared_maps=maps)
    assert got["refine"] is refine and got["seed"] == 3 and summary["_posterior"] == "decoder-only"
    assert got["shared_maps"] == maps
