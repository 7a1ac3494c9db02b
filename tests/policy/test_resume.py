"""Interrupted training resumes from its last checkpoint and ends with exactly the weights of an
uninterrupted run (same seed, CPU): train-cfm (fast) and train-policy (slow, compiles twice)."""
import json

import jax
import numpy as np
import pytest

from mjxsysid.cfm.train import CFMConfig, train_cfm
from mjxsysid.policy.adaptive.config import TrainConfig
from mjxsysid.policy.adaptive.train import _same_config


class Stop(Exception):
    pass


def _interrupt_at(prefix):
    def log(msg):
        if msg.startswith(prefix):
            raise Stop(msg)
    return log


def _leaves_equal(a, b):
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    assert len(la) == len(lb)
    for x, y in zip(la, lb):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


TINY_CFM = CFMConfig(epochs=6, batch=32, width=16, blocks=1, time_dim=8, seed=3)


def _toy_pairs(n=256, seed=0):
    rng = np.random.default_rng(seed)
    z = rng.normal(size=(n, 8)).astype(np.float32)
    th = z @ rng.normal(size=(8, 19)) * 0.3 + 0.1 * rng.normal(size=(n, 19))
    return th.astype(np.float32), z


def test_cfm_resume_gives_the_uninterrupted_weights(tmp_path, monkeypatch, capsys):
    th, z = _toy_pairs()
    ref, hist_ref = train_cfm(th, z, TINY_CFM, log=None)
    ckpt = tmp_path / "cfm.ckpt.npz"
    with pytest.raises(Stop):  # killed while logging epoch 5: the checkpoint holds epoch 4
        train_cfm(th, z, TINY_CFM, log=_interrupt_at("[cfm] epoch 5/"), checkpoint=ckpt, checkpoint_every=2)
    assert ckpt.is_file()
    lines = []
    capsys.readouterr()
    monkeypatch.setenv("MJXSYSID_PROGRESS", "1")  # the bar, as on a terminal: resumes at epoch 4 of 6
    got, hist = train_cfm(th, z, TINY_CFM, log=lines.append, checkpoint=ckpt, checkpoint_every=2)
    err = capsys.readouterr().err
    assert "train cfm" in err and "4/6" in err and "6/6" in err and "train=" in err, err
    assert any("resumed from" in m and "epoch 4" in m for m in lines), lines
    _leaves_equal(got, ref)
    assert hist["train_loss"] == hist_ref["train_loss"] and hist["epoch"] == list(range(1, 7))
    # A checkpoint of another config or data set is refused, not silently mixed in.
    with pytest.raises(ValueError, match="another config or data"):
        train_cfm(th[:200], z[:200], TINY_CFM, log=None, checkpoint=ckpt)


def test_train_decoders_resumes_and_keeps_finished_decoders(tmp_path):
    """The pipeline: an interrupted regression run resumes; the finished CFM is kept, not retrained."""
    from mjxsysid import theta as P
    from mjxsysid.cfm.pipeline import train_decoders
    rng = np.random.default_rng(0)
    theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(0), 300))
    z = rng.normal(size=(300, 8)).astype(np.float32)
    pairs = tmp_path / "pairs.npz"
    np.savez(pairs, theta_train=theta[:256], zhat_train=z[:256], theta_test=theta[256:], zhat_test=z[256:],
             meta_json=np.frombuffer(json.dumps({"prior": "default"}).encode(), np.uint8))
    out = tmp_path / "dec"
    cfg = TINY_CFM.replace(epochs=4)
    with pytest.raises(Stop):
        train_decoders(pairs, out, cfg, log=_interrupt_at("[regression] epoch 3/"), checkpoint_every=1)
    assert (out / "cfm.npz").is_file() and (out / "regression.ckpt.npz").is_file()
    assert not (out / "cfm.ckpt.npz").exists()
    lines = []
    train_decoders(pairs, out, cfg, log=lines.append, checkpoint_every=1)
    assert any("cfm.npz is already trained" in m for m in lines)
    assert any("[regression] resumed from" in m and "epoch 2" in m for m in lines)
    assert not (out / "regression.ckpt.npz").exists()
    from mjxsysid.cfm.sample import Decoder
    assert Decoder.load(out / "regression.npz").meta["final_train_loss"] > 0



