"""The model check's motor-map test (mjxsysid.identify.idlecheck): a log whose motors idle at a share of
their full speed fits better with that idle offset and fails the check; the same vehicle without one
does not. The logs are the exact forward model's (tests/support/exact_model_log.py), 6 s: the shapes of
tests/identify/test_windowcheck.py's, so the mode's compiled least squares serves both."""
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.identify import calibrate as C
from mjxsysid.identify import idlecheck as I
from mjxsysid.identify import logspace as L
from mjxsysid.identify.coords import PHYSICAL_PRIOR, visible_from_theta
from mjxsysid.identify.batched import _Logs
from mjxsysid.identify.inference import _starts
from mjxsysid.identify.logdata import prepare
from mjxsysid.identify.mode import find_modes
from support.exact_model_log import synthetic_log

IDLE = 0.1


def _check(rec, shared=None):
    """The motor-map check of a log's arrays from its mode, as the posterior computes it; with ``shared``
    (maps other flights showed) also the check with them: (check, check with them)."""
    d = prepare(rec)
    st = _starts(d, None, np.random.default_rng(0), PHYSICAL_PRIOR, 12)
    modes = find_modes(_Logs([d]), st[None].astype(np.float32), PHYSICAL_PRIOR)
    if shared is None:
        return I.run(_Logs, [d], modes)[0]
    return I.run(_Logs, [d], modes)[0], I.run(_Logs, [d], modes, shared=shared)[0]


def _idle_log(theta, idle, **kw):
    """The vehicle's log with its motors at Ω_max (idle + (1 − idle) s): the simulator's ``motor_idle``."""
    wmax = float(np.asarray(theta)[P.OMEGA_MAX])
    return synthetic_log(theta, rotor_gain=np.full(4, 1.0 - idle), rotor_offset=np.full(4, idle * wmax), **kw)


def test_mapped_commands_and_the_equivalent_vehicle():
    u = np.array([[0.0, 0.5, 1.0, 1.2]])
    assert np.allclose(I.mapped(u, 0.1), [[0.1, 0.55, 1.0, 1.0]])
    assert np.allclose(I.mapped(u, -0.1), [[0.0, 0.45, 1.0, 1.0]])
    y = np.linspace(-1, 1, L.N_Y).astype(np.float32)
    e = I.equivalent(y, 0.5, 0.1)
    s = 0.1 + 0.9 * 0.5
    # the same thrust at the mean command: T/W ∝ 1 / s², and the same torque per command differential
    assert np.exp(e[L.LOG_TW]) * s ** 2 == pytest.approx(np.exp(y[L.LOG_TW]) * 0.5 ** 2, rel=1e-5)
    assert np.exp(e[L.LOG_AUTH_X]) * s * 0.9 == pytest.approx(np.exp(y[L.LOG_AUTH_X]) * 0.5, rel=1e-5)
    assert e[L.LOG_TAU_M] == y[L.LOG_TAU_M] and e[L.LOG_AUTH_Z] == y[L.LOG_AUTH_Z]
    assert np.allclose(I.equivalent(e, 0.5, 0.1, inverse=True), y, atol=1e-6)
    # the simulator's map, curved: the same share of Ω_max, and the torque per differential by its slope
    from mjxsysid.sim.motors import commanded_speed
    from mjxsysid.sim.quadrotor import SimConfig
    uu = np.linspace(0.0, 1.0, 41)[:, None].repeat(4, 1)
    for kappa in (0.3, 1.6, 2.0):                      # concave, and convex (u² at κ 2)
        cfg = SimConfig(motor_idle=-0.1, motor_kappa=kappa)
        assert np.allclose(I.mapped(uu, -0.1, kappa), np.asarray(commanded_speed(uu, 1.0, cfg)), atol=1e-6)
        s, h = float(I.mapped(0.5, -0.1, kappa)), 1e-4
        slope = float(I.mapped(0.5 + h, -0.1, kappa) - I.mapped(0.5 - h, -0.1, kappa)) / (2 * h)
        assert I._slope(0.5, -0.1, kappa) == pytest.approx(slope, rel=1e-6)
        e = I.equivalent(y, 0.5, -0.1, kappa=kappa)
        assert np.exp(e[L.LOG_TW]) * s ** 2 == pytest.approx(np.exp(y[L.LOG_TW]) * 0.5 ** 2, rel=1e-5)
        assert np.exp(e[L.LOG_AUTH_X]) * s * slope == pytest.approx(np.exp(y[L.LOG_AUTH_X]) * 0.5, rel=1e-4)
    assert np.allclose(I.mapped(uu, 0.0, 2.0), uu ** 2)
    with pytest.raises(ValueError, match="motor_kappa must be in \\[0, 2\\]"):
        SimConfig(motor_kappa=2.5)


