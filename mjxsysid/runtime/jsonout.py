"""JSON as the project writes it: valid JSON that any parser reads. A missing number (NaN, ±inf)
is ``null``; numpy scalars and arrays are numbers and lists; tuples are lists; other objects
their ``str``."""
from __future__ import annotations

import json
import math
from pathlib import Path


def plain(obj):
    """``obj`` with every value JSON can hold: floats that are not finite -> None, numpy -> Python,
    tuples and sets -> lists, paths and other objects -> str; dict keys -> str."""
    if isinstance(obj, dict):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set)):
        return [plain(v) for v in obj]
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return float(obj) if math.isfinite(obj) else None
    if hasattr(obj, "tolist"):          # numpy arrays and scalars (numpy is not imported here)
        return plain(obj.tolist())
    return str(obj)


def dumps(obj, **kw) -> str:
    """:func:`json.dumps` of :func:`plain` ``obj`` (NaN -> null), refusing anything else not JSON."""
    kw.pop("default", None)
    return json.dumps(plain(obj), allow_nan=False, **kw)


def write_json(path, obj, indent: int = 2, **kw) -> Path:
    """Write :func:`dumps` of ``obj`` (and a newline) to ``path``."""
    Path(path).write_text(dumps(obj, indent=indent, **kw) + "\n")
    return Path(path)
