"""The innovations' vibration whitening (mjxsysid.identify.vibration): detection, the filter, and the
closed-loop bias it removes."""
import numpy as np
import pytest
from scipy.signal import lfilter

from mjxsysid import theta as P
from mjxsysid.identify import coords as C
from mjxsysid.identify import likelihood as L
from mjxsysid.identify import logdata as LD
from mjxsysid.identify import vibration as V
from support.exact_model_log import likelihood_peaks, synthetic_log


def test_whitening_filter_recovers_a_resonators_polynomial():
    """A two-pole resonator's density (poles at 80 Hz, r 0.9) -> the whitening polynomial 1 − φ₁ q⁻¹ − φ₂ q⁻²
    (the higher orders ≈ 0), and white noise stays white (A = 1, the error's share 1)."""
    r, f0, dt = 0.9, 80.0, 0.002
    phi1, phi2 = 2 * r * np.cos(2 * np.pi * f0 * dt), -r * r
    w = np.linspace(0, np.pi, 2049)
    dens = 1.0 / np.abs(1 - phi1 * np.exp(-1j * w) - phi2 * np.exp(-2j * w)) ** 2
    a, err = V.whitening_filter(dens, order=8)
    np.testing.assert_allclose(a[:3], [1.0, -phi1, -phi2], atol=2e-3)
    np.testing.assert_allclose(a[3:], 0.0, atol=2e-3)
    a, err = V.whitening_filter(np.ones(2049), order=8)
    np.testing.assert_allclose(a, np.eye(9)[0], atol=1e-9)
    assert abs(err - 1) < 1e-9


def test_a_vibration_is_detected_and_white_noise_or_a_clean_flight_is_not():
    rng = np.random.default_rng(0)
    n = 10000
    body = lfilter([1.0], [1.0, -1.99, 0.9901], rng.standard_normal((n, 3)), axis=0) * 1e-3   # slow rates
    white = body + 0.05 * rng.standard_normal((n, 3))
    r = np.exp(-np.pi * 20 * 0.002)
    vib = lfilter([1.0], [1.0, -2 * r * np.cos(2 * np.pi * 90 * 0.002), r * r], rng.standard_normal((n, 3)), axis=0)
    for y, expect in ((body, False), (white, False), (body + 0.01 * vib, True)):
        poly, eps, found = V.gyro_whiteners(y, 0.002)
        assert np.all(found == expect), (expect, found)
        assert poly.shape == ((3, V.ORDER + 1) if expect else (3, 1))
        assert np.all(np.isfinite(eps) == expect)
        assert np.all(V.detected_axes(y, 0.002) == expect)
    # a gyro logged at 100 or 20 Hz: the 90 Hz peak lies above its Nyquist frequency (the resampling's images)
    assert np.all(V.detected_axes(body + 0.01 * vib, 0.002, max_hz=250.0))
    assert not np.any(V.detected_axes(body + 0.01 * vib, 0.002, max_hz=50.0))
    assert not np.any(V.detected_axes(body + 0.01 * vib, 0.002, max_hz=10.0))
    # the feature every log carries, whichever rate term reads the gyro
    theta = P.paper_hardware().copy()
    for vibration, expect in ((0.0, False), (0.2, True)):
        rec = synthetic_log(theta, seconds=10.0, gyro_noise=0.005, gyro_vibration=vibration, seed=1, closed_loop=True)
        assert LD.vibrating(LD.prepare(rec)) is expect
    # a gyro its log says was resampled from 20 Hz shows no rotor (its Nyquist frequency, 10 Hz, is below 25 Hz)
    t = np.arange(len(rec["imu"])) * LD.DT
    rec["native"] = {"imu": (t[::25], np.asarray(rec["imu"])[::25])}
    assert LD.native_rate_hz(rec, "imu") == pytest.approx(20.0) and LD.vibrating(LD.prepare(rec)) is False
    assert np.all(np.asarray(LD.prepare(rec, rates="innovations").kf_rscale) == 1.0)     # nor whitened


def test_innovations_unbiased_under_a_vibration_in_closed_loop():
    """A rate controller reacting to a rotor vibration on the gyro (0.2 rad/s, at the rotors' frequency,
    as the simulator's): the innovations without the whitening read the vibration as rate signal (τ_m
    at the τ grid's fastest end, the roll authority 5×+); whitened, the least squares lands on the true τ_m's
    grid neighbour (9 % apart) and the likelihood peaks within 4 % of τ_m and 1 % of the roll authority."""
    theta = P.paper_hardware().copy()
    rec = synthetic_log(theta, seconds=10.0, gyro_noise=0.005, gyro_vibration=0.2, seed=1, closed_loop=True)
    v = np.asarray(C.visible_from_theta(theta))
    white = L.linear_start(LD.prepare(rec, rates="innovations", vibration=False))
    assert np.exp(white[4] - v[4]) < 0.5 and np.exp(white[5] - v[5]) > 3, np.exp(white[4:6] - v[4:6])
    data = LD.prepare(rec, rates="innovations")
    assert np.asarray(data.kf_rscale).shape == (3,) and float(data.kf_n) == 5000 - 1 - LD.first_row(5000) - V.ORDER
    x0 = L.linear_start(data)
    assert abs(np.exp(x0[4] - v[4]) - 1) < 0.1, np.exp(x0[4] - v[4])
    np.testing.assert_allclose(x0[5:7], v[5:7], atol=0.02)
    d_tau, d_roll = likelihood_peaks(data, v, x0)
    assert abs(d_tau) <= 0.04 and abs(d_roll) <= 0.01, (d_tau, d_roll)
    # the host's innovations (the correlation discounts') are the whitened ones: about white at the truth
    e = L.innovation_series(np.concatenate([v, x0[12:20], [0.0]]), data)
    assert e.shape == (3, int(data.kf_n))
    phi = [float(a[1:] @ a[:-1] / (a @ a)) for a in e - e.mean(1, keepdims=True)]
    assert max(abs(p) for p in phi) < 0.2, phi
