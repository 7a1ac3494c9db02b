"""Checkpoints and shipped weights as .npz (plain arrays, ``allow_pickle=False``) + JSON.

A pytree is stored flat: one array per leaf, keyed by its path (``jax.tree_util.keystr``).
Loading needs a template with the same structure (e.g. freshly initialised parameters) and
checks every key and shape, so a mismatched file fails with a message naming the leaf.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import jax
import numpy as np

_META = "__meta_json__"


def save_tree(path, tree, meta: dict | None = None) -> Path:
    """Write ``tree`` (and a JSON-serialisable ``meta`` dict) to ``path`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    leaves = jax.tree_util.tree_flatten_with_path(tree)[0]
    arrays = {jax.tree_util.keystr(k): np.asarray(v) for k, v in leaves}
    if _META in arrays:
        raise ValueError(f"reserved key {_META} in tree")
    arrays[_META] = np.frombuffer(json.dumps(meta or {}).encode(), np.uint8)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)
    return path


def load_meta(path) -> dict:
    with np.load(_existing(path), allow_pickle=False) as f:
        return json.loads(bytes(f[_META]).decode()) if _META in f.files else {}


def load_tree(path, template):
    """Read a tree saved by :func:`save_tree` into the structure of ``template``."""
    path = _existing(path)
    with np.load(path, allow_pickle=False) as f:
        flat, treedef = jax.tree_util.tree_flatten_with_path(template)
        out = []
        for k, leaf in flat:
            name = jax.tree_util.keystr(k)
            if name not in f.files:
                raise ValueError(f"{path}: missing array {name} (not a checkpoint of this model?)")
            arr = f[name]
            if arr.shape != np.shape(leaf):
                raise ValueError(f"{path}: {name} has shape {arr.shape}, expected {np.shape(leaf)}")
            out.append(arr.astype(np.asarray(leaf).dtype))
        extra = set(f.files) - {jax.tree_util.keystr(k) for k, _ in flat} - {_META}
        if extra:
            raise ValueError(f"{path}: unexpected arrays {sorted(extra)[:5]} (different architecture?)")
    return jax.tree_util.tree_unflatten(treedef, out)


def _existing(path) -> Path:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"weights/checkpoint file not found: {path}")
    return path
