"""NUTS on the log-grounded target (mjxsysid.identify.nuts): the map to unconstrained coordinates and
its log-Jacobian, the convergence check, and the SMC's draws refined on an exact-model log."""
import jax.numpy as jnp
import numpy as np
import pytest

from mjxsysid.identify import nuts as S
from mjxsysid.identify.coords import PHYSICAL_PRIOR, visible_from_theta
from mjxsysid.identify.target import N_Y, _y_lo_hi

LO, HI = _y_lo_hi(PHYSICAL_PRIOR)


def _jacobian_fd(z, h=1e-6):
    """∂y/∂z (17, 17) of :func:`S.to_constrained` at z (17,) by central differences (float64)."""
    return np.stack([(S.to_constrained(z + h * e, LO, HI) - S.to_constrained(z - h * e, LO, HI)) / (2 * h)
                     for e in np.eye(N_Y)], 1)


def test_unconstrained_map_round_trips_into_the_support_with_its_log_jacobian():
    rng = np.random.default_rng(0)
    z = rng.normal(0.0, 2.5, (6, N_Y))
    y = S.to_constrained(z, LO, HI)
    assert np.all((y >= LO) & (y <= HI))
    # J's triangle inequality holds by construction (1/A_z <= 1/A_x + 1/A_y), whatever z
    assert np.all(np.exp(-y[:, S.AZ]) <= np.exp(-y[:, S.AX]) + np.exp(-y[:, S.AY]) + 1e-12)
    np.testing.assert_allclose(S.to_unconstrained(y, LO, HI), z, atol=1e-8)
    for zz in z:
        sign, logdet = np.linalg.slogdet(_jacobian_fd(zz))
        assert sign > 0
        assert S.log_jacobian(zz, LO, HI) == pytest.approx(logdet, abs=1e-6)
    # the JAX path (float32, what NUTS runs) computes the same map
    yj = np.asarray(S.to_constrained(jnp.asarray(z, jnp.float32), jnp.asarray(LO), jnp.asarray(HI)))
    np.testing.assert_allclose(yj, y, atol=2e-4 * np.max(HI - LO))
    np.testing.assert_allclose(np.asarray(S.log_jacobian(jnp.asarray(z, jnp.float32), LO, HI)),
                               S.log_jacobian(z, LO, HI), atol=1e-3)



def test_one_loop_draws_are_blackjax_window_adaptation_s():
    """:func:`S.window_nuts` (one loop, the kernel once, one program for any lengths up to its plan's) draws
    what blackjax's public ``window_adaptation`` followed by ``nuts`` draws, to the bit, on a correlated
    Gaussian, thinned where asked: a blackjax that changed its engine's internals, a loop that used the final
    step size too early, or a thinning that kept the wrong draws would fail here."""
    import blackjax
    import jax

    cov = jnp.asarray([[1.0, 0.8, 0.0], [0.8, 1.0, 0.3], [0.0, 0.3, 0.5]], jnp.float32)
    prec = jnp.linalg.inv(cov)

    def logdensity(u):
        return -0.5 * u @ prec @ u

    key, u = jax.random.PRNGKey(3), jnp.asarray([2.0, -1.0, 0.5], jnp.float32)
    kw = {"target_acceptance": 0.9, "max_doublings": 5}
    total, kept = 160 + 2 * 12, 12
    run = jax.jit(lambda steps, stages, u, warmup, n, thin: S.window_nuts(logdensity, steps, stages, u, warmup, n, thin,
                                                                           kept=kept, **kw))

    def reference(key, u, warmup, draws):               # the public API's two stages, compiled as one
        k_warm, k_draw = jax.random.split(key)
        adapt = blackjax.window_adaptation(blackjax.nuts, logdensity, is_mass_matrix_diagonal=False,
                                           target_acceptance_rate=kw["target_acceptance"],
                                           max_num_doublings=kw["max_doublings"])
        (state, params), _ = adapt.run(k_warm, u, num_steps=warmup)
        kernel = blackjax.nuts(logdensity, **params)

        def one(s, k):
            s, info = kernel.step(k, s)
            return s, (s.position, info.is_divergent, info.num_integration_steps)

        return jax.lax.scan(one, state, jax.random.split(k_draw, draws))[1], params["step_size"]

    for warmup, thin in ((40, 1), (160, 2)):            # Stan's short schedule; its windows, thinned
        draws = kept * thin
        steps, stages = S.plan(key, warmup, draws, total, kw["target_acceptance"])
        pos, div, leap, step = run(steps, stages, u, warmup, warmup + draws, thin)
        (ref_pos, ref_div, ref_leap), ref_step = jax.jit(reference, static_argnums=(2, 3))(key, u, warmup, draws)
        np.testing.assert_array_equal(np.asarray(pos), np.asarray(ref_pos)[::thin])
        assert int(leap) == int(np.sum(ref_leap)) and int(div) == int(np.sum(ref_div))
        assert float(step) == float(ref_step)
        assert np.ptp(np.asarray(pos), 0).min() > 0          # the chain moved in every coordinate
    assert run._cache_size() == 1                           # one program for both lengths
    with pytest.raises(ValueError, match="exceed the 184 steps"):
        S.plan(key, 170, 24, total)


