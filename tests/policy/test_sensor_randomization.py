"""Sensor randomisation options (default off): IMU white noise, bias and vibration whose levels are
drawn per episode / per flight, for the policy's training env, the collected (θ, ẑ) pairs and so
the decoders trained on them. The simulator's side: tests/sim/test_sim.py."""
import argparse
import json

import numpy as np
import pytest

from mjxsysid.cli.decoders import imu_config
from mjxsysid.policy.adaptive.config import IMU_FIELDS, EnvConfig, TrainConfig
from mjxsysid.policy.adaptive.env import TrainEnv
from mjxsysid.sim import SimConfig
from support.paths import ROOT

RANGE = dict(gyro_noise=0.05, accel_noise=0.5, gyro_bias=0.025, accel_bias=0.25, randomize_imu=True)


def test_defaults_change_nothing():
    """Off by default: the env's simulator is the one the shipped policy trained with."""
    env = TrainEnv(EnvConfig())
    assert env.sim.config == SimConfig(gyro_noise=0.005, accel_noise=0.05)
    assert imu_config(argparse.Namespace(imu_noise=(0, 0), imu_bias=(0, 0), imu_vibration=(0, 0),
                                         randomize_imu=False)) == SimConfig()


def test_training_config_reaches_the_env_simulator():
    """A train-policy --config JSON with the noise range (tools/configs/policy_sensor_randomized.json)
    builds an env whose simulator draws the levels per episode up to that range."""
    over = json.loads((ROOT / "tools/configs/policy_sensor_randomized.json").read_text())
    cfg = TrainConfig.from_dict({**TrainConfig().to_dict(), "env": {**TrainConfig().to_dict()["env"], **over["env"]}})
    sim = TrainEnv(cfg.env).sim.config
    for k in IMU_FIELDS:
        assert getattr(sim, k) == getattr(cfg.env, k)
    assert sim.randomize_imu and sim.gyro_noise >= 0.05 and sim.accel_noise >= 0.5
    assert sim.gyro_bias >= 0.025 and sim.accel_bias >= 0.25
    assert TrainConfig.from_dict(cfg.to_dict()) == cfg     # round trip (the run's saved config)


def test_collect_flags():
    args = argparse.Namespace(imu_noise=(0.05, 0.5), imu_bias=(0.025, 0.25), imu_vibration=(0.0, 0.0),
                              randomize_imu=True)
    assert imu_config(args) == SimConfig(**RANGE)
    with pytest.raises(ValueError, match="--imu-bias"):
        imu_config(argparse.Namespace(imu_noise=(0, 0), imu_bias=(-1, 0), imu_vibration=(0, 0), randomize_imu=False))
    from mjxsysid.dataset.collect import collect
    with pytest.raises(TypeError, match="sim_config"):
        collect("unused", n_train=1, n_test=1, sim_config={"gyro_noise": 0.05})


def test_a_share_of_clean_flights():
    """imu_clean_fraction: that share of the per-flight draws has a clean IMU (both levels 0, so no
    bias either), the rest draw as before; a bad share or one without randomize_imu is an error
    naming it, in the simulator and in `collect`'s flags."""
    import jax
    from mjxsysid import theta as P
    from mjxsysid.sim import Quadrotor
    sim = Quadrotor(SimConfig(**RANGE, imu_clean_fraction=0.3))
    keys = jax.random.split(jax.random.PRNGKey(0), 1000)
    st = jax.jit(jax.vmap(lambda k: sim.init(P.PAPER_HARDWARE, k)))(keys)
    std, bias = np.asarray(st.imu_std), np.asarray(st.imu_bias)
    level = std[:, :2, 0] / np.array([RANGE["gyro_noise"], RANGE["gyro_bias"]])     # the white noise's, the bias's
    clean = np.all(level == 0, 1)
    assert 0.25 < clean.mean() < 0.35, clean.mean()
    assert np.all(bias[clean] == 0) and level[~clean].min() > 0 and level[~clean].max() < 1
    for bad in (dict(RANGE, imu_clean_fraction=1.5), dict(gyro_noise=0.05, imu_clean_fraction=0.3)):
        with pytest.raises(ValueError, match="imu_clean_fraction"):
            SimConfig(**bad)
    args = argparse.Namespace(imu_noise=(0.05, 0.5), imu_bias=(0.025, 0.25), imu_vibration=(0.0, 0.0),
                              randomize_imu=True, imu_clean_fraction=0.3)
    assert imu_config(args) == SimConfig(**RANGE, imu_clean_fraction=0.3)
    with pytest.raises(ValueError, match="--imu-clean-fraction needs --randomize-imu"):
        imu_config(argparse.Namespace(**{**vars(args), "randomize_imu": False}))


@pytest.mark.slow
def test_tiny_pipeline_with_randomized_imu(tmp_path):
    """collect (randomised IMU) -> train-cfm on those pairs, at tiny size, through the CLI; the
    pairs and the decoder record the IMU range."""
    from mjxsysid.cli import main
    from mjxsysid.dataset.collect import load_pairs
    pairs = tmp_path / "pairs"
    assert main(["collect", "--out", str(pairs), "--train", "6", "--test", "2", "--batch", "4", "--seconds", "1",
                 "--imu-noise", "0.05", "0.5", "--imu-bias", "0.025", "0.25", "--randomize-imu"]) == 0
    arrays, meta = load_pairs(pairs)
    assert meta["imu"]["randomize_imu"] and meta["imu"]["gyro_noise"] == 0.05
    assert np.isfinite(arrays["zhat_traj_train"]).all()


@pytest.mark.slow
def test_tiny_policy_training_with_randomized_imu(tmp_path):
    """Two PPO iterations of the tiny training with the noise range: it runs, finite."""
    from mjxsysid.policy.adaptive.train import train
    tiny = dict(num_envs=64, unroll=16, epochs=2, minibatches=4, log_every=1, checkpoint_every=4,
                warmup=0.3, ramp=0.3)
    res = train(TrainConfig(iterations=2, env=EnvConfig(**RANGE), **tiny), tmp_path, resume=False, log=lambda *a, **k: None)
    assert np.isfinite(res["stats"]["reward"])
