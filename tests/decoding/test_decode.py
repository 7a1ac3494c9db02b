"""`mjxsysid decode`: flight-log replay, decoding at a rate, the summary, error paths."""
import json

import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.cfm.posterior import summarize_posterior
from mjxsysid.cli import main
from mjxsysid.logs.csvlog import LOG_COLUMNS, read_log, write_log
from mjxsysid.policy.interface import PRETRAINED_DIR, resolve_policy
from mjxsysid.decoding import decode_latents

pytestmark = pytest.mark.skipif(not (PRETRAINED_DIR / "cfm.npz").exists(), reason="no shipped decoder")


@pytest.fixture(scope="module")
def paper_flight():
    from mjxsysid.rollout.flight import fly_vehicles, one_flight
    # 2 s: the flight of notebooks 00 and 01, so their kernels load this compile from the cache.
    fl, _, _ = fly_vehicles(P.PAPER_HARDWARE, controller="policy", policy=resolve_policy("mjxsysid"),
                            reference="lemniscate", duration=2.0)
    return one_flight(fl)


def _log_from_flight(f):
    """The IMU the controller saw at each step is the previous step's output."""
    from mjxsysid.rollout.flight import seen_imu
    return f.time - 0.002, seen_imu(f.frame.imu), f.a_cmd, f.omega_cmd, f.frame.motor_cmd