def test_converged_names_the_coordinate_whose_chains_disagree_and_asks_enough_draws():
    ok = {"rhat": np.full(N_Y, 1.01), "ess_bulk": np.full(N_Y, 400.0), "divergences": 30}
    assert S.converged(ok)[0]                       # divergent draws at ρ_4's wall are rejected moves: reported
    good, why = S.converged(dict(ok, rhat=np.r_[np.full(N_Y - 1, 1.0), 1.3]))
    assert not good and "acc_z_bias" in why and "1.30" in why
    assert not S.converged(dict(ok, rhat=np.r_[np.nan, np.ones(N_Y - 1)]))[0]
    good, why = S.converged(dict(ok, ess_bulk=np.r_[np.full(N_Y - 1, 400.0), 40.0]))
    assert not good and "ESS ≥ 40" in why


@pytest.mark.usefixtures("xla_optimised_test")   # run time, not compiles
def test_the_smcs_draws_are_refined_by_nuts_to_a_longer_runs_bands(monkeypatch, exact_model_posteriors):
    """On a 4 s exact-model log: the SMC's draws replaced by short NUTS chains that mixed; their 5/50/95 %
    quantiles of thrust-to-weight and the roll and pitch authorities within 0.3 of a longer run's band
    widths, which hold the truth; without ``refine``, or where the chains never mix, the SMC's draws stay."""
    ex = exact_model_posteriors
    data, post, smc, ref = ex["data"], ex["refined"], ex["smc"], ex["reference"]
    assert min(S.LONGER) > 1
    monkeypatch.setattr(S, "LONGER", (1, 1))   # a retry as long as the first run, as the fixture's
    assert post["method"] == "smc_nuts" and post["nuts"]["converged"], post["nuts"]
    assert post["nuts"]["chains"] * post["nuts"]["draws"] >= 400 and len(post["v_raw"]) == 400
    assert smc["method"] == "smc" and "nuts" not in smc
    assert ex["ahead"][:2] == [("smc", True), ("nuts", True)], ex["ahead"]   # the programs compiled while the mode was found
    assert {"fit_ls", "smc", "nuts", "rhat_ess"} <= ex["exported"], ex["exported"]   # traces a warm run loads
    from mjxsysid.identify import inference
    again = inference.refine_posterior(data, smc, seed=1, calibration=None)      # the same SMC draws, refined after
    assert again["method"] == post["method"] and again["nuts"] == post["nuts"]
    for k in ("v_raw", "nuisance", "theta"):
        np.testing.assert_array_equal(again[k], post[k])
    with pytest.raises(ValueError, match="SMC posterior without NUTS"):
        inference.refine_posterior(data, post, seed=1)
    monkeypatch.setattr(S, "converged", lambda diag: (False, "forced"))   # chains that never mix
    kept = inference.refine_posterior(data, smc, seed=1, calibration=None)
    assert kept["method"] == "smc" and kept["nuts"]["warmup"] == S.WARMUP and "SMC" in kept["nuts"]["kept"]
    assert kept["nuts"]["attempts"] == 2 and kept["nuts"]["first"]["why"] == "forced"     # why it ran again
    assert post["nuts"]["attempts"] == 1 and "first" not in post["nuts"]
    np.testing.assert_array_equal(kept["v_raw"], smc["v_raw"])      # the SMC's own draws, after the longer try
    q, qr = (np.quantile(a, [0.05, 0.5, 0.95], 0) for a in (post["v_raw"], ref["y"].reshape(-1, N_Y)[:, :12]))
    truth = visible_from_theta(ex["theta"])
    for j in (0, 5, 6):
        width = qr[2, j] - qr[0, j]
        assert np.all(np.abs(q[:, j] - qr[:, j]) < 0.3 * width), (j, q[:, j], qr[:, j])
        assert qr[0, j] <= truth[j] <= qr[2, j], j


