"""Measured rotor speeds in the log-grounded likelihood (mjxsysid.identify.speeds): τ_m from command
to speed, the thrust and torque from the fitted command→speed map, the calibration's τ_m band left
raw, and speeds that cannot be used said so. The logs come from the tests' exact-model forward model
(support.exact_model_log), which carries the true rotor speeds on request."""
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.identify import coords as C
from mjxsysid.identify import logdata as LD
from mjxsysid.identify.calibrate import SPEED_WHY
from mjxsysid.identify.inference import log_grounded_posterior, log_target
from mjxsysid.identify.logspace import LOG_TAU_M
from mjxsysid.identify.speeds import SPEED_MODEL_SD, speed_term
from mjxsysid.logs.speedmap import first_row, speed_fit
from support.exact_model_log import synthetic_log
from support.paths import SHARED_DATA, require_shared

THETA = P.paper_hardware()
TRUE = C.log_quantities(THETA)


def _log(delay=0, speed_noise=5.0):
    return synthetic_log(THETA, seconds=4.0, gyro_noise=0.02, acc_noise=0.2, seed=3, speed_noise=speed_noise,
                         motor_delay=delay)


def _bands(post):
    return np.percentile(C.log_quantities(post["theta"]), [5, 50, 95], 0)


def test_speed_term_reads_tau_m_and_the_calibrated_band_holds_it():
    rec = _log()
    fit = speed_fit(rec, first_row(len(rec["motor"])))
    assert fit["used"] and fit["tau_m_s"] == pytest.approx(THETA[P.TAU_M], rel=0.03) and fit["delay_s"] == 0
    assert fit["omega_ref_rad_s"] == pytest.approx(THETA[P.OMEGA_MAX], rel=0.01) and fit["n_eff"] > 5000
    n, _, sd = speed_term(fit)[1]          # the model floor: τ_m's band no narrower than the map's form allows
    assert n < fit["n_eff"] and sd == pytest.approx(SPEED_MODEL_SD, rel=0.01)
    blind = {k: v for k, v in rec.items() if k != "rotor_speed"}
    d, base = LD.prepare(rec, rates="innovations"), LD.prepare(blind, rates="innovations")
    g = int(np.argmin(np.abs(np.asarray(d.log_tau) - np.log(THETA[P.TAU_M]))))
    for f in ("fg", "fa", "kf_r"):   # the fitted map at the true τ: the commands' lag features
        a, b = np.asarray(getattr(d, f))[g], np.asarray(getattr(base, f))[g]
        np.testing.assert_allclose(a, b, rtol=0.01, atol=1e-3 * np.abs(b).max())
    post = log_grounded_posterior(rec, None, samples=400, particles=256, seed=1)
    lo, med, hi = _bands(post)
    j = C.LOG_NAMES.index("motor_time_constant")
    assert lo[j] <= TRUE[j] <= hi[j] and abs(med[j] / TRUE[j] - 1) < 0.03, (lo[j], med[j], hi[j])
    cal = post["calibration"]
    assert post["features"]["rotor_speed_used"] and cal["factor"][LOG_TAU_M] == 1.0
    assert SPEED_WHY in cal["why"][LOG_TAU_M]


def test_speeds_fix_a_command_delay_that_biases_the_commands_alone():
    """The motors act on each logged command 20 ms late: read through the commands' lag, the rates see
    a slower τ_m and the roll and pitch authorities come out high; with the measured speeds (the delay
    profiled in the speed fit) the authorities and thrust-to-weight hold the truth."""
    rec = _log(delay=10)
    blind = {k: v for k, v in rec.items() if k != "rotor_speed"}
    with_s, without = (log_grounded_posterior(r, None, samples=400, particles=256, seed=1, calibration=None)
                       for r in (rec, blind))
    lo, med, hi = _bands(with_s)
    for j in (0, 1, 2, 3):        # thrust-to-weight, τ_m, roll and pitch authority
        assert lo[j] <= TRUE[j] <= hi[j] and abs(med[j] / TRUE[j] - 1) < 0.02, (C.LOG_NAMES[j], lo[j], TRUE[j], hi[j])
    lo, med, hi = _bands(without)
    for j in (1, 2):
        assert lo[j] > TRUE[j] and med[j] / TRUE[j] - 1 > 0.025, (C.LOG_NAMES[j], lo[j], TRUE[j], hi[j])


def test_noisy_speeds_enter_through_the_fitted_map_and_leave_the_authorities_unbiased():
    """The logged speeds carry white noise of 40 rad/s (7 % of the hover speed; the fit's R² 0.56, near the
    least it accepts). Through the fitted command→speed map, thrust-to-weight, τ_m and the roll and pitch
    authorities hold the truth; the raw samples as regressors (errors in variables) bias the authorities low."""
    rec = _log(speed_noise=40.0)
    model, raw = (log_grounded_posterior(LD.prepare(rec, speeds=m), None, samples=400, particles=256, seed=1,
                                         calibration=None) for m in ("model", "raw"))
    lo, med, hi = _bands(model)
    for j in (0, 1, 2, 3):
        assert lo[j] <= TRUE[j] <= hi[j] and abs(med[j] / TRUE[j] - 1) < 0.02, (C.LOG_NAMES[j], lo[j], TRUE[j], hi[j])
    med_raw = _bands(raw)[1]
    for j in (2, 3):     # the raw samples' authorities 2.5–5 % low, at least 1 % below the fitted map's
        assert med_raw[j] / TRUE[j] < 0.985 and med_raw[j] < med[j] - 0.01 * TRUE[j], (C.LOG_NAMES[j], med_raw[j], med[j])


