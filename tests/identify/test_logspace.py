"""The log space's one table (identify/logspace.py): no integer index into its vectors elsewhere, one
name per quantity across the log's and θ's summaries, one thrust-to-weight."""
import ast
import warnings
from pathlib import Path

import jax
import numpy as np
import pytest

from mjxsysid import theta as P
from mjxsysid.cfm.posterior import summarize_posterior
from mjxsysid.identify import calibrate as Cal
from mjxsysid.identify import coords as C
from mjxsysid.identify import gap as G
from mjxsysid.identify import logspace as L

PACKAGE = Path(L.__file__).resolve().parents[1]
TABLE = {"identify/logspace.py"}
NOT_YET: set = set()
"""Modules the check leaves out besides the table (none)."""
LOG_VECTORS = {"v", "h", "x", "y", "z", "xs", "ys", "v0", "h0", "v_raw", "mode", "nuisance", "x_lin", "sigma_x",
               "starts", "fits", "lo", "hi", "est"}
"""Names that hold a log-space vector (v, h, x, y, z, the nuisances, v's bounds, the quantities) in the
identify room."""
LOG_KEYS = {"v", "v_raw", "mode", "nuisance"}
"""Keys of the posterior's dict that hold one, wherever it is read."""
SIZES = {"N_V", "N_H", "N_X", "N_Y", "N_Z", "N_NUIS"}


ROWS = "# rows, not coordinates"
"""A line ending in this comment indexes a batch's rows (``y[:1]``), not a log-space axis."""


def _literal_ints(index) -> list[ast.AST]:
    """The integer literals an index expression uses directly on its last axis: a[3], a[..., 3],
    a[:, 1:4], a[[0, 4]], a[-1] (not a[0, L.RHO]'s row, nor those inside a call: a[np.all(m, -1)])."""
    out, todo = [], [index.elts[-1] if isinstance(index, ast.Tuple) and index.elts else index]
    while todo:
        n = todo.pop()
        if isinstance(n, ast.Constant) and type(n.value) is int:
            out.append(n)
        elif isinstance(n, ast.UnaryOp) and isinstance(n.op, ast.USub):
            todo.append(n.operand)
        elif isinstance(n, (ast.Tuple, ast.List)):
            todo += n.elts
        elif isinstance(n, ast.Slice):
            todo += [b for b in (n.lower, n.upper, n.step) if b is not None]
    return out


def _holder(node) -> str | None:
    """The variable a subscript reads (``v`` of v[..., 4], ``nuisance`` of post["nuisance"][:, 8])."""
    while isinstance(node, ast.Subscript):
        if isinstance(node.slice, ast.Constant) and isinstance(node.slice.value, str):
            return "key:" + node.slice.value
        node = node.value
    return node.id if isinstance(node, ast.Name) else None


def integer_indices(src: str, in_room: bool) -> list[str]:
    """Integer indices into a log-space vector in a module's source: subscripts with integer literals
    of :data:`LOG_VECTORS` (in the identify room) or :data:`LOG_KEYS` (anywhere), and offsets
    N_V + 4 etc. in an index or a definition."""
    found, lines = [], src.splitlines()
    for n in ast.walk(ast.parse(src)):
        if hasattr(n, "lineno") and lines[n.lineno - 1].rstrip().endswith(ROWS):
            continue
        if isinstance(n, ast.Subscript):
            h = _holder(n.value) or ""
            log_vec = h[4:] in LOG_KEYS if h.startswith("key:") else (in_room and h in LOG_VECTORS)
            if log_vec and _literal_ints(n.slice):
                found.append(f"{n.lineno}: {ast.unparse(n)}")
        if isinstance(n, (ast.Subscript, ast.Assign)):
            inner = n.slice if isinstance(n, ast.Subscript) else n.value
            for b in ast.walk(inner):
                if (isinstance(b, ast.BinOp) and isinstance(b.op, (ast.Add, ast.Sub))
                        and any(isinstance(s, ast.Name) and s.id in SIZES for s in (b.left, b.right))
                        and any(isinstance(s, ast.Constant) for s in (b.left, b.right))):
                    found.append(f"{n.lineno}: offset {ast.unparse(b)}")
    return found


def test_the_check_finds_what_it_must():
    """The AST check flags the forms the table replaces and passes the named ones."""
    bad = ("v[..., 4]", "x[:, 1:4]", "x[N_V + 8]", "x[-1]", "v[[0, 4, 5]]", "post['nuisance'][:, 8]",
           "a = x[N_V:N_V + 4]", "N_Y = N_V + 5")
    for s in bad:
        assert integer_indices(s, in_room=True), s
    good = ("v[..., L.LOG_TAU_M]", "x[:, L.RHO]", "x[L.X_BIAS]", "q[1, j]", "rho[..., 0]", "len(v) < N_V + 2",
            "v[np.all(np.isfinite(v), -1)]", "post['theta'][:, 0]", "ys[0, L.Y_LOG_NOISE]",
            "np.broadcast_to(y[:1], (3, 17))  " + ROWS)
    for s in good:
        assert not integer_indices(s, in_room=True), s
    assert not integer_indices("v[0]", in_room=False)         # a `v` outside the room is anything