def test_an_idling_motor_fails_the_check_and_the_same_vehicle_without_idle_passes():
    table = C.load()
    thr = table[I.KEY]["threshold"]
    th = P.paper_hardware()
    fits = _check(synthetic_log(th, seconds=6.0, closed_loop=True, gyro_noise=0.01))
    other = (-0.1, 0.5)                             # a concave map another flight of the vehicle showed
    idles, shared = _check(_idle_log(th, IDLE, seconds=6.0, closed_loop=True, gyro_noise=0.01), (other, (IDLE, 1.0)))
    assert fits["gain"] < thr < idles["gain"], (fits["gain"], thr, idles["gain"])
    assert idles["map"] == (IDLE, 1.0)
    tw = idles["thrust_to_weight"]
    assert tw[IDLE, 1.0] < tw[None]                 # without the idle, thrust-to-weight comes out high
    feats = {f: -1.0 for f in C.FEATURE_NAMES} | {"rates_used": True}
    bad = C.model_check(feats | I.features(idles), [1.0] * 4, table)
    assert bad["idle"]["ok"] is False and "command→speed map" in bad["reasons"][-1] and f"{IDLE:+.2f}" in bad["reasons"][-1]
    good = C.model_check(feats | I.features(fits), [1.0] * 4, table)
    assert good["idle"]["ok"] is True and all(good["ok"].values())
    # thrust-to-weight re-fitted under the idle: lower, by the shift the bands are widened with
    shift = idles["shift"][L.LOG_TW]
    assert shift == pytest.approx(np.log(tw[IDLE, 1.0] / tw[None]), abs=1e-4) and shift < -0.05
    f_bad = feats | I.features(idles)
    m0 = float(np.log(tw[None]))                                   # a posterior at the linear map's re-fit
    low, high = I.widening(bad["idle"], f_bad, L.LOG_TW, m0)       # the span of the plausible maps holds the idle's
    assert low - 1e-5 <= shift <= high + 1e-5 and (IDLE, 1.0) in idles["plausible"], idles["plausible"]
    assert high < 0.0 and idles["gain"] > I.SPAN_TOL              # the linear map is not plausible: its value left out
    assert I.widening(bad["idle"], f_bad, L.LOG_TW, m0 + 0.1) == pytest.approx((low - 0.1, high - 0.1))  # to the values
    assert I.widening(bad["idle"], f_bad, L.LOG_TAU_M, 0.3) == pytest.approx(tuple(idles["span"][k][L.LOG_TAU_M]
                                                                                 for k in (0, 1)))  # by the shifts
    assert I.widening(bad["idle"], f_bad | {"idle_span": None}, L.LOG_TW, m0) == (shift, 0.0)     # rows without a span
    assert I.widening(good["idle"], feats | I.features(fits), L.LOG_TW, m0) == (0.0, 0.0)
    assert I.widening(bad["idle"], f_bad | {"idle_shift": None, "idle_span": None}, L.LOG_TW, m0) is None
    # a map the vehicle's other flights showed: in the span, though this log's own fit rejects it
    assert other not in idles["plausible"] and shared["shared"] == [other] and shared["plausible"] == idles["plausible"]
    assert I.features(shared)["idle_plausible"] == [list(m) for m in idles["plausible"]] + [list(other)]
    assert I.features(idles)["idle_plausible"] == [list(m) for m in idles["plausible"]]
    lo_s, hi_s = np.array(shared["span"])
    assert np.all(lo_s <= np.array(idles["span"][0]) + 1e-9) and np.all(hi_s >= np.array(idles["span"][1]) - 1e-9)
    assert max(abs(lo_s - np.array(idles["span"][0])).max(), abs(hi_s - np.array(idles["span"][1])).max()) > 0.01
    from mjxsysid.identify import PosteriorConfig
    assert PosteriorConfig(shared_maps=[[0.1, 2]]).shared_maps == ((0.1, 2.0),)
    with pytest.raises(ValueError, match="shared_maps.*not among"):
        PosteriorConfig(shared_maps=[(0.3, 1.0)])


