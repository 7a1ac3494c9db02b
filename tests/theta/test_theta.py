import dataclasses
import json

import jax
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.policy.adaptive.losses import identifiable_log


def test_field_table_generates_the_layout():
    """Every view of θ's layout is generated from the one field table: these are its values."""
    assert P.PARAM_NAMES == (
        "mass", "arm_length", "thrust_coeff", "torque_coeff", "inertia[0]", "inertia[1]", "inertia[2]",
        "drag[0]", "drag[1]", "drag[2]", "max_rotor_speed", "motor_effectiveness[0]", "motor_effectiveness[1]",
        "motor_effectiveness[2]", "motor_effectiveness[3]", "motor_time_constant",
        "external_torque[0]", "external_torque[1]", "external_torque[2]")
    assert P.PARAM_UNITS == ("kg", "m", "N/(rad/s)^2", "N m/(rad/s)^2", "kg m^2", "kg m^2", "kg m^2",
                             "kg/s", "kg/s", "kg/s", "rad/s", "-", "-", "-", "-", "s", "N m", "N m", "N m")
    assert P.N_PARAMS == 19 == sum(f.size for f in P.FIELDS)
    assert (P.MASS, P.ARM, P.KT, P.KTAU, P.OMEGA_MAX, P.TAU_M) == (0, 1, 2, 3, 10, 15)
    assert all(type(i) is int for i in (P.MASS, P.ARM, P.KT, P.KTAU, P.OMEGA_MAX, P.TAU_M))
    assert (P.INERTIA, P.DRAG, P.ETA, P.TAU_EXT) == (slice(4, 7), slice(7, 10), slice(11, 15), slice(16, 19))
    assert P.VEHICLE_KEYS == {
        "mass": (slice(0, 1), None), "arm_length": (slice(1, 2), None), "thrust_coeff": (slice(2, 3), None),
        "torque_coeff": (slice(3, 4), None), "inertia": (slice(4, 7), 3), "drag": (slice(7, 10), 3),
        "max_rotor_speed": (slice(10, 11), None), "motor_effectiveness": (slice(11, 15), 4),
        "motor_time_constant": (slice(15, 16), None), "external_torque": (slice(16, 19), 3)}
    assert list(P.VEHICLE_KEYS) == [f.name for f in P.FIELDS] == list(P.SLICES)
    assert P.LOG_MASK.dtype == bool and P.LOG_MASK.tolist() == [
        True] * 11 + [False] * 4 + [True] + [False] * 3
    assert P.POSITIVE_MASK.tolist() == [True] * 7 + [False] * 3 + [True] * 6 + [False] * 3
    assert np.flatnonzero(P.NONNEGATIVE_MASK).tolist() == [7, 8, 9]
    expected_offset = np.zeros(19, np.float32)
    expected_offset[7:10] = 1e-3
    np.testing.assert_array_equal(P.LOG_OFFSET, expected_offset)
    assert P.LOG_OFFSET.dtype == np.float32


def test_priors_are_siblings():
    """XAdapPrior carries only the fields it samples from; every prior is a SizeFactorPrior."""
    assert not isinstance(P.XADAP_PRIOR, P.Prior)
    assert all(isinstance(p, P.SizeFactorPrior) for p in [*P.PRIORS.values(), *P.HELDOUT_FAMILIES.values()])
    fields = {f.name for f in dataclasses.fields(P.XAdapPrior)}
    assert {"mass_range", "drag_iso"} <= fields and not fields & {"mass_base", "mass_scale", "drag_xy", "drag_noise"}
    assert P.get_prior(P.XADAP_PRIOR) is P.XADAP_PRIOR and P.get_prior("weak_motor") is P.HELDOUT_FAMILIES["weak_motor"]


def test_names_units_and_nominal():
    assert len(P.PARAM_NAMES) == len(P.PARAM_UNITS) == P.N_PARAMS == 19
    assert P.PARAM_NAMES[P.OMEGA_MAX] == "max_rotor_speed"
    # The paper vehicle: 4 k_t Ω_max² / (m g) ≈ 6.2 (DESIGN §2), κ = 0.014 m.
    np.testing.assert_allclose(P.thrust_to_weight(P.PAPER_HARDWARE), 6.2, atol=0.05)
    np.testing.assert_allclose(P.torque_ratio(P.PAPER_HARDWARE), 0.014, atol=1e-4)


