"""Scale-out on JAX's own runtime: one batch axis sharded over every device.

Every batched workload has one vmap boundary (``rollout.harness.fly_batch``, the CFM sampler's
integration over cases, the policy evaluation rollout, the training environment batch). There,
the batch axis (vehicles, environments, cases) is padded to a multiple of the device count and
placed with ``NamedSharding(mesh, P('batch'))``; arrays shared by the batch (network weights)
are replicated. ``jax.jit`` then partitions the computation; nothing else changes. Results are
those of one device up to float reassociation (stated per workload in tests/runtime/test_distributed.py).

On one device every function here is a no-op: no padding, no placement, the same arrays.

Multi-host: the same code runs under ``jax.distributed.initialize()`` (see :func:`maybe_initialize`):
``jax.devices()`` then lists the devices of every process, the mesh spans them all, each process
supplies its own shards of the (identical, seeded) host inputs and gathers the results.

API (all present in jax 0.10 and 0.11): ``jax.sharding.Mesh``, ``NamedSharding``,
``PartitionSpec``, ``jax.device_put``, ``jax.make_array_from_callback``,
``jax.experimental.multihost_utils.process_allgather``, ``jax.distributed.initialize``.
"""
from __future__ import annotations

import contextlib
import os

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "batch"

_device_limit: int | None = None


@contextlib.contextmanager
def limit_devices(n: int | None):
    """Within the block, meshes use at most ``n`` devices (None: all). For comparisons and
    benchmarks in one process (``limit_devices(1)``: the single-device path, no sharding)."""
    global _device_limit
    if n is not None and int(n) < 1:
        raise ValueError(f"limit_devices: n must be >= 1, got {n}")
    prev, _device_limit = _device_limit, (None if n is None else int(n))
    try:
        yield
    finally:
        _device_limit = prev


def device_count() -> int:
    """Devices a batch is sharded over: every device of every process (``jax.devices()``),
    capped by :func:`limit_devices` or ``$MJXSYSID_DEVICES``."""
    n = len(jax.devices())
    cap = _device_limit
    env = os.environ.get("MJXSYSID_DEVICES")
    if cap is None and env:
        try:
            cap = int(env)
        except ValueError:
            raise ValueError(f"$MJXSYSID_DEVICES must be a positive integer, got {env!r}")
        if cap < 1:
            raise ValueError(f"$MJXSYSID_DEVICES must be a positive integer, got {env!r}")
    return n if cap is None else min(n, cap)


def batch_mesh(divides: int | None = None) -> Mesh:
    """1-D mesh with axis ``'batch'`` over :func:`device_count` devices. With ``divides``, the
    largest device count ≤ that which divides ``divides`` (for batches that must not be padded,
    e.g. the training environments)."""
    n = device_count()
    if divides is not None:
        n = max(d for d in range(1, n + 1) if int(divides) % d == 0)
    if n < len(jax.devices()) and jax.process_count() > 1:  # every process must hold a shard
        what = (f"a batch of {divides} cannot be split evenly over" if divides is not None
                else "$MJXSYSID_DEVICES / limit_devices cannot leave out any of")
        raise ValueError(f"{what} the {len(jax.devices())} devices of {jax.process_count()} processes"
                         + (f"; use a multiple of {len(jax.devices())}" if divides is not None else ""))
    return Mesh(np.asarray(jax.devices()[:n]), (AXIS,))


