"""The posterior_calibration release stage at the tiny sizes with the posterior stubbed (default
tier: the vehicles fly on the CPU, the posterior is a fake): a row file per set, the table with its
provenance, the held-out evaluation, resuming by set, and the table in the shipped tree."""
import json

import numpy as np

from mjxsysid.release import Release
from mjxsysid.release.sizes import TINY
from mjxsysid.release.stages import STAGES, Stage, StageResult
from mjxsysid.release.stages.calibration import pieces
from mjxsysid.release.stages.ship import build_tree


def _fake_posteriors(calls):
    """log_grounded_posteriors' stand-in: per log, 64 draws spread about zero in the visible
    coordinates (12,), features that pass the model check, no velocity."""
    from mjxsysid.identify.coords import N_V
    rng = np.random.default_rng(0)

    def fake(datas, seeds, calibration, batch):
        calls.append(len(datas))
        return [{"method": ("smc_nuts", "smc")[(len(calls) + k) % 2], "v_raw": rng.normal(0.0, 0.5, (64, N_V)), "weights": [1.0] * 4,
                 "features": {"rates_nsr": rng.uniform(-2, -1), "acc_nsr": rng.uniform(-2, -1),
                              "rates_nsr_x": -1.5, "rates_nsr_y": -1.5, "rates_nsr_z": -1.5, "rates_used": True,
                              "windows": 8, "velocity_used": False, "rotor_speed_used": False}}
                for k in range(len(datas))]
    return fake


def test_calibration_stage_collects_fits_evaluates_and_resumes_by_set(tmp_path, monkeypatch):
    import mjxsysid.identify.inference as I
    from mjxsysid.identify.calibrate import for_method, load
    calls = []
    monkeypatch.setattr(I, "log_grounded_posteriors", _fake_posteriors(calls))
    stages = (Stage("policy", lambda r, o: StageResult(), (), (), 1, "stub"), STAGES["posterior_calibration"])
    rel = Release(tmp_path / "rel", {"scale": "tiny"}, stages=stages, log=None, device=lambda: "dev",
                  commit=lambda: "c0ffee")
    rel.record["stages"]["policy"] = {"status": "done", "run": 0}
    cal = TINY.calibration
    assert rel.run(["posterior_calibration"]) == ["posterior_calibration"]
    out = rel.stage_dir("posterior_calibration")
    n_train, n_held, n_misfit = cal.logs()
    assert n_misfit and sum(calls) == n_train + n_held + n_misfit
    for _, name, s, _, _, f in pieces(cal):                        # a row file per set, with its provenance
        rows = json.loads((out / f).read_text())
        assert f == f"rows/{name}.json" and rows["release"]["device"] == "dev" and rows["rows"]
        assert rows["paths"] == s.paths
    assert not list(out.rglob("*.partial"))
    table = load(out / "posterior_calibration.json")
    prov = table["provenance"]
    assert prov["rows"] == n_train and prov["commit"] == "c0ffee" and prov["device"] == "dev"
    nuts = sum(r["method"] == "smc_nuts" for f in (out / "rows").glob("train*.json")
               for r in json.loads(f.read_text())["rows"])
    assert 0 < nuts < n_train and table["by_method"]["smc_nuts"]["logs"] == nuts   # NUTS's rows: a table of their own
    assert prov["sizes"]["bins"] == cal.bins and set(prov["sizes"]["train"]) == set(cal.train)
    assert table["window_check"] == load()["window_check"]        # rows without its statistic: the shipped threshold
    assert set(prov["collected"]) == {f for *_, f in pieces(cal)}
    assert [c["call"].rsplit(".", 1)[1] for c in prov["calls"]] == ["collect", "collect", "collect", "fit_file"]
    held = [next(iter(for_method(table, m)["provenance"]["held_out"].values())) for m in ("smc_nuts", "smc")]
    assert all(h["rows"] for h in held) and sum(h["rows"] for h in held) == n_held   # each sampler's rows, in its table
    assert set().union(*(h["mean_coverage"] for h in held)) == set(cal.held_out_levels)
    misfit = json.loads((out / "misfit/evaluation.json").read_text())   # the misfit set: evaluated apart, not fitted
    assert misfit["rows"] == n_misfit and prov["rows"] == n_train
    ev = json.loads((out / "evaluation.json").read_text())
    assert ev["rows"] == n_held and set(ev["calibrated"]) == set(cal.held_out_levels)
    assert (out / "evaluation.md").read_text().startswith("## Calibrated")
    entry = rel.entry("posterior_calibration")
    assert set(entry["figures"]["mean_coverage"]) == set(cal.held_out_levels)
    assert set(entry["figures"]["misfit_mean_coverage"]) == set(cal.train_levels)
    assert entry["figures"]["train_logs"] == n_train and entry["calls"][-1]["call"].endswith(".report")
    # a second run (the table lost, one held-out set cut halfway) collects the rest of that set only
    (out / "posterior_calibration.json").unlink()
    held = next(f for kind, *_, f in pieces(cal) if kind == "held_out")
    cut = json.loads((out / held).read_text())
    kept = len(cut["rows"]) // 2
    (out / (held + ".partial")).write_text(json.dumps(cut | {"rows": cut["rows"][:kept], "cut_by_budget": True}))
    (out / held).unlink()
    calls.clear()
    rel = Release(tmp_path / "rel", stages=stages, log=None, device=lambda: "dev", commit=lambda: "c0ffee")
    assert rel.status("posterior_calibration") == "incomplete"
    assert rel.run() == ["posterior_calibration"] and sum(calls) == len(cut["rows"]) - kept    # resumed
    assert rel.entry("posterior_calibration")["config"]["collected_now"] == [held]
    assert load(out / "posterior_calibration.json")["provenance"]["rows"] == n_train
    # the shipped tree: the table with a release section, the evaluation under docs/runs/release/calibration/
    left = build_tree(rel, tmp_path / "tree", partial=True)
    assert "posterior_calibration/evaluation.json" not in left
    shipped = json.loads((tmp_path / "tree/mjxsysid/pretrained/posterior_calibration.json").read_text())
    assert shipped["provenance"]["release"]["stage"] == "posterior_calibration"
    assert shipped["provenance"]["release"]["commit"] == "c0ffee" and shipped["coords"] == table["coords"]
    for f in ("evaluation.json", "evaluation.md", "ranks.png", "coverage_width.png"):
        assert (tmp_path / "tree/docs/runs/release/calibration" / f).is_file(), f


