"""Ran at cbd6be6, against that commit's interface (`nuts.plan` of batched keys, `_chains_logs(steps, stages, ...)`);
HEAD builds the keys inside the program. Old (static lengths, 14b9d63) against new (traced lengths, one program) NUTS, the same inputs: one captured log's
NUTS arguments replicated to L logs; each program's first and retry shapes, warm, timed 3× alternated."""
import functools, importlib.util, sys, time
import jax, numpy as np
from mjxsysid.runtime import startup  # noqa: F401
import mjxsysid.identify.nuts as N
spec = importlib.util.spec_from_file_location("nuts_old", sys.argv[1]); O = importlib.util.module_from_spec(spec); spec.loader.exec_module(O)
L = int(sys.argv[2])
sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
from nuts_cmdbuf import replicated  # noqa: E402   the same inputs (this run's copy held them inline)
args, prior = replicated(sys.argv[3], L)
keysL = args[0]
res = {}
SHAPES = {"first": (200, 125, 1), "retry": (400, 500, 4)}
for W, D, thin in [SHAPES[x] for x in sys.argv[4].split(",")]:
    fo = jax.jit(functools.partial(O._chains_logs, prior=prior, warmup=W, draws=D, target_acceptance=N.TARGET_ACCEPTANCE, max_doublings=N.MAX_DOUBLINGS))
    steps, stages = N.plan(keysL, W, D, 900)
    fn = jax.jit(functools.partial(N._chains_logs, prior=prior, kept=125, target_acceptance=N.TARGET_ACCEPTANCE, max_doublings=N.MAX_DOUBLINGS))
    an = (steps, stages, *args[1:], np.int32(W), np.int32(W + D), np.int32(thin))
    for name, f, x in (("old", fo, args), ("new", fn, an)):
        t = time.perf_counter(); out = jax.block_until_ready(f(*x)); print(W, D, name, f"first call {time.perf_counter()-t:.1f} s", flush=True)
        res[(W, name)] = out
    ts = {"old": [], "new": []}
    for r in range(int(sys.argv[5])):
        for name, f, x in (("old", fo, args), ("new", fn, an)):
            t = time.perf_counter(); jax.block_until_ready(f(*x)); ts[name].append(round(time.perf_counter() - t, 2))
    print(W, D, thin, "warm runs", ts, "draws equal:", bool(np.array_equal(np.asarray(res[(W, "old")][0])[:, :, ::thin], np.asarray(res[(W, "new")][0]))), flush=True)
