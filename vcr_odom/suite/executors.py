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

import multiprocessing
import os
import signal
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

from vcr_odom.errors import ConfigError
from vcr_odom.suite.cells import Cell, record_failure, run_cell

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
    """A pool process's start: torch's threads, and the stop signals as in the command (Ctrl-C,
    SIGTERM, SIGHUP keep a cell's partial result)."""
    import torch

    torch.set_num_threads(threads)
    from vcr_odom.stop_signals import stop_on_signals

    stop_on_signals()


def run_here(cells: Sequence[Cell], suite_folder: Path, on_done: OnDone) -> None:
    """One cell after the other in this process (``--jobs 1``): no start-up cost, tracebacks as usual."""
    for cell in cells:
        row = run_cell(cell, suite_folder)
        on_done(cell, row)
        if row["status"] == "partial":  # only a stop signal leaves a cell partial: stop the suite too
            raise KeyboardInterrupt


def _pool_cell(cell: Cell, suite_folder: Path) -> dict[str, Any]:
    from vcr_odom.stop_signals import stopping_signal

    if stopping_signal() is not None:  # this process was told to stop: start nothing new
        raise KeyboardInterrupt
    return run_cell(cell, suite_folder)


def run_on_pool(cells: Sequence[Cell], suite_folder: Path, on_done: OnDone, jobs: int) -> None:
    """``jobs`` fresh processes (spawned: no torch state forked), each limited to its share of the cores.

    On Ctrl-C every worker gets it too (one process group); on SIGTERM or SIGHUP to this process alone,
    the workers are sent SIGTERM, so each keeps its cell's partial result; nothing new starts either way."""
    context = multiprocessing.get_context("spawn")
    threads = threads_per_job(jobs)
    pool = ProcessPoolExecutor(jobs, mp_context=context, initializer=limit_threads, initargs=(threads,))
    pending: dict[Future[dict[str, Any]], Cell] = {}
    try:
        with started_with(thread_variables(threads)):  # the pool starts its processes on submission
            pending = {pool.submit(_pool_cell, cell, suite_folder): cell for cell in cells}
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                cell = pending.pop(future)
                try:
                    row = future.result()
                except KeyboardInterrupt:
                    raise
                except Exception as error:  # the process died (killed, out of memory): this cell fails
                    row = record_failure(
                        cell, suite_folder, f"its process was lost ({type(error).__name__}: {error})"
                    )
                on_done(cell, row)
    except BaseException:
        for future in pending:
            future.cancel()
        for child in multiprocessing.active_children():
            if child.pid is not None:
                os.kill(child.pid, signal.SIGTERM)
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


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
            ray.init(address=address, **options)
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


def _ray_cell(cell: Cell, suite_folder: str, threads: int) -> dict[str, Any]:
    import torch

    torch.set_num_threads(threads)
    return run_cell(cell, Path(suite_folder))
