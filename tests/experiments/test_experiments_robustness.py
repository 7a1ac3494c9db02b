"""Robustness, payload and replay experiments (issue 10 §2): energy distance, envelope statistics,
the harness's payload event, tiny runs of each experiment, the CLI, notebook 03."""
import json
from pathlib import Path

import jax
import numpy as np
import pytest

from mjxsysid import theta as P


# ----------------------------------------------------------------------------- statistics

@pytest.mark.parametrize("n,m,shift,scale", [(1, 1, 0.3, 1.0), (5, 7, 1.0, 2.0), (100, 2000, 0.1, 0.5),
                                             (40, 3, -2.0, 3.0)])
def test_energy_distance_matches_scipy(n, m, shift, scale):
    stats = pytest.importorskip("scipy.stats")
    from mjxsysid.uses.fidelity import energy_distance
    r = np.random.default_rng(n * 7 + m)
    u, v = r.normal(size=n), r.normal(shift, scale, size=m)
    assert energy_distance(u, v) == pytest.approx(stats.energy_distance(u, v), rel=1e-9, abs=1e-12)
    assert energy_distance(u, v) == pytest.approx(energy_distance(v, u), rel=1e-12)


def test_energy_distance_edge_cases():
    from mjxsysid.uses.fidelity import energy_distance
    x = np.array([0.2, 0.5, 0.5, 3.0])
    assert energy_distance(x, x) == 0.0
    # two point masses a distance d apart: sqrt(2 d)
    assert energy_distance([0.0], [2.0]) == pytest.approx(2.0)
    with pytest.raises(ValueError, match="non-empty"):
        energy_distance([], [1.0])
    with pytest.raises(ValueError, match="finite"):
        energy_distance([np.nan], [1.0])


def test_envelope_containment_constructed():
    from mjxsysid.uses.fidelity import envelope_stats
    t_n = 10
    ens = np.tile(np.arange(101.0)[:, None], (1, t_n))  # 5th / 95th percentiles: 5 and 95 at every t
    true = np.array([50.0] * 4 + [5.0] + [95.0] + [200.0] * 3 + [1.0])
    inside, width = envelope_stats(true, ens)
    assert inside == pytest.approx(0.6)  # 4 inside + both edges
    assert width == pytest.approx(90.0)
    with pytest.raises(ValueError, match="differ in length"):
        envelope_stats(true[:3], ens)


def test_step_and_mc_stats_on_constructed_ensembles():
    from mjxsysid.uses.robustness import mc_stats, step_stats
    times = np.arange(1, 21) * 0.1
    base = np.linspace(0, 1, 20)
    r = np.random.default_rng(0)
    # decoded ensemble tight around the truth, ±20 % one wide: inside 1, width ratio ~ 0.1
    g = {"true": np.stack([base, base]), "decoded": base + 0.01 * r.normal(size=(2, 50, 20)),
         "pm20": base + 0.1 * r.normal(size=(2, 50, 20)),
         "failed": {"true": False, "decoded": np.zeros(50, bool), "pm20": np.zeros(50, bool)}}
    s = step_stats(g, times, onset=0.5)
    assert s["lateral"]["inside_decoded"] == 1.0 and s["lateral"]["width_ratio"] == pytest.approx(0.1, rel=0.3)
    # Monte Carlo: decoded drawn from the same distribution as the truth, ±20 % shifted by 1
    n, k = 200, 10
    true = r.normal(size=(2, n, 20))
    g = {"true": true, "decoded": r.normal(size=(2, n, k, 20)), "pm20": 1.0 + r.normal(size=(2, n, k, 20)),
         "failed": {"true": np.zeros(n, bool), "decoded": np.zeros((n, k), bool), "pm20": np.zeros((n, k), bool)}}
    m = mc_stats(g, times, onset=0.0)["vertical"]
    assert m["coverage_decoded"] == pytest.approx(0.9, abs=0.03)
    assert m["width_ratio_decoded"] == pytest.approx(1.0, abs=0.1)
    assert m["energy_distance_decoded_m"] < 0.2 < m["energy_distance_pm20_m"]


