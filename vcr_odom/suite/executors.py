"""Where a suite's cells run: here one after the other, on a process pool, or on a Ray cluster.

Each executor runs :func:`~vcr_odom.suite.cells.run_cell` on :class:`~vcr_odom.suite.cells.Cell`
objects (a few hundred bytes: a dataset's paths, a method, a stride) and hands each finished cell's
row to ``on_done`` as it comes. Frames are read where a cell runs and results are written to the suite
folder, so nothing large travels through the scheduler; on a cluster that folder and the data must be
on a file system every node sees (docs/scaling.md).

Threads: a cell's torch, kiss-icp (TBB) and open3d (OpenMP) threads are set to ``threads`` so that
jobs x threads does not exceed the cores (set before those libraries load, in a fresh process).
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from multiprocessing.context import BaseContext
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any

from vcr_odom.errors import ConfigError
from vcr_odom.suite.cells import Cell, read_row, record_failure, run_cell

OnDone = Callable[[Cell, dict[str, Any]], None]
THREADS_VARIABLE = "VCR_ODOM_THREADS"
"""Threads per process for kiss-icp's registration (0 or unset: all cores, kiss-icp's default)."""


def threads_per_job(jobs: int, cores: int | None = None) -> int:
    """The most threads each of ``jobs`` concurrent cells may use without oversubscribing the cores."""
    return max(1, (cores or os.cpu_count() or 1) // max(1, jobs))


def thread_variables(threads: int) -> dict[str, str]:
    """The environment that limits kiss-icp (:data:`THREADS_VARIABLE`), open3d (OpenMP reads it when it
    loads, hence given to a process as it starts) and numpy's BLAS."""
    names = (THREADS_VARIABLE, "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
    return dict.fromkeys(names, str(threads))


@contextmanager
def started_with(variables: dict[str, str]) -> Iterator[None]:
    """Processes started inside inherit ``variables``; this process's environment is restored after."""
    saved = {name: os.environ.get(name) for name in variables}
    os.environ.update(variables)
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def limit_threads(threads: int) -> None:
    """A worker process's start: torch's threads (set before any cell loads its libraries)."""
    import torch

    torch.set_num_threads(threads)


def run_here(cells: Sequence[Cell], suite_folder: Path, on_done: OnDone) -> None:
    """One cell after the other in this process (``--jobs 1``): no start-up cost, tracebacks as usual."""
    for cell in cells:
        row = run_cell(cell, suite_folder)
        on_done(cell, row)
        if row["status"] == "partial":  # only a stop signal leaves a cell partial: stop the suite too
            raise KeyboardInterrupt


# -- a pool of worker processes ------------------------------------------------------------------------
#
# Why not concurrent.futures.ProcessPoolExecutor: one worker lost (the OOM killer, a kill -9) breaks
# the whole executor, failing every cell it held or had queued, started or not; its workers prefetch
# queued cells, so they start new ones after their parent was killed; and its queues hold named
# semaphores, whose resource tracker (killed by a terminal's SIGHUP) then prints KeyError tracebacks.
# Here each worker is a spawned process with a pipe of its own, handed one cell at a time: a worker
# lost fails its own cell only and is replaced; a worker whose parent dies is told to stop (SIGTERM,
# keeping its cell's partial result) and takes no other cell; pipes need no resource tracker.

PR_SET_PDEATHSIG = 1
"""Linux's prctl option: the signal a process gets when its parent dies."""
PARENT_POLL_SECONDS = 1.0
"""Where prctl is not available, how often a worker looks for its parent."""
STOP_GRACE_SECONDS = 2.0
"""After Ctrl-C (which the terminal sends to every worker too), how long the workers get to stop on
their own before they are sent SIGTERM."""
STOP_WAIT_SECONDS = 120.0
"""How long a stopping worker may take to write its cell's partial result before it is killed."""


def die_with_parent(parent: int) -> None:
    """SIGTERM this process when its parent ``parent`` dies (a ``kill -9`` of the suite), so no worker
    goes on alone: Linux's ``PR_SET_PDEATHSIG``, else a thread watching the parent's pid."""
    armed = False
    if sys.platform.startswith("linux"):
        with suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) == 0
    if not armed:
        threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()
    if os.getppid() != parent:  # it died before the signal was armed
        os.kill(os.getpid(), signal.SIGTERM)


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(PARENT_POLL_SECONDS)
    os.kill(os.getpid(), signal.SIGTERM)


def _worker(connection: Connection, threads: int, parent: int) -> None:
    """A worker process: cells from ``connection``, one at a time, each answered with its row, until
    the pipe closes or a stop signal comes. Whatever stops it, it exits without a traceback."""
    from vcr_odom.stop_signals import stop_on_signals, stopping_signal

    try:
        stop_on_signals()  # Ctrl-C, SIGTERM, SIGHUP: the running cell keeps its partial result
        die_with_parent(parent)
        limit_threads(threads)
        while stopping_signal() is None:
            message = connection.recv()
            if message is None:
                return
            cell, suite_folder = message
            try:
                row = run_cell(cell, suite_folder)
            except KeyboardInterrupt:  # stopped: its partial result is on disk; say so, and take no other
                connection.send(read_row(cell, suite_folder))
                return
            connection.send(row)
    except (KeyboardInterrupt, EOFError, OSError):  # stopped while idle, or the parent is gone
        return
    finally:
        with suppress(OSError):
            connection.close()


