"""Weak systems mixed into policy training (issue 18 §2): the file format, the mixing, bad input."""
import jax
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.cli import main
from mjxsysid.policy.adaptive.config import EnvConfig
from mjxsysid.policy.adaptive.env import TrainEnv
from mjxsysid.policy.adaptive.focus import load_weak, replay_resample, save_weak


def _weak():
    th = np.stack([P.PAPER_HARDWARE, P.PAPER_HARDWARE]).astype(np.float32)
    th[0, P.MASS], th[1, P.MASS] = 2.5, 0.07       # far from each other and from most prior draws
    return th


def test_weak_file_round_trip_and_errors(tmp_path):
    th = _weak()
    p = save_weak(tmp_path / "weak.npz", th, zhat=np.zeros((2, 8)), meta={"found_by": "test"})
    got, meta = load_weak(p)
    np.testing.assert_array_equal(got, th)
    assert meta == {"found_by": "test"}
    np.savez(tmp_path / "empty.npz", theta=np.zeros((0, 19), np.float32))
    with pytest.raises(ValueError, match="no weak systems"):
        load_weak(tmp_path / "empty.npz")
    np.savez(tmp_path / "shape.npz", theta=np.zeros((3, 18), np.float32))
    with pytest.raises(ValueError, match=r"\(n, 19\)"):
        load_weak(tmp_path / "shape.npz")
    bad = th.copy()
    bad[0, P.MASS] = -1.0
    np.savez(tmp_path / "neg.npz", theta=bad)
    with pytest.raises(ValueError, match="mass"):
        load_weak(tmp_path / "neg.npz")
    with pytest.raises(FileNotFoundError):
        load_weak(tmp_path / "missing.npz")


@pytest.mark.parametrize("weight", [0.0, 0.5, 1.0])
def test_focus_mixing_keeps_shapes_and_its_weight(weight):
    th = _weak()
    env = TrainEnv(EnvConfig(focus_weight=weight), focus_theta=th)
    masses = jax.jit(jax.vmap(lambda k: env.reset(k, 0.0).theta))(jax.random.split(jax.random.PRNGKey(0), 400))
    assert masses.shape == (400, 19)
    is_focus = np.isin(np.asarray(masses[:, P.MASS]), th[:, P.MASS])
    assert abs(is_focus.mean() - weight) < 0.08, (weight, is_focus.mean())   # ~3.2 binomial std at 0.5
    if weight == 1.0:                                  # both systems drawn, uniformly
        assert 0.4 < np.mean(np.asarray(masses[:, P.MASS]) == th[0, P.MASS]) < 0.6
    with pytest.raises(ValueError, match=r"focus_weight must be in \[0, 1\]"):
        TrainEnv(EnvConfig(focus_weight=1.5))


def test_train_policy_focus_errors_are_one_line(tmp_path, capsys):
    np.savez(tmp_path / "empty.npz", theta=np.zeros((0, 19), np.float32))
    assert main(["train-policy", "--focus", str(tmp_path / "empty.npz"), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert "no weak systems" in err and len(err.splitlines()) == 1
    assert main(["train-policy", "--focus-weight", "1.5", "--out", str(tmp_path / "r")]) == 2
    assert "--focus-weight must be in [0, 1]" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


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