def test_calibrate_widens_a_flagged_logs_bands_toward_the_value_under_the_idle():
    table = C.for_method(C.load(), "smc_nuts")
    rng = np.random.default_rng(0)
    v = np.asarray(PHYSICAL_PRIOR.sample_v(rng, 1), np.float64)[0] + 0.01 * rng.standard_normal((4000, L.N_V))
    feats = {f: -1.0 for f in C.FEATURE_NAMES} | {"rates_used": True, "velocity_used": False, "rotor_speed_used": False}
    shift = np.zeros(L.N_V)
    shift[L.LOG_TW] = -0.3                      # the idle moves thrust-to-weight down, nothing else
    flagged = feats | {"idle_gain": 1e3, "idle_at": "idle +0.10 Ω_max", "idle_shift": shift.tolist(), "idle_span": None}
    passed = feats | {"idle_gain": 0.0, "idle_at": "no other map fits better", "idle_shift": shift.tolist()}
    out_f, rep_f = C.calibrate(v, flagged, [1.0] * 4, table)
    out_p, rep_p = C.calibrate(v, passed, [1.0] * 4, table)
    lo_f, hi_f = np.percentile(out_f[:, L.LOG_TW], [5, 95])
    lo_p, hi_p = np.percentile(out_p[:, L.LOG_TW], [5, 95])
    assert lo_f == pytest.approx(lo_p - 0.3, abs=0.02) and hi_f == pytest.approx(hi_p, abs=0.01)
    assert rep_f["factor"][L.LOG_TW] > rep_p["factor"][L.LOG_TW] and "edges moved by -0.3 and +0" in rep_f["why"][L.LOG_TW]
    assert rep_f["factor"][L.LOG_AUTH_X] == pytest.approx(rep_p["factor"][L.LOG_AUTH_X])     # not moved: not widened
    assert "command→speed map" in rep_f["check"]["reasons"][-1]
    span = np.stack([np.minimum(shift, 0), np.maximum(shift, 0)])       # the plausible maps' shifts
    span[1, L.LOG_AUTH_X] += 0.2                # a curved map moves the roll authority up: widened up, not down
    out_s, rep_s = C.calibrate(v, flagged | {"idle_span": span.tolist()}, [1.0] * 4, table)
    assert np.percentile(out_s[:, L.LOG_TW], 5) == pytest.approx(lo_f, abs=0.01)
    lo_a, hi_a = np.percentile(out_s[:, L.LOG_AUTH_X], [5, 95])
    assert hi_a - np.percentile(out_p[:, L.LOG_AUTH_X], 95) == pytest.approx(0.2, abs=0.02)
    assert lo_a == pytest.approx(np.percentile(out_p[:, L.LOG_AUTH_X], 5), abs=0.01) and "+0.2" in rep_s["why"][L.LOG_AUTH_X]
    moved = np.zeros((2, L.N_V))
    moved[:, L.LOG_TW] = -0.5, -0.2                            # the linear map rejected: the band moves down whole
    out_m = C.calibrate(v, flagged | {"idle_span": moved.tolist()}, [1.0] * 4, table)[0]
    assert np.percentile(out_m[:, L.LOG_TW], 5) == pytest.approx(lo_p - 0.5, abs=0.02)
    assert np.percentile(out_m[:, L.LOG_TW], 95) == pytest.approx(hi_p - 0.2, abs=0.02)
    lost = C.calibrate(v, flagged | {"idle_shift": None}, [1.0] * 4, table)[1]     # no shifts: nothing seen
    assert not lost["seen"].any() and "command→speed map" in lost["why"][L.LOG_AUTH_X]


