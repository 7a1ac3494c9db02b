"""ONNX export of mjxsysid's policy (issue 12 §1): the files, parity with the JAX controller on
recorded flight inputs (batch 1 free running, dynamic batch 3), the documented layout, errors."""
import json

import numpy as np
import pytest

pytest.importorskip("jax2onnx")
ort = pytest.importorskip("onnxruntime")
onnx = pytest.importorskip("onnx")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

TOL = 1e-5


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """`mjxsysid export` of the shipped policy into a tmp folder (few timing calls). Its 2 s
    flight is the 2 s policy lemniscate of tests/test_api.py and test_decode.py, whose compile
    the persistent cache then holds."""
    from mjxsysid.cli import main
    out = tmp_path_factory.mktemp("export") / "policy.onnx"
    rc = main(["export", "--out", str(out), "--seconds", "2", "--calls", "20"])
    meta = json.loads((out.parent / "policy.onnx.json").read_text())
    vec = dict(np.load(out.parent / "policy_testvectors.npz"))
    return rc, out, meta, vec


def _session(path):
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


@pytest.fixture(scope="module")
def jax_run(exported):
    """The JAX controller itself stepped over the recorded inputs: its state before and its
    outputs after every step."""
    from mjxsysid.control.low_level import Command
    from mjxsysid.policy.adaptive.controller import PolicyController
    vec = exported[3]
    ctrl = PolicyController.load()

    def body(carry, x):
        i, u, c = x
        new, motor = ctrl.step_at(carry, u, Command(c[0], c[1:4]), i)
        return new, (carry.history, carry.zhat, motor, new.zhat, new.history)

    n = vec["imu"].shape[0]
    out = jax.jit(lambda xs: jax.lax.scan(body, ctrl.init(), xs)[1])(
        (jnp.arange(n), jnp.asarray(vec["imu"]), jnp.asarray(vec["command"])))
    return ctrl, dict(zip(("history", "latent", "motor", "latent_next", "history_next"), map(np.asarray, out)))


def test_export_writes_both_files_and_a_complete_description(exported):
    from mjxsysid.policy.interface import PRETRAINED_DIR, file_sha256
    rc, out, meta, _ = exported
    assert rc == 0
    assert (out.parent / "policy_dynamic.onnx").is_file()
    assert meta["weights_sha256"] == file_sha256(PRETRAINED_DIR / "policy.npz")
    assert meta["rate_hz"] == 500.0 and meta["phi_every"] == 10 and len(meta["motor_order"]) == 4
    assert meta["parity"]["ok"] and meta["parity"]["max_abs_diff"] <= TOL
    assert meta["parity"]["refresh_steps"] == 100  # 2 s = 1000 steps, ẑ refreshed every 10th
    lat = meta["latency"]["batch_1"]
    assert lat["step_us"]["median_us"] > 0 and lat["refresh_step_us"]["median_us"] > 0
    # φ (the convolutions) lives only inside the If on `refresh`, so other steps skip it
    g = onnx.load(out).graph
    assert "Conv" not in {n.op_type for n in g.node}
    (cond,) = [n for n in g.node if n.op_type == "If" and n.input[0] == "refresh"]
    branches = {a.name: {n.op_type for n in a.g.node} for a in cond.attribute}
    assert "Conv" in branches["then_branch"] and "Conv" not in branches["else_branch"]
    # the documented names, shapes and dtypes are the graphs' own
    dt = {1: "float32", 9: "bool"}
    for file, key, b in ((out, "shape", 1), (out.parent / "policy_dynamic.onnx", "dynamic_shape", "B")):
        g = onnx.load(file).graph
        for doc, vi in ((meta["inputs"], g.input), (meta["outputs"], g.output)):
            got = [(v.name, [d.dim_param or d.dim_value for d in v.type.tensor_type.shape.dim],
                    dt[v.type.tensor_type.elem_type]) for v in vi]
            assert got == [(d["name"], d[key], d["dtype"]) for d in doc]
            assert all(d[key][0] == b for d in doc if d[key])


def test_free_running_onnx_matches_the_jax_controller_on_a_recorded_flight(exported, jax_run):
    _, out, _, vec = exported
    _, ref = jax_run
    # the test vectors are the controller's own outputs on the recorded inputs
    assert np.max(np.abs(vec["motor"] - ref["motor"])) <= TOL
    sess = _session(out)
    h, z = np.zeros((1, 100, 14), np.float32), np.zeros((1, 8), np.float32)
    motors, latents = [], []
    for t in range(vec["imu"].shape[0]):
        m, z, h = sess.run(None, {"imu": vec["imu"][t:t + 1], "command": vec["command"][t:t + 1],
                                  "history": h, "latent": z, "reset": np.array([t == 0]),
                                  "refresh": np.array((t + 1) % 10 == 0)})
        motors.append(m[0])
        latents.append(z[0])
    assert np.max(np.abs(np.array(motors) - ref["motor"])) <= TOL
    assert np.max(np.abs(np.array(latents) - ref["latent_next"])) <= TOL
    assert np.ptp(ref["latent_next"][-1] - ref["latent_next"][10]) > 1e-3  # ẑ really moved


