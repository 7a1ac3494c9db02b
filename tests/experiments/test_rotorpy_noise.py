"""The rotorpy-noise experiment (mjxsysid.experiments.rotorpy_noise, RotorPy's case): the mapping of θ onto RotorPy's parameters
(no RotorPy needed), the one-line error without it, and a short flight when it is installed."""
import sys

import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.experiments import get_experiment
from mjxsysid.experiments import rotorpy_noise as T


def test_vehicle_maps_onto_rotorpy_parameters():
    """Hover thrust of the mapped rotors carries the weight; the rotors sit at the arm length in
    RotorPy's order with mjxsysid's yaw signs; the linear drag equals D at hover speed; the worn
    motor is the one asked for."""
    theta = T.worn_vehicle(2, 0.8)
    assert theta[P.ETA.start + 1] == pytest.approx(0.8) and theta[P.ETA.start] == pytest.approx(1.0)
    q = T.rotorpy_params(theta)
    hover = np.sqrt(q["mass"] * P.GRAVITY / (4 * q["k_eta"]))
    assert 4 * q["k_eta"] * hover ** 2 == pytest.approx(q["mass"] * P.GRAVITY, rel=1e-6)
    arms = [np.linalg.norm(q["rotor_pos"][f"r{i}"][:2]) for i in range(1, 5)]
    np.testing.assert_allclose(arms, theta[P.ARM], rtol=1e-6)
    fl = q["rotor_pos"]["r1"]
    assert fl[0] > 0 and fl[1] > 0                        # RotorPy's rotor 1 is front-left (FLU)
    assert 4 * q["k_d"] * hover == pytest.approx(float(theta[P.DRAG][0]), rel=1e-6)
    assert q["tau_m"] == pytest.approx(float(theta[P.TAU_M])) and q["rotor_speed_max"] == pytest.approx(float(theta[P.OMEGA_MAX]))
    with pytest.raises(ValueError):
        T.worn_vehicle(1, -0.5)


def test_without_rotorpy_the_tool_names_the_install_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "rotorpy", None)          # import rotorpy now fails
    for name in [m for m in sys.modules if m.startswith("rotorpy.")]:
        monkeypatch.delitem(sys.modules, name)
    with pytest.raises(SystemExit) as e:
        T.import_rotorpy()
    assert "pip install rotorpy" in str(e.value) and str(e.value).startswith("error: RotorPy is not installed")


@pytest.mark.slow
def test_quick_flight_decodes_the_clean_log(tmp_path):
    pytest.importorskip("rotorpy")
    res = get_experiment("rotorpy-noise")(tmp_path, quick=True, progress=False)["numbers"]
    assert (tmp_path / "results.md").is_file()
    clean = res["vehicles"]["worn_motor"]["levels"]["clean"]
    assert clean["rmse_m"] < 0.10 and clean["inside"] >= 20 and not clean["lost"]
    assert clean["posterior"] == "log-grounded" and 0 <= clean["inside_decoder_only"] <= 24


def test_both_vehicles_are_valid_and_unknown_names_are_refused(tmp_path):
    """The experiment's second vehicle is a draw of the policy's own prior; a level or vehicle it
    does not know is an error naming the choices (before RotorPy is needed)."""
    assert set(T.VEHICLES) == {"worn_motor", "prior_seed1"}
    th = T.VEHICLES["prior_seed1"]()
    assert th.shape == (19,) and np.isfinite(th).all()
    np.testing.assert_array_equal(th, T.prior_vehicle(1))
    assert not np.allclose(th, P.PAPER_HARDWARE)
    with pytest.raises(ValueError, match="unknown level.*x7.*x5_vibration"):
        T.run(tmp_path, levels="clean,x7")
    with pytest.raises(ValueError, match="unknown level.*heavy.*prior_seed1"):
        T.run(tmp_path, vehicles="heavy")


def test_external_torque_is_added_to_rotorpys_body_moment():
    """RotorPy has no external torque: the experiment adds θ's τ_ext (body frame, as the simulator's
    xfrc_applied = R τ_ext) to the moment RotorPy's wrench returns, and leaves the force alone."""
    class Base:
        def compute_body_wrench(self, w, rotor_speeds, airspeed):
            return np.array([0.0, 0.0, 9.0]), np.array([0.1, -0.2, 0.3])

    force, moment = T.with_external_torque(Base, [0.02, 0.0, -0.01])().compute_body_wrench(None, None, None)
    np.testing.assert_allclose(force, [0.0, 0.0, 9.0])
    np.testing.assert_allclose(moment, [0.12, -0.2, 0.29])
