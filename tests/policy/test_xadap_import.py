"""Parity of the pure-JAX Xadap importer (mjxsysid.policy.xadap) with onnxruntime.

Needs the released policy files (env var MJXSYSID_XADAP_DIR, default
``<repo>/../shared/external/xadap``) and the optional ``onnx`` + ``onnxruntime`` packages;
the tests that need them skip with a message otherwise.
"""
from __future__ import annotations

import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxsysid.policy.xadap import network as xadap
from mjxsysid.policy.xadap.network import (
    build_history_input,
    load_npz,
    normalize_state,
    save_npz,
    xadap_encoder,
    xadap_policy,
)
from mjxsysid.policy.xadap.onnx_import import load_xadap

from support.paths import XADAP_DIR, have as _have, require_xadap

N_SAMPLES = 64
TOL = 1e-5


needs_files = pytest.mark.skipif(
    not XADAP_DIR.is_dir(),
    reason=f"Xadap policy files not found at {XADAP_DIR} (set MJXSYSID_XADAP_DIR)")
needs_onnx = pytest.mark.skipif(not _have("onnx"), reason="onnx not installed (pip install onnx)")
needs_ort = pytest.mark.skipif(
    not _have("onnxruntime"), reason="onnxruntime not installed (pip install onnxruntime)")


@pytest.fixture(scope="module")
def weights(xadap_weights):
    return xadap_weights


@pytest.fixture(scope="module")
def sessions():
    require_xadap("onnxruntime")
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    enc = ort.InferenceSession(str(XADAP_DIR / "encoder.onnx"), opts,
                               providers=["CPUExecutionProvider"])
    pol = ort.InferenceSession(str(XADAP_DIR / "mlp.onnx"), opts,
                               providers=["CPUExecutionProvider"])

    def run(sess, x):  # graphs have a fixed batch of 1: one call per sample
        name = sess.get_inputs()[0].name
        return np.concatenate([sess.run(None, {name: xi[None]})[0] for xi in x])

    return {"encoder": lambda x: run(enc, x), "policy": lambda x: run(pol, x)}


def _realistic_history(w, rng, n):
    """Normalised histories from plausible raw states/actions, via build_history_input."""
    s = np.zeros((n, 100, 8), np.float32)
    s[..., 0:3] = rng.normal(0.0, 1.5, (n, 100, 3))  # body rates
    s[..., 3] = 9.8 + rng.normal(0.0, 2.0, (n, 100))  # specific force z
    s[..., 4:7] = rng.normal(0.0, 1.5, (n, 100, 3))  # commanded rates
    s[..., 7] = 9.8 + rng.normal(0.0, 2.0, (n, 100))  # commanded thrust
    a = np.tanh(rng.normal(0.0, 0.6, (n, 100, 4))).astype(np.float32)
    return np.asarray(jax.vmap(build_history_input, (None, 0, 0))(w, s, a))


def _encoder_inputs(w, seed=0):
    rng = np.random.default_rng(seed)
    half = N_SAMPLES // 2
    noise = rng.normal(0.0, 1.5, (half, 1200)).astype(np.float32)
    return np.concatenate([noise, _realistic_history(w, rng, N_SAMPLES - half)]).astype(np.float32)


def _policy_inputs(seed=1):
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, 1.5, (N_SAMPLES, 20)).astype(np.float32)
    x[:, 12:] = np.tanh(x[:, 12:])  # latents live in (-1, 1)
    return x


# ------------------------------------------------------------------------------ parity


@needs_files
@needs_onnx
@needs_ort
def test_encoder_parity_onnxruntime(weights, sessions):
    x = _encoder_inputs(weights)
    ref = sessions["encoder"](x)
    got = np.asarray(jax.jit(jax.vmap(xadap_encoder, (None, 0)))(weights, x))
    assert got.shape == ref.shape == (N_SAMPLES, 8) and got.dtype == np.float32
    err = np.abs(got - ref).max()
    print(f"encoder max abs err {err:.3g}")
    assert err <= TOL


@needs_files
@needs_onnx
@needs_ort
def test_policy_parity_onnxruntime(weights, sessions):
    x = _policy_inputs()
    ref = sessions["policy"](x)
    got = np.asarray(jax.jit(jax.vmap(xadap_policy, (None, 0)))(weights, x))
    assert got.shape == ref.shape == (N_SAMPLES, 4) and got.dtype == np.float32
    err = np.abs(got - ref).max()
    print(f"policy max abs err {err:.3g}")
    assert err <= TOL
    assert np.all(np.abs(got) <= 1.0)


