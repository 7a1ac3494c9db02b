"""Plugin: an xdist worker exits at once after its results are sent (the teardown it skips)."""
import atexit
import os
import sys

import pytest


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    """An xdist worker ends here, its results sent (``workerfinished``, at session finish) and
    every plugin unconfigured: ``os._exit`` after closing the in-process notebooks' IPython shell.
    A normal exit spent about 9 s tearing down what the worker holds (JAX's atexit hook clears
    every jit cache one by one, IPython's resets the shell with a full garbage collection, then
    the interpreter frees thousands of traced and compiled programs), and the tier waited for it.
    ``MJXSYSID_TESTS_FULL_EXIT=1`` keeps the normal exit (e.g. for a coverage run, whose data a
    worker writes at exit)."""
    mod = sys.modules.get("IPython.core.interactiveshell")
    if mod is not None and mod.InteractiveShell.initialized():
        shell = mod.InteractiveShell.instance()
        atexit.unregister(shell.atexit_operations)
        if shell.history_manager is not None:
            shell.history_manager.end_session()
            shell.history_manager.close()
            shell.history_manager = None
    if os.environ.get("PYTEST_XDIST_WORKER") and not os.environ.get("MJXSYSID_TESTS_FULL_EXIT"):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