def padded_size(n: int, mesh: Mesh) -> int:
    """n rounded up to a multiple of the mesh size."""
    d = mesh.size
    return -(-int(n) // d) * d


def _pad(x, target: int):
    """Pad axis 0 of x to ``target`` rows by repeating the last row (valid inputs, no NaN)."""
    x = jnp.asarray(x)
    extra = target - x.shape[0]
    if extra == 0:
        return x
    return jnp.concatenate([x, jnp.repeat(x[-1:], extra, axis=0)], axis=0)


def _place(x, sharding: NamedSharding):
    if jax.process_count() == 1:
        return jax.device_put(x, sharding)  # also inside jit (a tracer): a placement request
    try:
        host = np.asarray(x)  # identical on every process (same seed): each supplies its own shards
    except jax.errors.TracerArrayConversionError:
        return jax.lax.with_sharding_constraint(x, sharding)  # inside jit
    return jax.make_array_from_callback(host.shape, sharding, lambda idx: host[idx])


def _spread_over_processes(x) -> bool:
    """Is x a concrete array whose values live partly in other processes?"""
    try:
        return isinstance(x, jax.Array) and not x.is_fully_addressable and not x.is_fully_replicated
    except jax.errors.ConcretizationTypeError:
        return False  # a tracer inside jit: the compiler places it


def shard_batch(tree, n: int | None = None, *, axes=0, mesh: Mesh | None = None):
    """Pad the leading (batch) axis of a pytree to a multiple of the device count and shard it.

    tree: leaves (B, ...) where ``axes`` (a pytree prefix of ``tree``, like vmap's ``in_axes``)
    is 0; leaves where it is None are shared and replicated. Returns the placed tree; leaves
    (B', ...) with B' = :func:`padded_size` (B). On one device, returns ``tree`` itself.
    ``n``: the batch size B (default: read from the first batched leaf)."""
    mesh = mesh or batch_mesh()
    if mesh.size == 1:
        return tree
    flat_axes = _broadcast_axes(axes, tree)
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    if n is None:
        n = next(np.shape(x)[0] for x, a in zip(leaves, flat_axes) if a == 0)
    target = padded_size(n, mesh)
    batched = NamedSharding(mesh, PartitionSpec(AXIS))
    shared = NamedSharding(mesh, PartitionSpec())
    out = []
    for x, a in zip(leaves, flat_axes):
        if a == 0:
            if np.shape(x)[0] != n:
                raise ValueError(f"shard_batch: a batched leaf has leading size {np.shape(x)[0]}, expected {n}")
            out.append(_place(_pad(x, target), batched))
        elif a is None:
            out.append(_place(jnp.asarray(x), shared))
        else:
            raise ValueError(f"shard_batch: batch axis must be 0 or None, got {a}")
    return jax.tree_util.tree_unflatten(treedef, out)


def replicate(tree, mesh: Mesh | None = None):
    """Place every leaf of ``tree`` on every device of the mesh (no-op on one device)."""
    mesh = mesh or batch_mesh()
    if mesh.size == 1:
        return tree
    sh = NamedSharding(mesh, PartitionSpec())
    return jax.tree.map(lambda x: _place(jnp.asarray(x), sh), tree)


def _broadcast_axes(axes, tree) -> list:
    """Flatten ``axes`` (a prefix of ``tree``) to one entry per leaf of ``tree``."""
    out = []

    def expand(a, sub):
        n = len(jax.tree_util.tree_leaves(sub))
        out.extend([a] * n)
        return a

    jax.tree.map(expand, axes, tree, is_leaf=lambda x: x is None)
    return out


def unpad(tree, n: int, *, axis: int = 0):
    """Drop the padding of :func:`shard_batch`: keep the first ``n`` entries along ``axis`` of
    every leaf. Leaves spread over several processes are gathered first (host arrays then).
    A tree with nothing to drop and nothing to gather is returned as is (one device)."""
    def one(x):
        if _spread_over_processes(x):
            from jax.experimental import multihost_utils
            x = multihost_utils.process_allgather(x, tiled=True)
        if x.shape[axis] == n:
            return x
        return jax.lax.slice_in_dim(x, 0, n, axis=axis) if isinstance(x, jax.Array) else \
            np.take(x, np.arange(n), axis=axis)
    return jax.tree.map(one, tree)


def constrain_batch(tree, mesh: Mesh | None):
    """Inside jit: ask for the leading axis of every leaf to be sharded over ``mesh`` (data
    parallelism; the compiler then all-reduces what is summed over it). No-op for None, a
    1-device mesh, or leaves whose leading size the mesh does not divide."""
    if mesh is None or mesh.size == 1:
        return tree
    sh = NamedSharding(mesh, PartitionSpec(AXIS))
    return jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x, sh)
                        if x.ndim and x.shape[0] % mesh.size == 0 else x, tree)


