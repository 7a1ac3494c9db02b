"""A quiet command line and the Python API: importing prints nothing (MJX's warp probe is
dropped, real import errors are not), progress bars obey --quiet, and ``mjxsysid.fly`` /
``mjxsysid.decode`` return what the CLI writes."""
import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from support.paths import ROOT

PY = sys.executable
ENV = dict(os.environ, PYTHONPATH=str(ROOT), MJXSYSID_PROGRESS="0")


def _run(code_or_args, tmp_path=None):
    args = ["-c", code_or_args] if isinstance(code_or_args, str) else code_or_args
    return subprocess.run([PY, *args], capture_output=True, text=True, env=ENV, cwd=tmp_path or ROOT,
                          timeout=300)


def test_import_prints_nothing_and_import_mjxsysid_is_light():
    r = _run("import mjxsysid.sim")
    assert r.returncode == 0 and r.stdout == "" and r.stderr == "", (r.stdout, r.stderr)
    r = _run("import sys, mjxsysid; print(sorted(m for m in ('jax', 'mujoco') if m in sys.modules)); "
             "print(mjxsysid.fly.__module__)")
    assert r.returncode == 0 and r.stdout == "[]\nmjxsysid.api\n" and r.stderr == "", (r.stdout, r.stderr)


def test_cli_error_is_one_line_with_nothing_else(tmp_path):
    """A command that imports MJX, JAX and the policy stack: stdout empty, stderr one line."""
    (tmp_path / "v.json").write_text('{"mass": 1}')
    r = _run(["-m", "mjxsysid.cli", "fly", "--vehicle", "v.json", "--out", "o"], tmp_path)
    assert r.returncode == 2 and r.stdout == "", r.stdout
    assert r.stderr.count("\n") == 1 and "v.json: missing key(s)" in r.stderr, r.stderr
    r = _run(["-m", "mjxsysid.cli", "fly", "--help"])
    assert r.returncode == 0 and r.stderr == "" and "--quiet" in r.stdout