def test_the_check_says_when_it_did_not_run():
    table = C.load()
    feats = {f: -1.0 for f in C.FEATURE_NAMES} | {"rates_used": True}
    none = C.model_check(feats | I.features(None), [1.0] * 4, table)
    assert none["idle"]["ok"] is None and "not run" in none["idle"]["why"] and all(none["ok"].values())
    no_threshold = {k: v for k, v in table.items() if k != I.KEY}
    chk = C.model_check(feats | {"idle_gain": 1e6, "idle_at": "x"}, [1.0] * 4, no_threshold)
    assert chk["idle"]["ok"] is None and "no threshold" in chk["idle"]["why"]
    assert C.for_method(table, "smc_nuts")[I.KEY] == table[I.KEY]
    d = prepare(synthetic_log(P.paper_hardware(), seconds=6.0, speed_noise=5.0))
    assert I.checkable(d) == I.SPEED_SKIP


def test_a_flight_that_cannot_test_the_map_says_so_on_thrust_to_weight():
    """A log whose fit no idle of the grid moves beyond the threshold (a hover) passes the check blind: its
    thrust-to-weight says it rests on the assumed map; a log the check can test says nothing of the kind."""
    table = C.for_method(C.load(), "smc_nuts")
    thr = table[I.KEY]["threshold"]
    rng = np.random.default_rng(1)
    v = np.asarray(PHYSICAL_PRIOR.sample_v(rng, 1), np.float64)[0] + 0.01 * rng.standard_normal((400, L.N_V))
    feats = {f: -1.0 for f in C.FEATURE_NAMES} | {"rates_used": True, "velocity_used": False, "rotor_speed_used": False,
                                                  "idle_gain": 0.0, "idle_at": "no other map fits better",
                                                  "idle_shift": [0.0] * L.N_V}
    hover = feats | {"idle_power": 0.5 * thr}
    figure8 = feats | {"idle_power": 100 * thr}
    assert I.blind(C.model_check(hover, [1.0] * 4, table)["idle"], hover)
    assert not I.blind(C.model_check(figure8, [1.0] * 4, table)["idle"], figure8)
    why_h = C.calibrate(v, hover, [1.0] * 4, table)[1]["why"]
    why_f = C.calibrate(v, figure8, [1.0] * 4, table)[1]["why"]
    assert "collective varied too little" in why_h[L.LOG_TW] and "collective" not in why_f[L.LOG_TW]
    assert "collective" not in why_h[L.LOG_AUTH_X]


def test_a_curved_map_is_flagged_and_the_span_of_plausible_maps_holds_the_truth():
    """The Crazyflie's kind of map, Ω ∝ √u less a dead band: the check flags it, a curved map fits best and
    re-fits thrust-to-weight near the truth, and the widened band reaches the truth."""
    th = P.paper_hardware()
    true_tw = float(np.asarray(visible_from_theta(th))[L.LOG_TW])
    c = _check(synthetic_log(th, seconds=6.0, closed_loop=True, gyro_noise=0.01,
                             motor_map=lambda u: I.mapped(u, -0.1, 0.0)))
    assert c["gain"] > C.load()[I.KEY]["threshold"] and c["map"][1] < 1.0, (c["gain"], c["map"])
    fit0 = np.log(c["thrust_to_weight"][None])
    assert fit0 - true_tw > 0.5                                       # the linear map's thrust-to-weight: far too high
    assert abs(np.log(c["thrust_to_weight"][c["map"]]) - true_tw) < 0.15, c["thrust_to_weight"]
    low, high = I.widening({"ok": False}, I.features(c), L.LOG_TW, fit0)
    assert fit0 + low <= true_tw and (-0.1, 0.0) in c["plausible"] and "(curved)" in I.features(c)["idle_at"]
    assert I.features(c)["idle_map"] == list(c["map"]) and I.features(None)["idle_map"] is None