def test_shipped_vehicle_file_is_the_paper_vehicle():
    np.testing.assert_allclose(P.load_vehicle(P.vehicle_path("paper_hardware")), P.PAPER_HARDWARE,
                               rtol=1e-6)


def test_vehicle_file_round_trip(tmp_path):
    th = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(0), 1))[0]
    path = P.save_vehicle(th, tmp_path / "v.json")
    assert set(json.loads(path.read_text())) == set(P.VEHICLE_KEYS)
    np.testing.assert_allclose(P.load_vehicle(path), th, rtol=1e-6)


@pytest.mark.parametrize("edit,match", [
    (lambda d: d.pop("mass"), "missing key.*mass"),
    (lambda d: d.update(colour="red"), "unknown key.*colour"),
    (lambda d: d.update(inertia=[1e-3, 1e-3]), "inertia must be a list of 3"),
    (lambda d: d.update(mass=-1.0), "mass must be > 0"),
    (lambda d: d.update(mass="heavy"), "mass must be a number"),
    (lambda d: d.update(inertia=[1e-3, 1e-3, 5e-3]), "inertia\\[2\\] violates the triangle"),
    (lambda d: d.update(motor_effectiveness=[1, 1, 0, 1]), "motor_effectiveness\\[2\\] must be > 0"),
    (lambda d: d.update(drag=[0.1, -0.1, 0.1]), "drag\\[1\\] must be >= 0"),
    (lambda d: d.update(thrust_coeff=float("nan")), "thrust_coeff is not finite"),
])
def test_vehicle_file_errors_name_the_key(tmp_path, edit, match):
    d = P.theta_to_dict(P.PAPER_HARDWARE)
    edit(d)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=match):
        P.load_vehicle(path)


def test_file_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.json"):
        P.load_vehicle(tmp_path / "nope.json")
    (tmp_path / "x.json").write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        P.load_vehicle(tmp_path / "x.json")


def test_validate_shape_and_batch_index():
    with pytest.raises(ValueError, match="shape"):
        P.validate_theta(np.ones(18))
    th = np.tile(P.PAPER_HARDWARE, (3, 1))
    th[2, P.MASS] = 0.0
    with pytest.raises(ValueError, match="mass must be > 0 \\(batch element 2\\)"):
        P.validate_theta(th)


@pytest.fixture(scope="module")
def prior_samples():
    return {name: np.asarray(p.sample(jax.random.PRNGKey(0), 20_000)) for name, p in P.PRIORS.items()}


def test_every_prior_sample_is_valid_and_flyable(prior_samples):
    for name, th in prior_samples.items():
        P.validate_theta(th)
        f = P.flyability(th)
        # Each prior's floor of per-rotor thrust-to-weight (1.5; the first stress prior, past the
        # training prior's edges on purpose, 1.2: every rotor can still lift its share of the weight).
        assert f["twr_min"].min() >= P.PRIORS[name].twr_min_eff - 1e-4 >= 1.2 - 1e-4, name
        assert f["twr_max"].max() <= 8.5 + 1e-3, name
        # Every vehicle can cancel its external torque with a wide margin (the stress priors: 1.5).
        assert f["torque_margin"].min() > (1.5 if name.startswith("stress") else 2.0), name


def test_paper_vehicle_well_inside_default_prior(prior_samples):
    th = prior_samples["default"]
    pv = P.PAPER_HARDWARE
    for j, name in enumerate(P.PARAM_NAMES):
        lo, hi = np.percentile(th[:, j], [5, 95])
        assert lo <= pv[j] <= hi, (name, lo, pv[j], hi)
    twr = np.asarray(P.thrust_to_weight(th))
    assert np.percentile(twr, 5) < P.thrust_to_weight(pv) < np.percentile(twr, 95)


