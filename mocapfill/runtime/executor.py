"""Where independent tasks run: one abstraction, :class:`Executor`, handed down to everything that runs many tasks
(``batch``'s files, ``evaluate``'s trials, a long take's windows).

- :class:`InProcess` (``jobs`` = 1, the library's default): one task after the other, here.
- :class:`LocalProcesses` (``jobs`` > 1): long-lived worker processes (``spawn``: nothing inherited from the caller)
  that each get one task at a time.  A worker that dies (killed, out of memory) ends only the task it was running
  (``on_failure(task, WorkerLost)``) and is replaced.  (``concurrent.futures.ProcessPoolExecutor`` breaks as a whole
  on one dead worker and cannot say which task killed it.)
- :class:`DaskCluster` (a scheduler address or ``distributed.Client``): one Dask task per task
  (``Client.submit(pure=False)``), results as they complete (``distributed.as_completed``).

Within one task, :func:`forked_map` spreads its independent parts (one fill's per-marker models) over this process
and forked ones: they inherit the arrays instead of receiving them, which a one-second fill could not afford to send.

:func:`make_executor` turns the CLI's ``--jobs`` / ``--scheduler`` into one.  ``func`` must be picklable for the
processes and the cluster (a module-level function, or a :func:`functools.partial` of one) and should handle its
own errors; ``on_result(task, result)`` is called in the caller's process in completion order.  No scheduler of our
own: the local pool hands the next task, in the order given, to the next idle worker.
"""

from __future__ import annotations

import collections
import contextlib
import multiprocessing
import os
import signal
import sys
import uuid
from multiprocessing.connection import wait as wait_connections
from typing import Any, Callable, Sequence

from .blas import one_blas_thread_environment

__all__ = ["Executor", "InProcess", "LocalProcesses", "DaskCluster", "make_executor", "resolve_jobs", "WorkerLost",
           "SchedulerUnreachable", "WORKER_NAME", "CONNECT_TIMEOUT", "forked_map", "can_fork"]

#: Name of the local worker processes (``multiprocessing.active_children()`` shows it).
WORKER_NAME = "mocapfill-worker"
#: How long a :class:`DaskCluster` tries to reach a scheduler given by address.
CONNECT_TIMEOUT = "20s"


#: What a worker that could not start says: the usual cause, a script run on spawned processes without its guard.
START_FAILED = ("the worker processes exited as they started ({how}); a script that fills on several processes "
                "(jobs other than 1) must start from an `if __name__ == \"__main__\":` block, which the workers do "
                "not run again")


class SchedulerUnreachable(Exception):
    """No Dask scheduler answered at the address given (the message says why)."""


class WorkerLost(Exception):
    """The local worker process running a task died (``exitcode`` negative = killed by that signal)."""

    def __init__(self, exitcode: int | None) -> None:
        self.exitcode = exitcode
        if exitcode is not None and exitcode < 0:
            try:
                name = signal.Signals(-exitcode).name
            except ValueError:
                name = f"signal {-exitcode}"
            how = f"killed by {name}" + (", out of memory?" if name == "SIGKILL" else "")
        else:
            how = f"exit status {exitcode}"
        super().__init__(how)


def resolve_jobs(jobs: int | None, n_tasks: int | None = None) -> int:
    """``jobs`` as a count of processes: None or 1 = this process, 0 (or less) = every core this process may use;
    never more than ``n_tasks``."""
    jobs = 1 if jobs is None else int(jobs)
    if jobs <= 0:
        try:
            jobs = len(os.sched_getaffinity(0))
        except AttributeError:  # pragma: no cover - not on Linux
            jobs = os.cpu_count() or 1
    if n_tasks is not None:
        jobs = min(jobs, n_tasks)
    return max(1, jobs)


OnResult = Callable[[Any, Any], None]
OnFailure = Callable[[Any, BaseException], Any]


class Executor:
    """Runs ``func(task)`` for every task; see the module docstring.  Subclasses implement :meth:`run`."""

    #: Tasks run at once (a cluster's is unknown here: 0).
    jobs: int = 1
    #: Whether tasks run on other machines (paths must then be absolute, files on a shared file system).
    remote: bool = False

    def run(self, func: Callable[[Any], Any], tasks: Sequence[Any], on_result: OnResult, *,
            on_failure: OnFailure) -> None:
        """Run ``func(task)`` for every task; ``on_result(task, result)`` as each ends.  A task whose worker is lost
        gets ``on_result(task, on_failure(task, exception))``; the others go on."""
        raise NotImplementedError

    def results(self, func: Callable[[Any], Any], tasks: Sequence[Any]) -> list[Any]:
        """``[func(task) for task in tasks]``, run here or elsewhere, in the tasks' order; a lost worker raises."""
        out: dict[int, Any] = {}

        def lost(task: tuple[int, Any], exc: BaseException) -> Any:
            raise exc

        self.run(_Indexed(func), list(enumerate(tasks)), lambda task, result: out.__setitem__(task[0], result),
                 on_failure=lost)
        return [out[i] for i in range(len(tasks))]


