"""The coverage run's merge (benchmarks/log_grounded.py --merge): shards of one draw joined per noise
level, from one run or several (synthetic rows: nothing flies here)."""
import json

import numpy as np
import pytest

from mjxsysid.experiments import log_grounded_coverage as B


def _run(path, shard, levels, vehicles, seed=5):
    """A shard's run file: each level's rows for ``vehicles`` (inside: vehicle index even)."""
    n = len(B.LOG_NAMES)
    out = {"command": f"python benchmarks/log_grounded.py --vehicles 4 --shard {shard}", "prior": "wide_actuators",
           "vehicles": 4, "seed": seed, "shard": shard, "levels": []}
    for lv in levels:
        rows = [{"vehicle": v, "seconds": 1.0 + v, "method": "smc", "inside": [v % 2 == 0] * n,
                 "width": [0.1 * (v + 1)] * n, "rel_error_median": [0.01] * n} for v in vehicles]
        out["levels"].append(B.level_summary(lv, rows))
    path.write_text(json.dumps(out))
    return path


def test_merge_joins_shards_across_runs_and_keeps_only_complete_levels(tmp_path, capsys):
    # levels split over two runs for shard 0 (x1, then clean), shard 1 in one run; x20 only in shard 1
    files = [_run(tmp_path / "a0.json", "0/2", ["x1"], [0, 2]), _run(tmp_path / "b0.json", "0/2", ["clean"], [0, 2]),
             _run(tmp_path / "a1.json", "1/2", ["x1", "clean", "x20"], [1, 3])]
    res = B.merge(tmp_path / "m.json", files)
    assert [lv["level"] for lv in res["levels"]] == ["clean", "x1"]          # the noise levels' order
    assert "x20" in capsys.readouterr().err
    for lv in res["levels"]:
        assert lv["flown"] == 4 and [r["vehicle"] for r in lv["rows"]] == [0, 1, 2, 3]
        assert set(lv["rows"][0]) == set(B.ROW_KEYS)
        assert lv["coverage_90"]["thrust_to_weight"] == 0.5
        assert lv["median_width"]["thrust_to_weight"] == pytest.approx(0.25)
        assert lv["seconds_median"] == pytest.approx(2.5)
    back = json.loads((tmp_path / "m.json").read_text())
    assert back["levels"][0]["rows"][0]["inside"][0] == 1 and (tmp_path / "m.png").exists()
    with pytest.raises(ValueError, match="different draws"):
        B.merge(tmp_path / "x.json", [files[0], _run(tmp_path / "s.json", "1/2", ["x1"], [1, 3], seed=6)])
    with pytest.raises(ValueError, match="given twice"):
        B.merge(tmp_path / "x.json", [files[0], files[0], files[2]])
    with pytest.raises(ValueError, match="no noise level"):
        B.merge(tmp_path / "x.json", [files[0]])


def test_shard_takes_every_kth_vehicle_and_names_a_bad_spec():
    th = np.arange(10 * 19, dtype=float).reshape(10, 19)
    part, index, seed = B.shard(th, "1/4", 5)
    assert index.tolist() == [1, 5, 9] and seed == 1005 and np.array_equal(part, th[[1, 5, 9]])
    for bad in ("4/4", "x", "1/"):
        with pytest.raises(ValueError, match="--shard"):
            B.shard(th, bad, 5)
