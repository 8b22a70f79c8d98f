"""Where independent tasks run: in this process, on local worker processes that survive each other, or on Dask.

- :func:`run_local` runs ``func(task)`` for every task, in this process (``jobs`` = 1) or on ``jobs`` long-lived
  worker processes (``spawn``) that each get one task at a time.  A worker that dies (killed, out of memory) ends
  only the task it was running (``on_death(task, exitcode)`` gives its result) and is replaced.
  (``concurrent.futures.ProcessPoolExecutor`` breaks as a whole on one dead worker and cannot say which task
  killed it.)
- :func:`run_dask` submits ``func(task)`` once per task to a Dask distributed cluster (``Client.submit``) and hands
  the results over as they complete (``distributed.as_completed``).

``func`` must be a module-level function (workers import it by name) that handles its own errors; results come
back to ``on_result(task, result)`` in completion order.  No scheduler of our own: the local pool only hands the
next task to the next idle worker.
"""

from __future__ import annotations

import collections
import contextlib
import multiprocessing
import os
import signal
import uuid
from multiprocessing.connection import wait as wait_connections
from typing import Any, Callable, Sequence

__all__ = ["run_local", "run_dask", "SchedulerUnreachable", "WORKER_NAME", "CONNECT_TIMEOUT"]

#: Name of the local worker processes (``multiprocessing.active_children()`` shows it).
WORKER_NAME = "mocapfill-worker"
#: How long :func:`run_dask` tries to reach a scheduler given by address.
CONNECT_TIMEOUT = "20s"


class SchedulerUnreachable(Exception):
    """No Dask scheduler answered at the address given (the message says why)."""


def _worker_loop(func: Callable[[Any], Any], conn) -> None:
    """A local worker: run the tasks the parent sends, one at a time, until it sends None or goes away."""
    try:
        while True:
            task = conn.recv()
            if task is None:
                return
            conn.send(func(task))
    except KeyboardInterrupt:
        # Ctrl-C reaches the whole process group; the task's atomic writes have removed their temporary files.  A
        # second SIGINT (the parent's, when it stops us) must not interrupt the exit with a traceback.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except (EOFError, OSError):
        return  # the parent is gone


class _Worker:
    def __init__(self, ctx, func: Callable[[Any], Any]) -> None:
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_worker_loop, args=(func, child), daemon=True, name=WORKER_NAME)
        self.process.start()
        child.close()
        self.task: Any = None

    def stop(self, timeout: float) -> None:
        """Ask an idle worker to leave; interrupt a busy one (SIGINT, then SIGKILL after ``timeout``)."""
        if self.process.is_alive() and self.task is None:
            with contextlib.suppress(OSError):
                self.conn.send(None)
        elif self.process.is_alive():
            self.process.join(min(timeout, 1.0))  # after a Ctrl-C at a terminal it is already leaving
            if self.process.is_alive():
                with contextlib.suppress(OSError):
                    os.kill(self.process.pid, signal.SIGINT)  # lets atomic writes remove their temporary files
        self.process.join(timeout)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self.conn.close()


def run_local(func: Callable[[Any], Any], tasks: Sequence[Any], jobs: int, on_result: Callable[[Any], None], *,
              on_death: Callable[[Any, int | None], Any]) -> None:
    """Run ``func(task)`` for every task: in this process when ``jobs`` <= 1, else on ``jobs`` worker processes.

    ``on_result(result)`` is called in the parent as each task ends.  ``on_death(task, exitcode)`` makes the result
    of a task whose worker died (``exitcode`` negative = killed by that signal); the batch goes on.  On an exception
    in the parent (Ctrl-C, ``on_result`` raising) busy workers are interrupted and everything stops before it
    propagates; ``on_death`` is also called for their tasks' clean-up, its result discarded.
    """
    if jobs <= 1:
        for task in tasks:
            on_result(func(task))
        return
    ctx = multiprocessing.get_context("spawn")
    pending = collections.deque(tasks)
    workers: list[_Worker] = []
    try:
        while pending or any(w.task is not None for w in workers):
            while pending:
                idle = next((w for w in workers if w.task is None), None)
                if idle is None:
                    if len(workers) >= jobs:
                        break
                    idle = _Worker(ctx, func)
                    workers.append(idle)
                if not idle.process.is_alive():  # died while idle (killed from outside): nothing was lost
                    idle.stop(0)
                    workers.remove(idle)
                    continue
                task = pending.popleft()
                try:
                    idle.conn.send(task)
                    idle.task = task
                except OSError:  # died just now: the task never reached it; retry it on a fresh worker
                    pending.appendleft(task)
                    idle.stop(0)
                    workers.remove(idle)
            busy = [w for w in workers if w.task is not None]
            ready = set(wait_connections([w.conn for w in busy] + [w.process.sentinel for w in busy]))
            for w in busy:
                if w.conn not in ready and w.process.sentinel not in ready:
                    continue
                task, result, died = w.task, None, False
                try:
                    if w.conn.poll():
                        result = w.conn.recv()
                    else:
                        died = True
                except (EOFError, OSError):
                    died = True
                w.task = None
                if died:
                    w.process.join()
                    result = on_death(task, w.process.exitcode)
                    w.stop(0)
                    workers.remove(w)
                on_result(result)
    finally:
        for w in workers:
            task = w.task
            w.stop(10.0)
            if task is not None:
                with contextlib.suppress(Exception):
                    on_death(task, w.process.exitcode)  # its clean-up (temporary files); the result is not wanted


def run_dask(func: Callable[[Any], Any], tasks: Sequence[Any], scheduler: Any,
             on_result: Callable[[Any, Any], None], *, on_error: Callable[[Any, BaseException], Any],
             prepare: Callable[[Any], Any] = lambda task: task, name: str = "task") -> None:
    """Submit ``func(prepare(task))`` once per task to a Dask cluster; ``on_result(task, result)`` as each ends.

    ``scheduler`` is an address (``"tcp://host:8786"``, connected and closed here) or a ``distributed.Client``.
    A task Dask cannot finish (``KilledWorker``: its worker died on it more often than
    ``distributed.scheduler.allowed-failures``; a lost connection) gets ``on_error(task, exception)`` as its result.
    Tasks are submitted with ``pure=False`` (a rerun must run again, not reuse a cached result).

    Raises ImportError without the ``distributed`` package, :class:`SchedulerUnreachable` when the scheduler cannot
    be reached.  On an exception in the parent (Ctrl-C) the tasks not yet finished are cancelled.
    """
    from distributed import Client, as_completed

    own = not isinstance(scheduler, Client)
    if own:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT)
        except (OSError, TimeoutError, ValueError) as exc:
            raise SchedulerUnreachable(" ".join(str(exc).split())) from None
    else:
        client = scheduler
    run = uuid.uuid4().hex[:8]
    futures = {}
    try:
        for i, task in enumerate(tasks):
            futures[client.submit(func, prepare(task), key=f"{name}-{run}-{i}", pure=False)] = task
        for future in as_completed(futures):
            task = futures[future]
            try:
                result = future.result()
            except Exception as exc:
                result = on_error(task, exc)
            future.release()
            on_result(task, result)
    except BaseException:
        with contextlib.suppress(Exception):
            client.cancel(list(futures))
        raise
    finally:
        if own:
            client.close()