@needs_files
@needs_onnx
@needs_ort
def test_full_pipeline_parity(weights, sessions):
    """normalize_state + build_history_input + encoder + policy vs the same chain in ORT."""
    rng = np.random.default_rng(3)
    hist = _realistic_history(weights, rng, 8)
    s12 = np.concatenate([rng.normal(0, 1, (8, 3)), 9.8 + rng.normal(0, 1, (8, 1)),
                          rng.normal(0, 1, (8, 3)), 9.8 + rng.normal(0, 1, (8, 1)),
                          np.tanh(rng.normal(0, 0.5, (8, 4)))], axis=1).astype(np.float32)

    @jax.jit
    def act(w, s12, hist):
        z = xadap_encoder(w, hist)
        return xadap_policy(w, jnp.concatenate([normalize_state(w, s12), z], -1)), z

    got, z = jax.vmap(act, (None, 0, 0))(weights, s12, hist)
    z_ref = sessions["encoder"](hist)
    obs_n = ((s12 - weights.mean[:12]) / np.sqrt(weights.var[:12] + 1e-8)).astype(np.float32)
    ref = sessions["policy"](np.concatenate([obs_n, z_ref], 1).astype(np.float32))
    assert np.abs(np.asarray(z) - z_ref).max() <= TOL
    assert np.abs(np.asarray(got) - ref).max() <= TOL


@needs_files
@needs_onnx
@needs_ort
def test_second_reshape_is_not_a_transpose(weights, sessions):
    """Negative control: reading (100, 32) -> (1, 32, 100) as a transpose breaks parity."""
    x = _encoder_inputs(weights)[:8]
    ref = sessions["encoder"](x)

    def transposed(w, xf):
        h = jnp.tanh(xf.reshape(100, 12) @ w.enc_in_w.T + w.enc_in_b).T[None]  # WRONG on purpose
        for cw, cb, s in ((w.enc_conv0_w, w.enc_conv0_b, 4), (w.enc_conv1_w, w.enc_conv1_b, 1),
                          (w.enc_conv2_w, w.enc_conv2_b, 1)):
            h = jax.lax.conv_general_dilated(h, cw, (s,), "VALID",
                                             dimension_numbers=("NCH", "OIH", "NCH"))
            h = h + cb[None, :, None]
            h = jnp.where(h >= 0, h, 0.01 * h)
        return jnp.tanh(w.enc_out_w @ h.reshape(-1) + w.enc_out_b)

    bad = np.asarray(jax.vmap(transposed, (None, 0))(weights, x))
    assert np.abs(bad - ref).max() > 1e-2


# ------------------------------------------------------------------------------ JAX behaviour


@needs_files
@needs_onnx
def test_vmap_equals_per_sample_and_jit(weights):
    xe = _encoder_inputs(weights)[:16]
    xp = _policy_inputs()[:16]
    for fn, x in ((xadap_encoder, xe), (xadap_policy, xp)):
        batched = np.asarray(jax.vmap(fn, (None, 0))(weights, x))
        single = np.stack([np.asarray(fn(weights, xi)) for xi in x])
        jitted = jax.jit(fn)
        single_jit = np.stack([np.asarray(jitted(weights, xi)) for xi in x])
        lead = np.asarray(fn(weights, x.reshape(4, 4, -1))).reshape(16, -1)  # leading dims
        np.testing.assert_allclose(batched, single, rtol=0, atol=1e-6)
        np.testing.assert_allclose(single_jit, single, rtol=0, atol=1e-6)
        np.testing.assert_allclose(lead, single, rtol=0, atol=1e-6)
    # weights are a pytree: passing them as a traced jit argument works too
    leaves = jax.tree_util.tree_leaves(weights)
    assert len(leaves) == 27
    assert jax.jit(lambda w, x: xadap_policy(w, x))(weights, xp[0]).shape == (4,)
    assert jax.jit(xadap_encoder)(weights, xe[0]).shape == (8,)


