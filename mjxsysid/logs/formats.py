"""Flight-log formats, detected by content: one reader module per format, one contract.

Every reader is ``read(path, segment=None) -> dict`` and returns the log contract of
:func:`mjxsysid.logs.ulog.read_ulog`: on a 2 ms grid ``t`` (T,) s, ``imu`` (T, 6) gyro rad/s and
specific force m/s² in the body frame FLU (x forward, y left, z up), ``a_cmd`` (T,) m/s², ``omega_cmd``
(T, 3) rad/s, ``motor`` (T, 4) Ω_cmd/Ω_max in [0, 1] in mjxsysid's rotor order (1 front-right,
2 front-left, 3 back-left, 4 back-right); optional ``rotor_speed`` (T, 4) measured rotor speed in
rad/s (same order) and ``velocity_body`` (T, 3) m/s (FLU); ``native`` {channel: (t (N,), values)}
the samples before resampling, ``resampled`` {channel: how it was brought to 2 ms} and ``source``
(format, path, rates_hz, segment, conversions: one sentence each).

A format module exposes ``sniff(head: bytes) -> bool`` (the file's first 4 KiB) and ``read``;
heavy parsers are imported inside ``read`` (optional extras), never at import.
"""
from __future__ import annotations

import importlib
from pathlib import Path

FORMATS = (
    # (name, module, pip extra); tried in order, the CSV last
    ("PX4 ULog", "mjxsysid.logs.ulog", "px4"),
    ("Crazyflie uSD", "mjxsysid.logs.crazyflie", None),
    ("Betaflight blackbox", "mjxsysid.logs.blackbox", "blackbox"),
    ("ArduPilot DataFlash", "mjxsysid.logs.dataflash", "ardupilot"),
    ("ROS bag", "mjxsysid.logs.rosbag", "rosbag"),
    ("PX4 CSV (data-driven-dynamics)", "mjxsysid.logs.px4csv", None),
)
HEAD_BYTES = 4096


def _module(name: str):
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as e:
        if e.name == name:
            return None
        raise


def detect(path) -> str:
    """The format of the file at ``path`` by its content (not its name): a name of
    :data:`FORMATS`, or "CSV" (the project's CSV contract, :mod:`mjxsysid.logs.csvlog`); a folder
    holding metadata.yaml is a ROS 2 bag."""
    path = Path(path)
    if path.is_dir() and (path / "metadata.yaml").is_file():
        return "ROS bag"                                   # a ROS 2 bag is a folder
    if path.is_dir():
        raise ValueError(f"{path}: a folder, not a log (a ROS 2 bag folder holds metadata.yaml); give a log file, "
                         f"or several to `decode --log`")
    if not path.is_file():
        raise FileNotFoundError(f"flight log not found: {path}")
    with open(path, "rb") as f:
        head = f.read(HEAD_BYTES)
    for name, mod, _ in FORMATS:
        m = _module(mod)
        if m is not None and hasattr(m, "sniff") and m.sniff(head):
            return name
    return "CSV"


def reader(fmt: str):
    """The ``read(path, segment=None)`` function of format ``fmt`` (a name of :data:`FORMATS`)."""
    for name, mod, _ in FORMATS:
        if name == fmt:
            return importlib.import_module(mod).read
    raise ValueError(f"unknown log format {fmt!r}; known: {[f[0] for f in FORMATS]}")
