"""NUTS of one captured log's arguments replicated to L logs, under this process's XLA_FLAGS: the first call
(compile + run) and warm runs of the first attempt's plan; draws hashed, so runs under other flags compare.
python nuts_cmdbuf.py L REPEATS ARGS.pkl"""
import hashlib, json, os, pickle, sys, time
import jax, jax.numpy as jnp, numpy as np


def replicated(path, L):
    """The captured run_chains arguments at ``path`` ((args, {"prior": ...}) pickled) for L logs: each log its own
    keys and starts (8 chains), the log's data, δ, weights, m and chol repeated -> (args, prior)."""
    (a, k) = pickle.load(open(path, "rb"))
    keys, u0, data, ld, w, lo, hi, m, chol = a
    rep = lambda x: jax.tree.map(lambda y: jnp.broadcast_to(jnp.asarray(y), (L,) + jnp.shape(y)), x)  # noqa: E731
    rng = np.random.default_rng(0)
    keysL = jnp.asarray(np.asarray(jax.random.split(jax.random.PRNGKey(1), L * 8)).reshape(L, 8, 2), jnp.uint32)
    u0L = jnp.asarray(rng.normal(size=(L, 8, 17)), jnp.float32)
    return (keysL, u0L, rep(data), rep(ld), rep(w), lo, hi, rep(m), rep(chol)), k["prior"]


def main():
    from mjxsysid.runtime import startup  # noqa: F401
    import mjxsysid.identify.nuts as N
    L, R = int(sys.argv[1]), int(sys.argv[2])
    args, prior = replicated(sys.argv[3], L)
    per = 1000 // N.CHAINS
    plans = ((N.WARMUP, per, 1), (N.LONGER[0] * N.WARMUP, per * N.LONGER[1], N.LONGER[1]))

    def go():
        with jax.default_matmul_precision("highest"):   # as log_grounded_posteriors runs it (target.full_precision)
            out = N.run_chains(*args, prior=prior, plans=plans, attempt=0, logs=True)
        return jax.block_until_ready(out)
    t = time.perf_counter()
    out = go()
    first = time.perf_counter() - t
    warm = []
    for _ in range(R):
        t = time.perf_counter()
        go()
        warm.append(round(time.perf_counter() - t, 2))
    h = hashlib.sha256(np.asarray(out[0]).tobytes()).hexdigest()[:12]
    print(json.dumps({"xla_flags": os.environ.get("XLA_FLAGS", ""), "logs": L, "first_s": round(first, 1), "warm_s": warm,
                      "draws_sha": h, "leapfrogs_per_draw_mean": float(np.mean(out[2]))}), flush=True)


if __name__ == "__main__":
    main()
