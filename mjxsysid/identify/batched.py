"""Logs of one shape evaluated together (:class:`_Logs`): the log-grounded posterior's batched programs (the mode's
least squares, the targets, the SMC, NUTS, the residuals and the innovations' likelihoods), each vmapped over a
leading log axis, and the single-log programs where there is one log."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.identify import logspace as L
from mjxsysid.identify.likelihood import _rate_loglik_jit, rate_loglik_logs, residuals_jit, residuals_logs
from mjxsysid.identify.mode import _fit_ls_logs, _fit_ls_many, _ls_jacobian, _ls_jacobian_logs
from mjxsysid.identify.nuts import CHAINS, compile_chains, run_chains
from mjxsysid.identify.proposals import StudentT
from mjxsysid.identify.smc import program as smc_program
from mjxsysid.identify.target import _batch_log_target_logs, _y_lo_hi, log_target, target_evals
from mjxsysid.runtime import exported
from mjxsysid.runtime.ahead import Ahead, signature


def _take(tree, idx):
    """The logs ``idx`` of a stacked pytree (leading axis: the log)."""
    idx = np.asarray(idx)
    return jax.tree.map(lambda a: a[idx], tree)


def _pow2_pad(idx):
    """Indices padded to the next power of two by repeating the first: a subset of a batch takes
    one of a few compiled shapes, not one per size."""
    idx = list(idx)
    n = 1 << int(np.ceil(np.log2(max(len(idx), 1))))
    return np.asarray(idx + [idx[0]] * (n - len(idx)))


def _pad_rows(a, n: int) -> np.ndarray:
    """``a`` (m, ...) padded to n rows by repeating its first (the rows of :func:`_pow2_pad`)."""
    a = np.asarray(a)
    return np.concatenate([a, np.broadcast_to(a[:1], (n - len(a),) + a.shape[1:])]) if n > len(a) else a  # rows, not coordinates


class _Logs:
    """Logs of one shape (their :class:`LogData` pytrees' leaves alike) evaluated together.

    One log runs the single-log programs (on a CPU the starts one after the other, see
    :func:`_fit_ls_many`); several run programs vmapped over a leading log axis (:data:`~.inference.LOG_BATCH`),
    the logs (or a subset of them) padded to a power of two (:func:`_pow2_pad`): a batch's last,
    shorter chunk reuses the programs the full ones compiled."""

    def __init__(self, datas):
        self.datas = list(datas)
        self.ahead = Ahead(on=False)         # programs compiled ahead (:meth:`compile_ahead`)
        self.stack = None
        if len(self.datas) > 1:         # the logs padded to a power of two, on the device once
            padded = [self.datas[i] for i in _pow2_pad(range(len(self.datas)))]
            self.stack = jax.tree.map(lambda *a: jnp.asarray(np.stack(a)), *padded)

    def __len__(self):
        return len(self.datas)

    def _sub(self, idx):
        """The padded indices of the logs ``idx`` and their stacked data (all of them: the stack)."""
        p = _pow2_pad(idx)
        return p, self.stack if list(idx) == list(range(len(self))) else _take(self.stack, p)

    def targets(self, y, ld, w, prior, idx=None):
        """log target of y (m, N, 17) for the logs ``idx`` (m,) (default all), each with its log δ
        (m, 4) and weights (m, 4) (None: 1) -> (m, N)."""
        idx = list(range(len(self))) if idx is None else list(idx)
        w = np.ones((len(idx), L.N_CHANNELS), np.float32) if w is None else np.asarray(w, np.float32)
        if self.stack is None:
            return np.asarray(log_target(y[0], self.datas[idx[0]], ld[0], w[0], prior))[None]  # rows, not coordinates
        p, data = self._sub(idx)
        y, ld, w = (_pad_rows(np.asarray(a, np.float32), len(p)) for a in (y, ld, w))
        n = y.shape[1]
        chunk = max(16, target_evals() // len(p))
        padn = -n % chunk
        if padn:
            y = np.concatenate([y, np.broadcast_to(y[:, :1], (len(p), padn, y.shape[2]))], 1)  # rows, not coordinates
        out = [np.asarray(_batch_log_target_logs(jnp.asarray(y[:, i:i + chunk]), data, jnp.asarray(ld), jnp.asarray(w), prior))
               for i in range(0, y.shape[1], chunk)]
        return np.concatenate(out, 1)[:len(idx), :n]

    def fit(self, z, ld, ls):
        """Levenberg–Marquardt from every start z (L, K, 13) -> (L, K, 13)."""
        if self.stack is None:
            z0 = z[0]  # rows, not coordinates
            return np.asarray(_fit_ls_many(jnp.asarray(z0), self.datas[0], jnp.asarray(ld[0]), jnp.asarray(ls[0])))[None]
        p, data = self._sub(range(len(self)))
        z, ld, ls = (_pad_rows(np.asarray(a, np.float32), len(p)) for a in (z, ld, ls))
        return np.asarray(_fit_ls_logs(jnp.asarray(z), data, jnp.asarray(ld), jnp.asarray(ls)))[:len(self)]

    def residuals(self, x):
        """:func:`~.likelihood.residuals` of every log at x (L, 21) -> its four arrays (rates (L, R, 3), their
        scales, acc_z (L, Wa), its scale (L,)), as NumPy arrays."""
        if self.stack is None:
            x0 = x[0]  # rows, not coordinates
            return [np.asarray(a)[None] for a in residuals_jit(jnp.asarray(x0, jnp.float32), self.datas[0])]
        p, data = self._sub(range(len(self)))
        x = _pad_rows(np.asarray(x, np.float32), len(p))
        return [np.asarray(a)[:len(self)] for a in residuals_logs(jnp.asarray(x), data)]

    def rate_logliks(self, xs):
        """The innovations' log-likelihood per gyro axis of every log at its xs (L, D, 21) -> (L, D, 3)."""
        if self.stack is None:
            xs0 = xs[0]  # rows, not coordinates
            return np.asarray(_rate_loglik_jit(jnp.asarray(xs0, jnp.float32), self.datas[0]))[None]
        p, data = self._sub(range(len(self)))
        xs = _pad_rows(np.asarray(xs, np.float32), len(p))
        return np.asarray(rate_loglik_logs(jnp.asarray(xs), data))[:len(self)]

    def jacobians(self, z, ld, ls, w):
        """The tempered residuals' Jacobians at z (L, 13) -> (L, R, 13)."""
        if self.stack is None:
            z0 = z[0]  # rows, not coordinates
            return np.asarray(_ls_jacobian(jnp.asarray(z0), (self.datas[0], jnp.asarray(ld[0]), jnp.asarray(ls[0])),
                                           jnp.asarray(w[0])))[None]
        p, data = self._sub(range(len(self)))
        z, ld, ls, w = (_pad_rows(np.asarray(a, np.float32), len(p)) for a in (z, ld, ls, w))
        return np.asarray(_ls_jacobian_logs(jnp.asarray(z), data, jnp.asarray(ld), jnp.asarray(ls), jnp.asarray(w)))[:len(self)]

    def _smc_call(self, idx, keys, y0, ld, w, qv, qn, lap, prior, n_mcmc, max_stages) -> tuple:
        """The SMC's program for the logs ``idx`` (:func:`.smc.program`: the one-log program where there is one
        log) and its arguments: the (name, function, static arguments, arguments) of
        :func:`mjxsysid.runtime.exported.call`."""
        idx = list(idx)
        args = (np.asarray(keys, np.uint32), np.asarray(y0, np.float32), np.asarray(ld, np.float32), np.asarray(w, np.float32))
        if self.stack is None:
            return (*smc_program(False, prior, n_mcmc, max_stages), *(jnp.asarray(a[0]) for a in args[:2]),
                    self.datas[idx[0]], *(jnp.asarray(a[0]) for a in args[2:]), qv[0], qn[0], lap[0])
        p, data = self._sub(idx)
        args = [_pad_rows(a, len(p)) for a in args]
        pad = len(p) - len(idx)
        stk = lambda ts: None if ts[0] is None else jax.tree.map(lambda *a: jnp.stack(a), *(ts + [ts[0]] * pad))  # noqa: E731
        return (*smc_program(True, prior, n_mcmc, max_stages), *(jnp.asarray(a) for a in args[:2]), data,
                *(jnp.asarray(a) for a in args[2:]), stk(list(qv)), stk(list(qn)), stk(list(lap)))

    def smc(self, idx, keys, y0, ld, w, qv, qn, lap, prior, n_mcmc, max_stages):
        """The tempered SMC of the logs ``idx`` (m,) from their particles y0 (m, P, 17) -> the
        outputs of :func:`.smc._smc_impl`, each with a leading axis m."""
        call = self._smc_call(idx, keys, y0, ld, w, qv, qn, lap, prior, n_mcmc, max_stages)
        self.ahead.wait(("smc", signature(*call[3:])))
        out = exported.call(*call)
        return [np.asarray(o)[None] for o in out] if self.stack is None else [np.asarray(o)[:len(idx)] for o in out]

    def _nuts_call(self, idx, keys, u0, ld, w, m, chol, prior) -> tuple:
        """The arguments of :func:`.nuts.run_chains` for the logs ``idx`` (the one-log program where there is one
        log), and whether they carry a leading log axis."""
        idx = list(idx)
        lo, hi = (jnp.asarray(a, jnp.float32) for a in _y_lo_hi(prior))
        args = [np.asarray(keys, np.uint32)] + [np.asarray(a, np.float32) for a in (u0, ld, w, m, chol)]
        if self.stack is None:
            k, u, a, b, mm, c = (jnp.asarray(x[0]) for x in args)  # rows, not coordinates
            return (k, u, self.datas[idx[0]], a, b, lo, hi, mm, c), False
        p, data = self._sub(idx)
        k, u, a, b, mm, c = (jnp.asarray(_pad_rows(x, len(p))) for x in args)
        return (k, u, data, a, b, lo, hi, mm, c), True

    def nuts(self, idx, keys, u0, ld, w, m, chol, prior, plans, attempt):
        """NUTS of the logs ``idx`` (m,) from their starts (:func:`.nuts.start`: keys (m, C, 2), u0
        (m, C, 17), m (m, 17), chol (m, 17, 17)) with their log δ and weights (m, 4), run with the lengths
        ``plans[attempt]`` -> the outputs of :func:`.nuts.run_chains`, each with a leading axis m."""
        args, logs = self._nuts_call(idx, keys, u0, ld, w, m, chol, prior)
        self.ahead.wait(("nuts", signature(*args), tuple(plans), logs))
        out = run_chains(*args, prior=prior, plans=plans, attempt=attempt, logs=logs)
        return [np.asarray(o)[:len(idx)] if logs else np.asarray(o)[None] for o in out]

    def compile_ahead(self, ahead, qv, qn, prior, *, particles: int, n_mcmc: int, max_stages: int, plans=None):
        """Start compiling, on ``ahead``'s thread (:class:`~mjxsysid.runtime.ahead.Ahead`), the programs the SMC of
        every log (``particles`` each, the logs' decoded proposals ``qv`` and nuisance proposals ``qn``) and
        NUTS with ``plans`` (None: no NUTS) will run; :meth:`smc` and :meth:`nuts` wait for them. Their shapes
        are the logs'; only a Laplace proposal, known at the mode, stands in (zeros of its shapes)."""
        self.ahead = ahead
        n, eye = len(self), np.eye(L.N_Y, dtype=np.float32)
        zeros = lambda *shape: np.zeros((n,) + shape, np.float32)  # noqa: E731
        lap = [StudentT(np.zeros(L.N_Y, np.float32), eye)] * n
        smc = self._smc_call(range(n), np.zeros((n, 2), np.uint32), zeros(particles, L.N_Y), zeros(L.N_CHANNELS),
                             zeros(L.N_CHANNELS), qv, qn, lap, prior, n_mcmc, max_stages)
        ahead.submit(("smc", signature(*smc[3:])), lambda: exported.compile_only(*smc))
        if plans is None:
            return
        args, logs = self._nuts_call(range(n), np.zeros((n, CHAINS, 2), np.uint32), zeros(CHAINS, L.N_Y),
                                     zeros(L.N_CHANNELS), zeros(L.N_CHANNELS), zeros(L.N_Y), np.broadcast_to(eye, (n,) + eye.shape), prior)
        ahead.submit(("nuts", signature(*args), tuple(plans), logs),
                     lambda: compile_chains(*args, prior=prior, plans=plans, logs=logs))
