"""The process around the science: start-up, XLA flags, the compilation cache, devices, progress,
checkpoints, profiling, JSON output and MJX's import probe. Imports nothing else of mjxsysid.

- :mod:`.startup`      a command's start-up: the compilation cache (per CPU), the multi-process join.
- :mod:`.xla_flags`    XLA:CPU's faster compiling.
- :mod:`.distributed`  devices and processes: sharding a batch, joining a cluster.
- :mod:`.progress`     progress bars and messages, quiet mode.
- :mod:`.checkpoint`   checkpoints as npz + JSON (no pickle), atomic writes.
- :mod:`.profiling`    compile time per JAX program.
- :mod:`.jsonout`      valid JSON out of NumPy/JAX values (null for a missing number).
- :mod:`.quiet`        MJX's "Failed to import warp" probe silenced, real errors kept.
"""