# ----------------------------------------------------------------------------- payload physics

def test_payload_theta_and_torque_closed_form():
    from mjxsysid.rollout.harness import payload_theta, payload_torque
    th = P.PAPER_HARDWARE
    tp = np.asarray(payload_theta(th, 0.1, np.array([0.1, 0.0, 0.0])))
    assert tp[P.MASS] == pytest.approx(th[P.MASS] + 0.1)
    np.testing.assert_allclose(tp[P.INERTIA], th[P.INERTIA] + np.array([0.0, 1e-3, 1e-3]), rtol=1e-6)
    np.testing.assert_array_equal(np.delete(tp, [P.MASS, 4, 5, 6]), np.delete(th, [P.MASS, 4, 5, 6]))
    # level: the front-mounted weight pitches the nose down (+y in FLU), 0.1 kg g 0.1 m
    tau = np.asarray(payload_torque(np.array([1.0, 0, 0, 0]), np.float32(0.1), np.array([0.1, 0.0, 0.0])))
    np.testing.assert_allclose(tau, [0.0, 0.1 * P.GRAVITY * 0.1, 0.0], atol=1e-7)
    # pitched 90° nose down the weight points along the arm: no torque
    q = np.array([np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0])
    np.testing.assert_allclose(np.asarray(payload_torque(q, np.float32(0.1), np.array([0.1, 0, 0]))), 0, atol=1e-7)
    with pytest.raises(ValueError, match="payload_mass"):
        from mjxsysid.rollout.harness import Disturbance
        Disturbance.make(payload_mass=-0.1)


def test_payload_switches_at_its_step(sim):
    """Identical flights up to the event step; at that step the accelerometer reads the same
    thrust over the larger mass and the offset weight starts a nose-down pitch (closed form)."""
    from mjxsysid.rollout.harness import Disturbance, fly
    from mjxsysid.control.high_level import Cascade
    from mjxsysid.control.low_level import KTheta
    from mjxsysid.control.references import Hover
    th = P.PAPER_HARDWARE
    k_ev = 25
    event = k_ev * sim.config.dt
    run = jax.jit(lambda d: fly(sim, th, KTheta.make(th), Cascade.make("baseline"), Hover.make(), d,
                                jax.random.PRNGKey(0), 40))
    base = run(Disturbance.make())
    pay = run(Disturbance.make(payload_mass=0.1, payload_pos=(0.1, 0.0, 0.0), payload_time=event - 1e-4))
    f0, f1 = base.frame, pay.frame
    np.testing.assert_array_equal(np.asarray(f0.pos[:k_ev]), np.asarray(f1.pos[:k_ev]))
    np.testing.assert_array_equal(np.asarray(f0.imu[:k_ev]), np.asarray(f1.imu[:k_ev]))
    assert not np.allclose(np.asarray(f0.omega[k_ev]), np.asarray(f1.omega[k_ev]))
    ratio = float(f1.imu[k_ev, 5] / f0.imu[k_ev, 5])  # same rotor thrust; drag differs by ~1e-4 N
    assert ratio == pytest.approx(th[P.MASS] / (th[P.MASS] + 0.1), rel=5e-4)
    d_wy = float(f1.omega[k_ev, 1] - f0.omega[k_ev, 1])
    expect = 0.1 * P.GRAVITY * 0.1 / (th[5] + 0.1 * 0.1**2) * sim.config.dt
    assert d_wy == pytest.approx(expect, rel=0.05)


def test_default_disturbance_has_no_payload():
    from mjxsysid.rollout.harness import Disturbance
    d = Disturbance.make()
    assert float(d.payload_mass) == 0.0 and np.isinf(float(d.payload_time))


# ----------------------------------------------------------------------------- experiments (tiny)

HEAD_KEYS = {"experiment", "config", "seeds", "commit", "device", "wall_s", "policy", "decoders", "numbers"}


