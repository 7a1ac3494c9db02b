"""Inputs that cannot hurt: malformed vehicle files, flight logs and weights files are refused
before any work starts, with one line naming the file, the key/line/array and the problem
(CLI: exit status 2), never a traceback. Property-based (hypothesis) where inputs are generated."""
import json
import math
import shutil

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mjxsysid import theta as P
from mjxsysid.cli import main
from mjxsysid.logs.csvlog import LOG_COLUMNS, read_log

SETTINGS = settings(max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
PAPER = P.theta_to_dict(P.PAPER_HARDWARE)
SCALAR = [k for k, (_, n) in P.VEHICLE_KEYS.items() if n is None]
LISTS = {k: n for k, (_, n) in P.VEHICLE_KEYS.items() if n is not None}
POSITIVE = ["mass", "arm_length", "thrust_coeff", "torque_coeff", "max_rotor_speed", "motor_time_constant"]


def _one_line_naming(err: str, path) -> None:
    assert "\n" not in err.strip(), err
    assert str(path) in err, err
    assert "Traceback" not in err


# ----------------------------------------------------------------------------------------
# Vehicle files
# ----------------------------------------------------------------------------------------

non_numbers = st.one_of(st.none(), st.booleans(), st.text(max_size=5), st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))
non_finite = st.sampled_from([math.nan, math.inf, -math.inf])


@st.composite
def bad_vehicle(draw):
    """(dict, key expected in the message) of a vehicle that must be refused."""
    d = json.loads(json.dumps(PAPER))
    kind = draw(st.sampled_from(["missing", "unknown", "type", "length", "list_type", "non_finite",
                                 "non_positive", "negative_drag", "huge", "unflyable", "torque"]))
    if kind == "missing":
        k = draw(st.sampled_from(sorted(d)))
        del d[k]
        return d, k
    if kind == "unknown":
        k = draw(st.text(min_size=1, max_size=12).filter(lambda s: s not in P.VEHICLE_KEYS))
        d[k] = draw(st.floats(allow_nan=False))
        return d, "unknown key"
    if kind == "type":
        k = draw(st.sampled_from(SCALAR))
        d[k] = draw(st.one_of(non_numbers, st.lists(st.floats(), max_size=3)))
        return d, k
    if kind == "length":
        k = draw(st.sampled_from(sorted(LISTS)))
        n = draw(st.integers(0, 6).filter(lambda n: n != LISTS[k]))
        d[k] = [0.01] * n
        return d, k
    if kind == "list_type":
        k = draw(st.sampled_from(sorted(LISTS)))
        i = draw(st.integers(0, LISTS[k] - 1))
        d[k][i] = draw(non_numbers)
        return d, k
    if kind == "non_finite":
        k = draw(st.sampled_from(sorted(d)))
        v = draw(non_finite)
        if k in LISTS:
            d[k][draw(st.integers(0, LISTS[k] - 1))] = v
        else:
            d[k] = v
        return d, k
    if kind == "non_positive":
        k = draw(st.sampled_from(POSITIVE + ["inertia", "motor_effectiveness"]))
        v = draw(st.floats(max_value=0.0, allow_nan=False, allow_infinity=False))
        if k in LISTS:
            i = draw(st.integers(0, LISTS[k] - 1))
            d[k][i] = v
            return d, f"{k}[{i}]"
        d[k] = v
        return d, k
    if kind == "negative_drag":
        i = draw(st.integers(0, 2))
        d["drag"][i] = -draw(st.floats(min_value=1e-6, max_value=1e6))
        return d, f"drag[{i}]"
    if kind == "huge":
        k = draw(st.sampled_from(POSITIVE))
        d[k] = draw(st.sampled_from([1e39, 1e300, 10 ** 400]))
        return d, k
    if kind == "unflyable":  # heavier than the rotors can lift (paper vehicle: thrust-to-weight 6.2)
        d["mass"] = PAPER["mass"] * draw(st.floats(min_value=6.3, max_value=1e4))
        return d, "cannot hover"
    d["external_torque"][draw(st.integers(0, 2))] = draw(st.sampled_from([-1, 1])) * draw(
        st.floats(min_value=50.0, max_value=1e6))
    return d, "external_torque"