@dataclass
class _Worker:
    process: BaseProcess
    connection: Connection
    cell: Cell | None = None


def run_on_pool(cells: Sequence[Cell], suite_folder: Path, on_done: OnDone, jobs: int) -> None:
    """``jobs`` fresh processes (spawned: no torch state forked), each limited to its share of the cores,
    each given one cell at a time; a worker lost fails its own cell and another takes its place.

    On Ctrl-C every worker gets it too (one process group); on SIGTERM or SIGHUP to this process alone,
    the workers are sent SIGTERM, so each keeps its cell's partial result; nothing new starts either way,
    and this returns (raises) once every worker has exited."""
    context = multiprocessing.get_context("spawn")
    threads = threads_per_job(jobs)
    queue = deque(cells)
    workers: list[_Worker] = []
    _start_resource_tracker()
    try:
        while True:
            for worker in workers:
                if worker.cell is None and queue:
                    _hand(worker, queue.popleft(), suite_folder)
            while queue and len(workers) < jobs:  # at the start, and in place of a worker lost
                workers.append(_start_worker(context, threads))
                _hand(workers[-1], queue.popleft(), suite_folder)
            for worker in [w for w in workers if w.cell is None]:  # no cell left for it
                workers.remove(worker)
                _dismiss(worker)
            if not workers:
                return
            ready = set(wait([w.connection for w in workers] + [w.process.sentinel for w in workers]))
            for worker in [w for w in workers if {w.connection, w.process.sentinel} & ready]:
                cell, row = worker.cell, _answer(worker)
                assert cell is not None
                worker.cell = None
                if row is None:  # its process died under the cell: that cell fails, the others go on
                    workers.remove(worker)
                    worker.process.join()
                    worker.connection.close()
                    if worker.process.exitcode == 0:  # it exited on a signal as it answered: the folder says
                        row = read_row(cell, suite_folder)
                    else:
                        reason = f"its process was lost ({_death(worker.process)}); the other cells went on"
                        row = record_failure(cell, suite_folder, reason)
                elif row["status"] == "partial":  # the worker alone was told to stop: it takes no more
                    workers.remove(worker)
                    _dismiss(worker)
                on_done(cell, row)
    except BaseException:
        _stop_workers(workers)
        raise


def _start_worker(context: BaseContext, threads: int) -> _Worker:
    ours, theirs = context.Pipe(duplex=True)
    process = context.Process(target=_worker, args=(theirs, threads, os.getpid()), name="vcr-odom cell")
    with started_with(thread_variables(threads)):  # OpenMP reads its threads as the process starts
        process.start()
    theirs.close()
    return _Worker(process, ours)


def _hand(worker: _Worker, cell: Cell, suite_folder: Path) -> None:
    """Give ``worker`` its next cell (a worker already dead is found by ``wait``: its sentinel)."""
    worker.cell = cell
    with suppress(OSError):
        worker.connection.send((cell, suite_folder))


def _answer(worker: _Worker) -> dict[str, Any] | None:
    """The row the worker sent for its cell; None where it died without one (its sentinel fired with
    nothing in its pipe: what it wrote before exiting would be there)."""
    try:
        return worker.connection.recv() if worker.connection.poll(0) else None
    except (EOFError, OSError):
        return None


def _death(process: BaseProcess) -> str:
    code = process.exitcode
    if code is not None and code < 0:
        name = signal.Signals(-code).name
        return f"killed by {name}" + (", perhaps for memory" if name == "SIGKILL" else "")
    return f"exit code {code}"


def _dismiss(worker: _Worker) -> None:
    """An idle worker is told there is no more work and waited for."""
    with suppress(OSError):
        worker.connection.send(None)
    worker.process.join(STOP_WAIT_SECONDS)
    if worker.process.is_alive():
        worker.process.kill()
        worker.process.join()
    worker.connection.close()


def _stop_workers(workers: list[_Worker]) -> None:
    """Stop every worker and wait for it: a busy one keeps its cell's partial result (SIGTERM, as
    ``run`` takes it; after Ctrl-C, which the terminal sent it too, a moment first to stop on its own),
    an idle one is dismissed; none is left running, and none starts another cell."""
    from vcr_odom.stop_signals import stopping_signal

    for worker in workers:
        if worker.cell is None:
            with suppress(OSError):
                worker.connection.send(None)
    if stopping_signal() == signal.SIGINT:
        deadline = time.monotonic() + STOP_GRACE_SECONDS
        for worker in workers:
            worker.process.join(max(0.0, deadline - time.monotonic()))
    for worker in workers:
        if worker.process.is_alive():
            with suppress(OSError):
                os.kill(worker.process.pid, signal.SIGTERM)  # type: ignore[arg-type]
    deadline = time.monotonic() + STOP_WAIT_SECONDS
    for worker in workers:
        worker.process.join(max(0.0, deadline - time.monotonic()))
        if worker.process.is_alive():
            worker.process.kill()
            worker.process.join()
        worker.connection.close()