def _check_results(out: Path, name: str) -> dict:
    res = json.loads((out / "results.json").read_text())
    assert HEAD_KEYS <= set(res) and res["experiment"] == name
    assert res["policy"]["sha256"] and res["decoders"]["cfm_sha256"]
    assert res["numbers"]["headline"]
    md = (out / "results.md").read_text()
    assert md.startswith(f"# {name}") and "paper" in md
    return res


def _check_tiny_robustness(tmp_path: Path) -> None:
    """The robustness experiment's tiny run (notebook 03's fast settings: 0.8 s, 4 decoded and 4
    perturbed models, σ 1 and 5 N, one prior vehicle): its numbers, figures and envelopes."""
    res = _check_results(tmp_path, "robustness")
    n = res["numbers"]
    step = n["paper_vehicle"]["step"]["[1, 1, 0] N"]["lateral"]
    assert 0.0 <= step["inside_decoded"] <= 1.0 and step["width_decoded_m"] > 0
    mc = n["paper_vehicle"]["mc"]
    assert set(mc) == {"sigma=1 N", "sigma=5 N"}
    # stronger noise, larger true spread of the lateral error
    assert mc["sigma=5 N"]["lateral"]["width_true_m"] > mc["sigma=1 N"]["lateral"]["width_true_m"]
    assert n["prior_vehicles"]["n"] == 1 and len(n["prior_vehicles"]["per_vehicle"]) == 1
    assert set(n["targets"]) >= {"paper_vehicle_lateral_inside_ge_0.90", "paper_vehicle_envelope_narrower_than_pm20"}
    for f in ("robustness_step_f1_1_0.png", "robustness_step_f0_0_1.png", "robustness_mc_envelopes.png",
              "robustness_mc_final_hist.png", "robustness_prior_vehicles.png", "envelopes.npz"):
        assert (tmp_path / f).stat().st_size > 0
    with np.load(tmp_path / "envelopes.npz") as z:
        assert z["step_f1_1_0_decoded"].shape == (2, 4, len(z["times"]))
        assert z["mc_sigma5_decoded_q"].shape == (2, 3, len(z["times"]))
        assert z["mc_sigma5_decoded_final"].shape == (2, 3 * 2) and z["mc_sigma5_true_final"].shape == (2, 3)


def test_payload_tiny(tmp_path):
    """A 5 s hover with the payload at 2.5 s: the rotors end up carrying the extra 0.1 kg g."""
    from mjxsysid.experiments import payload
    cfg = payload.PayloadConfig(duration=5.0, event=2.5, samples=4, replay_samples=2, window=0.5, post_window=1.0)
    payload.run(tmp_path, quick=True, cfg=cfg, progress=False)
    res = _check_results(tmp_path, "payload")
    n = res["numbers"]
    fl = n["flight"]
    assert not fl["failed"]
    assert fl["thrust_end_N"] - fl["thrust_before_N"] == pytest.approx(0.1 * P.GRAVITY, rel=0.05)
    d = n["decoded"]
    assert d["mass_kg"]["true_after"] == pytest.approx(P.PAPER_HARDWARE[P.MASS] + 0.1)
    assert d["tau_ext_y_Nm"]["true_after"] == pytest.approx(0.1 * P.GRAVITY * 0.1, rel=1e-5)
    assert d["thrust_to_weight"]["expected_shift"] < 0
    assert set(n["replay"]["whole_flight"]) >= {"random", "regression", "cfm", "cfm_mean", "true"}
    # the payload-aware true θ explains the commands better than a random vehicle
    assert n["replay"]["whole_flight"]["true"]["rmse"] < n["replay"]["whole_flight"]["random"]["rmse"]
    assert (tmp_path / "payload_decoded.png").exists() and (tmp_path / "payload_replay.png").exists()