def test_log_replay_reproduces_the_flight_latent(paper_flight, tmp_path):
    path = write_log(tmp_path / "flight.csv", *_log_from_flight(paper_flight))
    rec = read_log(path)
    # a flight's log in memory (what the studies hand the log-grounded posterior) is the log on disk
    from mjxsysid.rollout.flight import flight_log
    mem = flight_log(paper_flight.frame)
    for k in ("imu", "motor"):
        np.testing.assert_allclose(mem[k], rec[k], rtol=1e-6, atol=1e-6)
    from mjxsysid.policy.adaptive.controller import PolicyController
    z = PolicyController.load().replay(rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"])
    np.testing.assert_allclose(z, paper_flight.latent, atol=2e-4)
    # End to end through the CLI.
    out = tmp_path / "dec"   # the decoders alone (--decoder-only: the behaviour before the log-grounded posterior)
    # --samples 20 --rate 2: the shapes of test_api.py's decode of this log (one compile in this worker group)
    assert main(["decode", "--log", str(path), "--decoder-only", "--samples", "20", "--rate", "2", "--out", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert set(P.PARAM_NAMES) <= set(s) and "true" not in s["mass"]
    # a correct log of a prior vehicle: the plausibility and out-of-prior checks find nothing
    assert s["_checks"]["warnings"] == [] and s["_checks"]["out_of_prior"] == []
    assert "Out of the decoders' training prior" not in (out / "summary.md").read_text()
    # With the logged vehicle's known parameters (--truth), the summary says what is inside.
    truth = P.save_vehicle(P.PAPER_HARDWARE, tmp_path / "paper.json")
    out_t = tmp_path / "dec_truth"
    assert main(["decode", "--log", str(path), "--truth", str(truth), "--samples", "20", "--rate", "2",
                 "--out", str(out_t)]) == 0
    st = json.loads((out_t / "summary.json").read_text())
    for n, v in zip(P.PARAM_NAMES, P.PAPER_HARDWARE):
        assert st[n]["true"] == pytest.approx(float(v), rel=1e-6)
        assert st[n]["inside"] == (st[n]["q05"] <= st[n]["true"] <= st[n]["q95"])
        assert st["_decoder_only"][n]["mean"] == pytest.approx(s[n]["mean"], rel=1e-5)   # the truth changes the report, not the decoding
    assert sum(st[n]["inside"] for n in P.PARAM_NAMES) >= 15
    assert "_log_grounded" not in s
    # the posterior of record is the log-grounded one; the decoders' stays beside it
    assert st["_posterior"] == "log-grounded" and set(P.PARAM_NAMES) <= set(st["_decoder_only"])
    assert st["_log_grounded"]["rates"] == "windows"            # the default rate term, said
    assert st["thrust_to_weight"]["inside"], st["thrust_to_weight"]
    gap = st["_log_grounded"]["gap"]["thrust_to_weight"]
    assert gap["seen_by_log"] and gap["log_inside"]
    assert (out_t / "information_gap.png").stat().st_size > 0 and (out_t / "marginals_decoder_only.png").exists()
    assert "information gap" in (out_t / "summary.md").read_text()


def test_decode_summary_brackets_the_paper_vehicle(paper_flight):
    # The first second of the flight (the 1 s flight this test was written for: same steps).
    latent, time = paper_flight.latent[:500], paper_flight.time[:500]
    dec = decode_latents(latent, time, rate=10, samples=100)
    assert dec["samples"].shape == (9, 100, 19) and dec["regression"].shape == (9, 19)
    np.testing.assert_allclose(dec["times"][1] - dec["times"][0], 0.1, atol=1e-6)
    s = summarize_posterior(dec["samples"][-1], P.PAPER_HARDWARE)
    for n in P.PARAM_NAMES:
        assert s[n]["q05"] <= s[n]["mean"] <= s[n]["q95"]
    inside = sum(s[n]["inside"] for n in P.PARAM_NAMES)
    assert inside >= 15, inside  # calibrated 90 % intervals: most of 19 contain the truth
    with pytest.raises(ValueError, match="rate"):
        decode_latents(latent, time, rate=0, samples=10)


def test_read_log_errors(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("t,gyro_x\n0,0\n")
    with pytest.raises(ValueError, match="missing column"):
        read_log(p)
    rows = np.zeros((50, len(LOG_COLUMNS)))
    np.savetxt(p, rows, delimiter=",", header=",".join(LOG_COLUMNS), comments="")
    with pytest.raises(ValueError, match="at least 100"):
        read_log(p)
    rows = np.zeros((120, len(LOG_COLUMNS)))
    rows[:, 0] = np.arange(120) * 0.002
    rows[5, -1] = 3.0
    np.savetxt(p, rows, delimiter=",", header=",".join(LOG_COLUMNS), comments="")
    with pytest.raises(ValueError, match="normalised"):
        read_log(p)
    with pytest.raises(FileNotFoundError):
        read_log(tmp_path / "nope.csv")


def test_project_valid():
    th = np.tile(P.PAPER_HARDWARE, (2, 1))
    th[1, 6] = 1.0  # J_zz > J_xx + J_yy
    ok, changed = P.project_valid(th)
    assert changed.tolist() == [False, True]
    P.validate_theta(ok)


def test_decode_cli_errors(tmp_path, capsys):
    assert main(["decode", "--vehicle", "v.json", "--log", "l.csv", "--out", str(tmp_path)]) == 2
    assert "either --vehicle or --log" in capsys.readouterr().err
    assert main(["decode", "--truth", "v.json", "--out", str(tmp_path)]) == 2
    assert "--truth needs --log" in capsys.readouterr().err
    assert main(["decode", "--rates", "innovations", "--out", str(tmp_path)]) == 2
    assert "--rates needs --log" in capsys.readouterr().err
    assert main(["decode", "--log", "l.csv", "--rates", "innovations", "--decoder-only", "--out", str(tmp_path)]) == 2
    assert "not --decoder-only" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["decode", "--log", "l.csv", "--rates", "kalman", "--out", str(tmp_path)])
    assert "invalid choice" in capsys.readouterr().err
    import mjxsysid
    with pytest.raises(ValueError, match="rates must be"):
        mjxsysid.decode("l.csv", rates="kalman")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert main(["decode", "--log", "l.csv", "--truth", str(bad), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "bad.json" in err and "not valid JSON" in err and len(err.splitlines()) == 1
    neg = tmp_path / "neg.json"
    P.save_vehicle(P.PAPER_HARDWARE, neg)
    d = json.loads(neg.read_text())
    d["mass"] = -1.0
    neg.write_text(json.dumps(d))
    assert main(["decode", "--log", "l.csv", "--truth", str(neg), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "mass" in err and len(err.splitlines()) == 1


@pytest.mark.slow
def test_closed_loop_fidelity_runs():
    """Slow (≈ 1 min of compiles on CPU): envelopes are computed and bounded."""
    from mjxsysid.uses.fidelity import closed_loop_fidelity
    r = closed_loop_fidelity(P.PAPER_HARDWARE, n_models=8, reference="hover", duration=1.0,
                             force_step=(1.0, 1.0, 0.0))
    m = r["mean"]
    assert 0.0 <= m["inside_decoded"] <= 1.0 and m["width_decoded_m"] >= 0.0
    assert m["width_pm20_m"] >= 0.0
    # the log-grounded posterior's draws: their mass as broad as the prior (an external force acts
    # through it), so the envelope is wider than the decoded one; weighed, narrower than that
    kw = {"n_models": 8, "reference": "hover", "duration": 1.0, "force_step": (1.0, 1.0, 0.0)}
    lg, lw = (closed_loop_fidelity(P.PAPER_HARDWARE, posterior=p, **kw)["mean"]
              for p in ("log_grounded", "log_grounded_weighed"))
    assert lg["width_decoded_m"] > lw["width_decoded_m"] and lg["inside_decoded"] >= 0.5


def test_read_log_fast_path_equals_the_careful_parser_and_memory_limit(paper_flight, tmp_path, monkeypatch):
    """A clean log is read by numpy's C parser; an extra text column sends the same rows through
    the careful parser: the arrays agree exactly. A log that cannot fit is one line naming the limit."""
    import mjxsysid.logs.csvlog as D
    clean = write_log(tmp_path / "clean.csv", *_log_from_flight(paper_flight))
    lines = clean.read_text().splitlines()
    (tmp_path / "extra.csv").write_text("\n".join([lines[0] + ",pilot"] + [ln + ",bob" for ln in lines[1:]]) + "\n")
    assert D._read_log_fast(clean) is not None and D._read_log_fast(tmp_path / "extra.csv") is None
    a, b = read_log(clean), read_log(tmp_path / "extra.csv")
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    monkeypatch.setattr(D, "available_memory", lambda: 1000)
    with pytest.raises(ValueError, match=r"needs about .* GB of memory to decode, .* available: split the log") as e:
        read_log(clean)
    assert "\n" not in str(e.value)


def test_summary_md_says_a_vibrating_log_was_calibrated_on_vibrating_logs():
    from mjxsysid.decoding.command import _model_check_lines
    on = {"log_thrust_to_weight": "simulated logs with velocity", "log_motor_time_constant": "vibrating simulated logs",
          "log_yaw_authority": ""}
    g = {"calibration": {"model_check": {"window": {"why": "w"}, "idle": {"why": "i"}, "reasons": []},
                         "features": {"vibration": True}, "calibrated_on": on}}
    lines = _model_check_lines(g)
    assert lines[-1] == ("- rotor vibration: a narrow-band peak in the gyro; calibrated on vibrating simulated logs: "
                         "log_motor_time_constant")
    g["calibration"]["features"]["vibration"] = False
    assert not any("vibration" in ln for ln in _model_check_lines(g))


def test_summary_md_says_a_log_without_velocity_leaves_the_body_drag_unseen():
    from mjxsysid.decoding.command import _model_check_lines
    from mjxsysid.identify.calibrate import NO_VELOCITY, NO_VELOCITY_WHY
    g = {"calibration": {"model_check": {"window": {"why": "w"}, "idle": {"why": "i"}, "reasons": []},
                         "features": {"velocity_used": False},
                         "calibrated_on": {"log_thrust_to_weight": NO_VELOCITY, "log_yaw_authority": "x"}}}
    assert f"- velocity: {NO_VELOCITY_WHY} (log_thrust_to_weight)" in _model_check_lines(g)
    g["calibration"]["features"]["velocity_used"] = True
    assert not any(ln.startswith("- velocity") for ln in _model_check_lines(g))


def test_summary_md_says_whether_nuts_mixed_and_why_it_ran_again():
    from mjxsysid.decoding.command import _model_check_lines
    chk = {"model_check": {"window": {"why": "w"}, "idle": {"why": "i"}, "reasons": []}}
    nuts = {"attempts": 1, "chains": 8, "warmup": 200, "draws": 125, "thin": 1, "converged": True,
            "why": "split R̂ ≤ 1.02, bulk ESS ≥ 457, 0 divergent"}
    assert "- NUTS: 8 chains mixed (split R̂ ≤ 1.02, bulk ESS ≥ 457, 0 divergent)" in _model_check_lines(
        {"calibration": chk, "nuts": nuts})
    again = dict(nuts, attempts=2, warmup=400, draws=500, thin=4,
                 first={"why": "NUTS's chains disagree (split R̂ 1.31 ≥ 1.1 on log_yaw_authority)"})
    line = [ln for ln in _model_check_lines({"calibration": chk, "nuts": again}) if "NUTS" in ln][0]
    assert "second, longer run (400 warm-up steps, 500 draws thinned by 4)" in line and "log_yaw_authority" in line
    failed = dict(again, converged=False, why="NUTS's chains disagree (split R̂ 1.2 ≥ 1.1 on ext_acc[2])")
    line = [ln for ln in _model_check_lines({"calibration": chk, "nuts": failed}) if "NUTS" in ln][0]
    assert "did not mix in 2 attempt(s)" in line and "SMC's draws are kept" in line and "ext_acc[2]" in line
    assert not any("NUTS" in ln for ln in _model_check_lines({"calibration": chk}))       # the SMC alone: no line


def test_summary_tables_carry_truth_columns_only_where_a_truth_is_known():
    """A real log has no truth: summary.md's posterior tables drop the empty "true" and "inside" columns; a simulated
    flight keeps them."""
    from mjxsysid.decoding.command import _posterior_table
    real = _posterior_table({"a": {"mean": 1.0, "q05": 0.5, "q95": 2.0, "seen_by_log": True},
                             "b": {"mean": 1.0, "q05": 0.1, "q95": 9.0, "seen_by_log": False}})
    assert real[0] == "| quantity | mean | 5 % | 95 % | seen by the log |"
    assert real[3] == "| b | 1 | 0.1 | 9 | no: as broad as the prior |"
    sim = _posterior_table({"a": {"mean": 1.0, "q05": 0.5, "q95": 2.0, "true": 1.2, "inside": True}})
    assert sim[0] == "| quantity | mean | 5 % | 95 % | true | inside |" and sim[2] == "| a | 1 | 0.5 | 2 | 1.2 | yes |"
    assert all(r.count("|") == sim[0].count("|") for r in sim) and all(r.count("|") == real[0].count("|") for r in real)