@needs_files
@needs_onnx
def test_history_layout_matches_published_wrapper(weights):
    """build_history_input == the wrapper's normalize_obs(ADAP_MODULE) (tile over time)."""
    rng = np.random.default_rng(5)
    s = rng.normal(0, 3, (100, 8))
    a = np.tanh(rng.normal(0, 1, (100, 4)))
    mean, var = np.asarray(weights.mean), np.asarray(weights.var)
    flat = np.concatenate([s.reshape(-1), a.reshape(-1)])[None]  # [s oldest first, a]
    sm, sv = np.tile(mean[:8], [1, 100]), np.tile(var[:8], [1, 100])
    am, av = np.tile(mean[8:12], [1, 100]), np.tile(var[8:12], [1, 100])
    ref = np.concatenate([(flat[:, :800] - sm) / np.sqrt(sv + 1e-8),
                          (flat[:, 800:] - am) / np.sqrt(av + 1e-8)], 1)[0]
    got = np.asarray(build_history_input(weights, s.astype(np.float32), a.astype(np.float32)))
    assert got.shape == (1200,)
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-5)
    # most recent state is at the end of the state block (row 99 -> entries 792..799)
    np.testing.assert_allclose(got[792:800], ref[792:800], rtol=1e-5, atol=1e-5)
    s12 = np.concatenate([s[-1], a[-1]]).astype(np.float32)
    np.testing.assert_allclose(np.asarray(normalize_state(weights, s12)),
                               (s12 - mean[:12]) / np.sqrt(var[:12] + 1e-8), rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(weights.obs_mean, mean[:12])
    np.testing.assert_array_equal(weights.obs_var, var[:12])
    assert weights.mean.shape == weights.var.shape == (46,)


# ------------------------------------------------------------------------------ npz, errors


@needs_files
@needs_onnx
def test_npz_round_trip_is_exact(weights, tmp_path):
    p = tmp_path / "xadap.npz"
    save_npz(weights, p)
    w2 = load_npz(p)
    for k in weights.__dataclass_fields__:
        a, b = np.asarray(getattr(weights, k)), np.asarray(getattr(w2, k))
        assert a.dtype == b.dtype and a.shape == b.shape, k
        np.testing.assert_array_equal(a, b, err_msg=k)
    x = _policy_inputs()[:4]
    np.testing.assert_array_equal(np.asarray(jax.vmap(xadap_policy, (None, 0))(weights, x)),
                                  np.asarray(jax.vmap(xadap_policy, (None, 0))(w2, x)))
    with np.load(p, allow_pickle=False) as z:  # no object arrays inside
        assert all(z[k].dtype != object for k in z.files)


def test_bad_path_errors(tmp_path):
    missing = tmp_path / "nope"
    with pytest.raises(FileNotFoundError, match="nope"):
        load_xadap(missing)
    with pytest.raises(FileNotFoundError, match="encoder.onnx"):
        load_xadap(tmp_path)  # directory exists but is empty
    with pytest.raises(FileNotFoundError, match="missing.npz"):
        load_npz(tmp_path / "missing.npz")
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="not an Xadap weights file"):
        load_npz(tmp_path / "other.npz")


@needs_files
def test_missing_single_file_and_bad_stats(tmp_path):
    d = tmp_path / "x"
    d.mkdir()
    for n in ("encoder.onnx", "mlp.onnx", "mean.csv"):
        shutil.copy(XADAP_DIR / n, d / n)
    with pytest.raises(FileNotFoundError, match="var.csv"):
        load_xadap(d)
    if not _have("onnx"):
        pytest.skip("onnx not installed (pip install onnx)")
    (d / "var.csv").write_text(" ".join(["1.0"] * 45) + "\n")
    with pytest.raises(ValueError, match="var.csv.*46"):
        load_xadap(d)


@needs_files
@needs_onnx
def test_unexpected_graph_structure_is_rejected(tmp_path):
    import onnx

    d = tmp_path / "x"
    shutil.copytree(XADAP_DIR, d)
    m = onnx.load(str(d / "encoder.onnx"))
    conv = next(n for n in m.graph.node if n.op_type == "Conv")
    for a in conv.attribute:
        if a.name == "strides":
            a.ints[:] = [2]
    (d / "encoder.onnx").chmod(0o644)
    onnx.save(m, str(d / "encoder.onnx"))
    with pytest.raises(ValueError, match=r"encoder\.onnx: unexpected graph structure.*Conv"):
        load_xadap(d)


@needs_files
@needs_onnx
def test_wrong_input_shapes(weights):
    with pytest.raises(ValueError, match="1200"):
        xadap_encoder(weights, jnp.zeros(1199))
    with pytest.raises(ValueError, match="20"):
        xadap_policy(weights, jnp.zeros(12))
    with pytest.raises(ValueError, match="states"):
        build_history_input(weights, jnp.zeros((8, 100)), jnp.zeros((100, 4)))
    assert xadap.HISTORY_DIM == 1200 and xadap.POLICY_INPUT_DIM == 20