class _Indexed:
    """``func`` applied to the second item of an ``(index, task)`` pair (picklable when ``func`` is)."""

    def __init__(self, func: Callable[[Any], Any]) -> None:
        self.func = func

    def __call__(self, pair: tuple[int, Any]) -> Any:
        return self.func(pair[1])


class InProcess(Executor):
    """Every task here, one after the other."""

    def run(self, func, tasks, on_result, *, on_failure) -> None:
        for task in tasks:
            on_result(task, func(task))


class LocalProcesses(Executor):
    """``jobs`` long-lived ``spawn`` worker processes, one task each at a time."""

    def __init__(self, jobs: int) -> None:
        self.jobs = max(1, int(jobs))

    def run(self, func, tasks, on_result, *, on_failure) -> None:
        _run_local(func, tasks, self.jobs, on_result, on_failure)


class DaskCluster(Executor):
    """One Dask task per task on the cluster at ``scheduler`` (an address, connected and closed per run, or a
    ``distributed.Client``)."""

    jobs = 0
    remote = True

    def __init__(self, scheduler: Any, *, name: str = "mocapfill") -> None:
        self.scheduler, self.name = scheduler, name

    def run(self, func, tasks, on_result, *, on_failure) -> None:
        _run_dask(func, tasks, self.scheduler, on_result, on_failure, self.name)


def make_executor(jobs: int | None = 1, scheduler: Any = None, *, n_tasks: int | None = None,
                  name: str = "mocapfill") -> Executor:
    """The executor for ``jobs`` local processes (1 = here, 0 = every core, at most ``n_tasks``) or, with a
    ``scheduler``, a Dask cluster.  Raises ImportError when a scheduler is given without ``distributed``."""
    if scheduler is not None:
        import distributed  # noqa: F401  (fail here, before any task runs)

        return DaskCluster(scheduler, name=name)
    jobs = resolve_jobs(jobs, n_tasks)
    return InProcess() if jobs <= 1 else LocalProcesses(jobs)


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
        with one_blas_thread_environment():  # the workers are the parallelism
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


def _run_local(func: Callable[[Any], Any], tasks: Sequence[Any], jobs: int, on_result: OnResult,
               on_failure: OnFailure) -> None:
    """:meth:`LocalProcesses.run`.  On an exception in the parent (Ctrl-C, ``on_result`` raising) busy workers are
    interrupted and everything stops before it propagates; ``on_failure`` is also called for their tasks' clean-up
    (temporary files), its result discarded."""
    ctx = multiprocessing.get_context("spawn")
    pending = collections.deque(tasks)
    workers: list[_Worker] = []
    done = 0  # tasks a worker finished: until one has, a worker that dies unasked died starting (no retry for ever)

    def start_failed(w: _Worker) -> None:  # (w stopped: its process joined)
        if not done:
            from ..errors import MocapfillError

            raise MocapfillError(START_FAILED.format(how=WorkerLost(w.process.exitcode)))

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
                    start_failed(idle)
                    continue
                task = pending.popleft()
                try:
                    idle.conn.send(task)
                    idle.task = task
                except OSError:  # died just now: the task never reached it; retry it on a fresh worker
                    pending.appendleft(task)
                    idle.stop(0)
                    workers.remove(idle)
                    start_failed(idle)
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
                done += not died
                if died:
                    w.process.join()
                    result = on_failure(task, WorkerLost(w.process.exitcode))
                    w.stop(0)
                    workers.remove(w)
                on_result(task, result)
    finally:
        for w in workers:
            task = w.task
            w.stop(10.0)
            if task is not None:
                with contextlib.suppress(Exception):
                    on_failure(task, WorkerLost(w.process.exitcode))  # its clean-up; the result is not wanted


def _run_dask(func: Callable[[Any], Any], tasks: Sequence[Any], scheduler: Any, on_result: OnResult,
              on_failure: OnFailure, name: str) -> None:
    """:meth:`DaskCluster.run`: submit ``func(task)`` once per task; ``on_result(task, result)`` as each ends.

    ``scheduler`` is an address (``"tcp://host:8786"``, connected and closed here) or a ``distributed.Client``.
    A task Dask cannot finish (``KilledWorker``: its worker died on it more often than
    ``distributed.scheduler.allowed-failures``; a lost connection) gets ``on_failure(task, exception)`` as its result.
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
            futures[client.submit(func, task, key=f"{name}-{run}-{i}", pure=False)] = task
        for future in as_completed(futures):
            task = futures[future]
            try:
                result = future.result()
            except Exception as exc:
                result = on_failure(task, exc)
            future.release()
            on_result(task, result)
    except BaseException:
        with contextlib.suppress(Exception):
            client.cancel(list(futures))
        raise
    finally:
        if own:
            client.close()


def can_fork() -> bool:
    """Whether :func:`forked_map` may fork here: on Linux, from a process that may have children (not a daemonic
    pool worker) and runs no other thread (a fork copies only the calling thread, and a lock another thread held
    would stay locked in the child).  A process that imported JAX (the learned denoiser) runs JAX's own threads,
    which Python's thread count does not see and JAX warns a fork may deadlock on: it does not fork either."""
    import threading

    return (sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods()
            and not multiprocessing.current_process().daemon and threading.active_count() == 1
            and "jax" not in sys.modules)