def test_sequence_decoder_resume_gives_the_uninterrupted_weights(tmp_path):
    """train-cfm's sequence decoder (cfm_seq) checkpoints and resumes like the CFM (through the
    pipeline, as `mjxsysid train-cfm` runs it: one compiled config), and the pipeline keeps a
    finished cfm_seq.npz."""
    from mjxsysid import theta as P
    from mjxsysid.cfm.pipeline import train_decoders
    from mjxsysid.cfm.sequence import SequenceDecoder, train_seq_cfm
    rng = np.random.default_rng(1)
    theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(0), 160))
    zt = rng.normal(size=(160, 5, 8)).astype(np.float32)
    pairs = tmp_path / "pairs.npz"
    np.savez(pairs, theta_train=theta[:128], zhat_train=zt[:128, -1], theta_test=theta[128:],
             zhat_test=zt[128:, -1], zhat_traj_train=zt[:128], zhat_traj_test=zt[128:],
             traj_times=0.2 + 0.1 * np.arange(5),
             meta_json=np.frombuffer(json.dumps({"prior": "default"}).encode(), np.uint8))
    small = TINY_CFM.replace(epochs=4)
    seq_over = {"set_width": 8, "heads": 2, "cond_dim": 8}

    def run(out, **kw):
        return train_decoders(pairs, out, small, kinds=("cfm_seq",), seq_cfg=seq_over, checkpoint_every=1, **kw)

    ref = run(tmp_path / "ref", log=None)
    out = tmp_path / "dec"
    ckpt = out / "cfm_seq.ckpt.npz"
    with pytest.raises(Stop):
        run(out, log=_interrupt_at("[cfm_seq] epoch 3/"))
    assert ckpt.is_file() and not (out / "cfm_seq.npz").exists()
    cfg = SequenceDecoder.load(tmp_path / "ref" / "cfm_seq.npz").cfg
    with pytest.raises(ValueError, match="another config or data"):
        train_seq_cfm(rng.normal(size=(100, 19)).astype(np.float32), zt[:100], cfg, log=None, checkpoint=ckpt)
    lines = []
    got = run(out, log=lines.append)
    assert any("resumed from" in m and "epoch 2" in m for m in lines), lines
    _leaves_equal(SequenceDecoder.load(out / "cfm_seq.npz").params,
                  SequenceDecoder.load(tmp_path / "ref" / "cfm_seq.npz").params)
    for k in ("final_train_loss", "final_val_loss"):
        assert got["cfm_seq"][k] == ref["cfm_seq"][k], k
    assert not ckpt.exists()
    lines = []
    res = run(out, log=lines.append)
    assert any("cfm_seq.npz is already trained" in m for m in lines), lines
    assert res["cfm_seq"]["final_train_loss"] == SequenceDecoder.load(out / "cfm_seq.npz").meta["final_train_loss"]


@pytest.mark.slow
def test_policy_resume_gives_the_uninterrupted_weights(tmp_path):
    """Slow (two compiles of a PPO iteration, ≈ 2–3 min on a 2-core CPU). The environments'
    state is in the checkpoint, so a resumed run continues bit for bit (and the iteration compiled
    in the background computes what the jitted one does)."""
    from mjxsysid.runtime.checkpoint import load_tree
    from mjxsysid.policy.adaptive.weights import POLICY_MODULES
    from mjxsysid.policy.adaptive.train import train
    from mjxsysid.policy.adaptive import networks as N
    cfg = TrainConfig(iterations=6, num_envs=32, unroll=8, epochs=1, minibatches=2, log_every=1,
                      checkpoint_every=2)
    # The uninterrupted run on the jitted path, the cut and resumed one compiled in the background.
    train(cfg, tmp_path / "full", resume=False, log=lambda m: None, background_compile=False)
    with pytest.raises(Stop):  # killed while logging iteration 5: the checkpoint holds iteration 4
        train(cfg, tmp_path / "cut", resume=False, log=_interrupt_at("it     5/"))
    lines = []
    train(cfg, tmp_path / "cut", resume=True, log=lines.append)
    assert any("resumed from" in m and "iteration 4" in m for m in lines), lines[:2]
    tmpl = N.Networks().init(jax.random.PRNGKey(0))
    tmpl = {k: tmpl[k] for k in POLICY_MODULES}
    _leaves_equal(load_tree(tmp_path / "cut" / "policy.npz", tmpl, finite=True),
                  load_tree(tmp_path / "full" / "policy.npz", tmpl, finite=True))


TINY_TRAIN = dict(num_envs=64, unroll=16, epochs=2, minibatches=4, log_every=1, checkpoint_every=2)


def test_checkpoints_written_before_init_from_still_resume():
    cfg = TrainConfig(iterations=2, **TINY_TRAIN)
    saved = json.loads(json.dumps(cfg.to_dict()))
    saved.pop("init_from")
    assert _same_config(saved, cfg)
    assert not _same_config({**saved, "iterations": 3}, cfg) and not _same_config(None, cfg)
    assert not _same_config({**saved, "init_from": "x.npz"}, cfg)