def _start_resource_tracker() -> None:
    """multiprocessing's resource tracker, started now with SIGHUP ignored: spawning a worker starts it
    otherwise, in this process group, where a closed terminal's SIGHUP would kill it, and the next
    worker started would print "resource_tracker: process died unexpectedly"."""
    from multiprocessing import resource_tracker

    if not hasattr(signal, "SIGHUP"):
        resource_tracker.ensure_running()
        return
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        resource_tracker.ensure_running()
    finally:
        signal.signal(signal.SIGHUP, previous)


def run_on_ray(cells: Sequence[Cell], suite_folder: Path, on_done: OnDone, address: str, jobs: int) -> None:
    """Ray tasks, one per cell, each asking for one of the cluster's CPUs (a cell slot):
    ``address="local"`` starts a local cluster of ``jobs`` slots here, each cell taking cores / jobs
    threads; any other address joins that cluster (``auto``, ``ray://host:10001``, ...), one thread a
    cell, as many cells per node as it has CPUs.

    On Ctrl-C or SIGTERM the running tasks are cancelled (a KeyboardInterrupt in each: its cell keeps
    its partial result) and the queued ones never start."""
    try:
        import ray
    except ImportError:
        raise ConfigError("--ray needs Ray: pip install 'vcr-odom[ray]'") from None
    threads = threads_per_job(jobs) if address == "local" else 1
    environment = {"env_vars": thread_variables(threads)}
    started_here = not ray.is_initialized()
    if started_here:
        options: dict[str, Any] = {"runtime_env": environment, "log_to_driver": False}
        if address == "local":
            ray.init(num_cpus=jobs, include_dashboard=False, **options)
        else:
            check_ray_address(address)
            try:
                ray.init(address=address, **options)
            except (ConnectionError, RuntimeError, ValueError, TimeoutError) as error:
                raise ConfigError(f"--ray {address}: cannot join a Ray cluster there ({error})") from None
    remote = ray.remote(num_cpus=1, max_retries=0)(_ray_cell)  # never more than a --jobs 1 cluster has
    pending: dict[Any, Cell] = {}
    try:
        pending = {remote.remote(cell, str(suite_folder), threads): cell for cell in cells}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                cell = pending.pop(ref)
                try:
                    row = ray.get(ref)
                except (
                    ray.exceptions.RayTaskError,
                    ray.exceptions.WorkerCrashedError,
                    ray.exceptions.NodeDiedError,
                ) as error:
                    row = record_failure(
                        cell, suite_folder, f"its Ray task was lost ({type(error).__name__}: {error})"
                    )
                on_done(cell, row)
    except BaseException:
        for ref in pending:
            ray.cancel(ref)
        for ref in pending:  # let each cancelled cell write its partial result before Ray goes
            with suppress(Exception):  # cancelled or failed: its folder says which
                ray.get(ref, timeout=60)
        raise
    finally:
        if started_here:
            ray.shutdown()


RAY_CONNECT_SECONDS = 5.0
"""How long ``--ray HOST:PORT`` may take to answer: Ray's own client retries for minutes."""


def ray_endpoint(address: str) -> tuple[str, int] | None:
    """``(host, port)`` of ``--ray HOST:PORT`` or ``ray://HOST:PORT``; None for ``local``, ``auto`` and
    other forms Ray resolves itself."""
    rest = address.split("://", 1)[1] if "://" in address else address
    host, colon, port = rest.rstrip("/").rpartition(":")
    if not colon or not port.isdigit() or not host:
        return None
    return host.strip("[]"), int(port)


def check_ray_address(address: str) -> None:
    """A cluster that cannot be reached fails in seconds, naming the address, before anything is
    written: ``ray.init`` would retry for minutes, printing its logs. Only a TCP connection is tried
    (Ray's protocol is Ray's to check)."""
    endpoint = ray_endpoint(address)
    if endpoint is None:
        return
    try:
        with socket.create_connection(endpoint, timeout=RAY_CONNECT_SECONDS):
            pass
    except OSError as error:
        reason = error.strerror or str(error) or type(error).__name__
        raise ConfigError(
            f"--ray {address}: nothing answers at {endpoint[0]} port {endpoint[1]} ({reason}); "
            "is the cluster started (ray start --head) and the address right?"
        ) from None


def _ray_cell(cell: Cell, suite_folder: str, threads: int) -> dict[str, Any]:
    import torch

    torch.set_num_threads(threads)
    return run_cell(cell, Path(suite_folder))
