"""Traced programs kept on disk: a command run again loads its largest programs' StableHLO (``jax.export``)
instead of tracing them in Python, as JAX's persistent compilation cache spares their compile.

A warm ``decode --log`` of a 10 s log spent 3.6 s tracing NUTS's program (blackjax's window adaptation and
sampler, :func:`mjxsysid.identify.nuts._chains`) and 0.3 s lowering it, of 20.6 s. The SMC's program
(:func:`mjxsysid.identify.smc.program`), the mode's Levenberg–Marquardt on a CPU
(:func:`mjxsysid.identify.mode._fit_ls_many`) and NUTS's R̂ and ESS go through here too. The files live beside the
compilation cache (``<cache>/exported``) and only while that cache is on. A file's key holds everything the
trace depends on: the package's source, blackjax's and JAX's versions, the backend, the matmul precision and
x64 setting, the function's name and static arguments, and the shapes and dtypes of its arguments.
"""
from __future__ import annotations

import functools
import hashlib
import os
import threading
from pathlib import Path

import jax

FOLDER = "exported"
"""The subfolder of the persistent compilation cache that holds the exported programs."""


@functools.lru_cache(maxsize=1)
def source_hash() -> str:
    """sha256 of the package's Python sources and the versions of what it traces through (jax, jaxlib, blackjax)."""
    import importlib.metadata as md
    h = hashlib.sha256()
    root = Path(__file__).resolve().parents[1]
    for p in sorted(root.rglob("*.py")):
        h.update(str(p.relative_to(root)).encode())
        h.update(p.read_bytes())
    for dist in ("jax", "jaxlib", "blackjax"):
        try:
            h.update(f"{dist}=={md.version(dist)}".encode())
        except md.PackageNotFoundError:
            h.update(f"{dist} absent".encode())
    return h.hexdigest()


def _key(name: str, static: dict, leaves, tree) -> str:
    """The file key of ``name`` called with ``static`` on the flat ``leaves`` of the arguments' pytree ``tree``."""
    avals = [(tuple(x.shape), str(x.dtype)) for x in leaves]
    cfg = (jax.default_backend(), str(jax.config.jax_default_matmul_precision), bool(jax.config.jax_enable_x64))
    text = repr((source_hash(), cfg, name, sorted((k, repr(v)) for k, v in static.items()), str(tree), avals))
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def folder() -> Path | None:
    """Where exported programs are kept: ``<compilation cache>/exported``; None while that cache is off, or
    where JAX cannot serialize them (its serializer needs the ``flatbuffers`` package)."""
    where = jax.config.jax_compilation_cache_dir
    return Path(where) / FOLDER if where and can_serialize() else None


@functools.lru_cache(maxsize=1)
def can_serialize() -> bool:
    """Whether ``jax.export`` can write a program: its serializer imports ``flatbuffers`` (a dependency of
    this package; a machine without it, such as a bare GPU host, compiles as usual)."""
    try:
        import flatbuffers  # noqa: F401
    except ImportError:
        return False
    return True


def call(name: str, fn, static: dict, *args):
    """``fn(*args, **static)`` through a program exported once per key (:func:`_key`) and kept in
    :func:`folder`: the first call traces and saves it, later processes load it. ``fn`` is a pure function of
    arrays (``args``: pytrees of them, of any registered node type: they travel flattened) returning a tuple
    of arrays, with the hashable ``static`` keyword arguments. Without a compilation cache, it is jitted as usual."""
    program, leaves = _program(name, fn, static, args)
    return program(*leaves)


def compile_only(name: str, fn, static: dict, *args) -> None:
    """Compile what :func:`call` with these arguments would run, and run nothing (``args``: arrays of the shapes
    and dtypes the call will pass; their values are not read): the call then finds it compiled."""
    program, leaves = _program(name, fn, static, args)
    program.lower(*leaves).compile()


def _program(name: str, fn, static: dict, args) -> tuple:
    """The jitted program :func:`call` runs for ``args`` (exported and saved where the key has no file yet), and
    the arguments' flat leaves."""
    leaves, tree = jax.tree.flatten(args)
    jitted = _jitted(fn, tuple(sorted(static.items())), tree)
    where = folder()
    if where is None:
        return jitted, leaves
    path = where / f"{name}-{_key(name, static, leaves, tree)}.bin"
    if str(path) in _REFUSED:
        return jitted, leaves
    if not path.is_file():
        try:
            exp = jax.export.export(jitted, disabled_checks=_disabled_checks())(*leaves)
        except (ValueError, NotImplementedError):    # a custom call or host callback JAX will not serialize: jitted
            _REFUSED.add(str(path))                  # and not traced for export again in this process
            return jitted, leaves
        where.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.{threading.get_ident()}.tmp")   # a writer per thread
        tmp.write_bytes(exp.serialize())
        tmp.replace(path)                            # atomic: a reader never sees half a file
    return _runner(str(path)), leaves


_REFUSED: set = set()
"""The files of programs ``jax.export`` refused in this process."""

LOCAL_CUSTOM_CALLS = ("lapack_sormqr_ffi", "lapack_dormqr_ffi")
"""LAPACK's calls that ``jax.export`` does not promise to keep (the QR solve of the mode's Levenberg–Marquardt on a
CPU): serialized anyway, since a file is read only by the JAX, jaxlib and backend its key names."""


def _disabled_checks() -> list:
    """``jax.export``'s checks waived for :data:`LOCAL_CUSTOM_CALLS`."""
    return [jax.export.DisabledSafetyCheck.custom_call(t) for t in LOCAL_CUSTOM_CALLS]


@functools.lru_cache(maxsize=16)
def _jitted(fn, static: tuple, tree):
    """``fn`` with ``static`` bound, called on the flat leaves of its arguments' pytree ``tree``, jitted."""
    def flat(*leaves):
        return fn(*jax.tree.unflatten(tree, leaves), **dict(static))
    return jax.jit(flat)


@functools.lru_cache(maxsize=32)
def _runner(path: str):
    """The exported program at ``path``, jitted (compiled once per process, from the compilation cache)."""
    return jax.jit(jax.export.deserialize(bytearray(Path(path).read_bytes())).call)


__all__ = ["call", "can_serialize", "compile_only", "folder", "source_hash", "FOLDER"]
