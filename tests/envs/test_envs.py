"""dm_control environments (issue 20 §1): the dm_env contract, the shipped policy flying the
same trajectory as in the MJX simulator, tasks, decoded ensembles, the viewer's no-display path."""
import numpy as np
import pytest
from absl.testing import absltest
from dm_env import test_utils

from mjxsysid import theta as P
from mjxsysid.envs import TASKS, PolicyAgent, ensemble_envs, make_env
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.rollout.flight import fly_vehicles, one_flight


class EnvironmentContractTest(test_utils.EnvironmentTestMixin, absltest.TestCase):
    """dm_env's own checks (specs, reset/step protocol, observations matching their specs) on
    random motor commands."""

    def make_object_under_test(self):
        return make_env(task="hover", duration=0.1)


@pytest.fixture(scope="module")
def mjx_flight():
    # The 2 s lemniscate of the shipped policy that tests/decoding/test_decode.py flies (same worker: one compile).
    fl, _, _ = fly_vehicles(P.PAPER_HARDWARE, controller="policy", policy=resolve_policy("mjxsysid"),
                            reference="lemniscate", duration=2.0)
    return one_flight(fl)


def fly_env(env, agent):
    ts = env.reset()
    obs = [ts.observation]
    rewards = []
    while not ts.last():
        ts = env.step(agent(ts))
        obs.append(ts.observation)
        rewards.append(ts.reward)
    return {k: np.array([o[k] for o in obs]) for k in obs[0]}, np.array(rewards), ts


def test_shipped_policy_flies_the_mjx_trajectory(mjx_flight):
    """Same θ, reference and policy: CPU MuJoCo (float64) and MJX (float32) agree to 1e-4 m over
    2 s (measured 9e-7 m: the same model file, field edits and rotor equations; what remains is
    float32 round-off, which the closed loop keeps from growing), and the latents to 1e-3."""
    agent = PolicyAgent()
    obs, rew, last = fly_env(make_env(task="lemniscate", duration=2.0), agent)
    assert obs["position"].shape == (1001, 3) and last.discount == 1.0
    np.testing.assert_allclose(obs["position"][1:], np.asarray(mjx_flight.frame.pos), atol=1e-4)
    np.testing.assert_allclose(obs["command"][:-1, 0], np.asarray(mjx_flight.a_cmd), atol=1e-3)
    np.testing.assert_allclose(agent.latent, np.asarray(mjx_flight.latent)[-1], atol=1e-3)
    np.testing.assert_allclose(obs["reference_position"][:-1], np.asarray(mjx_flight.ref_pos), atol=1e-5)
    assert rew.mean() > 0.95            # within 5 cm of the reference nearly all the time


def test_tasks_force_step_and_termination():
    agent = PolicyAgent()
    hover, _, _ = fly_env(make_env(task="hover", duration=1.0), agent)
    pushed, _, _ = fly_env(make_env(task="force_step", duration=1.0, step_time=0.5), agent)
    np.testing.assert_array_equal(pushed["position"][:251], hover["position"][:251])   # the same until 0.5 s
    assert (pushed["position"][-1, :2] - hover["position"][-1, :2] > 2e-3).all()      # then pushed along +x, +y
    # No thrust: the vehicle falls, and the episode ends (discount 0) at the ground.
    env = make_env(task="hover", duration=5.0)
    ts = env.reset()
    n = 0
    while not ts.last():
        ts = env.step(np.zeros(4))
        n += 1
    assert ts.discount == 0.0 and n < 500 and ts.observation["position"][2] <= 0.0
    for task in TASKS:
        assert make_env(task=task, duration=0.01).reset().observation["imu"].shape == (6,)


def test_ensemble_and_errors():
    th = np.stack([P.PAPER_HARDWARE] * 3).astype(np.float64)
    th[1, P.MASS] = 1.5
    th[2, P.INERTIA] = [0.001, 0.001, 0.01]                   # violates J_z ≤ J_x + J_y: projected
    envs = ensemble_envs(th, task="hover", duration=0.1)
    assert len(envs) == 3
    assert envs[1].physics.model.body_mass[1] == pytest.approx(1.5)
    j = envs[2].physics.model.body_inertia[1]
    assert j[2] <= j[0] + j[1] + 1e-9
    with pytest.raises(ValueError, match="unknown task"):
        make_env(task="loop")
    with pytest.raises(ValueError, match=r"\(K, 19\)"):
        ensemble_envs(np.zeros((3, 18)))
    bad = P.PAPER_HARDWARE.copy()
    bad[P.MASS] = -1.0
    with pytest.raises(ValueError, match="mass"):
        make_env(bad)


def test_view_without_a_display_says_how_to_get_a_video(monkeypatch, capsys):
    from mjxsysid.cli import main
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    assert main(["view", "--task", "hover"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no display" in err and "mjxsysid fly" in err and "--video" in err