def test_payload_response_stats():
    from mjxsysid.experiments.payload import response
    t = np.arange(0, 60) * 0.1
    y = np.where(t < 3.0, 1.0, 2.0 - np.exp(-(t - 3.0) / 0.2))  # jumps from 1 to 2, τ = 0.2 s
    r = response(t, y, event=3.0, window=1.0, expected=2.0)
    assert r["before"] == 1.0 and r["after"] == pytest.approx(2.0, abs=1e-4)
    assert r["moved"] == pytest.approx(0.5, abs=1e-3)
    assert r["t_half_s"] == pytest.approx(0.2, abs=1e-6)  # first sample with 1 − e^{−t/τ} ≥ 0.5
    assert r["t_settle_s"] == pytest.approx(0.4, abs=1e-6)  # e^{−t/τ} ≤ 0.2 from t = 0.32 s on
    flat = response(t, np.ones_like(t), event=3.0, window=1.0, expected=1.0)
    assert not flat["resolved"] and flat["t_half_s"] is None and flat["moved"] == 0.0


def test_replay_tiny(tmp_path):
    from mjxsysid.experiments import action_replay as replay
    cfg = replay.ReplayConfig(vehicles=0, flights=("hover",), samples=2)
    replay.run(tmp_path, quick=True, cfg=cfg, progress=False)
    res = _check_results(tmp_path, "replay")
    pv = res["numbers"]["flights"]["hover"]["paper_vehicle"]
    assert pv["cfm"]["rmse"] < pv["random"]["rmse"]
    assert res["numbers"]["paper"]["lemniscate_5s"]["cfm"]["rmse"] == 0.032
    assert "| hover | CFM (1 sample) |" in (tmp_path / "results.md").read_text()
    assert (tmp_path / "replay.json").exists()


# ----------------------------------------------------------------------------- CLI