def forked_map(func: Callable[[Any], Any], items: Sequence[Any], jobs: int | None,
               cost: Sequence[float] | None = None) -> list[Any]:
    """``[func(item) for item in items]``, in the items' order, on this process and up to ``jobs - 1`` forked ones.

    For the independent parts of one computation (the markers' models of one fill): the other processes are forked
    from this one, so ``func`` (a closure is fine), the items and the arrays they read are inherited, not pickled;
    only the results travel back (by pickle, through a pipe).  Every process, this one included, takes the next item
    from a shared counter until none is left, so no process idles while another works, and no pool, queue or
    manager thread is set up for a call that often lasts a tenth of a second.  ``func`` must not rely on side
    effects: they stay in the process that ran it.  ``jobs`` as :func:`resolve_jobs`; here, one item after the
    other, where that gives 1, there are fewer than two items, or :func:`can_fork` says no.  The first exception
    ``func`` raises (here or in a forked process) is raised here once every process has stopped; a forked process
    that dies (killed, out of memory) raises :class:`~mocapfill.errors.MocapfillError` (the command line's one-line
    error).  ``cost`` (one number per item) or None: the costliest items are taken first, so that no process is left
    alone with a large one at the end.
    """
    items = list(items)
    n = len(items)
    jobs = resolve_jobs(jobs, n)
    if jobs <= 1 or not can_fork():
        return [func(item) for item in items]
    import pickle

    order = list(range(n)) if cost is None else sorted(range(n), key=lambda i: -cost[i])
    context = multiprocessing.get_context("fork")
    counter, lock = context.RawValue("l", 0), context.Lock()

    def take(stop: bool = False) -> int:
        """The next item's place in ``order`` (n: none left); ``stop``: leave none for anyone (an error)."""
        with lock:
            i = counter.value
            counter.value = n if stop else i + 1
        return i

    def work(results: list, failed: list) -> None:
        while (i := take()) < n:
            try:
                results.append((order[i], func(items[order[i]])))
            except BaseException as exc:  # (KeyboardInterrupt too: every process stops)
                failed.append(exc)
                take(stop=True)
                return

    children: list[tuple[int, int]] = []  # (pid, read end of its pipe)
    try:
        for _ in range(jobs - 1):
            read_end, write_end = os.pipe()
            pid = os.fork()
            if pid == 0:  # pragma: no cover - the forked process (its coverage is not collected)
                status = 1
                try:
                    os.close(read_end)
                    results: list = []
                    failed: list = []
                    work(results, failed)
                    try:
                        data = pickle.dumps((results, failed), protocol=pickle.HIGHEST_PROTOCOL)
                    except Exception as exc:  # an unpicklable result or exception
                        data = pickle.dumps(([], [RuntimeError(f"a worker's result cannot be sent back: {exc}")]))
                    with os.fdopen(write_end, "wb") as pipe:
                        pipe.write(data)
                    status = 0
                finally:
                    os._exit(status)  # (no atexit handlers, no flushing of the buffers inherited from the caller)
            os.close(write_end)
            children.append((pid, read_end))
        results, failed = [], []
        work(results, failed)
        lost = False
        while children:
            pid, read_end = children[0]
            with os.fdopen(read_end, "rb") as pipe:
                children[0] = (pid, -1)  # (the file object closes the pipe now: never closed twice)
                data = pipe.read()
            os.waitpid(pid, 0)
            children.pop(0)
            try:
                theirs, their_failures = pickle.loads(data)
            except Exception:  # nothing, or part of it: the process died before it had written it all
                lost = True
                continue
            results.extend(theirs)
            failed.extend(their_failures)
        if failed:
            raise failed[0]
        if lost or len(results) < n:
            from ..errors import MocapfillError

            raise MocapfillError("a worker process died (killed, out of memory?); --jobs 1 fills in one process")
        out: list[Any] = [None] * n
        for i, value in results:
            out[i] = value
        return out
    finally:
        for pid, read_end in children:  # interrupted here: no forked process is left working
            if read_end >= 0:
                with contextlib.suppress(OSError):
                    os.close(read_end)
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
            with contextlib.suppress(OSError):
                os.waitpid(pid, 0)
