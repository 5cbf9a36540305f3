"""Worker processes for the independent fits of a diagnosis round.

A diagnosis round fits every candidate on every cross-validation fold and,
after an adoption, tries re-initialising each earlier effect; the fits are
independent of each other and the effect fits run Dr.Jit on one thread
(:func:`~sionna_mmir.effects.ops.single_thread`), so a round uses one core
unless the fits are spread over processes.  :class:`FitPool` runs a list of
tasks ``fn(shared, *args)`` either in this process (``workers = 1``) or in
``workers`` spawned processes; ``shared`` (the fold models, several MB) is
written once per call to a temporary file that each worker loads once,
instead of being sent with every task.  The results come back in task order
and are the same numbers the serial path computes: each task is a pure
function of its inputs.

A worker that dies (a crash inside a compiled kernel) does not lose the
round: the pool is dropped and the tasks are run again in this process.
"""
from __future__ import annotations

import atexit
import contextlib
import os
import pickle
import shutil
import tempfile
import time
import uuid
import warnings

from ..errors import ConfigError

#: ``workers = "auto"``: one worker per core this process may run on
AUTO = "auto"


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:                    # not on Linux
        return max(1, os.cpu_count() or 1)


def check_workers(workers) -> int:
    """``workers`` as a number of processes >= 1 (``"auto"``: :func:`available_cores`)."""
    if workers is None or (isinstance(workers, str) and workers.strip().lower() == AUTO):
        return available_cores()
    try:
        n = int(workers)
    except (TypeError, ValueError):
        n = None
    if n is None or isinstance(workers, bool) or n != float(workers) or n < 1:
        raise ConfigError(f"--workers must be 'auto' or an integer >= 1, got {workers!r}")
    return n


# ---------------------------------------------------------------- worker side
_LOADED = {"path": None, "value": None}