def test_cli_unknown_experiment_exits_2(tmp_path, capsys):
    from mjxsysid.cli import main
    assert main(["experiment", "no-such-experiment", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown experiment 'no-such-experiment'" in err[0] and "robustness" in err[0]
    assert main(["experiment", "payload", "--decoders", str(tmp_path / "missing"), "--out", str(tmp_path)]) == 2
    assert "--decoders" in capsys.readouterr().err


def test_config_validation():
    from mjxsysid.uses.robustness import RobustnessConfig
    from mjxsysid.experiments.payload import PayloadConfig
    with pytest.raises(ValueError, match="mc_models"):
        RobustnessConfig(mc_models=0)
    with pytest.raises(ValueError, match="onset"):
        RobustnessConfig(duration=1.0, onset=2.0)
    with pytest.raises(ValueError, match="event"):
        PayloadConfig(duration=3.0, event=2.9)
    with pytest.raises(ValueError, match="window"):
        RobustnessConfig(window="3s")
    with pytest.raises(ValueError, match="id_rate"):
        RobustnessConfig(id_rate=0.0)


def test_flight_window_needs_the_sequence_decoder():
    """window='flight' with a single-latent decoder is a named error before any flight (robustness
    study and closed-loop fidelity)."""
    from mjxsysid.uses.robustness import RobustnessConfig, robustness_study
    from mjxsysid.cfm.sample import Decoder

    class Single(Decoder):  # any single-latent decoder: never sampled
        def __init__(self):
            pass
    with pytest.raises(TypeError, match="sequence decoder"):
        robustness_study(P.PAPER_HARDWARE[None], Single(), "mjxsysid", RobustnessConfig(window="flight"),
                         jax.random.PRNGKey(0), log=lambda m: None)
    from mjxsysid.uses.fidelity import closed_loop_fidelity
    with pytest.raises(TypeError, match="sequence decoder"):
        closed_loop_fidelity(P.PAPER_HARDWARE, decoder=Single(), window="flight")
    with pytest.raises(ValueError, match="window"):
        closed_loop_fidelity(P.PAPER_HARDWARE, decoder=Single(), window="3s")
    with pytest.raises(ValueError, match="identification must be one of"):
        closed_loop_fidelity(P.PAPER_HARDWARE, decoder=Single(), window="instant", identification="test")
    with pytest.raises(ValueError, match="posterior must be one of .*log_grounded"):
        closed_loop_fidelity(P.PAPER_HARDWARE, decoder=Single(), window="instant", posterior="mcmc")
    with pytest.raises(ValueError, match="RobustnessConfig.posterior must be one of"):
        RobustnessConfig(posterior="mcmc")


@pytest.mark.slow
def test_robustness_with_the_log_grounded_posterior_weighed(tmp_path):
    """The weighed log-grounded variant runs end to end (its draws carry the true mass) and its step
    envelope is narrower than the mass-blind log-grounded one's (the force acts through the mass)."""
    from mjxsysid.uses.robustness import RobustnessConfig
    from mjxsysid.experiments import robustness_envelopes as robustness
    widths = {}
    for variant in ("log_grounded", "log_grounded_weighed"):
        cfg = RobustnessConfig(duration=1.0, onset=0.3, n_decoded=8, n_perturbed=8, mc_rollouts=3, mc_models=2,
                               sigmas=(1.0,), chunk=64)
        res = robustness.run(tmp_path / variant, quick=True, cfg=cfg, n_prior=0, progress=False, variant=variant)
        step = res["numbers"]["paper_vehicle"]["step"]["[1, 1, 0] N"]["lateral"]
        widths[variant] = step["width_decoded_m"]
        assert res["config"]["posterior"] == variant and 0.0 <= step["inside_decoded"] <= 1.0
    assert widths["log_grounded_weighed"] < widths["log_grounded"], widths


@pytest.mark.slow
def test_fidelity_identifies_on_a_held_out_flight():
    """Closed-loop fidelity decodes the latents of a separate, undisturbed identification flight
    by default (held out, as robustness does), and the test flight's own only when asked."""
    from mjxsysid.cfm.sequence import SequenceDecoder
    from mjxsysid.uses.fidelity import closed_loop_fidelity

    class Recorder(SequenceDecoder):  # a stand-in decoder: records what it is asked to decode
        max_len = 100

        def __init__(self):
            object.__setattr__(self, "seen", [])

        def sample_theta(self, zs, key, n):
            self.seen.append(np.asarray(zs))
            return np.repeat(P.PAPER_HARDWARE[None], n, 0)
    got = {}
    for ident in ("held_out", "same"):
        rec = Recorder()
        r = closed_loop_fidelity(P.PAPER_HARDWARE, decoder=rec, n_models=2, reference="hover", duration=1.0,
                                 force_step=(2.0, 0.0, 0.0), identification=ident)
        assert r["identification"] == ident
        got[ident] = rec.seen[0]
    assert got["held_out"].shape == got["same"].shape
    assert not np.allclose(got["held_out"], got["same"])   # another flight (a lemniscate, no force)


# ----------------------------------------------------------------------------- notebook

@pytest.mark.parametrize("kernel", [pytest.param(False, id="inprocess"),
                                    pytest.param(True, id="kernel", marks=pytest.mark.slow)])
def test_notebook_03_executes(kernel, tmp_path, monkeypatch):
    """In this interpreter (default tier) or in a Jupyter kernel (slow): see support.notebooks.run_notebook.
    Its fast settings are the robustness experiment's tiny run, checked in full (``robustness_envelopes.run``)."""
    from support.notebooks import run_notebook
    outputs, rich = run_notebook("03_robustness.ipynb", tmp_path, monkeypatch, kernel=kernel,
                                 env={"MJXSYSID_NOTEBOOK_FAST": "1"})
    assert "inside decoded" in outputs and "energy distance" in outputs
    assert any("image/png" in d for d in rich)
    _check_tiny_robustness(tmp_path / "robustness")     # the experiment's tiny run is the notebook's


def test_provenance_commit_names_head_and_says_when_the_package_differs_from_it(monkeypatch):
    import subprocess
    from support.paths import ROOT
    from mjxsysid.experiments.common import git_commit
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no", "--", "mjxsysid"],
                           capture_output=True, text=True).stdout.strip()
    assert git_commit() == head + ("+dirty" if dirty else "")
    monkeypatch.setenv("MJXSYSID_COMMIT", "abc123")
    assert git_commit() == "abc123"