def test_a_log_without_speeds_reads_as_before_and_bad_speeds_are_not_used():
    rec = _log()
    blind = {k: v for k, v in rec.items() if k != "rotor_speed"}
    base = LD.prepare(blind)
    assert not np.any(np.asarray(base.speed_ll)) and np.asarray(base.speed).tolist() == [0.0, 0.0, 1.0]
    assert base._rows["speed"] == {"rotor_speed_used": False, "why": "the log carries no rotor speeds"}
    rng = np.random.default_rng(0)
    bad = {"zeros": np.zeros_like(rec["rotor_speed"]),
           "not speeds": rng.normal(2000.0, 300.0, rec["rotor_speed"].shape),
           "NaN": np.where(np.arange(len(rec["motor"]))[:, None] == 1500, np.nan, rec["rotor_speed"])}
    why = {"zeros": "do not vary", "not speeds": "R²", "NaN": "not finite"}
    v = np.asarray(C.visible_from_theta(THETA))
    y = np.concatenate([v, np.log([0.02] * 3 + [0.2]), [0.0]])[None].repeat(3, 0).astype(np.float32)
    y[1, LOG_TAU_M] += 0.2
    y[2, 0] += 0.05
    ref = log_target(y, base)
    for name, w in bad.items():
        d = LD.prepare({**blind, "rotor_speed": w})
        rep = d._rows["speed"]
        assert not rep["rotor_speed_used"] and why[name] in rep["why"], (name, rep["why"])
        np.testing.assert_array_equal(np.asarray(d.fg), np.asarray(base.fg))
        np.testing.assert_array_equal(log_target(y, d), ref)


def test_real_logs_with_rotor_speeds_use_them():
    """Indiflight's eRPM (omegaUnfiltered) and a Crazyflie's RPM deck: the speeds are used; Indiflight's τ_m
    from command to speed is near the 26 ms its repository identifies."""
    from mjxsysid.logs.csvlog import read_any_log
    paths = [require_shared(SHARED_DATA / "logs" / "formats" / "blackbox" / "indiflight_iros2024_LOG00281.BFL"),
             require_shared(SHARED_DATA / "logs" / "formats" / "crazyflie_usd" / "jana00")]
    fits = []
    for p in paths:
        rec = read_any_log(p)
        fits.append(speed_fit(rec, first_row(len(rec["motor"]))))
        assert fits[-1]["used"] and fits[-1]["samples"].startswith("native"), (p, fits[-1]["why"])
    assert 0.020 < fits[0]["tau_m_s"] < 0.030 and fits[0]["r2"] > 0.95


def test_per_rotor_maps_recover_each_motor_and_keep_the_authorities():
    """Each rotor's speed has its own gain and idle offset (a Crazyflie deck's spread: Ω_i = g_i Ω_max s_i + o_i,
    the mean speed at full command Ω_max), the vehicle trimmed. The per-rotor maps recover g_i and o_i, and
    thrust-to-weight, τ_m and the roll and pitch authorities hold the truth; one map for the four fits badly
    (R² 0.66) and biases thrust-to-weight (0.62×) and the roll and pitch authorities (0.97×) low."""
    gain, off = np.array([1.25, 1.107, 1.19, 1.094]), np.array([-0.257, -0.114, -0.183, -0.09])
    off = off - (gain + off).mean() + 1.0
    w = THETA[P.OMEGA_MAX]
    rec = synthetic_log(THETA, seconds=4.0, gyro_noise=0.02, acc_noise=0.2, seed=3, speed_noise=5.0,
                        rotor_gain=gain, rotor_offset=off * w)
    fit = speed_fit(rec, first_row(len(rec["motor"])))
    assert fit["per_rotor"] and fit["r2"] > 0.98 and fit["r2_shared"] < 0.8, (fit["r2"], fit["r2_shared"])
    np.testing.assert_allclose(np.array(fit["gain_rad_s"]) / w, gain, rtol=0.01)
    np.testing.assert_allclose(np.array(fit["offset_rad_s"]) / w, off, atol=0.005)
    assert fit["omega_ref_rad_s"] == pytest.approx(w, rel=0.005)
    per, shared = (log_grounded_posterior(LD.prepare(rec, speeds=m), None, samples=400, particles=256, seed=1,
                                          calibration=None) for m in ("model", "shared"))
    lo, med, hi = _bands(per)
    for j in (0, 1, 2, 3):
        assert lo[j] <= TRUE[j] <= hi[j] and abs(med[j] / TRUE[j] - 1) < 0.02, (C.LOG_NAMES[j], lo[j], TRUE[j], hi[j])
    lo, med, hi = _bands(shared)
    for j, below in ((0, 0.8), (2, 0.985), (3, 0.985)):
        assert hi[j] < TRUE[j] and med[j] / TRUE[j] < below, (C.LOG_NAMES[j], lo[j], TRUE[j], hi[j])