def test_prior_is_seeded_and_slow_actuator_range(prior_samples):
    a = P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(3), 10)
    b = P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(3), 10)
    np.testing.assert_array_equal(a, b)
    tm = prior_samples["slow_actuators"][:, P.TAU_M]
    assert tm.min() >= 0.05 and tm.max() <= 0.10
    tm = prior_samples["default"][:, P.TAU_M]
    assert tm.min() >= 0.02 and tm.max() <= 0.04
    # the decoders' prior: the default vehicles with τ_m over both ranges, everything else equal
    tm = prior_samples["wide_actuators"][:, P.TAU_M]
    assert tm.min() < 0.025 and tm.max() > 0.095 and tm.min() >= 0.02 and tm.max() <= 0.10
    rest = [j for j in range(P.N_PARAMS) if j != P.TAU_M]
    np.testing.assert_array_equal(prior_samples["wide_actuators"][:, rest], prior_samples["default"][:, rest])


def test_draws_of_every_size_up_to_4096_share_one_program_and_are_that_sizes_own():
    """A prior compiles one sampler for every n from 2 to 4,096: n vehicles are the first n of its 4,096
    draws, the n drawn by a program of their own size (to the last bit: XLA vectorises each size its way)."""
    from mjxsysid.theta.priors import _sampled, sample_bucket
    assert [sample_bucket(n) for n in (0, 1, 2, 16, 17, 600, 4096, 4097, 100_000)] == \
        [0, 1, 4096, 4096, 4096, 4096, 4096, 4097, 100_000]
    prior = P.HELDOUT_FAMILIES["weak_motor"]        # every draw kind: uniform, randint, a clip over rotors
    key = jax.random.PRNGKey(11)
    before = _sampled._cache_size()
    draws = {n: np.asarray(prior.sample(key, n)) for n in (2, 40, 4096)}
    assert _sampled._cache_size() - before <= 1                   # one program, 4,096 (none if already built)
    for n, th in draws.items():
        assert th.shape == (n, P.N_PARAMS)
        np.testing.assert_allclose(th, np.asarray(_sampled(prior, key, n)), rtol=3e-7, atol=0)   # n's own program


def test_prior_covers_released_policy_range(prior_samples):
    """The released xadap policy was trained on m 0.04–1.16 kg, l 0.03–0.20 m (its README):
    most of that box is covered."""
    th = prior_samples["default"]
    assert th[:, P.MASS].min() < 0.06 and th[:, P.MASS].max() > 1.16
    assert th[:, P.ARM].min() < 0.04 and th[:, P.ARM].max() > 0.20


def test_normalizer_round_trip(prior_samples):
    th = prior_samples["default"][:1000]
    norm = P.prior_normalizer(n=20_000)
    y = np.asarray(norm.normalize(th))
    assert np.abs(y.mean(0)).max() < 0.2 and np.abs(y.std(0) - 1).max() < 0.2
    np.testing.assert_allclose(np.asarray(norm.denormalize(y)), th, rtol=2e-4, atol=1e-7)
    back = P.Normalizer.from_dict(json.loads(json.dumps(norm.to_dict())))
    np.testing.assert_allclose(np.asarray(back.normalize(th)), y, rtol=1e-6)


def test_unknown_prior():
    with pytest.raises(ValueError, match="unknown prior"):
        P.get_prior("fast")


def test_widened_prior_is_the_prior_at_zero_and_wider_and_valid_beyond():
    key = jax.random.PRNGKey(3)
    base = np.asarray(P.DEFAULT_PRIOR.sample(key, 2000))
    np.testing.assert_array_equal(np.asarray(P.widened_prior(P.DEFAULT_PRIOR, 0.0).sample(key, 2000)), base)
    wide = P.widened_prior(P.DEFAULT_PRIOR, 0.4)
    assert wide.motor_time_constant == pytest.approx((0.02 / np.exp(0.4), 0.04 * np.exp(0.4)))
    assert wide.eta[1] <= 1.99 and wide.ext_torque_xy == pytest.approx(0.02 * np.exp(0.4))
    th = np.asarray(wide.sample(key, 2000))
    P.validate_theta(th)                                    # every draw a valid vehicle
    a, b = np.asarray(identifiable_log(base)), np.asarray(identifiable_log(th))
    assert (b.min(0) < a.min(0)).sum() >= 4 and (b.max(0) > a.max(0)).sum() >= 4   # wider both ways
    with pytest.raises(ValueError, match="amount must be"):
        P.widened_prior(P.DEFAULT_PRIOR, -0.1)