def test_no_integer_index_into_the_log_space_outside_its_table():
    """Outside identify/logspace.py (and the module being moved onto it), nothing indexes v, h, x, y,
    z or the nuisances with an integer: the names of the table do."""
    hits = {}
    for p in sorted(PACKAGE.rglob("*.py")):
        rel = p.relative_to(PACKAGE).as_posix()
        if rel in TABLE | NOT_YET:
            continue
        src = p.read_text()
        in_room = rel.startswith("identify/")
        if in_room or "mjxsysid.identify" in src:
            found = integer_indices(src, in_room)
            if found:
                hits[rel] = found
    assert not hits, hits


def test_logspace_views_agree():
    """The names, sizes and offsets come from the tables: x = [v, nuisances], y and z drop what the
    inference holds fixed, and the round trip y -> x -> y is exact."""
    assert (L.N_V, L.N_H, L.N_NUIS, L.N_X, L.N_Y, L.N_Z) == (12, 7, 9, 21, 17, 13)
    assert L.V_NAMES[L.LOG_TAU_M] == "log_motor_time_constant" and L.V_NAMES[L.LOG_AUTH_Z] == "log_authority[2]"
    assert L.X_NAMES[L.X_BIAS] == "acc_z_bias"
    assert L.X_NAMES[L.X_LOG_DISCREPANCY_GYRO] == ("log_discrepancy[gyro_x]", "log_discrepancy[gyro_y]",
                                                   "log_discrepancy[gyro_z]")
    assert L.Y_NAMES[L.Y_BIAS] == "acc_z_bias" and L.Y_NAMES[L.Y_LOG_NOISE][0] == "log_noise[gyro_x]"
    assert [L.Y_NAMES[i] for i in L.Z_IN_Y] == list(L.V_NAMES) + ["acc_z_bias"]
    assert np.array_equal(np.asarray(L.NUIS_NAMES)[L.NUIS_IN_Y], np.asarray(L.Y_NAMES)[L.Y_NUIS])
    rng = np.random.default_rng(0)
    x = rng.standard_normal((5, L.N_X)).astype(np.float32)
    y = L.y_from_x(x)
    np.testing.assert_array_equal(L.x_from_y(y, x[0, L.X_LOG_DISCREPANCY])[0], x[0])
    np.testing.assert_array_equal(L.y_from_z(L.z_from_y(y), y[:, L.Y_LOG_NOISE]), y)
    with pytest.raises(ValueError, match=r"missing.*log_yaw_authority"):
        L.pack(L.V_FIELDS, log_thrust_to_weight=0.0, rel_effectiveness=np.ones(3), log_motor_time_constant=0.0,
               log_authority=np.zeros(3), ext_acc=np.zeros(3))


def test_one_name_per_quantity_across_the_log_and_theta_summaries():
    """A name in both the log's table (QUANTITIES) and θ's summary (19 parameters, the derived
    quantities) is declared the same quantity there and has the same value on every vehicle; the joint
    summary enters it once and refuses an undeclared clash instead of overwriting."""
    theta_names = set(P.PARAM_NAMES) | set(P.DERIVED_NAMES)
    shared = {q.name for q in L.QUANTITIES if q.in_theta}
    assert set(L.LOG_NAMES) & theta_names == shared == {"thrust_to_weight", "motor_time_constant"}
    assert len(set(L.LOG_NAMES)) == len(L.LOG_NAMES) and len(theta_names) == len(P.PARAM_NAMES) + len(P.DERIVED_NAMES)
    th = np.asarray(P.get_prior("wide_actuators").sample(jax.random.PRNGKey(1), 200))
    s_theta, s_log = summarize_posterior(th), G.log_summary(th)
    for n in shared:
        assert s_theta[n]["q05"] == pytest.approx(s_log[n]["q05"], rel=1e-5), n
        assert s_theta[n]["q95"] == pytest.approx(s_log[n]["q95"], rel=1e-5), n
    joint = G.joint_summary(s_theta, s_log)
    assert set(joint) == theta_names | set(L.LOG_NAMES)
    with pytest.raises(ValueError, match=r"both name \['mass'\]"):
        G.joint_summary(s_theta, {**s_log, "mass": s_log["thrust_to_weight"]})


def test_one_thrust_to_weight():
    """Every report's thrust-to-weight is 4 η̄ k_t Ω_max² / (m g): θ's, the log coordinate's, the log
    quantities'; the η = 1 one is the nominal, the latent's training target only."""
    th = np.asarray(P.get_prior("wide_actuators").sample(jax.random.PRNGKey(2), 100))
    eta_mean = th[:, P.ETA].mean(1)
    tw = np.asarray(P.thrust_to_weight(th))
    nominal = 4 * th[:, P.KT] * th[:, P.OMEGA_MAX] ** 2 / (th[:, P.MASS] * P.GRAVITY)
    np.testing.assert_allclose(tw, eta_mean * nominal, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(P.nominal_thrust_to_weight(th)), nominal, rtol=1e-5)
    np.testing.assert_allclose(np.exp(np.asarray(C.visible_from_theta(th))[:, L.LOG_TW]), tw, rtol=1e-5)
    np.testing.assert_allclose(C.log_quantities(th)[:, L.LOG_NAMES.index("thrust_to_weight")], tw, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(P.derived(th))[:, P.DERIVED_NAMES.index("thrust_to_weight")], tw, rtol=1e-6)
    assert "thrust_to_weight" not in P.IDENTIFIABLE_NAMES
    np.testing.assert_allclose(np.asarray(P.identifiable(th))[:, 0], nominal, rtol=1e-5)
    assert not any("thrust_to_weight" in n and n != "thrust_to_weight" for n in L.LOG_NAMES + P.DERIVED_NAMES)


