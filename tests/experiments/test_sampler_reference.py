"""The sampler-reference experiment (mjxsysid.experiments.sampler_reference): its
measure, and NUTS against the log-grounded posterior's SMC on a short exact-model log."""
import numpy as np
import pytest

from mjxsysid.experiments import sampler_reference as S
from mjxsysid.identify.coords import visible_from_theta
from mjxsysid.identify.inference import default_method
from mjxsysid.identify.target import N_Y

def test_compare_measures_the_sampler_error_in_band_widths():
    rng = np.random.default_rng(1)
    mcmc = rng.standard_normal((20000, 12))
    smc = mcmc[:5000] + 0.5 * 3.29            # shifted by half the 90 % band (3.29 sd)
    out = S.compare(smc, mcmc, np.full(12, 1.5))
    np.testing.assert_allclose(out["sampler_error"], 0.5, atol=0.05)
    np.testing.assert_allclose(out["width_ratio"], 1.0, atol=0.05)
    assert out["inside_mcmc"].all() and out["inside_smc"].all()
    np.testing.assert_allclose(out["model_error"], 1.5 / 3.29, atol=0.05)


def test_nuts_and_the_smc_agree_on_an_exact_model_log(exact_model_posteriors):
    """On a 4 s log where the likelihood's model is exact: for thrust-to-weight and the roll and pitch
    authorities, NUTS's median inside the SMC's 90 % band and the SMC's inside NUTS's, the truth inside
    NUTS's band, the chains mixed (tests/conftest.py's run: 40 chains × (200 + 50) from the SMC's draws)."""
    post, ref = exact_model_posteriors["smc"], exact_model_posteriors["reference"]
    assert ref["y"].shape == (40, 50, N_Y)
    out = S.compare(post["v_raw"], ref["y"].reshape(-1, N_Y)[:, :12], visible_from_theta(exact_model_posteriors["theta"]))
    for j in (0, 5, 6):
        (s5, s50, s95), (m5, m50, m95) = out["smc"][:, j], out["mcmc"][:, j]
        assert s5 <= m50 <= s95 and m5 <= s50 <= m95, (j, out["smc"][:, j], out["mcmc"][:, j])
        assert out["inside_mcmc"][j], j
        assert ref["rhat"][j] < 1.1, (j, ref["rhat"][j])
    assert default_method(post) in ("laplace_is", "smc")


def test_plan_takes_the_levels_in_turn_and_names_a_bad_count():
    assert S.plan(5) == [(0, "clean"), (0, "x1"), (0, "x5_white"), (0, "x20"), (1, "clean")]
    with pytest.raises(ValueError, match="logs"):
        S.plan(0)


def test_default_method_takes_the_first_reliable_importance_sampler():
    ok, broad, few = {"ess_fraction": 0.5, "khat": 0.3}, {"ess_fraction": 0.5, "khat": 0.9}, {"ess_fraction": 0.01, "khat": None}
    assert default_method({"decoded_is": ok, "laplace_is": ok}) == "decoded_is"
    assert default_method({"decoded_is": few, "laplace_is": ok}) == "laplace_is"
    assert default_method({"laplace_is": broad}) == "smc"
