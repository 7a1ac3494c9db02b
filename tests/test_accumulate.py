"""Probing that accumulates: the replay buffer's weighted draws, old checkpoints' configs (the warm
start of training from a policy's weights: tests/test_policy.py, beside the tiny Trainer), and the probe loop's accumulate variant (its tiny
end-to-end run is `slow`; its checks of input run here)."""
import dataclasses
import json

import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.policy.adaptive.controller import PRETRAINED
from mjxsysid.policy.adaptive.focus import replay_resample, save_weak
from mjxsysid.policy.adaptive.config import TrainConfig
from mjxsysid.policy.adaptive.train import _same_config

TINY = dict(num_envs=64, unroll=16, epochs=2, minibatches=4, log_every=1, checkpoint_every=2)


def test_replay_draws_follow_the_badness():
    th = np.tile(P.PAPER_HARDWARE, (3, 1)).astype(np.float32)
    th[:, P.MASS] = [0.5, 0.6, 0.7]
    got = replay_resample(th, [0.0, 1.0, 3.0], 4000, seed=1)
    assert got.shape == (4000, 19)
    frac = [(got[:, P.MASS] == m).mean() for m in th[:, P.MASS]]
    assert frac[0] == 0 and abs(frac[2] - 0.75) < 0.03
    np.testing.assert_array_equal(got, replay_resample(th, [0.0, 1.0, 3.0], 4000, seed=1))
    for w, msg in (([0, 0, 0], "not all 0"), ([1, -1, 1], ">= 0"), ([1, 1], r"shape \(3,\)")):
        with pytest.raises(ValueError, match=msg):
            replay_resample(th, w, 10)
    with pytest.raises(ValueError, match="replay draws"):
        replay_resample(th, [1, 1, 1], 0)


def test_checkpoints_written_before_init_from_still_resume():
    cfg = TrainConfig(iterations=2, **TINY)
    saved = json.loads(json.dumps(cfg.to_dict()))
    saved.pop("init_from")
    assert _same_config(saved, cfg)
    assert not _same_config({**saved, "iterations": 3}, cfg) and not _same_config(None, cfg)
    assert not _same_config({**saved, "init_from": "x.npz"}, cfg)


def test_probe_loop_accumulate_checks_its_input_first(tmp_path):
    from mjxsysid.experiments.probe_loop import QUICK, run, train_config
    with pytest.raises(ValueError, match="unknown variant 'accumulated'"):
        run(tmp_path / "a", quick=True, progress=False, variant="accumulated")
    with pytest.raises(ValueError, match="replay_draws"):
        run(tmp_path / "a", progress=False, cfg=dataclasses.replace(QUICK, accumulate=True, replay_draws=0))
    assert not (tmp_path / "a").exists()
    assert train_config(QUICK, 0, init_from=PRETRAINED).init_from == str(PRETRAINED)
    assert train_config(QUICK, 0).init_from is None


def test_probe_loop_runs_written_before_the_variant_still_resume(tmp_path):
    from mjxsysid.experiments.common import to_jsonable
    from mjxsysid.experiments.probe_loop import QUICK, _check_config
    cfg = to_jsonable({"quick": True, "seed": 0, **dataclasses.asdict(QUICK)})
    old = {k: v for k, v in cfg.items() if k not in ("accumulate", "replay_draws")}
    (tmp_path / "loop_config.json").write_text(json.dumps(old))
    _check_config(tmp_path, cfg, resume=True)                            # the new keys at their defaults
    with pytest.raises(ValueError, match="another config"):
        _check_config(tmp_path, {**cfg, "accumulate": True}, resume=True)
    # the probe's seed is the loop's (runs before 2026-11-26 recorded the default, 0): they resume
    cfg1 = {**cfg, "seed": 1, "probe": {**cfg["probe"], "seed": 1}}
    (tmp_path / "loop_config.json").write_text(json.dumps({**cfg1, "probe": {**cfg["probe"], "seed": 0}}))
    _check_config(tmp_path, cfg1, resume=True)


@pytest.mark.slow
def test_probe_loop_accumulate_quick_end_to_end(tmp_path):
    """`experiment probe-loop --quick --variant accumulate`, two rounds, no last probe (≈ 4 min on
    2 CPU cores): round 1 fine-tunes the shipped policy, round 2 round 1's, each on a replay buffer
    of every round so far, re-scored under the current policy and drawn ∝ badness."""
    from mjxsysid.experiments.probe_loop import QUICK, run
    from mjxsysid.policy.adaptive.focus import load_weak
    out = tmp_path / "acc"
    cfg = dataclasses.replace(QUICK, rounds=2, final_probe=False, replay_draws=256)
    r = run(out, quick=True, progress=False, cfg=cfg, variant="accumulate")
    assert list(r["numbers"]["evaluation"]) == ["given", "probed", "probed2", "uniform"]
    n1, n2 = (len(load_weak(out / d / "weak.npz")[0]) for d in ("probe", "probe_round2"))
    rec = [json.loads((out / "stages" / f"replay_round{i}.json").read_text())["result"] for i in (1, 2)]
    assert len(rec[0]["badness"]) == n1 and len(rec[1]["badness"]) == n1 + n2   # the buffer accumulates
    assert len(load_weak(out / "replay_round2.npz")[0]) == 256
    from mjxsysid.checkpoint import load_meta
    assert load_meta(out / "probed2" / "policy.npz")["config"]["init_from"] == str(out / "probed" / "policy.npz")
    assert load_meta(out / "probed" / "policy.npz")["config"]["init_from"] == str(PRETRAINED)
    assert set(json.loads((out / "results.json").read_text())["numbers"]["replay"]) == {"1", "2"}