def test_old_names_still_answer_with_a_future_warning():
    """summary()["thrust_to_weight_total"] and PhysicalPrior.thrust_to_weight_total still read, with a
    FutureWarning naming the new one; an unknown name is a KeyError."""
    th = np.asarray(P.get_prior("default").sample(jax.random.PRNGKey(3), 50))
    s = G.log_summary(th)
    with pytest.warns(FutureWarning, match="now 'thrust_to_weight'"):
        assert s["thrust_to_weight_total"] == s["thrust_to_weight"]
    with pytest.warns(FutureWarning):
        assert s.get("thrust_to_weight_total") == s["thrust_to_weight"]
    with pytest.raises(KeyError):
        s["no_such_quantity"]
    with pytest.warns(FutureWarning, match="PhysicalPrior.thrust_to_weight"):
        assert C.PHYSICAL_PRIOR.thrust_to_weight_total == C.PHYSICAL_PRIOR.thrust_to_weight
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert s.get("thrust_to_weight")["q05"] > 0 and s.get("no_such_quantity", 1) == 1


def test_the_shipped_calibration_table_loads_with_the_table_names():
    """posterior_calibration.json, fitted before the table, loads: its coordinates are v's, by name and
    by the feature that groups them."""
    table = Cal.load()
    assert [c["name"] for c in table["coords"]] == list(L.V_NAMES)
    assert len(table["min_weight"]) == L.N_CHANNELS


def test_what_the_log_does_not_pin_is_said_not_seen_with_why():
    """Every entry of θ's summary that is not a log quantity is made of the hidden coordinates: moving h
    with v held changes it (and no log quantity). A log-grounded joint summary then marks it not seen,
    with that reason, and a log quantity as the log's own report says."""
    th = np.asarray(P.get_prior("wide_actuators").sample(jax.random.PRNGKey(4), 8), np.float64)
    v, h = np.asarray(C.visible_from_theta(th), np.float64), np.asarray(C.hidden_from_theta(th), np.float64)
    h2 = h + np.array([0.3, 0.2, 0.1, 0.1, 0.5, 0.5, 0.5])            # every hidden coordinate moved
    th2 = np.asarray(C.theta_from(v, h2, np.float64))

    def theta_side(t):
        return dict(zip(P.PARAM_NAMES + P.DERIVED_NAMES, np.concatenate([t, np.asarray(P.derived(t))], -1).T))

    a, b = theta_side(th), theta_side(th2)
    moved = {n for n in a if not np.allclose(a[n], b[n], rtol=1e-4)}
    assert moved == set(a) - {q.name for q in L.QUANTITIES if q.in_theta}, moved
    np.testing.assert_allclose(C.log_quantities(th2), C.log_quantities(th), rtol=1e-4, atol=1e-6)

    s_theta, s_log = summarize_posterior(th), G.log_summary(th)
    seen = {n: (n != "motor_time_constant", f"why {n}") for n in L.LOG_NAMES}
    joint = G.joint_summary(s_theta, s_log, seen=seen)
    assert joint["mass"]["seen_by_log"] is False and joint["mass"]["why"] == G.HIDDEN_WHY
    assert joint["torque_ratio"]["why"] == G.HIDDEN_WHY
    assert joint["thrust_to_weight"]["seen_by_log"] and joint["thrust_to_weight"]["why"] == "why thrust_to_weight"
    assert not joint["motor_time_constant"]["seen_by_log"]


def test_posterior_config_validates_and_overrides():
    """One object says how the posterior is computed: bad fields name themselves, keyword settings
    override a given config, None keeps its field (calibration's None means the raw posterior)."""
    import pytest

    from mjxsysid.identify import posterior_config as K
    base = K.PosteriorConfig(samples=200, refine=False)
    assert K.resolve(base, draws=None) == base and K.resolve(base, samples=np.int64(300)).samples == 300
    assert K.resolve(base, draws=512).draws == 512 and K.resolve(base, calibration=None).calibration is None
    assert K.resolve(None) == K.DEFAULT
    for bad, msg in (({"samples": 0}, "samples"), ({"rates": "kalman"}, "rates"), ({"calibration": 3}, "calibration"),
                     ({"particles": 1.5}, "particles")):
        with pytest.raises(ValueError, match=msg):
            K.PosteriorConfig(**bad)
    with pytest.raises(TypeError, match="no field.*partcles"):
        K.resolve(base, partcles=10)