@SETTINGS
@given(case=bad_vehicle())
def test_malformed_vehicle_files_are_refused_naming_file_and_key(tmp_path, case):
    d, key = case
    path = tmp_path / "vehicle.json"
    path.write_text(json.dumps(d))  # allow_nan: NaN/Infinity literals, which Python's json reads
    with pytest.raises(ValueError) as e:
        P.load_vehicle(path)
    _one_line_naming(str(e.value), path)
    assert key in str(e.value), (key, str(e.value))


@SETTINGS
@given(scale=st.lists(st.floats(min_value=0.9, max_value=1.1), min_size=19, max_size=19))
def test_plausible_vehicles_are_accepted(tmp_path, scale):
    """The checks refuse nothing physical: ±10 % around the paper vehicle always loads (κ, drag,
    inertia and τ_ext stay valid; thrust-to-weight stays near 6)."""
    th = P.PAPER_HARDWARE * np.asarray(scale, np.float32)
    th[P.INERTIA] = P.PAPER_HARDWARE[P.INERTIA] * scale[4]
    path = P.save_vehicle(th, tmp_path / "v.json")
    np.testing.assert_allclose(P.load_vehicle(path), th, rtol=1e-6)


@SETTINGS
@given(text=st.one_of(st.text(max_size=40), st.binary(max_size=40).map(lambda b: b.decode("latin-1")),
                      st.sampled_from(["", "[]", "1", "null", '"mass"', "{", '{"mass": 1, "mass": 2}',
                                       "[" * 5000 + "]" * 5000])))
def test_garbage_vehicle_files_are_refused(tmp_path, text):
    path = tmp_path / "v.json"
    path.write_bytes(text.encode("utf-8", "surrogatepass"))
    with pytest.raises(ValueError) as e:
        P.load_vehicle(path)
    _one_line_naming(str(e.value), path)


def test_binary_vehicle_file_and_duplicate_key(tmp_path):
    path = tmp_path / "v.json"
    path.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(ValueError, match="not a text"):
        P.load_vehicle(path)
    path.write_text('{"mass": 1.0, "mass": 2.0}')
    with pytest.raises(ValueError, match="mass appears twice"):
        P.load_vehicle(path)


# ----------------------------------------------------------------------------------------
# Flight logs
# ----------------------------------------------------------------------------------------

def _good_rows(n=120):
    rows = np.zeros((n, len(LOG_COLUMNS)))
    rows[:, 0] = np.arange(n) * 0.002
    rows[:, 6] = 9.81
    rows[:, 7] = 9.81
    rows[:, 11:] = 0.45
    return rows


