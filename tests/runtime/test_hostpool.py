"""mjxsysid.runtime.hostpool: one pool for a call's host work; here its rules without processes (the
processes' results are compared with one-by-one reductions in tests/identify/test_idlecheck.py)."""
import operator

import pytest

from mjxsysid.runtime.hostpool import MIN_PER_WORKER, HostPool


def test_a_pool_maps_in_order_here_or_on_threads_and_goes_to_processes_only_with_enough_items():
    with HostPool(1) as pool:
        assert pool.map(operator.add, range(5), range(5)) == [0, 2, 4, 6, 8]
        assert pool.map(operator.add, range(5), range(5), threads=True) == [0, 2, 4, 6, 8]
        assert pool.map(operator.add, [], []) == [] and pool.later(operator.add, [], [])() == []
        first, second = (pool.later(operator.mul, range(4), [k] * 4, threads=True) for k in (2, 3))
        assert second() == [0, 3, 6, 9] and first() == [0, 2, 4, 6]      # started together, collected in any order
        assert not pool.processes(10 ** 6)                    # one worker: never processes
    four = HostPool(4)
    assert not four.processes(MIN_PER_WORKER * 4 - 1) and four.processes(MIN_PER_WORKER * 4)
    assert four.map(operator.neg, range(3)) == [0, -1, -2] and four._procs is None    # too few: none spawned
    four.close()


def test_a_pool_without_workers_is_refused():
    with pytest.raises(ValueError, match="workers must be ≥ 1"):
        HostPool(0)
