"""The model check's window-length test (mjxsysid.identify.windowcheck): a closed loop that answers a
disturbance the model lacks moves the rate coordinates' fit with the windows' length and fails the check;
the same loop without it does not.

The logs are the exact forward model's (tests/support/exact_model_log.py), 6 s: one window bucket, so the
mode's compiled least squares serves every test here (and the Crazyflie's log16, of the same shapes)."""
import numpy as np

from mjxsysid import theta as P
from mjxsysid.identify import calibrate as C
from mjxsysid.identify import windowcheck as W
from mjxsysid.identify.coords import PHYSICAL_PRIOR
from mjxsysid.identify.batched import _Logs
from mjxsysid.identify.inference import _starts
from mjxsysid.identify.logdata import prepare
from mjxsysid.identify.mode import find_modes
from support.exact_model_log import synthetic_log
from support.paths import SHARED_DATA, require_shared


def _check(rec) -> dict:
    """The window check of a log's arrays from its mode, as the posterior computes it."""
    d = prepare(rec)
    st = _starts(d, None, np.random.default_rng(0), PHYSICAL_PRIOR, 12)
    modes = find_modes(_Logs([d]), st[None].astype(np.float32), PHYSICAL_PRIOR)
    return W.run(_Logs, [d], modes, PHYSICAL_PRIOR)[0]


def _features(check) -> dict:
    """Features inside the calibration set's range, with the window check's."""
    return {f: -1.0 for f in C.FEATURE_NAMES} | {"rates_used": True} | C.window_features(check)


def test_feedback_against_an_unmodelled_disturbance_fails_the_check_and_a_fitting_loop_passes():
    table = C.load()
    thr = table[W.KEY]["threshold"]
    fits = _check(synthetic_log(P.paper_hardware(), seconds=6.0, closed_loop=True, gyro_noise=0.01))
    gust = _check(synthetic_log(P.paper_hardware(), seconds=6.0, closed_loop=True, gyro_noise=0.01, torque_noise=20.0))
    assert fits["shift"] < thr < gust["shift"], (fits["shift"], thr, gust["shift"])
    assert gust["shifts"]["A_x"][4] < -0.5          # the roll authority biased low at long windows, as on a Crazyflie
    bad = C.model_check(_features(gust), [1.0] * 4, table)
    assert not bad["rates_ok"] and bad["acc_ok"] and bad["window"]["ok"] is False
    assert all(not C.coord_ok(bad, j) for j in np.flatnonzero(C.RATE_COORDS))
    assert "depend on the window length" in bad["why"]["rates_nsr_x"][0] and f"{thr:.2f}" in bad["why"]["rates_nsr"][0]
    good = C.model_check(_features(fits), [1.0] * 4, table)
    assert good["rates_ok"] and good["window"]["ok"] is True


def test_the_check_says_when_it_did_not_run():
    table = C.load()
    none = C.model_check(_features(None), [1.0] * 4, table)
    assert none["rates_ok"] and none["window"]["ok"] is None and "not run" in none["window"]["why"]
    no_threshold = {k: v for k, v in table.items() if k != W.KEY}
    chk = C.model_check(_features({"shift": 1e3, "coord": "A_x", "factor": 4}), [1.0] * 4, no_threshold)
    assert chk["rates_ok"] and "no threshold" in chk["window"]["why"]
    # each sampler's table carries the one threshold (the check reads the mode, not the draws)
    assert C.for_method(table, "smc_nuts")[W.KEY] == table[W.KEY]


def test_crazyflie_log16_fails_the_window_check():
    """A real flight whose rate loop answers what the model lacks (docs/logs.md, Crazyflie)."""
    rec_path = require_shared(SHARED_DATA / "logs" / "crazyflie" / "log16.bin")
    from mjxsysid.logs.csvlog import read_any_log
    chk = _check(read_any_log(rec_path))
    assert chk["shift"] > C.load()[W.KEY]["threshold"], chk