def _write(path, header, rows, sep=","):
    lines = [sep.join(header)] + [sep.join(f"{v:.7g}" for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


@st.composite
def bad_log(draw):
    """(header, rows as strings, separator, substring the message must hold)."""
    header = list(LOG_COLUMNS)
    rows = [[f"{v:.7g}" for v in r] for r in _good_rows(draw(st.integers(100, 130)))]
    kind = draw(st.sampled_from(["missing_col", "dup_col", "sep", "cell_text", "cell_nonfinite",
                                 "short", "empty", "time", "rate", "motor", "ragged", "no_header"]))
    r = draw(st.integers(0, 99))
    line = str(r + 2)  # header is line 1
    if kind == "missing_col":
        c = draw(st.integers(0, len(header) - 1))
        name = header.pop(c)
        rows = [row[:c] + row[c + 1:] for row in rows]
        return header, rows, ",", name
    if kind == "dup_col":
        c = draw(st.integers(1, len(header) - 1))
        header.append(header[c])
        rows = [row + ["0"] for row in rows]
        return header, rows, ",", header[c]
    if kind == "sep":
        return header, rows, draw(st.sampled_from([";", "\t"])), "separated by"
    if kind == "cell_text":
        c = draw(st.integers(0, len(header) - 1))
        rows[r][c] = draw(st.sampled_from(["abc", "", "1,5".replace(",", "."), "0x1g", "--1", "1e"]))
        if rows[r][c] == "1.5":
            rows[r][c] = "1.5.5"
        return header, rows, ",", f"line {line}, column {header[c]}"
    if kind == "cell_nonfinite":
        c = draw(st.integers(1, len(header) - 1))
        rows[r][c] = draw(st.sampled_from(["nan", "inf", "-inf", "NaN"]))
        return header, rows, ",", f"line {line}, column {header[c]}"
    if kind == "short":
        return header, rows[: draw(st.integers(1, 99))], ",", "need at least 100"
    if kind == "empty":
        return [], [], ",", "empty"
    if kind == "time":
        r = max(r, 1)
        rows[r][0] = rows[r - 1][0] if draw(st.booleans()) else f"{float(rows[r - 1][0]) - 0.01:.7g}"
        return header, rows, ",", f"line {r + 2}, column t"
    if kind == "rate":
        f = draw(st.sampled_from([0.5, 2.0, 10.0]))
        for row in rows:
            row[0] = f"{float(row[0]) * f:.7g}"
        return header, rows, ",", "500 Hz"
    if kind == "motor":
        m = draw(st.integers(1, 4))
        rows[r][10 + m] = draw(st.sampled_from(["1.5", "-0.2", "1200"]))
        return header, rows, ",", f"line {line}, column motor_{m}"
    if kind == "ragged":
        rows[r] = rows[r][: draw(st.integers(1, len(header) - 1))]
        return header, rows, ",", f"line {line}"
    return None, rows, ",", "no header"


@SETTINGS
@given(case=bad_log())
def test_malformed_logs_are_refused_naming_file_and_line(tmp_path, case):
    header, rows, sep, needle = case
    path = tmp_path / "log.csv"
    lines = ([sep.join(header)] if header is not None else []) + [sep.join(r) for r in rows]
    path.write_text("\n".join(lines) + ("\n" if lines else ""))
    with pytest.raises(ValueError) as e:
        read_log(path)
    _one_line_naming(str(e.value), path)
    assert needle in str(e.value), (needle, str(e.value))


def test_good_log_reads_with_extra_columns_any_order_and_blank_lines(tmp_path):
    rows = _good_rows()
    hdr = list(LOG_COLUMNS)[::-1] + ["battery_v"]
    data = np.column_stack([rows[:, ::-1], np.full(len(rows), 16.0)])
    path = _write(tmp_path / "log.csv", hdr, data)
    path.write_text(path.read_text() + "\n\n")
    rec = read_log(path)
    np.testing.assert_allclose(rec["t"], rows[:, 0])
    np.testing.assert_allclose(rec["motor"], rows[:, 11:])
    np.testing.assert_allclose(rec["imu"][:, 5], 9.81)


# ----------------------------------------------------------------------------------------
# The command line: exit status 2 and one line, before any work
# ----------------------------------------------------------------------------------------

def test_cli_refuses_bad_vehicle_and_log_in_one_line(tmp_path, capsys):
    v = tmp_path / "heavy.json"
    v.write_text(json.dumps(dict(PAPER, mass=50.0)))
    assert main(["fly", "--vehicle", str(v), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    _one_line_naming(err, v)
    assert "cannot hover" in err and not (tmp_path / "o").exists()
    log = _write(tmp_path / "semi.csv", LOG_COLUMNS, _good_rows(), sep=";")
    assert main(["decode", "--log", str(log), "--out", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err
    _one_line_naming(err, log)
    assert "semicolons" in err and not (tmp_path / "d").exists()


# ----------------------------------------------------------------------------------------
# Weights files
# ----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_tree():
    return {"a": np.arange(60, dtype=np.float32).reshape(6, 10), "b": {"c": np.ones(7, np.float32)}}


@SETTINGS
@given(cut=st.floats(min_value=0.0, max_value=0.999), flip=st.integers(0, 10 ** 6))
def test_truncated_or_corrupt_npz_is_a_named_error(tmp_path, small_tree, cut, flip):
    from mjxsysid.runtime.checkpoint import load_tree, save_tree
    path = save_tree(tmp_path / "w.npz", small_tree, {"k": 1})
    raw = path.read_bytes()
    path.write_bytes(raw[: int(cut * len(raw))])
    with pytest.raises(ValueError) as e:
        load_tree(path, small_tree)
    _one_line_naming(str(e.value), path)
    # One flipped byte: a named error, or (a byte zip/npy do not check) the right arrays.
    b = bytearray(raw)
    b[flip % len(b)] ^= 0xFF
    path.write_bytes(bytes(b))
    try:
        back = load_tree(path, small_tree)
    except ValueError as e:
        _one_line_naming(str(e), path)
    else:
        assert back["a"].shape == (6, 10) and back["b"]["c"].shape == (7,)


def test_weights_with_wrong_keys_shapes_or_nan(tmp_path, small_tree):
    from mjxsysid.runtime.checkpoint import load_tree, save_tree
    p = save_tree(tmp_path / "k.npz", {"a": small_tree["a"]})
    with pytest.raises(ValueError, match=r"k.npz: missing array \['b'\]\['c'\]"):
        load_tree(p, small_tree)
    p = save_tree(tmp_path / "s.npz", dict(small_tree, a=np.zeros((6, 9), np.float32)))
    with pytest.raises(ValueError, match=r"s.npz: \['a'\] has shape \(6, 9\), expected \(6, 10\)"):
        load_tree(p, small_tree)
    p = save_tree(tmp_path / "n.npz", dict(small_tree, a=np.full((6, 10), np.nan, np.float32)))
    with pytest.raises(ValueError, match=r"n.npz: \['a'\] has non-finite"):
        load_tree(p, small_tree, finite=True)
    np.save(tmp_path / "x.npy", np.ones(3))
    with pytest.raises(ValueError, match="x.npy: a single array"):
        load_tree(tmp_path / "x.npy", small_tree)


def test_truncated_policy_and_decoder_files_exit_2(tmp_path, capsys):
    from mjxsysid.policy.interface import PRETRAINED_DIR
    pol = tmp_path / "policy.npz"
    pol.write_bytes((PRETRAINED_DIR / "policy.npz").read_bytes()[:5000])
    assert main(["fly", "--controller", "policy", "--policy", str(pol), "--duration", "0.1",
                 "--out", str(tmp_path / "o")]) == 2
    _one_line_naming(capsys.readouterr().err, pol)
    dec = tmp_path / "dec"
    dec.mkdir()
    shutil.copy(PRETRAINED_DIR / "regression.npz", dec / "regression.npz")
    (dec / "cfm.npz").write_bytes((PRETRAINED_DIR / "cfm.npz").read_bytes()[:-100])
    from mjxsysid.cfm.load import load_decoders
    with pytest.raises(ValueError) as e:
        load_decoders(dec)
    _one_line_naming(str(e.value), dec / "cfm.npz")
    # A regression decoder under the name cfm.npz.
    shutil.copy(PRETRAINED_DIR / "regression.npz", dec / "cfm.npz")
    with pytest.raises(ValueError, match="cfm.npz: holds a regression decoder"):
        load_decoders(dec)


def test_decoders_of_another_policy_are_an_error(tmp_path):
    """Xadap's shipped decoders with mjxsysid's policy: refused, naming the file (a warning
    only with allow_mismatch=True)."""
    from mjxsysid.cfm.load import load_decoders
    from mjxsysid.policy.interface import PRETRAINED_DIR
    xa = PRETRAINED_DIR / "xadap"
    if not (xa / "cfm.npz").is_file():
        pytest.skip("no shipped Xadap decoders")
    with pytest.raises(ValueError, match="cfm.npz: trained on the latents of another policy"):
        load_decoders(xa, "mjxsysid")
    told = []
    load_decoders(xa, "mjxsysid", warn=told.append, allow_mismatch=True)
    assert told and "another policy" in told[0]
    load_decoders(None, "mjxsysid")  # the shipped pair matches


def test_xadap_npz_and_pairs_files_named_errors(tmp_path):
    from mjxsysid.dataset.collect import load_pairs
    from mjxsysid.policy.xadap.network import load_npz
    x = tmp_path / "xadap.npz"
    x.write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(ValueError, match="xadap.npz: not a readable Xadap weights file"):
        load_npz(x)
    np.savez(x, something=np.ones(3))
    with pytest.raises(ValueError, match="xadap.npz: not an Xadap weights file"):
        load_npz(x)
    p = tmp_path / "pairs.npz"
    p.write_bytes(b"")
    with pytest.raises(ValueError, match="pairs.npz: not a readable pairs file"):
        load_pairs(p)
    np.savez(p, theta_train=np.ones((5, 19)), zhat_train=np.ones((4, 8)), theta_test=np.ones((2, 19)),
             zhat_test=np.ones((2, 8)))
    with pytest.raises(ValueError, match=r"pairs.npz: theta_train \(5, 19\) and zhat_train \(4, 8\)"):
        load_pairs(tmp_path)
