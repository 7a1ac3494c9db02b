"""`mjxsysid.runtime.profiling` and `mjxsysid profile`: compile time per JAX program, from JAX's own events."""
import json

import jax
import jax.numpy as jnp
import pytest

from mjxsysid.runtime.profiling import compile_profile


def test_compile_profile_names_each_program_and_counts_its_builds():
    def profiled_twice(x):
        return jnp.sin(x) * 2.0

    f = jax.jit(profiled_twice)
    with compile_profile() as prof:
        f(jnp.ones(3))
        f(jnp.ones(3))          # the same shape: no new build
        f(jnp.ones(5))          # a new shape: a second build
    assert "jit(profiled_twice)" not in prof.programs      # trace (f) and lower/XLA (jit(f)): one program
    p = prof.programs["profiled_twice"]
    assert p.builds == 2 and p.compile > 0 and p.lower > 0 and p.trace > 0
    assert prof.wall >= prof.compile_s > 0
    s = prof.summary(top=3)
    assert s["programs"] == len(prof.programs) and s["builds"] >= 2 and len(s["top"]) <= 3
    assert "profiled_twice" in prof.table() and "jit(" not in prof.table()
    f(jnp.ones(7))              # after the block: not added to the finished profile
    assert prof.programs["profiled_twice"].builds == 2
    with compile_profile() as later:
        f(jnp.ones(3))          # compiled already: nothing to build
        f(jnp.ones(9))
    assert later.programs["profiled_twice"].builds == 1

def test_profile_command_runs_the_command_and_writes_json(tmp_path, capsys):
    from mjxsysid.cli import main
    pytest.importorskip("pyulog")
    from mjxsysid.logs.ulog_write import write_ulog
    from support.synthetic_log import synthetic_flight
    r = synthetic_flight(seconds=3.0)
    log = write_ulog(tmp_path / "flight.ulg", r["t"], r["imu"], r["a_cmd"], r["omega_cmd"], r["motor"])
    rc = main(["profile", "--json", str(tmp_path / "p.json"), "--", "check-log", str(log), "--json"])
    got = json.loads((tmp_path / "p.json").read_text())
    assert got["command"][0] == "check-log" and got["exit"] == rc and got["wall_s"] > 0
    assert "persistent-cache hits" in capsys.readouterr().err
    assert main(["profile"]) == 2 and "name the command" in capsys.readouterr().err
