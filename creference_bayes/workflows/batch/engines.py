"""Where a batch runs: a local process pool or a Dask cluster, both seen as a
:class:`concurrent.futures.Executor`, so that one runner serves both.

- :class:`LocalEngine`: a :class:`~concurrent.futures.ProcessPoolExecutor` with one process per
  worker (``forkserver`` start where the platform has it, else ``spawn``: no ``fork`` of a process
  that may already run threads).
- :class:`DaskEngine`: ``Client(address).get_executor(pure=False)`` on a running Dask distributed
  scheduler (the ``dist`` extra). Its futures are :class:`concurrent.futures.Future` objects, so
  :func:`concurrent.futures.wait` serves both engines.

An engine also says how many tasks run at once (:meth:`Engine.slots`): the runner keeps exactly
that many in flight, so a task's clock starts when it starts (the per-scene time limit relies on
it), and it can shut the engine down without waiting for tasks it gave up on.
:func:`each_completed` runs tasks that need no more than that (the advice of a batch's frames).
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import signal
import threading
import time
from collections import deque
from concurrent.futures import Executor, ProcessPoolExecutor

__all__ = ["Engine", "LocalEngine", "DaskEngine", "DASK_INSTALL_HINT", "default_workers", "each_completed",
           "InlineEngine"]

DASK_INSTALL_HINT = 'Dask distributed is needed for --scheduler: pip install "creference-bayes[dist]"'


def default_workers() -> int:
    """The number of cores this process may use (at least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _init_worker(parent_pid: int, interval: float = 1.0) -> None:
    """Pool initializer: leave Ctrl-C to the batch process, and end with it.

    Ctrl-C reaches every process of the group; the batch process handles it (it records what
    finished and ends the pool), so the workers ignore it. Workers would outlive a batch process
    killed with SIGKILL and wait for tasks forever: a thread ends them instead.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def watch():
        while True:
            time.sleep(interval)
            try:
                os.kill(parent_pid, 0)
            except ProcessLookupError:
                os._exit(1)
            except PermissionError:  # the PID exists (another user's): keep watching
                pass

    threading.Thread(target=watch, name="creference-watch-parent", daemon=True).start()


class Engine:
    """An executor and the number of tasks it runs at once."""

    name: str = "engine"
    #: whether :meth:`renew` ends the tasks still running (a process pool can; threads cannot)
    can_stop_tasks: bool = False

    @property
    def executor(self) -> Executor:
        raise NotImplementedError

    def slots(self) -> int:
        """Tasks that can run at once (≥ 1)."""
        raise NotImplementedError

    def renew(self) -> bool:
        """Replace a broken executor (a local pool whose process died); False if not possible."""
        return False

    def close(self, abandon: bool = False) -> None:
        """Shut down. ``abandon``: do not wait for tasks still running (stop them if possible)."""
        raise NotImplementedError

    def describe(self) -> str:
        return self.name

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.close(abandon=exc_type is not None)


class LocalEngine(Engine):
    """A local pool of ``workers`` processes."""

    name = "local"
    can_stop_tasks = True

    def __init__(self, workers: int | None = None):
        self.workers = default_workers() if workers is None else int(workers)
        if self.workers < 1:
            raise ValueError(f"workers: expected an integer >= 1, got {workers!r}")
        methods = multiprocessing.get_all_start_methods()
        self._context = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
        self._executor = self._new()

    def _new(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(max_workers=self.workers, mp_context=self._context,
                                   initializer=_init_worker, initargs=(os.getpid(),))

    @property
    def executor(self) -> Executor:
        return self._executor

    def slots(self) -> int:
        return self.workers

    def renew(self) -> bool:
        self.close(abandon=True)
        self._executor = self._new()
        return True

    def close(self, abandon: bool = False) -> None:
        if abandon:
            # A task cannot be interrupted inside its process: end the processes themselves.
            # ProcessPoolExecutor has no public way to do that before Python 3.14
            # (terminate_workers), hence the private attribute, read defensively.
            processes = list((getattr(self._executor, "_processes", None) or {}).values())
            self._executor.shutdown(wait=False, cancel_futures=True)
            for p in processes:
                if p.is_alive():
                    p.terminate()
            for p in processes:
                p.join(timeout=5)
            self._executor.shutdown(wait=True)  # let the pool's manager thread release its queues
        else:
            self._executor.shutdown(wait=True)

    def describe(self) -> str:
        return f"{self.workers} local worker process{'es' if self.workers != 1 else ''}"


class _InlineExecutor(Executor):
    """Runs each task in this process as it is submitted (its future is done on return)."""

    def submit(self, fn, /, *args, **kwargs):
        fut = cf.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except Exception as exc:
            fut.set_exception(exc)
        return fut


class InlineEngine(Engine):
    """This process, one task at a time: for work that one local worker would do, without the cost
    of starting a process (it cannot end a task, so no time limit; :func:`each_completed` only)."""

    name = "inline"

    def __init__(self):
        self._executor = _InlineExecutor()

    @property
    def executor(self) -> Executor:
        return self._executor

    def slots(self) -> int:
        return 1

    def close(self, abandon: bool = False) -> None:
        pass

    def describe(self) -> str:
        return "this process"


class DaskEngine(Engine):
    """A Dask distributed scheduler, by address (``tcp://host:8786``) or an existing client.

    Parameters
    ----------
    address : the scheduler's address; ignored when ``client`` is given
    client : an existing :class:`distributed.Client` (not closed by :meth:`close`)
    connect_timeout : seconds to reach the scheduler
    worker_timeout : seconds to wait for a first worker when none is connected
    """

    name = "dask"

    def __init__(self, address: str | None = None, *, client=None, connect_timeout: float = 20.0,
                 worker_timeout: float = 60.0):
        try:
            from distributed import Client
        except ImportError as exc:  # pragma: no cover - the dist extra is installed in CI
            raise ImportError(DASK_INSTALL_HINT) from exc
        self.address = address
        self._own = client is None
        if client is None:
            try:
                client = Client(address, timeout=f"{connect_timeout}s")
            except (OSError, TimeoutError) as exc:
                raise ConnectionError(f"cannot reach the Dask scheduler at {address} ({exc})") from None
        self._client = client
        self._executor = client.get_executor(pure=False)
        self._wait_for_workers(worker_timeout)
        self._description = (f"a Dask cluster at {client.scheduler.address} "
                             f"({self.slots()} worker threads at the start)")

    def _wait_for_workers(self, timeout: float) -> None:
        end = time.monotonic() + timeout
        while self.slots(strict=False) == 0:
            if time.monotonic() > end:
                self.close()
                raise ConnectionError(f"no Dask worker connected to {self.address or 'the scheduler'} "
                                      f"after {timeout:g} s (start one with: dask worker ADDRESS)")
            time.sleep(0.2)

    @property
    def executor(self) -> Executor:
        return self._executor

    def slots(self, strict: bool = True) -> int:
        """Threads of all workers now connected (workers may join or leave during a batch)."""
        n = sum(self._client.nthreads().values())
        return max(n, 1) if strict else n

    def close(self, abandon: bool = False) -> None:
        # Dask runs a task in a worker thread, which cannot be stopped: abandoned tasks are
        # cancelled (their results dropped) but may run on until they end by themselves.
        self._executor.shutdown(wait=not abandon)
        if self._own:
            self._client.close()

    def describe(self) -> str:
        return self._description


def each_completed(engine: Engine, fn, jobs: dict):
    """Run ``fn(*args)`` for every ``key: args`` of ``jobs`` on ``engine``, ``engine.slots()`` at a
    time, and yield ``(key, outcome)`` as each ends: what ``fn`` returned, or the exception the task
    raised or the engine raised for it (a local worker process that died loses every task running
    with it; the pool is then renewed and the rest go on). The caller closes the engine."""
    todo, running = deque(jobs.items()), {}
    while todo or running:
        while todo and len(running) < engine.slots():
            key, args = todo.popleft()
            running[engine.executor.submit(fn, *args)] = key
        done, _ = cf.wait(running, return_when=cf.FIRST_COMPLETED)
        ended, broken = [], False
        for fut in done:
            key = running.pop(fut)
            try:
                ended.append((key, fut.result()))
            except cf.BrokenExecutor as exc:
                ended.append((key, exc))
                broken = True
            except Exception as exc:  # the task's own, or the engine's (e.g. Dask's KilledWorker)
                ended.append((key, exc))
        if broken:  # the tasks still running died with the pool
            ended += [(key, cf.BrokenExecutor("lost with a worker process that died")) for key in running.values()]
            running.clear()
            engine.renew()
        yield from ended
