"""The one executor: the same results here and on local processes; a lost worker ends only its task."""

from __future__ import annotations

import os
import signal
import time

import pytest

from mocapfill.runtime.executor import InProcess, LocalProcesses, WorkerLost, make_executor, resolve_jobs


def square(x: int) -> int:
    return x * x


def die_on_three(x: int) -> int:
    if x == 3:
        os.kill(os.getpid(), signal.SIGKILL)
    return x


def test_make_executor_follows_jobs():
    assert isinstance(make_executor(), InProcess)  # the library's default: one process
    assert isinstance(make_executor(1), InProcess)
    assert isinstance(make_executor(2, n_tasks=5), LocalProcesses)
    assert isinstance(make_executor(2, n_tasks=1), InProcess)  # never more workers than tasks
    assert resolve_jobs(0) == len(os.sched_getaffinity(0))


@pytest.mark.parametrize("executor", [InProcess(), LocalProcesses(2)], ids=["in-process", "processes"])
def test_results_come_back_in_task_order(executor):
    assert executor.results(square, list(range(7))) == [x * x for x in range(7)]


def test_a_dead_worker_ends_only_its_task():
    seen, lost = {}, []

    def on_failure(task, exc):
        lost.append((task, exc))
        return None

    LocalProcesses(2).run(die_on_three, [1, 2, 3, 4, 5], seen.__setitem__, on_failure=on_failure)
    assert seen == {1: 1, 2: 2, 3: None, 4: 4, 5: 5}
    assert [t for t, _ in lost] == [3] and isinstance(lost[0][1], WorkerLost) and "SIGKILL" in str(lost[0][1])


def test_forked_map_keeps_the_items_order_and_runs_closures_elsewhere():
    from mocapfill.runtime.executor import can_fork, forked_map

    offset = 10  # a closure: the forked process inherits it and the items, nothing is pickled but the results
    items = list(range(7))
    here = os.getpid()

    def slow(x):
        time.sleep(0.05)  # (long enough for the forked process to start and take items too)
        return x + offset, os.getpid()

    out = forked_map(slow, items, 2, cost=[1, 5, 2, 9, 0, 3, 3])
    assert [v for v, _ in out] == [x + offset for x in items]  # the costliest first, the results in order
    if can_fork():  # this process and a forked one each took items
        assert {pid == here for _, pid in out} == {True, False}
    assert forked_map(lambda x: os.getpid(), items, 1) == [here] * len(items)  # jobs 1: here
    assert forked_map(lambda x: x, [], 2) == []


def test_a_process_that_imported_jax_does_not_fork(monkeypatch):
    import sys

    from mocapfill.runtime.executor import can_fork, forked_map

    monkeypatch.setitem(sys.modules, "jax", object())  # JAX's threads are native: the thread count misses them
    assert not can_fork()
    assert forked_map(lambda x: os.getpid(), range(4), 2) == [os.getpid()] * 4  # one item after the other, here


def test_forked_map_raises_a_workers_exception():
    from mocapfill.runtime.executor import forked_map

    def fail_on_three(x):
        if x == 3:
            raise ValueError("three")
        return x

    with pytest.raises(ValueError, match="three"):
        forked_map(fail_on_three, range(5), 2)


def test_forked_map_says_when_a_worker_dies():
    from mocapfill.errors import MocapfillError
    from mocapfill.runtime.executor import can_fork, forked_map

    if not can_fork():
        pytest.skip("this process cannot fork")
    here = os.getpid()

    def die_if_forked(x):
        time.sleep(0.02)
        if os.getpid() != here:  # (this process takes items too: it must live to report)
            os.kill(os.getpid(), signal.SIGKILL)
        return x

    with pytest.raises(MocapfillError, match="worker process died"):
        forked_map(die_if_forked, range(5), 2)
    assert forked_map(lambda x: x, range(5), 2) == list(range(5))  # and the next call works


def test_workers_that_die_starting_are_one_error_not_a_retry_for_ever(tmp_path):
    """A script without the ``__main__`` guard: each spawned worker runs it again, and its own spawn fails while it
    starts.  A task too large for the pipe's buffer saw the worker die during the send and was retried on a fresh
    worker, without end; now the first such death is one error that names the guard."""
    import subprocess
    import sys

    script = tmp_path / "no_guard.py"
    script.write_text("from mocapfill.runtime.executor import LocalProcesses\n"
                      "print(LocalProcesses(2).results(len, [b'x' * 10_000_000] * 3))\n")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert done.returncode != 0
    assert 'if __name__ == "__main__":' in done.stderr.splitlines()[-1], done.stderr[-500:]


def blas_threads(_) -> int:
    """The most threads a BLAS library loaded in this (worker) process may use."""
    import numpy  # noqa: F401  (its BLAS, loaded)
    from test_blas import _blas_threads

    return max(_blas_threads(), default=1)


def test_workers_hold_blas_to_one_thread():
    assert LocalProcesses(2).results(blas_threads, [0, 1]) == [1, 1]
