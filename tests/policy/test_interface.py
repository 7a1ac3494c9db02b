"""One interface for frozen latent policies: names, paths, errors, replay, CLI --policy."""
import json

import numpy as np
import pytest
from support.paths import XADAP_DIR

from mjxsysid.cli import main
from mjxsysid.policy.interface import PRETRAINED_DIR, LatentPolicy, resolve_policy


def test_resolve_names_and_paths(tmp_path):
    r = resolve_policy("mjxsysid")
    assert r.kind == "mjxsysid" and r.weights == PRETRAINED_DIR / "policy.npz"
    assert resolve_policy("policy") == r
    assert resolve_policy(str(PRETRAINED_DIR / "policy.npz")) == r           # a path
    assert resolve_policy("mjxsysid", PRETRAINED_DIR).weights == r.weights   # a folder with policy.npz
    assert r.decoders_dir == PRETRAINED_DIR and r.prior == "default"
    assert isinstance(r.load(), LatentPolicy)


@pytest.mark.parametrize("policy, weights, match", [
    ("bogus", None, "unknown policy 'bogus'"),
    ("xadap", None, "needs --weights"),
    ("mjxsysid", "missing.npz", "not found"),
    ("xadap", "missing_dir", "not found"),
    ("xadap", str(PRETRAINED_DIR / "policy.npz"), "not the released Xadap policy"),
    (str(PRETRAINED_DIR / "policy.npz"), str(PRETRAINED_DIR / "policy.npz"), "not both"),
])
def test_resolve_errors(policy, weights, match, monkeypatch):
    monkeypatch.delenv("MJXSYSID_XADAP_DIR", raising=False)
    with pytest.raises((ValueError, FileNotFoundError), match=match):
        resolve_policy(policy, weights)


def test_resolve_rejects_a_folder_that_is_no_policy(tmp_path):
    with pytest.raises(ValueError, match="not a policy"):
        resolve_policy(str(tmp_path))


def test_cli_policy_errors(tmp_path, capsys):
    assert main(["fly", "--controller", "oracle", "--policy", "xadap", "--out", str(tmp_path)]) == 2
    assert "do not apply" in capsys.readouterr().err
    assert main(["decode", "--policy", "nope", "--out", str(tmp_path)]) == 2
    assert "unknown policy 'nope'" in capsys.readouterr().err
    assert main(["replay", "--flights", "lemniscate_5s,loop", "--out", str(tmp_path)]) == 2
    assert "--flights" in capsys.readouterr().err
    from mjxsysid.uses.replay import FLIGHTS
    from mjxsysid.cli._common import FLIGHT_NAMES
    assert FLIGHT_NAMES == tuple(FLIGHTS)


# ---------------------------------------------------------------- the released policy

@pytest.fixture(scope="module")
def xadap_npz(xadap_weights, tmp_path_factory):
    from mjxsysid.policy.xadap.network import save_npz
    p = tmp_path_factory.mktemp("xadap") / "xadap.npz"
    save_npz(xadap_weights, p)
    return p


def test_xadap_by_name_path_and_environment(xadap_npz, monkeypatch):
    by_dir = resolve_policy("xadap", XADAP_DIR)
    by_npz = resolve_policy(str(xadap_npz))
    assert by_dir.kind == by_npz.kind == "xadap"
    assert by_dir.sha256() == by_npz.sha256()       # a digest of the weights, not of the files
    monkeypatch.setenv("MJXSYSID_XADAP_DIR", str(XADAP_DIR))
    assert resolve_policy("xadap") == by_dir
    assert by_dir.decoders_dir == PRETRAINED_DIR / "xadap" and by_dir.prior == "xadap"
    assert isinstance(by_dir.load(), LatentPolicy)
    # The shipped Xadap decoders were trained on exactly these weights' latents.
    meta = json.loads((by_dir.decoders_dir / "cfm.json").read_text())
    assert meta["data"]["pairs_meta"]["weights_sha256"] == by_dir.sha256()


def test_xadap_replay_reproduces_the_flight_latent(xadap_paper_recording):
    """Rebuilding the history from a recorded flight (IMU the policy saw, commands, motor
    commands) gives the latents the policy had in flight."""
    ref, r = xadap_paper_recording
    z = ref.load().replay(r["imu"], r["a_cmd"], r["omega_cmd"], r["motor_cmd"])
    assert np.abs(r["latent"]).max() > 0.1
    np.testing.assert_allclose(z, r["latent"], atol=1e-5)
    # A one-step misalignment of the IMU is detected (the test can fail).
    z_off = ref.load().replay(r["imu_after"], r["a_cmd"], r["omega_cmd"], r["motor_cmd"])
    assert np.abs(z_off - r["latent"]).max() > 1e-3


def test_cli_fly_with_the_released_policy(xadap_paper_recording, tmp_path):
    """`mjxsysid fly --policy xadap --weights DIR` (same flight as the shared recording, so the
    compiled rollout is reused) writes its outputs and names the policy."""
    out = tmp_path / "fly"
    assert main(["fly", "--policy", "xadap", "--weights", str(XADAP_DIR), "--period", "10",
                 "--duration", "2", "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["controller"].startswith("policy xadap") and not m["failed"] and m["pos_rmse_m"] < 0.3
    with np.load(out / "flight.npz") as f:
        np.testing.assert_allclose(f["motor_cmd"], xadap_paper_recording[1]["motor_cmd"], atol=1e-6)