def test_the_min_snap_sets_without_velocity_fly_several_paths():
    """The full calibration's min-snap training set without velocity asks collect for MINSNAP_PATHS path draws a
    shard and level; the other sets for one (their row files as recorded)."""
    import types
    from mjxsysid.release.sizes import FULL_CALIBRATION, MINSNAP_PATHS
    from mjxsysid.release.stages.calibration import _kwargs
    rel = types.SimpleNamespace(policy_path=None)
    kw = {name: _kwargs(rel, s, lv, sh) for _, name, s, lv, sh, _ in pieces(FULL_CALIBRATION)}
    assert MINSNAP_PATHS > 1
    assert kw["novel_ms"]["paths"] == MINSNAP_PATHS
    assert not kw["novel_ms"]["velocity"] and kw["novel_ms"]["references"] == ("minsnap:10",)
    assert all("paths" not in kw[n] for n in ("vel_lem", "vel_ms", "slow", "test_vel", "test_novel", "motor"))


def test_a_piece_cut_by_its_time_budget_stays_partial(tmp_path, monkeypatch):
    """tools/calibration_pieces.py's deadline: a piece collect stops for its budget keeps its rows under the
    .partial name, so the stage collects it again; one that finishes is renamed."""
    import types
    import mjxsysid.identify.inference as I
    from mjxsysid.release.stages.calibration import collect_piece
    monkeypatch.setattr(I, "log_grounded_posteriors", _fake_posteriors([]))
    rel = types.SimpleNamespace(policy_path=None, log=lambda m: None)
    piece = pieces(TINY.calibration)[0]
    _, ran = collect_piece(rel, tmp_path, piece, "dev", "c0ffee", time_budget_s=0.0)
    part = tmp_path / (piece[5] + ".partial")
    assert ran and not (tmp_path / piece[5]).exists() and json.loads(part.read_text())["cut_by_budget"]
    _, ran = collect_piece(rel, tmp_path, piece, "dev", "c0ffee")
    done = json.loads((tmp_path / piece[5]).read_text())
    assert ran and done["rows"] and "cut_by_budget" not in done and done["release"]["commit"] == "c0ffee"


