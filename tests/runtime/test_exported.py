"""Traced programs kept on disk (runtime/exported.py): the same results as jit, one file per key, loaded
by a later call, registered pytrees flattened on the way, and plain jit where nothing can be written."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxsysid.runtime import exported


@jax.tree_util.register_dataclass
@dataclasses.dataclass
class _Pair:
    a: jax.Array
    b: jax.Array


def _f(x, p, *, n):
    def body(c, _):
        return jnp.sin(c) * p.a + p.b, None
    return jax.lax.scan(body, x, None, length=n)[0], jnp.sum(x)


def test_exported_program_is_written_once_and_gives_jits_results(tmp_path, monkeypatch):
    monkeypatch.setattr(exported, "folder", lambda: tmp_path)
    x, p = jnp.arange(3.0), _Pair(jnp.float32(0.5), jnp.ones(3))
    want = jax.jit(_f, static_argnames="n")(x, p, n=4)
    got = exported.call("f", _f, {"n": 4}, x, p)
    files = sorted(tmp_path.glob("f-*.bin"))
    assert len(files) == 1
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    exported._runner.cache_clear()                    # a later process: loaded from the file, not traced
    again = exported.call("f", _f, {"n": 4}, x, p)
    np.testing.assert_array_equal(again[0], want[0])
    assert sorted(tmp_path.glob("f-*.bin")) == files
    exported.call("f", _f, {"n": 5}, x, p)            # another static: another program
    exported.call("f", _f, {"n": 4}, jnp.arange(4.0), _Pair(jnp.float32(0.5), jnp.ones(4)))   # other shapes
    assert len(list(tmp_path.glob("f-*.bin"))) == 3


def test_without_a_place_to_write_it_is_plain_jit(monkeypatch):
    monkeypatch.setattr(exported, "can_serialize", lambda: False)
    assert jax.config.jax_compilation_cache_dir and exported.folder() is None    # the suite's cache is on
    x, p = jnp.arange(3.0), _Pair(jnp.float32(0.5), jnp.ones(3))
    got = exported.call("g", _f, {"n": 2}, x, p)
    np.testing.assert_array_equal(got[0], jax.jit(_f, static_argnames="n")(x, p, n=2)[0])
    assert not list((Path(jax.config.jax_compilation_cache_dir) / exported.FOLDER).glob("g-*"))


def test_a_program_jax_will_not_serialize_is_plain_jit(tmp_path, monkeypatch):
    """A program with a custom call ``jax.export`` refuses (a ValueError) runs jitted, and no file is written."""
    monkeypatch.setattr(exported, "folder", lambda: tmp_path)

    tried = []

    def refuse(*a, **k):
        tried.append(a)
        raise ValueError("Cannot serialize code with custom calls whose targets have no compatibility guarantees")
    monkeypatch.setattr(jax.export, "export", refuse)
    x, p = jnp.arange(3.0), _Pair(jnp.float32(0.5), jnp.ones(3))
    for _ in range(2):                                # refused once: the next call does not try again
        got = exported.call("h", _f, {"n": 3}, x, p)
        np.testing.assert_array_equal(got[0], jax.jit(_f, static_argnames="n")(x, p, n=3)[0])
    assert not list(tmp_path.glob("h-*")) and len(tried) == 1


def test_a_qr_solve_is_kept_with_its_lapack_calls(tmp_path, monkeypatch):
    """LAPACK's QR solve (what the mode's Levenberg–Marquardt runs on a CPU, ``LOCAL_CUSTOM_CALLS``) is written to
    disk and gives jit's results, read back from the file."""
    monkeypatch.setattr(exported, "folder", lambda: tmp_path)

    import lineax as lx

    def lstsq(a, b):
        return (lx.linear_solve(lx.MatrixLinearOperator(a), b, lx.QR(), throw=False).value,)
    a = jnp.asarray(np.random.default_rng(0).normal(size=(30, 4)), jnp.float32)
    b = jnp.asarray(np.random.default_rng(1).normal(size=30), jnp.float32)
    with pytest.raises(ValueError, match="no compatibility guarantees"):
        jax.export.export(jax.jit(lstsq))(a, b)
    want = jax.jit(lstsq)(a, b)[0]
    exported.call("qr", lstsq, {}, a, b)
    assert len(list(tmp_path.glob("qr-*.bin"))) == 1
    exported._runner.cache_clear()
    np.testing.assert_allclose(exported.call("qr", lstsq, {}, a, b)[0], want, rtol=1e-6)