# ---------------------------------------------------------------------------------------
# Multi-host start-up
# ---------------------------------------------------------------------------------------

def launcher_env(environ=None) -> str | None:
    """Which cluster launcher started this process with more than one process, or None.

    - ``"jax"``: ``JAX_COORDINATOR_ADDRESS`` is set (with ``JAX_NUM_PROCESSES`` and
      ``JAX_PROCESS_ID``: passed to ``jax.distributed.initialize``);
    - ``"slurm"``: ``srun`` started more than one task (``SLURM_JOB_ID``, ``SLURM_STEP_NODELIST``,
      ``SLURM_PROCID``, ``SLURM_LOCALID`` set and ``SLURM_NTASKS`` > 1);
    - ``"ompi"``: ``mpirun`` of Open MPI with ``OMPI_COMM_WORLD_SIZE`` > 1.
    ``MJXSYSID_DISTRIBUTED=0`` turns detection off (a plain single-process run)."""
    env = os.environ if environ is None else environ
    if env.get("MJXSYSID_DISTRIBUTED", "") == "0":
        return None
    if env.get("JAX_COORDINATOR_ADDRESS"):
        return "jax"
    slurm = ("SLURM_JOB_ID", "SLURM_STEP_NODELIST", "SLURM_PROCID", "SLURM_LOCALID", "SLURM_NTASKS")
    if all(k in env for k in slurm) and _int(env, "SLURM_NTASKS") > 1:
        return "slurm"
    if "OMPI_MCA_orte_hnp_uri" in env and _int(env, "OMPI_COMM_WORLD_SIZE") > 1:
        return "ompi"
    return None


def _int(env, key) -> int:
    try:
        return int(env.get(key, "0"))
    except ValueError:
        raise ValueError(f"${key} must be an integer, got {env.get(key)!r}")


def maybe_initialize(environ=None) -> bool:
    """Call ``jax.distributed.initialize()`` if a cluster launcher started several processes
    (:func:`launcher_env`); must run before any JAX computation. Returns whether it did.

    ``"jax"``: coordinator, process count and id from ``JAX_COORDINATOR_ADDRESS``,
    ``JAX_NUM_PROCESSES``, ``JAX_PROCESS_ID``. ``"slurm"`` / ``"ompi"``: JAX's own cluster
    detection (coordinator = first node of the step, port from the job id). JAX then gives each
    process the GPU of its ``SLURM_LOCALID`` (one process per GPU); for one process per node
    with all its GPUs, export ``JAX_LOCAL_DEVICE_IDS=0,1,…``."""
    kind = launcher_env(environ)
    if kind is None:
        return False
    if kind == "jax":
        env = os.environ if environ is None else environ
        for k in ("JAX_NUM_PROCESSES", "JAX_PROCESS_ID"):
            if k not in env:
                raise ValueError(f"JAX_COORDINATOR_ADDRESS is set but ${k} is not")
        jax.distributed.initialize(coordinator_address=env["JAX_COORDINATOR_ADDRESS"],
                                   num_processes=_int(env, "JAX_NUM_PROCESSES"),
                                   process_id=_int(env, "JAX_PROCESS_ID"))
    else:
        jax.distributed.initialize()
    return True


def describe() -> dict:
    """Processes and devices in use (for run metadata)."""
    return {"process_count": jax.process_count(), "process_index": jax.process_index(),
            "devices": len(jax.devices()), "local_devices": len(jax.local_devices()),
            "mesh_devices": device_count(), "platform": jax.devices()[0].platform}