def test_a_convex_map_is_flagged_and_refitted_near_the_truth():
    """Gazebo-classic's motors read through PX4's thrust model with THR_MDL_FAC 0: the rotor speed linear in
    the ESC's command u = s² from 0.09 Ω_max (Ω = 100 + 1000 u rad/s of 1100), while the log's commands say
    √u. The check flags it, the convex map κ 2 fits best, and thrust-to-weight under it lies near the truth
    (the linear map's is 25 % low)."""
    th = P.paper_hardware()
    true_tw = float(np.asarray(visible_from_theta(th))[L.LOG_TW])
    c = _check(synthetic_log(th, seconds=6.0, closed_loop=True, gyro_noise=0.01,
                             motor_map=lambda s: 0.0909 + 0.9091 * np.clip(s, 0, 1) ** 2))
    assert c["gain"] > C.load()[I.KEY]["threshold"] and c["map"][1] == 2.0, (c["gain"], c["map"])
    assert np.log(c["thrust_to_weight"][None]) - true_tw < -0.15
    assert abs(np.log(c["thrust_to_weight"][c["map"]]) - true_tw) < 0.1, c["thrust_to_weight"]


def test_the_variants_reduced_on_threads_and_processes_are_the_ones_reduced_one_by_one(monkeypatch):
    """idlecheck._variants: every (map, log) pair, in order, equal to variant() called one by one and to the
    arrays of a full prepare() of the mapped log, on threads and on processes (``workers``), also when the
    pairs come a few at a time; the window check's reductions on the same pool equal windowcheck.variants()."""
    import sys

    import jax
    logs = [prepare(synthetic_log(P.paper_hardware(), seconds=6.0, seed=s)) for s in (0, 1)]
    maps = I.MAPS[:3] + I.MAPS[-2:]
    monkeypatch.setattr(I, "VARIANTS_AT_ONCE", 4)                       # two maps × two logs per round
    # a pytest-xdist worker's __main__ lacks the __spec__ a script's has (None), which spawning a process reads
    monkeypatch.setattr(sys.modules["__main__"], "__spec__", getattr(sys.modules["__main__"], "__spec__", None),
                        raising=False)
    from mjxsysid.identify import windowcheck as W
    from mjxsysid.runtime.hostpool import HostPool
    for workers in (1, 2):
        with HostPool(workers) as pool:
            got = list(I._variants(logs, maps, pool))
            jobs = [W._job(d) for d in logs] * 2                        # four logs: two per process
            windows = pool.map(W._reduced, *zip(*jobs))
            assert pool.processes(len(jobs)) == (workers == 2)
        for d, ws in zip(logs * 2, windows):
            want = W.variants(d)
            assert [k for k, _ in ws] == [k for k, _ in want] == list(W.WINDOW_FACTORS)
            for (_, a), (_, b) in zip(ws, want):
                for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
                    np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
        assert [m for m, _ in got] == list(maps)
        for m, vs in got:
            for d, v in zip(logs, vs):
                assert not hasattr(v, "_rows")                          # the arrays alone
                rec = dict(d._rows["rec"], motor=I.mapped(d._rows["rec"]["motor"], *m))
                full = prepare(rec, pad_to=(d.wmask.shape[0], d.bmask.shape[0]), **d._rows["rec_args"])
                for want in (I.variant(d, *m), full):
                    for a, b in zip(jax.tree.leaves(v), jax.tree.leaves(want), strict=True):
                        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))

