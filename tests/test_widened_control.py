"""Issue 28's fair control: the default prior widened in every direction by as far as the probe
reached (theta.widened_prior, probe_loop.probe_reach), trained with the probed policy's budget
(probe_loop.control_budget). The loop's use of them runs with `--variant widened` (GPU)."""
import dataclasses

import jax
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.experiments.probe_loop import QUICK, control_budget, probe_reach, run
from mjxsysid.policy.adaptive.losses import identifiable_log
from mjxsysid.policy.adaptive.config import TrainConfig


def test_widened_prior_is_the_prior_at_zero_and_wider_and_valid_beyond():
    key = jax.random.PRNGKey(3)
    base = np.asarray(P.DEFAULT_PRIOR.sample(key, 2000))
    np.testing.assert_array_equal(np.asarray(P.widened_prior(P.DEFAULT_PRIOR, 0.0).sample(key, 2000)), base)
    wide = P.widened_prior(P.DEFAULT_PRIOR, 0.4)
    assert wide.motor_time_constant == pytest.approx((0.02 / np.exp(0.4), 0.04 * np.exp(0.4)))
    assert wide.eta[1] <= 1.99 and wide.ext_torque_xy == pytest.approx(0.02 * np.exp(0.4))
    th = np.asarray(wide.sample(key, 2000))
    P.validate_theta(th)                                    # every draw a valid vehicle
    a, b = np.asarray(identifiable_log(base)), np.asarray(identifiable_log(th))
    assert (b.min(0) < a.min(0)).sum() >= 4 and (b.max(0) > a.max(0)).sum() >= 4   # wider both ways
    with pytest.raises(ValueError, match="amount must be"):
        P.widened_prior(P.DEFAULT_PRIOR, -0.1)


def test_probe_reach_measures_how_far_systems_leave_the_prior():
    inside = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(5), 500))
    r0 = probe_reach(inside, n=4000)
    assert r0["amount"] < 0.05, r0                          # the prior's own draws stay inside
    slow = inside.copy()
    slow[:, P.TAU_M] = 0.08                                  # twice the prior's slowest motor
    r = probe_reach(slow, n=4000)
    assert r["per_quantity"]["motor_time_constant"] == pytest.approx(np.log(2.0), abs=0.02)
    assert r["amount"] == pytest.approx(np.log(2.0), abs=0.02)
    assert r["per_quantity"]["thrust_to_weight"] < 0.05
    with pytest.raises(ValueError, match="probe_reach: systems must have shape"):
        probe_reach(np.zeros((0, P.N_PARAMS)))


def test_control_budget_is_the_probed_policys_whole_training(tmp_path):
    base = TrainConfig(iterations=100)
    assert control_budget(dataclasses.replace(QUICK, rounds=3, accumulate=True), base, "w.npz") == (300, "w.npz")
    assert control_budget(dataclasses.replace(QUICK, rounds=3), base, "w.npz") == (100, None)
    with pytest.raises(ValueError, match="unknown variant 'widen'"):
        run(tmp_path / "x", quick=True, progress=False, variant="accumulate,widen")
    assert not (tmp_path / "x").exists()