def test_only_the_probe_lines_are_dropped_and_import_errors_surface(tmp_path, capsys, monkeypatch):
    from mjxsysid.runtime.quiet import is_probe_line, quiet_import
    assert is_probe_line("Failed to import warp: No module named 'warp'")
    assert is_probe_line("Failed to import mujoco_warp: No module named 'warp'")
    assert not is_probe_line("Failed to import warp: libcuda.so: cannot open shared object file")
    (tmp_path / "fake_probe.py").write_text(
        "print(\"Failed to import warp: No module named 'warp'\")\nprint('something else')\n")
    (tmp_path / "fake_broken.py").write_text("print('before the error')\nimport no_such_module_xyz\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    quiet_import("fake_probe")
    assert capsys.readouterr().out == "something else\n"
    with pytest.raises(ModuleNotFoundError, match="no_such_module_xyz"):
        quiet_import("fake_broken")
    assert capsys.readouterr().out == "before the error\n"
    r = _run("import sys; sys.modules['mujoco.mjx'] = None; import mjxsysid.sim")
    assert r.returncode == 1 and "ModuleNotFoundError" in r.stderr and "mujoco.mjx" in r.stderr


AOT_LINE = ("E1126 14:46:36.199582   26128 cpu_aot_loader.cc:195] Loading XLA:CPU AOT result. Target machine "
            "feature +prefer-no-gather is not  supported on the host machine. Machine type used for XLA:CPU "
            "compilation doesn't match the machine type for execution. Compile machine features: [+avx]")


def test_the_stderr_filter_drops_only_the_cache_loaders_lines_and_survives_a_crash():
    from mjxsysid.runtime.quiet import is_aot_loader_line
    assert is_aot_loader_line(AOT_LINE.encode()) and is_aot_loader_line(AOT_LINE.replace("gather", "scatter").encode())
    assert not is_aot_loader_line(b"E1126 14:46:36.199582   26128 cpu_aot_loader.cc:195] Loading failed: bad file")
    start = "import os, sys; from mjxsysid.runtime.quiet import filter_native_stderr; assert filter_native_stderr(); "
    # the C++ logger writes to fd 2 directly; a partial line (a progress bar's "\r" redraw) goes through
    r = subprocess.run([PY, "-c", start + f"os.write(2, {AOT_LINE + chr(10)!r}.encode()); os.write(2, b'bar 1/2\\r'); "
                        "print('python stderr', file=sys.stderr); os.write(2, b'E1126 other error\\nno newline')"],
                       capture_output=True, env=ENV)      # bytes: "\r" kept as written
    assert r.returncode == 0 and r.stderr == b"bar 1/2\rpython stderr\nE1126 other error\nno newline"
    # what was written before a crash still arrives (the filter is another process)
    r = _run(start + "os.write(2, b'before the crash\\n'); import ctypes; ctypes.string_at(0)")
    assert r.returncode != 0 and "before the crash\n" in r.stderr
    r = subprocess.run([PY, "-c", start], capture_output=True, text=True, env=dict(ENV, MJXSYSID_RAW_STDERR="1"))
    assert r.returncode == 1 and "AssertionError" in r.stderr     # MJXSYSID_RAW_STDERR=1: not installed


def test_progress_bars_obey_quiet(capsys, monkeypatch):
    from mjxsysid.runtime import progress as pg
    monkeypatch.setenv("MJXSYSID_PROGRESS", "1")
    for _ in pg.progress(range(3), desc="unit-bar"):
        pass
    pg.echo("a message")
    with pg.stages(["fly", "decode"], desc="unit-stages") as st:
        st.start("fly")
        st.start("decode")
    out = capsys.readouterr()
    assert "unit-bar" in out.err and "3/3" in out.err and out.out == "a message\n"
    assert "unit-stages" in out.err and "2/2" in out.err and "decode" in out.err
    pg.set_quiet(True)
    try:
        for _ in pg.progress(range(3), desc="unit-bar"):
            pass
        pg.echo("a message")
        with pg.stages(["a", "b"], desc="st") as st:
            st.start("a")
            st.start("b")
    finally:
        pg.set_quiet(None)
    out = capsys.readouterr()
    assert out.err == "" and out.out == ""
    monkeypatch.setenv("MJXSYSID_PROGRESS", "0")
    for _ in pg.progress(range(3), desc="unit-bar"):
        pass
    assert capsys.readouterr().err == ""


def test_cli_quiet_flag_on_every_command():
    from mjxsysid.cli import build_parser
    p = build_parser()
    sub = next(a for a in p._actions if a.dest == "command")
    for name, sp in sub.choices.items():
        assert any("--quiet" in a.option_strings for a in sp._actions), name


# The group's first flights, decodes and log-grounded posterior (run again by test_decode.py and the
# notebooks in this worker): compiled at LLVM level 1, which compiles about as fast and runs them 2-4x faster.
@pytest.mark.usefixtures("xla_optimised_test")
def test_fly_and_decode_api_match_the_cli(tmp_path, capsys):
    import mjxsysid
    from mjxsysid import theta as P
    from mjxsysid.cli import main

    # The 2 s lemniscate flight of tests/decoding/test_decode.py and notebooks 01 / 04: one compile.
    res = mjxsysid.fly(mjxsysid.paper_vehicle(), controller="policy", reference="lemniscate", period=10.0,
                       duration=2.0)
    assert res.flight.latent.shape[:2] == (1, 1000) and not res.metrics["failed"]
    assert main(["fly", "--controller", "policy", "--reference", "lemniscate", "--period", "10",
                 "--duration", "2", "--out", str(tmp_path / "fly"), "-q"]) == 0
    cli = json.loads((tmp_path / "fly" / "metrics.json").read_text())
    for k in ("pos_rmse_m", "heading_rmse_deg", "saturation_frac"):
        np.testing.assert_allclose(res.metrics[k], cli[k], rtol=1e-6)
    post = mjxsysid.decode(res, samples=20, rate=2.0)
    assert post["samples"].shape == (4, 20, 19) and post["zhat"].shape == (4, 8)
    np.testing.assert_array_equal(post["theta_true"], P.PAPER_HARDWARE)
    assert main(["decode", "--reference", "lemniscate", "--period", "10", "--duration", "2", "--samples", "20", "--rate", "2",
                 "--out", str(tmp_path / "dec"), "--quiet"]) == 0
    capsys.readouterr()
    s = json.loads((tmp_path / "dec" / "summary.json").read_text())
    assert set(s) == set(post["summary"])
    for n in ("mass", "thrust_to_weight"):
        np.testing.assert_allclose([post["summary"][n][k] for k in ("mean", "q05", "q95")],
                                   [s[n][k] for k in ("mean", "q05", "q95")], rtol=1e-5)
    with np.load(tmp_path / "dec" / "decoded.npz") as f:
        np.testing.assert_allclose(f["samples"], post["samples"], rtol=1e-5)
    # A flight-log path decodes too; an oracle flight has no latent to decode.
    from mjxsysid.logs.csvlog import write_log
    from mjxsysid.rollout.flight import seen_imu
    one = res.one()
    log = write_log(tmp_path / "f.csv", one.time - 0.002, seen_imu(one.frame.imu), one.a_cmd,
                    one.omega_cmd, one.frame.motor_cmd)
    from_log = mjxsysid.decode(str(log), samples=20, rate=2.0, truth=mjxsysid.paper_vehicle())
    np.testing.assert_allclose(from_log["zhat"], post["zhat"], atol=2e-4)
    assert "inside" in from_log["summary"]["mass"]
    # a log's posterior of record is the log-grounded one, the decoders' beside it
    assert from_log["summary"]["_posterior"] == "log-grounded" and "mass" in from_log["summary"]["_decoder_only"]
    assert from_log["samples_log_grounded"].shape[1] == 19
    with pytest.raises(ValueError, match="latent policy"):
        mjxsysid.decode(dataclasses.replace(res, controller="oracle"))
