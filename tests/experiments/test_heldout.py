"""Held-out families (theta.HELDOUT_FAMILIES) and the held-out evaluation: each family's defining
damage, seeding and validity; the comparison with the oracle in closed form; the CLI's plumbing
(flights replaced by a stand-in: the real flights are the docs/runs/measurements/held-out/probing run)."""
import json

import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.cli import main
from mjxsysid.experiments import heldout as H


@pytest.fixture(scope="module")
def families():
    return {name: f.vehicles(64) for name, f in P.HELDOUT_FAMILIES.items()}


def test_each_family_has_its_damage_and_is_seeded_valid_flyable(families):
    assert len(families) >= 4
    for name, th in families.items():
        f = P.HELDOUT_FAMILIES[name]
        np.testing.assert_array_equal(th, f.vehicles(64))        # the same vehicles on every call
        assert P.get_prior(name) is f and f.description
        fl = P.flyability(th)
        assert fl["twr_min"].min() >= f.twr_min_eff - 1e-3, name  # every rotor lifts its floor × its share
        assert fl["torque_margin"].min() >= 1.0, name
    eta = families["weak_motor"][:, P.ETA]
    assert ((np.abs(eta - 0.5) < 1e-6).sum(-1) == 1).all() and (np.sort(eta, -1)[:, 1] >= 0.7 - 1e-6).all()
    assert len(set(np.argmin(eta, -1))) == 4                       # every rotor position is hit
    tm = families["slow_motors"][:, P.TAU_M]
    assert tm.min() >= 0.08 and tm.max() <= 0.10
    twr = np.asarray(P.nominal_thrust_to_weight(families["low_thrust"]))      # the family's range is drawn at η = 1
    assert twr.min() >= 1.6 - 1e-4 and twr.max() <= 1.8 + 1e-4
    th = families["payload_offset"]
    np.testing.assert_allclose(np.hypot(th[:, 16], th[:, 17]), 0.15 * th[:, P.MASS] * P.GRAVITY * th[:, P.ARM],
                               rtol=1e-5)
    th = families["yaw_torque"]
    kappa = th[:, P.KTAU] / th[:, P.KT]
    np.testing.assert_allclose(np.abs(th[:, 18]), 0.4 * th[:, P.MASS] * P.GRAVITY * kappa, rtol=1e-5)
    assert 0 < (th[:, 18] > 0).mean() < 1
    with pytest.raises(ValueError, match="n \\(vehicles of held-out family 'weak_motor'\\)"):
        P.HELDOUT_FAMILIES["weak_motor"].vehicles(0)
    with pytest.raises(ValueError, match="held-out family"):
        P.get_prior("weak_motors")


def test_compare_with_oracle_closed_form():
    pol = {"failed": np.array([0, 1, 1, 0.0]), "pos_rmse_m": np.array([0.2, 9, 9, 0.6])}
    ora = {"failed": np.array([0, 0, 1, 0.0]), "pos_rmse_m": np.array([0.1, 0.1, 9, 0.3])}
    r = H.compare_with_oracle(pol, ora)
    assert r["success_policy"] == 0.5 and r["success_oracle"] == 0.75 and r["n_both"] == 2
    assert r["rmse_ratio"] == pytest.approx(2.0) and r["lost_beyond_oracle"] == 1 and r["fails_more_than_oracle"]
    assert r["success_policy_where_oracle_flies"] == pytest.approx(2 / 3)
    none = H.compare_with_oracle({"failed": np.ones(2), "pos_rmse_m": np.ones(2)}, ora | {"failed": np.zeros(2),
                                                                                         "pos_rmse_m": np.ones(2)})
    assert none["rmse_ratio"] is None


def _stand_in(theta, *, controller, policy=None, **kw):
    """Flights replaced by a closed form: the oracle flies everything at 0.1 m; a policy loses the
    vehicles with τ_m > 0.09 s and flies the rest at 0.1 m × (1 + 5 τ_m)."""
    tm = np.asarray(theta)[:, P.TAU_M]
    if controller == "oracle":
        return None, {"failed": np.zeros(len(tm)), "pos_rmse_m": np.full(len(tm), 0.1)}, 1.0
    return None, {"failed": (tm > 0.09).astype(float), "pos_rmse_m": 0.1 * (1 + 5 * tm)}, 1.0


def test_held_out_cli_writes_every_policy_and_set(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(H, "fly_vehicles", _stand_in)
    out = tmp_path / "ho"
    assert main(["evaluate-policy", "--held-out", "--vehicles", "16", "--sets", "default,slow_motors,weak_motor",
                 "--weights", "mjxsysid", "--weights", "again=mjxsysid", "--out", str(out)]) == 0
    r = json.loads((out / "results.json").read_text())
    ev = r["numbers"]["evaluation"]
    assert list(ev) == ["default", "slow_motors", "weak_motor"] and set(ev["default"]) >= {"shipped", "again"}
    slow = ev["slow_motors"]["shipped"]
    assert 0 < slow["lost_beyond_oracle"] < 16 and slow["fails_more_than_oracle"] and ev["slow_motors"]["oracle_success"] == 1
    assert r["numbers"]["targets"]["shipped"]["slow_motors"] == {"ratio_le_1.3x": False, "fails_no_more_than_oracle": False}
    assert r["numbers"]["targets"]["shipped"]["weak_motor"]["ratio_le_1.3x"]       # 1 + 5 τ_m ≤ 1.2
    assert "| shipped |" in (out / "results.md").read_text()
    assert "1/2 families" in (out / "results.md").read_text()
    capsys.readouterr()
    assert main(["evaluate-policy", "--held-out", "--sets", "default,nowhere", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert "sets: unknown ['nowhere']" in err and len(err.splitlines()) == 1
    assert main(["evaluate-policy", "--held-out", "--weights", "a=x.npz", "--weights", "a=y.npz",
                 "--out", str(tmp_path / "x")]) == 2
    assert "two policies labelled 'a'" in capsys.readouterr().err
    assert main(["evaluate-policy", "--weights", "a.npz", "--weights", "b.npz", "--out", str(tmp_path / "x")]) == 2
    assert "several only with --held-out" in capsys.readouterr().err


def test_prior_sets_are_seeded_draws():
    a, b = H.set_vehicles("stress", 8, seed=3), H.set_vehicles("stress", 8, seed=3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, H.set_vehicles("stress", 8, seed=4))
    assert H.set_vehicles("paper", 5).shape == (1, 19)
