"""Action replay: metrics by hand, exact replay of a K_θ flight, decoders that know the truth."""
import json

import jax
import numpy as np
import pytest
from support.paths import XADAP_DIR

from mjxsysid import theta as P
from mjxsysid.control.low_level import Command, KTheta
from mjxsysid.uses.replay import METHODS, action_metrics, lowpass, pearson, replay_commands, replay_flight


def test_metrics_by_hand():
    t = np.arange(2000) * 0.002
    ref = 0.5 + 0.2 * np.sin(2 * np.pi * 1.0 * t)[:, None] * np.array([1, -1, 0.5, 2])
    m = action_metrics(ref, ref, fs=500)
    assert m["rmse"] == 0 and m["pcc"] == pytest.approx(1.0)
    m = action_metrics(ref + 0.1, ref, fs=500)
    assert m["rmse"] == pytest.approx(0.1) and m["pcc"] == pytest.approx(1.0)
    assert action_metrics(1.0 - ref, ref, fs=500)["pcc"] == pytest.approx(-1.0)
    # High-frequency noise lowers the raw correlation but not the low-passed one.
    noisy = ref + 0.3 * np.sin(2 * np.pi * 100 * t)[:, None]
    raw = np.mean([pearson(noisy[:, i], ref[:, i]) for i in range(4)])
    assert raw < 0.6 and action_metrics(noisy, ref, fs=500)["pcc"] > 0.99
    assert np.isnan(pearson(np.ones(10), np.arange(10.0)))
    np.testing.assert_allclose(lowpass(np.full((100, 2), 3.0), 5.0, 500.0), 3.0, atol=1e-9)
    with pytest.raises(ValueError, match="cutoff_hz"):
        lowpass(ref, 300.0, 500.0)


@pytest.fixture(scope="module")
def oracle_recording():
    """The paper vehicle flown 1 s by the paper's K_θ with its true θ: its motor commands are K_θ's own."""
    from mjxsysid.rollout.flight import fly_vehicles, one_flight, seen_imu
    fl, _, _ = fly_vehicles(P.PAPER_HARDWARE, controller="k_theta", reference="lemniscate", period=5.0,
                            duration=1.0)
    f = one_flight(fl)
    return {"time": f.time, "imu": seen_imu(f.frame.imu), "a_cmd": f.a_cmd, "omega_cmd": f.omega_cmd,
            "motor_cmd": f.frame.motor_cmd, "latent": np.zeros((len(f.time), 8), np.float32)}


def test_replay_of_a_k_theta_flight_is_exact(oracle_recording):
    """K_θ replayed on the recorded inputs with the true θ gives back the flown commands (checks
    the IMU alignment and the hold of θ̂ between updates); a wrong θ does not."""
    r = oracle_recording
    seg = np.zeros(len(r["time"]), np.int32)
    th = np.asarray(P.PAPER_HARDWARE, np.float32)[None]
    out = np.asarray(replay_commands(th, seg, r["imu"][:, :3], r["a_cmd"], r["omega_cmd"]))
    np.testing.assert_allclose(out, r["motor_cmd"], atol=1e-5)
    assert np.abs(r["motor_cmd"]).max() > 0.2
    heavy = th.copy()
    heavy[0, P.MASS] *= 1.3
    out = np.asarray(replay_commands(heavy, seg, r["imu"][:, :3], r["a_cmd"], r["omega_cmd"]))
    assert np.sqrt(np.mean((out - r["motor_cmd"]) ** 2)) > 0.02


class _Truth:
    """A decoder that always returns the given θ (what a perfect decoder would)."""
    def __init__(self, theta):
        self.theta = np.asarray(theta, np.float32)

    def sample_theta(self, z, key, n):
        return np.broadcast_to(self.theta, (len(z), n, P.N_PARAMS))

    def point(self, z):
        return np.broadcast_to(self.theta, (len(z), P.N_PARAMS))


def test_perfect_decoder_scores_like_the_truth(oracle_recording):
    truth = P.PAPER_HARDWARE
    r = replay_flight(oracle_recording, truth, _Truth(truth), _Truth(truth), jax.random.PRNGKey(0),
                      samples=3)
    assert set(r["metrics"]) == set(METHODS)
    assert r["update_times"][0] == pytest.approx(0.2) and np.allclose(np.diff(r["update_times"]), 0.1)
    for m in ("true", "cfm", "cfm_mean", "regression"):
        assert r["metrics"][m]["rmse"] < 1e-5 and r["metrics"][m]["pcc"] > 0.9999
    assert r["metrics"]["random"]["rmse"] > 0.05          # ±50 % per entry is far from the truth
    # θ̂ is held between updates: step j after update k uses the Random draw k.
    rec, th = oracle_recording, r["theta_hat"]["random"]
    assert th.shape == (len(r["update_times"]), P.N_PARAMS)
    first = len(rec["time"]) - len(r["times"])  # replayed span starts at the first update
    for k in (0, 3, len(th) - 2):
        for off in (0, 49):  # the first and the last step of update k's 0.1 s
            j = int(np.searchsorted(r["times"], r["update_times"][k])) + off
            i = first + j
            want = KTheta.make(th[k]).motor_command(Command(rec["a_cmd"][i], rec["omega_cmd"][i]),
                                                    rec["imu"][i, :3])
            np.testing.assert_allclose(r["random"][j], want, atol=1e-5)


def test_shipped_xadap_decoders_explain_its_commands(xadap_paper_recording):
    """On a recorded flight of the released policy, K_θ̂ from its shipped decoders tracks its
    motor commands far better than the Random baseline."""
    from mjxsysid.cfm.load import load_decoders
    ref, rec = xadap_paper_recording
    cfm, reg = load_decoders(None, ref)
    r = replay_flight(rec, P.PAPER_HARDWARE, cfm, reg, jax.random.PRNGKey(0), samples=8)
    m = r["metrics"]
    assert len(r["update_times"]) == 19  # 0.2, 0.3, …, 2.0 s
    assert m["cfm_mean"]["rmse"] < 0.8 * m["random"]["rmse"]
    assert m["regression"]["rmse"] < 0.8 * m["random"]["rmse"]


@pytest.mark.slow
def test_replay_cli_on_the_released_policy(xadap_weights, tmp_path):
    """`mjxsysid replay --policy xadap`: the shipped Xadap decoders explain its hover commands
    far better than Random. (CFM's mean action and the early-stopped Regression are within a few
    per cent of each other on this flight, so neither is asserted to win: docs/fair_comparisons.md.)"""
    from mjxsysid.cli import main
    out = tmp_path / "rp"
    assert main(["replay", "--policy", "xadap", "--weights", str(XADAP_DIR), "--flights", "hover",
                 "--samples", "8", "--out", str(out)]) == 0
    res = json.loads((out / "replay.json").read_text())
    pv = res["flights"]["hover"]["paper_vehicle"]
    assert pv["cfm_mean"]["rmse"] < 0.5 * pv["random"]["rmse"]
    assert pv["regression"]["rmse"] < 0.5 * pv["random"]["rmse"]
    assert pv["cfm_mean"]["pcc"] > pv["random"]["pcc"]
    for f in ("replay.md", "replay_summary.png", "replay_hover.png"):
        assert (out / f).is_file()