def test_landed_rows_are_compact_and_read_back(tmp_path):
    """tools/calibration_pieces.py --land: a device piece (plain, and one cut by the deadline) lands as xz in the
    set's folder, its features rounded, the piece's gzipped form replaced; read_rows reads all forms alike and
    --todo counts a partial piece as still to collect."""
    import gzip
    import importlib.util
    from pathlib import Path
    from mjxsysid.experiments.posterior_calibration import read_rows
    spec = importlib.util.spec_from_file_location("pieces", Path(__file__).parents[2] / "tools/calibration_pieces.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    src, rows = tmp_path / "device", tmp_path / "rows"
    src.mkdir()
    row = {"level": "x1", "truth_v": [0.1] * 12, "features": {"rates_nsr": -1.234567891, "idle_span": [[0.123456789]]}}
    (src / "vel_lem.1of4.json").write_text(json.dumps({"rows": [row] * 3}))
    (src / "test_vel.0of4.json.partial").write_text(json.dumps({"rows": [row]}))
    (rows / "train").mkdir(parents=True)
    (rows / "train/vel_lem.1of4.json.gz").write_bytes(gzip.compress(b'{"rows": []}'))
    out = tool.land([src], rows)
    assert sorted(p.relative_to(rows).as_posix() for p in out) == ["held_out/test_vel.0of4.json.xz",
                                                                    "train/vel_lem.1of4.json.xz"]
    assert [p.name for p in (rows / "train").iterdir()] == ["vel_lem.1of4.json.xz"]
    got = read_rows([rows / "train"])
    assert len(got) == 3 and got[0]["features"] == {"rates_nsr": -1.2346, "idle_span": [[0.1235]], "vibration": False}
    from mjxsysid.experiments.posterior_calibration import read_json
    assert read_json(rows / "held_out/test_vel.0of4.json.xz")["partial"].startswith("the first 1 logs")
    (src / "vel_lem.1of4.json.partial").write_text(json.dumps({"rows": [row]}))       # an older, cut copy
    tool.land([src / "vel_lem.1of4.json.partial"], rows)
    assert len(read_rows([rows / "train"])) == 3                       # the whole piece is kept
    left = [Path(f).name for f, _ in tool.todo(rows)]
    assert "test_vel.0of4.json" in left and "vel_lem.1of4.json" not in left


def test_a_cut_piece_resumes_with_the_logs_it_lacks(tmp_path, monkeypatch):
    """collect_piece on a .partial file identifies only the logs it lacks and keeps the rest; a file of other
    settings is refused by name."""
    import types
    import pytest
    import mjxsysid.identify.inference as I
    from mjxsysid.experiments.posterior_calibration import collect
    from mjxsysid.release.stages.calibration import collect_piece
    calls = []
    monkeypatch.setattr(I, "log_grounded_posteriors", _fake_posteriors(calls))
    rel = types.SimpleNamespace(policy_path=None, log=lambda m: None)
    piece = pieces(TINY.calibration)[0]
    collect_piece(rel, tmp_path / "full", piece, "dev", "c0ffee")
    full = json.loads((tmp_path / "full" / piece[5]).read_text())
    n = len(full["rows"])
    assert n >= 2
    part = tmp_path / "cut" / (piece[5] + ".partial")
    part.parent.mkdir(parents=True)
    part.write_text(json.dumps(full | {"rows": full["rows"][: n // 2], "cut_by_budget": True}))
    calls.clear()
    collect_piece(rel, tmp_path / "cut", piece, "dev", "c0ffee")
    done = json.loads((tmp_path / "cut" / piece[5]).read_text())
    key = lambda r: (r["vehicle"], r["level"], r["flight"])     # noqa: E731
    assert sum(calls) == n - n // 2 and sorted(map(key, done["rows"])) == sorted(map(key, full["rows"]))
    assert done["rows"][: n // 2] == full["rows"][: n // 2] and done["release"]["resumed_rows"] == n // 2
    other = tmp_path / "other.json"
    other.write_text(json.dumps(full | {"seed": full["seed"] + 1}))
    with pytest.raises(ValueError, match=r"cannot resume .*other.json.*seed"):
        collect(out=other, resume=True, vehicles=full["vehicles"], seed=full["seed"], levels=tuple(full["levels"]),
                references=tuple(full["references"]))


def test_a_landed_partial_piece_is_put_back_to_resume(tmp_path):
    """tools/calibration_pieces.py --resume-from: a piece landed as partial goes back as OUT/<piece>.partial
    (plain, without the note), which collect_piece resumes; a complete piece is not touched."""
    import importlib.util
    from pathlib import Path
    spec = importlib.util.spec_from_file_location("pieces", Path(__file__).parents[2] / "tools/calibration_pieces.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    src, rows, out = tmp_path / "device", tmp_path / "rows", tmp_path / "out"
    src.mkdir()
    row = {"level": "x1", "vehicle": 3, "flight": "lemniscate:10", "features": {"rates_nsr": -1.0}}
    (src / "slow.1of4.json.partial").write_text(json.dumps({"seed": 7, "rows": [row] * 2}))
    (src / "aero.0of4.json").write_text(json.dumps({"seed": 7, "rows": [row]}))
    tool.land([src], rows)
    got = tool.resume_into(out, ["rows/slow.1of4.json", "rows/aero.0of4.json"], rows)
    back = json.loads((out / "rows/slow.1of4.json.partial").read_text())
    assert got == ["rows/slow.1of4.json"] and back == {"seed": 7, "rows": [row] * 2}
    assert not (out / "rows/aero.0of4.json.partial").exists()