@pytest.mark.parametrize("refresh", [False, True])
def test_dynamic_batch_of_three(exported, jax_run, refresh):
    from mjxsysid.policy.adaptive.networks import Networks
    _, out, _, vec = exported
    ctrl, ref = jax_run
    idx = np.array([0, 17, 33])  # step 0 carries reset; the others continue from the recorded state
    f = {"imu": vec["imu"][idx], "command": vec["command"][idx], "history": ref["history"][idx],
         "latent": ref["latent"][idx], "reset": np.array([True, False, False]), "refresh": np.array(refresh)}
    m, z, h = _session(out.parent / "policy_dynamic.onnx").run(None, f)
    assert m.shape == (3, 4) and z.shape == (3, 8) and h.shape == (3, 100, 14)
    assert np.max(np.abs(m - ref["motor"][idx])) <= TOL
    assert np.max(np.abs(h - ref["history_next"][idx])) <= TOL
    phi = jax.jit(lambda h: Networks().adapt(ctrl.params, h))
    want = np.asarray(phi(ref["history_next"][idx])) if refresh else ref["latent"][idx]
    assert np.max(np.abs(z - want)) <= TOL
    # each row equals the batch-1 file run on that row alone
    one = _session(out)
    for i in range(3):
        r = one.run(None, {k: (v[i:i + 1] if v.ndim else v) for k, v in f.items()})
        assert np.max(np.abs(r[0] - m[i:i + 1])) <= 1e-6 and np.max(np.abs(r[1] - z[i:i + 1])) <= 1e-6


def test_documented_scaling_and_action_mapping(exported):
    """The JSON's normalisation, history row and action mapping are what the graph does."""
    _, out, meta, vec = exported
    nz = meta["observation"]
    x = np.concatenate([vec["imu"][:20], vec["command"][:20]], -1)
    h = np.zeros((20, 100, 14), np.float32)
    m, _, hn = _session(out.parent / "policy_dynamic.onnx").run(None, {
        "imu": vec["imu"][:20], "command": vec["command"][:20], "history": h,
        "latent": np.zeros((20, 8), np.float32), "reset": np.ones(20, bool), "refresh": np.array(False)})
    obs = (x - np.array(nz["shift"])) / np.array(nz["scale"])
    assert np.max(np.abs(hn[:, -1, :10] - obs)) <= 1e-6
    assert np.max(np.abs(hn[:, 0, :10] - obs)) <= 1e-6 and np.all(hn[:, 0, 10:] == 0)  # reset fill
    assert np.max(np.abs(m - np.clip((hn[:, -1, 10:] + 1) / 2, 0, 1))) <= 1e-6
    assert nz["scale"] == [4, 4, 4, 10, 10, 10, 10, 4, 4, 4] and nz["shift"][5] == nz["shift"][6] == 9.81


@pytest.mark.parametrize("case", ["suffix", "parent_is_file", "out_is_dir", "unknown_policy", "xadap",
                                  "calls"])
def test_bad_arguments_exit_2(tmp_path, capsys, monkeypatch, case):
    from mjxsysid.cli import main
    monkeypatch.delenv("MJXSYSID_XADAP_DIR", raising=False)
    (tmp_path / "file").write_text("x")
    (tmp_path / "dir.onnx").mkdir()
    xa = tmp_path / "xadap"
    xa.mkdir()
    for f in ("encoder.onnx", "mlp.onnx"):
        (xa / f).write_bytes(b"")
    out = str(tmp_path / "p.onnx")
    argv, word = {
        "suffix": (["--out", str(tmp_path / "p.txt")], ".onnx"),
        "parent_is_file": (["--out", str(tmp_path / "file" / "p.onnx")], "not a folder"),
        "out_is_dir": (["--out", str(tmp_path / "dir.onnx")], "is a folder"),
        "unknown_policy": (["--policy", "nosuch", "--out", out], "unknown policy 'nosuch'"),
        "xadap": (["--policy", "xadap", "--weights", str(xa), "--out", out], "already is ONNX"),
        "calls": (["--calls", "3", "--out", out], "--calls"),
    }[case]
    assert main(["export", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and word in err[0] and err[0].startswith("mjxsysid export: error:")
    assert not (tmp_path / "p.onnx").exists()
