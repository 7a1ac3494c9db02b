"""Programs compiled ahead on a background thread (mjxsysid.runtime.ahead): the call that follows compiles
nothing, a failure there costs only the time, and the switch turns it off."""
import threading

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxsysid.runtime.ahead import ENV, Ahead, signature


def _compiles_by_thread(fn):
    """Run ``fn()`` -> the names of the threads that ran an XLA compile meanwhile (one entry per compile)."""
    import jax.monitoring as mon
    from jax._src.dispatch import BACKEND_COMPILE_EVENT
    seen = []

    def on(event, duration, **kw):
        if event == BACKEND_COMPILE_EVENT:
            seen.append(threading.current_thread().name)
    mon.register_event_duration_secs_listener(on)
    try:
        fn()
    finally:
        mon.unregister_event_duration_listener(on)
    return seen


def test_a_program_compiled_ahead_is_the_one_its_call_runs():
    """The thread compiles the program (at the caller's matmul precision), the call waits for it and compiles
    nothing; the signature tells float64 NumPy from float32 as jit does (it does not) and shapes apart."""
    f = jax.jit(lambda x: jnp.tanh(x @ x.T) * 3.25 + 0.5)       # a program no other test compiles
    x = np.linspace(0, 1, 7 * 5, dtype=np.float32).reshape(7, 5)
    key = ("f", signature(x))
    assert key == ("f", signature(x.astype(np.float64))) and key != ("f", signature(x[:6]))
    with jax.default_matmul_precision("highest"), Ahead(on=True) as ahead:
        def submit_and_wait():
            ahead.submit(key, lambda: f.lower(x).compile())
            ahead.submit(key, lambda: pytest.fail("submitted twice"))  # a name already submitted: not again
            assert ahead.wait(key) is True
        ahead_threads = _compiles_by_thread(submit_and_wait)
        assert ahead.wait(key) is False                                 # waited for already
        main = _compiles_by_thread(lambda: np.asarray(f(x)))
    assert ahead_threads and all(t.startswith("mjxsysid-ahead") for t in ahead_threads), ahead_threads
    assert main == [], main
    np.testing.assert_allclose(np.asarray(f(x)), np.tanh(x @ x.T) * 3.25 + 0.5, rtol=1e-5)


def test_a_failure_ahead_costs_only_time_and_the_switch_turns_it_off(monkeypatch):
    """A compile that fails on the thread: wait says so and raises nothing (the call compiles it itself and
    raises what is real), result raises it; ``close`` drops what has not started; MJXSYSID_COMPILE_AHEAD=0 runs
    nothing."""
    started = threading.Event()
    release = threading.Event()
    with Ahead(on=True, threads=2) as ahead:
        ahead.submit("bad", lambda: 1 / 0)
        assert ahead.wait("bad") is False
        ahead.submit("value", lambda: 42)                        # what the trainer does: take what it compiled
        ahead.submit("raises", lambda: 1 / 0)
        assert "value" in ahead and ahead.result("value") == 42 and "value" not in ahead
        with pytest.raises(ZeroDivisionError):
            ahead.result("raises")
        assert ahead.result("never submitted") is None and set(ahead.seconds) == {"value"}
    ran = []
    with Ahead(on=True) as one:                                     # one thread: "never" waits behind "slow"
        one.submit("slow", lambda: (started.set(), release.wait(5)))
        one.submit("never", lambda: ran.append("never"))
        started.wait(5)
        threading.Timer(0.5, release.set).start()                    # "slow" still runs when the block is left
    assert ran == [] and release.is_set()                                                # dropped on leaving: nothing asked for it
    from mjxsysid.runtime.ahead import enabled
    monkeypatch.setenv("MJXSYSID_BACKGROUND_COMPILE", "0")           # the trainer's older name for the switch
    assert not enabled()
    monkeypatch.delenv("MJXSYSID_BACKGROUND_COMPILE")
    assert enabled()
    monkeypatch.setenv(ENV, "0")
    off = Ahead()
    off.submit("x", lambda: pytest.fail("ran while off"))
    assert not off.on and off.wait("x") is False
    off.close()