def test_a_coordinate_whose_chains_disagree_is_not_seen():
    report = {"seen": np.ones(12, bool), "why": ["calibrated band 0.01 of the prior's range"] * 12}
    S.unmixed_not_seen(report, {"rhat_v": [1.01] * 7 + [1.4] + [1.0] * 3 + [float("nan")]})
    assert report["seen"].tolist() == [True] * 7 + [False] + [True] * 3 + [False]
    assert "R̂ 1.40" in report["why"][7] and report["why"][0].startswith("calibrated")


def test_a_coordinate_whose_chains_disagree_is_drawn_from_the_prior():
    """Sharp and wrong is worse than broad and right: where the chains did not meet (a hover's flat ridge), the
    band is the prior's, not the SMC's narrow one."""
    from mjxsysid.identify.coords import PHYSICAL_PRIOR
    rng = np.random.default_rng(0)
    v = np.tile(PHYSICAL_PRIOR.sample_v(rng, 1), (500, 1)) + 1e-3 * rng.standard_normal((500, 12)).astype(np.float32)
    prior_v = PHYSICAL_PRIOR.sample_v(rng, 500)
    report = {"seen": np.ones(12, bool), "why": [""] * 12, "factor": np.ones(12)}
    nuts = {"rhat_v": [1.0] * 5 + [1.3] + [1.0] * 6, "chain_spread_v": [0.0] * 5 + [0.5] + [0.0] * 6}
    out = S.unmixed_not_seen(report, nuts, v, lambda n: prior_v[:n])
    assert np.array_equal(out[:, 5], prior_v[:, 5]) and np.array_equal(np.delete(out, 5, 1), np.delete(v, 5, 1))
    assert "means 0.5 apart" in report["why"][5]
    assert not report["seen"][5] and np.isnan(report["factor"][5]) and "as broad as the prior" in report["why"][5]
    lo, hi = PHYSICAL_PRIOR.v_bounds()
    assert np.ptp(np.percentile(out[:, 5], [5, 95])) > 0.5 * (hi[5] - lo[5])
    def never(n):
        raise AssertionError("prior drawn though every coordinate mixed")
    assert S.unmixed_not_seen(dict(report), {"rhat_v": [1.0] * 12}, v, never) is v


def test_a_reference_runs_the_first_of_the_plans_it_is_given():
    """nuts_reference in another program's plans (the refinement's, to share its compile): the first plan must
    be the reference's own lengths, and a wrong one is refused before anything runs."""
    with pytest.raises(ValueError, match=r"first of its plans .* must be \(300, 500, 1\)"):
        S.nuts_reference(None, None, None, None, None, chains=4, warmup=300, draws=500, plans=((200, 50, 1),))
    with pytest.raises(ValueError, match="chains >= 2"):
        S.nuts_reference(None, None, None, None, None, chains=1, warmup=300, draws=500)
