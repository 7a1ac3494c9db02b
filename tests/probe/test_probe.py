"""Probing (issue 18 §1): the latent search finds a planted weak region, the closed-loop badness
aggregates what it should, bad input is one line; the whole probe on CPU is `slow`."""
import json

import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.cli import main
from mjxsysid.probe import ProbeConfig, SearchConfig, closed_loop_badness, latent_search, system_badness


def test_search_finds_a_planted_weak_region():
    """A toy closed loop that fails along one known latent direction d (score = how far along d):
    the search's best latents lie far along d and its Gaussian over δ points along d."""
    rng = np.random.default_rng(0)
    anchors = rng.normal(size=(200, 8))
    d = np.zeros(8)
    d[[2, 5]] = 1 / np.sqrt(2)
    score = lambda z: 1.0 / (1.0 + np.exp(-3.0 * (z @ d - 2.0)))         # fails past 2 std along d
    res = latent_search(score, anchors, SearchConfig(population=64, iterations=6, keep=8, seed=1))
    assert (res["z"] @ d > 2.0).all()                                       # every kept latent in the region
    h = [it["mean_score"] for it in res["history"]]
    assert res["score"][0] > 0.9 and np.mean(h[-3:]) > 2 * h[0], h         # seeds 0-5: 3.3-7.3x
    shift = res["z"].mean(0) - anchors.mean(0)
    assert shift @ d / np.linalg.norm(shift) > 0.8, shift                   # found along d (seeds 0-4: 0.85-0.96)
    with pytest.raises(ValueError, match="anchors"):
        latent_search(score, np.zeros((0, 8)))
    with pytest.raises(ValueError, match="elite"):
        SearchConfig(elite=0.0)


class _ToyDecoder:
    """z -> copies of the paper vehicle whose mass is exp(z[0]) × the paper vehicle's."""

    def sample_theta(self, z, key, n):
        th = np.broadcast_to(P.PAPER_HARDWARE, (len(z), n, 19)).copy()
        th[..., P.MASS] = P.PAPER_HARDWARE[P.MASS] * np.exp(np.asarray(z)[:, None, 0])
        return th


def test_closed_loop_badness_aggregates_failures_and_oracle_ratios():
    def fly(theta):          # heavy vehicles fail; the rest fly at 2x the oracle's RMSE, the oracle at 1 cm
        m = theta[:, P.MASS]
        return m > 2.0, np.full(len(m), 0.02), np.full(len(m), 0.01)

    z = np.array([[0.0] + [0.0] * 7, [1.5] + [0.0] * 7])                   # masses 0.93 kg and 4.1 kg
    bad, th = closed_loop_badness(z, decoder=_ToyDecoder(), key=None, samples=3, fly=fly, fail_badness=5.0)
    np.testing.assert_allclose(bad, [2.0, 5.0])
    assert th.shape == (2, 3, 19)


def test_systems_the_oracle_cannot_fly_do_not_count_as_weak():
    """A system the oracle fails on is no evidence against the policy: it counts
    ``infeasible_badness`` (0 by default) whether or not the policy fails too."""
    def fly(theta):          # heavy vehicles: policy and oracle both fail (oracle RMSE NaN)
        heavy = theta[:, P.MASS] > 2.0
        return heavy, np.full(len(heavy), 0.03), np.where(heavy, np.nan, 0.01)

    z = np.array([[0.0] + [0.0] * 7, [1.5] + [0.0] * 7])
    bad, _ = closed_loop_badness(z, decoder=_ToyDecoder(), key=None, samples=2, fly=fly)
    np.testing.assert_allclose(bad, [3.0, 0.0])
    np.testing.assert_allclose(system_badness([1, 0, 1], [0.1, 0.02, 0.1], [np.nan, 0.01, 0.01],
                                              infeasible_badness=1.0), [1.0, 2.0, 5.0])