def one_blas_thread():
    """Limit BLAS to one thread (until the returned limiter's ``restore()``).

    The effect models are small: BLAS threads only spin-wait beside the
    single-threaded Dr.Jit fits (a serial round used 1.7 cores for the
    work of one), and they would take the other workers' cores."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


def _init_worker(parent: int):
    """A worker is one core's worth of work: BLAS and Dr.Jit on one thread;
    it exits when ``parent`` (the loop's process id) is gone, even when that
    happened before the worker started (a killed loop leaves no process)."""
    import threading

    from ..utils.backend import init_backend

    threading.Thread(target=_exit_with_parent, args=(parent,), daemon=True).start()
    _LOADED["blas"] = one_blas_thread()
    init_backend()
    import drjit as dr

    dr.set_thread_count(1)


def _exit_with_parent(parent: int, period: float = 1.0) -> None:
    """Exit this process as soon as its parent is no longer ``parent``."""
    while os.getppid() == parent:
        time.sleep(period)
    os._exit(0)


def _call(fn, path, args):
    """Run one task in a worker: ``fn(shared, *args)`` with ``shared`` loaded
    from ``path`` (kept until a task names another file)."""
    if _LOADED["path"] != path:
        _LOADED["value"] = None
        with open(path, "rb") as f:
            _LOADED["value"] = pickle.load(f)
        _LOADED["path"] = path
    return fn(_LOADED["value"], *args)


# ---------------------------------------------------------------- parent side
_EXECUTORS: dict = {}
_TMP: dict = {}


def _executor(n: int):
    from concurrent.futures import ProcessPoolExecutor
    import multiprocessing

    if n not in _EXECUTORS:
        from ..utils.backend import VARIANT_ENV, init_backend

        # the workers must pick the parent's Mitsuba variant (they inherit the environment)
        os.environ.setdefault(VARIANT_ENV, init_backend())
        _EXECUTORS[n] = ProcessPoolExecutor(max_workers=n, initializer=_init_worker,
                                            initargs=(os.getpid(),),
                                            mp_context=multiprocessing.get_context("spawn"))
    return _EXECUTORS[n]


def _tmpdir() -> str:
    if "dir" not in _TMP:
        _TMP["dir"] = tempfile.mkdtemp(prefix="sionna_mmir_fits_")
    return _TMP["dir"]


def shutdown() -> None:
    """Stop every worker process and remove the shared files (also at exit)."""
    for ex in _EXECUTORS.values():
        ex.shutdown(wait=True, cancel_futures=True)
    _EXECUTORS.clear()
    if "dir" in _TMP:
        shutil.rmtree(_TMP.pop("dir"), ignore_errors=True)


atexit.register(shutdown)


class FitPool:
    """Runs independent fit tasks, in this process or in worker processes.

    Parameters
    ----------
    workers : int or "auto"
        Processes (1: run every task here).  The pool of processes is made on
        first use and shared by every :class:`FitPool` of the same size.
    """

    def __init__(self, workers=1):
        self.workers = check_workers(workers)

    def map(self, fn, shared, tasks, done=None, follow=None) -> list:
        """``[fn(shared, *args) for args in tasks]``, in task order.

        ``fn`` must be a module-level function (workers import it by name);
        ``shared`` and the task arguments must pickle.  ``done(i)`` is called
        as task ``i`` finishes (in any order).  ``follow(i, result)``, if
        given, returns further tasks that task ``i``'s result calls for; they
        are appended to the list (their results follow in the order they
        were appended) and start before the tasks not yet started.  After a
        worker died every task runs again here, so ``follow`` must not
        count on being called once per result (tell results apart by what
        they hold, not by their position)."""
        tasks = [tuple(t) for t in tasks]
        if self.workers <= 1 or (len(tasks) <= 1 and follow is None):
            return _serial(fn, shared, tasks, done, follow)
        from concurrent.futures.process import BrokenProcessPool

        given = len(tasks)
        try:
            with self._on_workers(shared) as (ex, path):
                return self._run_queue(ex, fn, path, tasks, done, follow)
        except BrokenProcessPool:
            self._died()
            return _serial(fn, shared, tasks[:given], done, follow)

    def _run_queue(self, ex, fn, path, tasks, done, follow) -> list:
        """:meth:`map` on the executor ``ex``: at most one task per worker in
        flight, the next taken from the front of a queue where follow-ups go
        first (a task queued in the executor could not be overtaken: a
        follow-up would wait behind every task given, at the end of the
        round)."""
        from collections import deque
        from concurrent.futures import FIRST_COMPLETED, wait

        queue, futures, results = deque(range(len(tasks))), {}, {}

        def start():
            while queue and len(futures) < self.workers:
                i = queue.popleft()
                futures[ex.submit(_call, fn, path, tasks[i])] = i

        start()
        while futures:
            finished, _ = wait(futures, return_when=FIRST_COMPLETED)
            for fut in finished:
                i = futures.pop(fut)
                results[i] = fut.result()
                new = [tuple(t) for t in (follow(i, results[i]) if follow is not None else ())]
                tasks.extend(new)
                queue.extendleft(reversed(range(len(tasks) - len(new), len(tasks))))
                if done is not None:
                    done(i)
            start()
        return [results[i] for i in range(len(tasks))]

    def first(self, fn, shared, tasks, accept):
        """``(i, fn(shared, *tasks[i]))`` for the first ``i`` in task order whose
        result ``accept`` takes, or None: what running the tasks one by one
        and stopping at the first accepted one returns.

        On worker processes every task is started at once and the results
        are read in order; once one is accepted the tasks not yet started are
        cancelled (those already running finish and are discarded)."""
        tasks = [tuple(t) for t in tasks]
        if self.workers <= 1 or len(tasks) <= 1:
            return _serial_first(fn, shared, tasks, accept)
        from concurrent.futures import wait
        from concurrent.futures.process import BrokenProcessPool

        try:
            with self._on_workers(shared) as (ex, path):
                futures = [ex.submit(_call, fn, path, t) for t in tasks]
                try:
                    return next(((i, r) for i, r in enumerate(f.result() for f in futures)
                                 if accept(r)), None)
                finally:
                    for fut in futures:
                        fut.cancel()
                    wait(futures)            # the shared file outlives every started task
        except BrokenProcessPool:
            self._died()
            return _serial_first(fn, shared, tasks, accept)

    @contextlib.contextmanager
    def _on_workers(self, shared):
        """The process pool and the path of ``shared``, pickled once for all
        tasks of a call (removed after it)."""
        path = os.path.join(_tmpdir(), f"{uuid.uuid4().hex}.pkl")
        with open(path, "wb") as f:
            pickle.dump(shared, f, protocol=pickle.HIGHEST_PROTOCOL)
        try:
            yield _executor(self.workers), path
        finally:
            os.remove(path)

    def _died(self):
        warnings.warn("a fit worker process died; running its tasks in this process",
                      RuntimeWarning, stacklevel=3)
        _EXECUTORS.pop(self.workers, None)

    def __getstate__(self):
        return {"workers": self.workers}

    def __setstate__(self, state):
        self.workers = state["workers"]


def _serial_first(fn, shared, tasks, accept):
    for i, t in enumerate(tasks):
        r = fn(shared, *t)
        if accept(r):
            return i, r
    return None


def _serial(fn, shared, tasks, done, follow=None):
    out, tasks, i = [], list(tasks), 0
    while i < len(tasks):
        out.append(fn(shared, *tasks[i]))
        if follow is not None:
            tasks += [tuple(t) for t in follow(i, out[-1])]
        if done is not None:
            done(i)
        i += 1
    return out


#: the in-process pool
SERIAL = FitPool(1)

__all__ = ["AUTO", "FitPool", "SERIAL", "available_cores", "check_workers", "one_blas_thread",
           "shutdown"]
