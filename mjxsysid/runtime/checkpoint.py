"""Checkpoints and shipped weights as .npz (plain arrays, ``allow_pickle=False``) + JSON.

A pytree is stored flat: one array per leaf, keyed by its path (``jax.tree_util.keystr``).
Loading needs a template with the same structure (e.g. freshly initialised parameters) and
checks every key and shape, so a mismatched file fails with a message naming the leaf.
"""
from __future__ import annotations

import contextlib
import json
import os
import struct
import zipfile
import zlib
from pathlib import Path

import jax
import numpy as np

from mjxsysid.runtime import jsonout

_META = "__meta_json__"


def save_tree(path, tree, meta: dict | None = None) -> Path:
    """Write ``tree`` (and a JSON-serialisable ``meta`` dict) to ``path`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    leaves = jax.tree_util.tree_flatten_with_path(tree)[0]
    arrays = {jax.tree_util.keystr(k): np.asarray(v) for k, v in leaves}
    if _META in arrays:
        raise ValueError(f"reserved key {_META} in tree")
    arrays[_META] = np.frombuffer(jsonout.dumps(meta or {}).encode(), np.uint8)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)
    return path


@contextlib.contextmanager
def open_npz(path, what: str = "weights/checkpoint file"):
    """``np.load`` of an .npz (no pickle) whose failures name the file: a missing file raises
    ``FileNotFoundError``; an empty, truncated or corrupt file (or a plain .npy, or a read error
    while inside the block) raises ``ValueError("PATH: not a readable WHAT ...")``."""
    path = _existing(path, what)
    # zipfile and numpy raise many types on damaged files (BadZipFile, zlib.error, EOFError,
    # OSError, ValueError, KeyError, NotImplementedError for a garbled version field, ...).
    bad = (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, KeyError, NotImplementedError,
           IndexError, TypeError, struct.error, UnicodeDecodeError, OverflowError, MemoryError)
    try:
        f = np.load(path, allow_pickle=False)
    except bad as e:
        raise ValueError(f"{path}: not a readable {what} (empty, truncated or corrupt .npz: "
                         f"{type(e).__name__}: {e})") from None
    if not isinstance(f, np.lib.npyio.NpzFile):
        raise ValueError(f"{path}: a single array (.npy), not a {what} (.npz)")
    try:
        yield f
    except bad as e:
        if isinstance(e, ValueError) and str(e).startswith(str(path)):
            raise
        raise ValueError(f"{path}: not a readable {what} (truncated or corrupt: "
                         f"{type(e).__name__}: {e})") from None
    finally:
        f.close()


def load_meta(path) -> dict:
    """The JSON metadata saved with a tree ({} if none). Errors name the file."""
    with open_npz(path) as f:
        if _META not in f.files:
            return {}
        meta = json.loads(bytes(f[_META]).decode())
        if not isinstance(meta, dict):
            raise ValueError(f"{path}: metadata is not a JSON object")
        return meta


def load_tree(path, template, *, finite: bool = False):
    """Read a tree saved by :func:`save_tree` into the structure of ``template`` (arrays, or
    ``jax.ShapeDtypeStruct`` leaves from ``jax.eval_shape``, which avoids initialising a model
    just to load it). Every key and shape is checked: a missing or unexpected array or a wrong shape (and with ``finite``, for
    weights, NaN/inf values) raise ``ValueError`` naming the file and the array."""
    with open_npz(path) as f:
        flat, treedef = jax.tree_util.tree_flatten_with_path(template)
        out = []
        for k, leaf in flat:
            name = jax.tree_util.keystr(k)
            if name not in f.files:
                raise ValueError(f"{path}: missing array {name} (not a checkpoint of this model?)")
            arr = f[name]
            shape = tuple(leaf.shape) if hasattr(leaf, "shape") else np.shape(leaf)
            if arr.shape != shape:
                raise ValueError(f"{path}: {name} has shape {arr.shape}, expected {shape}")
            if finite and np.issubdtype(arr.dtype, np.floating) and not np.all(np.isfinite(arr)):
                raise ValueError(f"{path}: {name} has non-finite values (NaN/inf)")
            out.append(arr.astype(leaf.dtype if hasattr(leaf, "dtype") else np.asarray(leaf).dtype))
        extra = set(f.files) - {jax.tree_util.keystr(k) for k, _ in flat} - {_META}
        if extra:
            raise ValueError(f"{path}: unexpected arrays {sorted(extra)[:5]} (different architecture?)")
    return jax.tree_util.tree_unflatten(treedef, out)


def _existing(path, what: str = "weights/checkpoint file") -> Path:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    return path