def test_probe_bad_input_is_one_line(tmp_path, capsys):
    assert main(["probe", "--reference", "loop", "--quick", "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err.strip()
    assert "unknown probe reference 'loop'" in err and len(err.splitlines()) == 1
    with pytest.raises(ValueError, match="anchors >= 2"):
        ProbeConfig(anchors=1)


@pytest.mark.slow
def test_probe_quick_end_to_end(tmp_path):
    """`mjxsysid probe --quick` (≈ 45 s on 2 CPU cores): weak.npz loads as training focus, the
    report is written, and the weak latents are at least as bad as the anchors on average."""
    from mjxsysid.policy.adaptive.focus import load_weak
    out = tmp_path / "probe"
    assert main(["probe", "--quick", "--out", str(out), "-q"]) == 0
    theta, meta = load_weak(out / "weak.npz")
    r = json.loads((out / "results.json").read_text())
    assert theta.shape == (r["weak_systems"], 19) and 1 <= r["weak_systems"] <= r["weak_decoded"] == 16
    assert meta["found_by"] == "mjxsysid probe"
    assert max(r["weak_badness"]) >= r["anchor_badness_mean"]
    for f in ("results.md", "weak_vs_prior.png"):
        assert (out / f).is_file()


def test_probe_loop_is_registered_and_checks_its_config_first(tmp_path):
    from mjxsysid.experiments import get_experiment
    from mjxsysid.experiments.probe_loop import QUICK, LoopConfig
    run = get_experiment("probe-loop")
    with pytest.raises(ValueError, match="focus_weight"):
        run(tmp_path / "x", quick=True, progress=False, cfg=LoopConfig(focus_weight=0.0))
    assert not (tmp_path / "x").exists()
    assert P.get_prior("stress").twr == (1.5, 2.5) and QUICK.vehicles < 100


@pytest.mark.slow
def test_probe_loop_quick_end_to_end(tmp_path):
    """`mjxsysid experiment probe-loop --quick` (≈ 4 min on 2 CPU cores): two rounds of probe →
    tiny retrained policy (the second with its predecessor's own decoders), the control, four
    evaluations, a last probe, the results files; a rerun reuses every stage; another config in
    the same folder is refused."""
    from mjxsysid.policy.adaptive.focus import load_weak
    out = tmp_path / "loop"
    assert main(["experiment", "probe-loop", "--quick", "--out", str(out), "-q"]) == 0
    r = json.loads((out / "results.json").read_text())
    ev, num = r["numbers"]["evaluation"], r["numbers"]
    assert list(ev) == ["given", "probed", "probed2", "probed3", "uniform"] and num["final_policy"] == "probed3"
    assert set(ev["given"]) == {"default", "stress", "paper", "stress_wide", "latent"}
    assert ev["given"]["default"]["success_policy"] == 1.0          # the shipped policy on its own prior
    assert 0.5 < ev["given"]["latent"]["r2_thrust_to_weight"] <= 1.0
    assert set(num["on_weak_systems"]) == {"1", "2", "3"} and set(num["on_weak_systems"]["2"]) == set(ev)
    assert set(num["probes"]) == {"1", "2", "3", "4"} and set(num["calibration"]) == {"probed", "probed2", "probed3"}
    n1, n2 = (len(load_weak(out / d / "weak.npz")[0]) for d in ("probe", "probe_round2"))
    assert len(load_weak(out / "focus_round2.npz")[0]) == n1 + n2   # round 2 trains on both rounds' systems
    for f in ("probe/weak.npz", "uniform_stress.npz", "probed/policy.npz", "uniform/policy.npz", "results.md",
              "probe_loop.png", "probed/decoders/cfm.npz", "probed2/policy.npz", "probe_round3/weak.npz"):
        assert (out / f).is_file(), f
    from mjxsysid.experiments.probe_loop import QUICK, run
    t = (out / "stages" / "train_probed.json").stat().st_mtime
    assert run(out, quick=True, progress=False)["numbers"]["headline"] == num["headline"]
    assert (out / "stages" / "train_probed.json").stat().st_mtime == t        # reused, not rerun
    import dataclasses
    with pytest.raises(ValueError, match="another config"):
        run(out, quick=True, progress=False, cfg=dataclasses.replace(QUICK, focus_weight=0.5))


@pytest.mark.slow
@pytest.mark.parametrize("kernel", [False, True], ids=["inprocess", "kernel"])
def test_notebook_05_executes(kernel, tmp_path, monkeypatch):
    """notebooks/05_probing.ipynb on its quick settings (≈ 1 min): one round — probe, the weak
    systems against the prior, a tiny focused training."""
    from support.notebooks import run_notebook
    outputs, _ = run_notebook("05_probing.ipynb", tmp_path, monkeypatch, kernel=kernel,
                              env={"MJXSYSID_NOTEBOOK_FAST": "1"})
    assert "weak latents:" in outputs and "trained 2 iterations" in outputs, outputs[-2000:]
    assert (tmp_path / "probe" / "weak.npz").is_file() and (tmp_path / "focused" / "policy.npz").is_file()
