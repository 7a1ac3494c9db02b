"""Tests of the CFM decoder (mjxsysid.cfm): path, networks, sampler, training on a bimodal toy,
calibration metrics, save/load, errors. Small widths and few epochs: fast on CPU."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.cfm import (CFMConfig, Decoder, GaussianSmoothedLinearPath, count_params,
                          init_params, load_decoder, random_baseline, save_decoder, train_cfm,
                          train_regression)
from mjxsysid.cfm import calibration as C
from mjxsysid.cfm.flow_coords import FlowNormalizer, decoder_normalizer
from mjxsysid.cfm.sample import METHODS, point, sample
from mjxsysid.render.posterior import plot_rank_histograms

TINY = CFMConfig(width=32, blocks=1, time_dim=16, epochs=2, batch=128)


# ----------------------------------------------------------------------------------------
# Path
# ----------------------------------------------------------------------------------------

def test_path_closed_forms():
    path = GaussianSmoothedLinearPath()
    assert (path.sigma, path.tau_max) == (0.05, 0.95)
    k = jax.random.split(jax.random.PRNGKey(0), 4)
    x0, x1, e1, e2 = (jax.random.normal(kk, (7, 19)) for kk in k)
    xt, u = path.sample_location_and_flow(x0, x1, jnp.zeros(7), e1)
    np.testing.assert_allclose(xt, x0 + 0.05 * e1, atol=1e-6)
    np.testing.assert_allclose(u, x1 - x0, atol=1e-6)
    xt, _ = path.sample_location_and_flow(x0, x1, jnp.ones(7), e1)
    np.testing.assert_allclose(xt, x1 + 0.05 * e1, atol=1e-6)
    xt, _ = path.sample_location_and_flow(x0, x1, 0.25, e1)  # scalar τ broadcasts
    np.testing.assert_allclose(xt, 0.75 * x0 + 0.25 * x1 + 0.05 * e1, atol=1e-6)
    _, u1 = path.sample_location_and_flow(x0, x1, jnp.full(7, 0.3), e1)
    _, u2 = path.sample_location_and_flow(x0, x1, jnp.full(7, 0.7), e2)
    np.testing.assert_array_equal(u1, u2)  # u independent of ε and τ
    tau = np.asarray(path.sample_tau(jax.random.PRNGKey(1), 20000))
    assert tau.shape == (20000,) and tau.min() >= 0.0 and tau.max() <= 0.95
    assert tau.max() > 0.94 and abs(tau.mean() - 0.475) < 0.01
    with pytest.raises(ValueError):
        GaussianSmoothedLinearPath(sigma=-1.0)
    with pytest.raises(ValueError):
        GaussianSmoothedLinearPath(tau_max=1.5)


# ----------------------------------------------------------------------------------------
# Networks and sampler
# ----------------------------------------------------------------------------------------

def test_paper_size_parameter_count():
    shapes = jax.eval_shape(lambda: init_params(CFMConfig(), "cfm"))
    n = count_params(shapes)
    assert n == 5_179_667 and 4.5e6 < n < 5.5e6
    assert count_params(jax.eval_shape(lambda: init_params(CFMConfig(), "regression"))) == 4_747_795


def test_sampler_shapes_and_determinism():
    params = init_params(TINY, "cfm")
    z = jax.random.normal(jax.random.PRNGKey(2), (3, 8))
    for method in METHODS:
        a = sample(params, TINY, z, jax.random.PRNGKey(0), 5, steps=4, method=method)
        b = sample(params, TINY, z, jax.random.PRNGKey(0), 5, steps=4, method=method)
        c = sample(params, TINY, z, jax.random.PRNGKey(1), 5, steps=4, method=method)
        assert a.shape == (3, 5, 19) and bool(jnp.all(jnp.isfinite(a)))
        np.testing.assert_array_equal(a, b)
        assert not np.allclose(a, c)
    # jit-able end to end
    f = jax.jit(lambda p, zz, k: sample(p, TINY, zz, k, 2, steps=3))
    assert f(params, z, jax.random.PRNGKey(0)).shape == (3, 2, 19)
    assert point(init_params(TINY, "regression"), TINY, z).shape == (3, 19)


def test_errors():
    params = init_params(TINY, "cfm")
    key = jax.random.PRNGKey(0)
    with pytest.raises(ValueError, match=r"\(m, 8\)"):
        sample(params, TINY, jnp.zeros((3, 7)), key, 2)
    with pytest.raises(ValueError, match=r"\(m, 8\)"):
        sample(params, TINY, jnp.zeros(8), key, 2)
    with pytest.raises(ValueError, match="unknown ODE method"):
        sample(params, TINY, jnp.zeros((1, 8)), key, 2, method="rk4")
    with pytest.raises(ValueError, match=r"\(n, 19\)"):
        train_cfm(np.zeros((10, 18)), np.zeros((10, 8)), TINY, log=None)
    with pytest.raises(ValueError, match=r"\(n, 8\)"):
        train_regression(np.zeros((10, 19)), np.zeros((10, 3)), TINY, log=None)
    with pytest.raises(ValueError, match="different lengths"):
        train_cfm(np.zeros((10, 19)), np.zeros((9, 8)), TINY, log=None)
    with pytest.raises(ValueError, match="unknown decoder kind"):
        init_params(TINY, "gan")
    with pytest.raises(ValueError, match="unknown CFMConfig key"):
        CFMConfig.from_dict({"widht": 3})
    with pytest.raises(ValueError):
        CFMConfig(epochs=0)
    with pytest.raises(ValueError, match="samples must have shape"):
        C.coverage(np.zeros((4, 19)), np.zeros((4, 19)))
    with pytest.raises(ValueError, match="truths must have shape"):
        C.coverage(np.zeros((4, 10, 19)), np.zeros((4, 18)))
    dec = Decoder("regression", init_params(TINY, "regression"), TINY, None)
    with pytest.raises(ValueError, match="'cfm' decoder"):
        dec.sample_theta(np.zeros(8), key, 3)


# ----------------------------------------------------------------------------------------
# Bimodal toy: CFM keeps both modes, regression collapses to the mean
# ----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def bimodal():
    rng = np.random.default_rng(0)
    n = 4096
    z = rng.uniform(-1, 1, (n, 1)).astype(np.float32)
    sign = rng.choice([-1.0, 1.0], (n, 1))
    x = (sign * (1.0 + 0.5 * z) * np.ones((1, 2)) + 0.05 * rng.standard_normal((n, 2))).astype(np.float32)
    cfg = CFMConfig(theta_dim=2, z_dim=1, width=64, blocks=2, time_dim=32, epochs=20, lr=2e-3)
    p_cfm, hist = train_cfm(x, z, cfg, log=None)
    p_reg, _ = train_regression(x, z, cfg, log=None, early_stopping=False)
    return cfg, p_cfm, p_reg, hist


def test_cfm_recovers_both_modes_regression_collapses(bimodal):
    cfg, p_cfm, p_reg, hist = bimodal
    assert hist["train_loss"][-1] < hist["train_loss"][0]
    zq = np.array([[-0.5], [0.5]], np.float32)
    s = np.asarray(sample(p_cfm, cfg, zq, jax.random.PRNGKey(1), 1000))
    r = np.asarray(point(p_reg, cfg, zq))
    for i in range(2):
        mode = (1.0 + 0.5 * zq[i, 0]) * np.ones(2)
        near_pos = np.linalg.norm(s[i] - mode, axis=-1) < 0.3
        near_neg = np.linalg.norm(s[i] + mode, axis=-1) < 0.3
        assert 0.3 <= near_pos.mean() <= 0.7, near_pos.mean()
        assert 0.3 <= near_neg.mean() <= 0.7, near_neg.mean()
        assert (near_pos | near_neg).mean() > 0.8
        # regression predicts ≈ the conditional mean (0), far from both modes
        assert min(np.linalg.norm(r[i] - mode), np.linalg.norm(r[i] + mode)) > 0.8
        assert np.linalg.norm(r[i]) < 0.3
    # other solvers agree with Euler on the mode split
    s2 = np.asarray(sample(p_cfm, cfg, zq[1:], jax.random.PRNGKey(1), 500, steps=10, method="heun"))
    assert 0.3 <= (s2[0] @ np.ones(2) > 0).mean() <= 0.7
    # CFM's samples score better than the regression's point estimate (energy score)
    truth = np.array([[1.25, 1.25]])
    es_cfm = C.energy_score(s[1:], truth)[0]
    es_reg = C.point_scores(r[1:], truth)["energy"][0]
    assert es_cfm < es_reg


# ----------------------------------------------------------------------------------------
# Calibration metrics on known distributions
# ----------------------------------------------------------------------------------------

def _gaussian_case(scale, m=2000, S=200, d=3, seed=0):
    rng = np.random.default_rng(seed)
    mu = rng.standard_normal((m, d))
    truth = mu + rng.standard_normal((m, d))           # posterior N(μ, 1)
    samples = mu[:, None, :] + scale * rng.standard_normal((m, S, d))
    return samples, truth


def test_coverage():
    s, t = _gaussian_case(1.0)
    cov = C.coverage(s, t, (0.5, 0.9))
    assert cov.shape == (2, 3)
    np.testing.assert_allclose(cov[0], 0.5, atol=0.04)
    np.testing.assert_allclose(cov[1], 0.9, atol=0.03)
    s, t = _gaussian_case(0.3)                          # over-confident
    cov = C.coverage(s, t, (0.5, 0.9))
    assert np.all(cov[0] < 0.3) and np.all(cov[1] < 0.5)
    s, t = _gaussian_case(3.0)                          # under-confident
    assert np.all(C.coverage(s, t, (0.5,))[0] > 0.8)


def test_sbc(tmp_path):
    s, t = _gaussian_case(1.0, m=1000, S=99)
    ranks = C.sbc_ranks(s, t)
    assert ranks.shape == (1000, 3) and ranks.min() >= 0 and ranks.max() <= 99
    p = C.sbc_uniformity(ranks, 99)
    assert np.all(p > 0.01), p
    s, t = _gaussian_case(0.5, m=1000, S=99)
    assert np.all(C.sbc_uniformity(C.sbc_ranks(s, t), 99) < 1e-6)
    # ties (e.g. a parameter that is exactly 0 everywhere) get random ranks, not all 0
    r = C.sbc_ranks(np.zeros((500, 20, 1)), np.zeros((500, 1)))
    assert 5 < r.mean() < 15
    out = plot_rank_histograms(ranks, 99, tmp_path / "sbc.png", pvalues=C.sbc_uniformity(ranks, 99), names=["a", "b", "c"])
    assert out.is_file() and out.stat().st_size > 1000


def test_c2st():
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((400, 2)), rng.standard_normal((400, 2))
    assert 0.4 <= C.c2st(a, b) <= 0.6
    assert C.c2st(a, b + 3.0) > 0.95
    assert C.c2st(a, b + 3.0, classifier="logistic") > 0.95
    # same mean, different spread: the MLP sees it
    assert C.c2st(a, 3.0 * b) > 0.7
    with pytest.raises(ValueError):
        C.c2st(a, b[:, :1])


def test_energy_score_prefers_truth():
    s_true, t = _gaussian_case(1.0, m=300, S=100)
    s_wide, _ = _gaussian_case(2.5, m=300, S=100)
    s_narrow, _ = _gaussian_case(0.3, m=300, S=100)
    es = [C.energy_score(x, t).mean() for x in (s_true, s_wide, s_narrow, s_true + 1.0)]
    assert es[0] < min(es[1:]), es
    cr = [C.crps(x, t).mean() for x in (s_true, s_wide, s_narrow)]
    assert cr[0] < min(cr[1:]), cr
    # single case API and the degenerate (point) score
    assert np.isscalar(C.energy_score(s_true[0], t[0])) or np.ndim(C.energy_score(s_true[0], t[0])) == 0
    ps = C.point_scores(np.zeros((2, 3)), np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(ps["energy"], [5.0, 1.0])
    np.testing.assert_allclose(ps["mae"], [1.5, 2.0, 0.5])
    # a point estimate at the posterior mean scores worse than the posterior itself
    assert C.point_scores(s_true.mean(1), t)["energy"].mean() > es[0]
    rep = C.calibration_report(s_true[:50], t[:50], names=["a", "b", "c"])
    assert set(rep["coverage"]) == {"a", "b", "c"} and len(rep["coverage_mean"]) == 2


# ----------------------------------------------------------------------------------------
# Training with validation, save / load, Decoder, random baseline
# ----------------------------------------------------------------------------------------

def test_train_save_load_roundtrip(tmp_path):
    theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(0), 640))
    norm = P.Normalizer.fit(theta)
    y = np.asarray(norm.normalize(theta))
    z = np.random.default_rng(0).standard_normal((640, 8)).astype(np.float32)
    logs = []
    params, hist = train_cfm(y[:512], z[:512], TINY, log=logs.append, val=(y[512:], z[512:]))
    assert len(hist["train_loss"]) == 2 and len(hist["val_loss"]) == 2
    assert all(np.isfinite(hist["val_loss"])) and hist["steps_per_epoch"] == 4
    assert len(logs) == 2 and "steps/s" in logs[0]

    f = save_decoder(tmp_path / "dec.npz", "cfm", params, TINY, norm, {"note": "test"})
    loaded = load_decoder(f)
    assert loaded.kind == "cfm" and loaded.cfg == TINY and loaded.meta == {"note": "test"}
    for a, b in zip(jax.tree_util.tree_leaves(params), jax.tree_util.tree_leaves(loaded.params)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(loaded.normalizer.shift, norm.shift)

    dec = Decoder.load(f)
    key = jax.random.PRNGKey(3)
    th = dec.sample_theta(z[:2], key, 4, steps=5)
    ref = norm.denormalize(sample(params, TINY, z[:2], key, 4, steps=5))
    assert th.shape == (2, 4, 19)
    np.testing.assert_allclose(th, ref, rtol=1e-5)
    assert dec.sample_theta(z[0], key, 4, steps=5).shape == (4, 19)
    with pytest.raises(ValueError, match="'regression' decoder"):
        dec.point(z[:2])

    rp = init_params(TINY, "regression")
    g = Decoder("regression", rp, TINY, norm).save(tmp_path / "reg.npz")
    reg = Decoder.load(g)
    np.testing.assert_allclose(reg.point(z[:3]), norm.denormalize(point(rp, TINY, z[:3])), rtol=1e-5)
    assert reg.point(z[0]).shape == (19,)

    with pytest.raises(ValueError, match="not a decoder file"):
        from mjxsysid.runtime.checkpoint import save_tree
        load_decoder(save_tree(tmp_path / "other.npz", {"a": np.zeros(3)}, {"x": 1}))
    with pytest.raises(FileNotFoundError):
        load_decoder(tmp_path / "missing.npz")


def test_random_baseline():
    nom = P.PAPER_HARDWARE
    a = np.asarray(random_baseline(jax.random.PRNGKey(0), 2000))
    b = np.asarray(random_baseline(jax.random.PRNGKey(1), 2000))
    assert a.shape == (2000, 19) and not np.allclose(a, b)
    np.testing.assert_array_equal(a, np.asarray(random_baseline(jax.random.PRNGKey(0), 2000)))
    ratio = a[:, nom != 0] / nom[nom != 0]
    assert ratio.min() >= 0.5 - 1e-6 and ratio.max() <= 1.5 + 1e-6
    assert np.all(a[:, nom == 0] == 0)              # external torque stays 0
    P.validate_theta(a)                             # inertia clipped to the triangle inequality
    raw = np.asarray(random_baseline(jax.random.PRNGKey(0), 2000, fix_inertia=False))
    r = raw / nom.clip(1e-30)
    assert np.all(np.abs(r[:, nom != 0] - 1) <= 0.5 + 1e-6)
    assert abs(np.mean(r[:, 0]) - 1.0) < 0.03 and abs(np.std(r[:, 0]) - 1 / np.sqrt(12)) < 0.02


def test_identifiable_flow_coordinates(tmp_path):
    """The 'identifiable' decoder coordinates: an exact, invertible log-linear map whose Ω_max and
    J axes are log thrust-to-weight (up to the η linearisation) and log angular authorities,
    standardised over the prior; saved with the decoder; samples come back in normalised θ."""
    norm = decoder_normalizer("default", n=20_000, coords="identifiable")
    th = P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(5), 4000)
    y = norm.normalize(th)
    v = np.asarray(norm.to_flow(y))
    np.testing.assert_allclose(np.asarray(norm.from_flow(v)), np.asarray(y), atol=1e-5)
    assert np.all(np.abs(v.mean(0)) < 0.06) and np.all(np.abs(v.std(0) - 1) < 0.06)
    auth = np.log(np.asarray(P.angular_authority(th)))
    for a in range(3):   # exactly affine in the log authority
        assert abs(np.corrcoef(v[:, P.INERTIA.start + a], auth[:, a])[0, 1]) > 0.99999
    assert np.corrcoef(v[:, P.OMEGA_MAX], np.log(np.asarray(P.thrust_to_weight(th))))[0, 1] > 0.95
    keep = [j for j in range(19) if j not in (P.OMEGA_MAX, 4, 5, 6)]   # the other axes: y itself, rescaled
    for j in keep:
        assert abs(np.corrcoef(v[:, j], np.asarray(y)[:, j])[0, 1]) > 0.99999
    plain = decoder_normalizer("default", n=20_000)
    np.testing.assert_array_equal(np.asarray(plain.to_flow(y)), np.asarray(y))
    with pytest.raises(ValueError, match="coordinates"):
        decoder_normalizer("default", n=100, coords="polar")
    with pytest.raises(ValueError, match="coords"):
        TINY.replace(coords="polar")

    cfg = TINY.replace(coords="identifiable")
    params = init_params(cfg)
    f = save_decoder(tmp_path / "dec.npz", "cfm", params, cfg, norm, {})
    dec = Decoder.load(f)
    assert dec.cfg.coords == "identifiable" and dec.normalizer.flow_map is not None
    z = np.random.default_rng(0).standard_normal((2, 8)).astype(np.float32)
    key = jax.random.PRNGKey(3)
    raw = sample(params, cfg, z, key, 4, steps=5)                     # the flow's coordinates
    np.testing.assert_allclose(np.asarray(dec.sample_norm(z, key, 4, steps=5)),
                               np.asarray(norm.from_flow(raw)), atol=1e-5)
    np.testing.assert_allclose(np.asarray(dec.sample_theta(z, key, 4, steps=5)),
                               np.asarray(norm.denormalize(norm.from_flow(raw))), rtol=1e-4)
    bad = norm.to_dict()
    bad["flow_map"] = np.zeros((19, 19)).tolist()
    with pytest.raises(ValueError, match="singular"):
        FlowNormalizer.from_dict(bad)


def test_regression_early_stopping_keeps_the_best_validation_epoch():
    """The Regression baseline keeps the epoch of lowest validation loss (here it over-fits 64
    noisy pairs, so the best epoch is early), not the last; early stopping without validation
    data is refused."""
    rng = np.random.default_rng(0)
    z = rng.normal(size=(64, 8)).astype(np.float32)
    x = (0.3 * z[:, :1] + rng.normal(size=(64, 19))).astype(np.float32)   # mostly noise
    zv = rng.normal(size=(256, 8)).astype(np.float32)
    xv = (0.3 * zv[:, :1] + rng.normal(size=(256, 19))).astype(np.float32)
    cfg = CFMConfig(width=64, blocks=2, time_dim=16, epochs=30, batch=16, lr=3e-3)
    p, hist = train_regression(x, z, cfg, log=None, val=(xv, zv))
    vl = np.asarray(hist["val_loss"])
    assert hist["best_epoch"] == int(np.argmin(vl)) + 1 < cfg.epochs
    assert hist["best_val_loss"] == pytest.approx(vl.min()) and vl[-1] > vl.min()
    p_last, _ = train_regression(x, z, cfg, log=None, val=(xv, zv), early_stopping=False)
    from mjxsysid.cfm.train import _make_eval, make_network
    ev = _make_eval("regression", cfg, make_network(cfg, "regression"), xv, zv)
    assert float(ev(p)) == pytest.approx(vl.min(), rel=1e-5) and float(ev(p_last)) == pytest.approx(vl[-1], rel=1e-5)
    with pytest.raises(ValueError, match="early stopping needs validation"):
        train_regression(x, z, cfg, log=None)


def test_validation_split_is_seeded_disjoint_and_ten_percent():
    from mjxsysid.cfm.pipeline import validation_split
    tr, va = validation_split(1000, seed=0)
    assert len(va) == 100 and len(tr) == 900 and not set(tr) & set(va)
    assert sorted(np.concatenate([tr, va])) == list(range(1000))
    np.testing.assert_array_equal(va, validation_split(1000, seed=0)[1])
    assert not np.array_equal(va, validation_split(1000, seed=1)[1])
