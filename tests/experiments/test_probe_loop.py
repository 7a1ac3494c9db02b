"""The probe → retrain loop (mjxsysid.experiments.probe_loop): its accumulate variant (a replay buffer of
every round's weak systems; the tiny end-to-end run is `slow`, its checks of input run here), the fair
widened control (the prior widened as far as the probe reached, trained with the probed policy's budget;
the loop's use of it runs with `--variant widened`, GPU), and resuming runs written before a variant."""
import dataclasses
import json

import jax
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.experiments.probe_loop import QUICK, control_budget, probe_reach, run
from mjxsysid.policy.adaptive.config import TrainConfig
from mjxsysid.policy.adaptive.controller import PRETRAINED


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
    from mjxsysid.runtime.checkpoint import load_meta
    assert load_meta(out / "probed2" / "policy.npz")["config"]["init_from"] == str(out / "probed" / "policy.npz")
    assert load_meta(out / "probed" / "policy.npz")["config"]["init_from"] == str(PRETRAINED)
    assert set(json.loads((out / "results.json").read_text())["numbers"]["replay"]) == {"1", "2"}


def test_probe_reach_measures_how_far_systems_leave_the_prior():
    inside = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(5), 500))
    r0 = probe_reach(inside, n=4000)
    assert r0["amount"] < 0.05, r0                          # the prior's own draws stay inside
    slow = inside.copy()
    slow[:, P.TAU_M] = 0.08                                  # twice the prior's slowest motor
    r = probe_reach(slow, n=4000)
    assert r["per_quantity"]["motor_time_constant"] == pytest.approx(np.log(2.0), abs=0.02)
    assert r["amount"] == pytest.approx(np.log(2.0), abs=0.02)
    assert r["per_quantity"]["nominal_thrust_to_weight"] < 0.05
    with pytest.raises(ValueError, match="probe_reach: systems must have shape"):
        probe_reach(np.zeros((0, P.N_PARAMS)))


def test_control_budget_is_the_probed_policys_whole_training(tmp_path):
    base = TrainConfig(iterations=100)
    assert control_budget(dataclasses.replace(QUICK, rounds=3, accumulate=True), base, "w.npz") == (300, "w.npz")
    assert control_budget(dataclasses.replace(QUICK, rounds=3), base, "w.npz") == (100, None)
    with pytest.raises(ValueError, match="unknown variant 'widen'"):
        run(tmp_path / "x", quick=True, progress=False, variant="accumulate,widen")
    assert not (tmp_path / "x").exists()
