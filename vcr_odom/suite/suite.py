"""A whole suite into one folder: which cells still need to run, running them, and the summary after
each, so the folder always says what is done (resumable after anything, SIGKILL included).

Layout: ``<folder>/suite.json`` (the suite as read), ``cells/<dataset>/<method>_stride<K>/`` (each a
``run``/``map`` result folder per attempt), ``summary.json``, ``summary.md``, ``plots/``."""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vcr_odom.errors import ConfigError
from vcr_odom.io import atomic_write_text
from vcr_odom.results import check_output_folder, write_json
from vcr_odom.suite.cells import Cell, cells_of, read_row
from vcr_odom.suite.executors import check_ray_address, run_here, run_on_pool, run_on_ray
from vcr_odom.suite.spec import SuiteSpec, check_inputs, load_suite
from vcr_odom.suite.summary import write_plots, write_summary

try:
    import fcntl
except ImportError:  # not POSIX: no lock (two runs into one folder duplicate work, nothing worse)
    fcntl = None  # type: ignore[assignment]

CellProgress = Callable[[Cell, dict[str, Any]], None]
LOCK_FILE = ".benchmark.lock"
"""Held (``flock``) by the run writing into a suite folder; the kernel lets it go when that run ends,
however it ends, so a ``kill -9`` leaves no stale lock."""


@dataclass
class SuiteOutcome:
    folder: Path
    rows: list[dict[str, Any]]
    ran: list[str] = field(default_factory=list)
    """Keys of the cells run this time (complete ones are skipped)."""
    skipped: list[str] = field(default_factory=list)
    interrupted: bool = False


@dataclass
class SuitePlan:
    """A suite checked and its folder locked: all its cells, those to run, and why each of those is
    run again where it ran before (another suite's settings, a metrics.json that does not parse)."""

    suite_file: Path
    folder: Path
    suite: SuiteSpec
    cells: list[Cell]
    todo: list[Cell]
    reruns: dict[str, str] = field(default_factory=dict)
    """``key: reason`` for the cells in ``todo`` whose earlier attempts do not count."""


@contextmanager
def planned(suite_file: Path, folder: Path, *, ray: str | None = None) -> Iterator[SuitePlan]:
    """The suite read and every input checked (nothing written yet where any is wrong), then its folder
    made and locked against a second run into it for as long as this lasts.

    Why a lock: two runs into one folder would each run every cell not yet complete, twice the work
    for the same figures. The second is refused, naming the folder, rather than made to wait."""
    suite = load_suite(suite_file)
    check_inputs(suite, suite_file, here=ray is None)
    folder = check_output_folder(folder, "--out")
    if ray is not None and ray != "local":
        check_ray_address(ray)
    folder.mkdir(parents=True, exist_ok=True)
    with _locked(folder):
        _check_same_suite(folder, suite)
        cells = cells_of(suite)
        rows = {cell.key: read_row(cell, folder) for cell in cells}
        todo = [cell for cell in cells if rows[cell.key]["status"] != "complete"]
        reruns = {c.key: rows[c.key]["reason"] for c in todo if rows[c.key]["reason"].startswith("rerun: ")}
        yield SuitePlan(suite_file, folder, suite, cells, todo, reruns)


@contextmanager
def _locked(folder: Path) -> Iterator[None]:
    path = folder / LOCK_FILE
    if fcntl is None:
        yield
        return
    descriptor = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.pread(descriptor, 64, 0).decode(errors="replace").strip() or "?"
            raise ConfigError(
                f"--out {folder}: another benchmark is writing into it (process {holder}); "
                "wait for it to finish, or give another --out"
            ) from None
        os.ftruncate(descriptor, 0)
        os.pwrite(descriptor, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(descriptor)  # lets the lock go


def run_suite(
    suite_file: Path,
    folder: Path,
    *,
    jobs: int = 1,
    ray: str | None = None,
    on_cell: CellProgress | None = None,
) -> SuiteOutcome:
    """Run every cell of ``suite_file`` not yet complete in ``folder``; Ctrl-C / SIGTERM stop the suite
    with what is complete kept (``interrupted``), the summary written either way."""
    if jobs < 1:
        raise ConfigError(f"--jobs must be 1 or more; got {jobs}")
    with planned(suite_file, folder, ray=ray) as plan:
        return run_plan(plan, jobs=jobs, ray=ray, on_cell=on_cell)


def run_plan(
    plan: SuitePlan, *, jobs: int = 1, ray: str | None = None, on_cell: CellProgress | None = None
) -> SuiteOutcome:
    """Run the cells of a :func:`planned` suite (see :func:`run_suite`)."""
    suite, cells, todo, folder, suite_file = plan.suite, plan.cells, plan.todo, plan.folder, plan.suite_file
    write_json(folder / "suite.json", suite.to_dict())
    atomic_write_text(folder / "suite.toml", suite_file.read_text(encoding="utf-8-sig"))
    outcome = SuiteOutcome(folder, [], skipped=[c.key for c in cells if c not in todo])

    def summarise() -> list[dict[str, Any]]:
        rows = [read_row(cell, folder) for cell in cells]
        write_summary(folder, rows, suite_file)
        return rows

    def done(cell: Cell, row: dict[str, Any]) -> None:
        outcome.ran.append(cell.key)
        summarise()
        if on_cell is not None:
            on_cell(cell, row)

    summarise()
    try:
        if ray is not None:
            run_on_ray(todo, folder, done, ray, jobs)
        elif jobs == 1:
            run_here(todo, folder, done)
        else:
            run_on_pool(todo, folder, done, jobs)
    except KeyboardInterrupt:
        outcome.interrupted = True
    finally:
        outcome.rows = summarise()
    write_plots(folder, outcome.rows, {d.name: d for d in suite.dataset})
    return outcome


def _check_same_suite(folder: Path, suite: SuiteSpec) -> None:
    """A folder resumed with another suite file must not mix two datasets under one name."""
    previous_file = folder / "suite.json"
    if not previous_file.is_file():
        return
    try:
        previous = {d["name"]: d for d in json.loads(previous_file.read_text(encoding="utf-8"))["dataset"]}
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise ConfigError(f"{previous_file}: unreadable ({error}); give another --out") from None
    for dataset in suite.dataset:
        before = previous.get(dataset.name)
        if before is not None and before != dataset.to_dict():
            raise ConfigError(
                f"--out {folder}: its dataset {dataset.name!r} was read from other data "
                f"({_source(before)}) than this suite's ({_source(dataset.to_dict())}); "
                "give another --out, or another name to the dataset"
            )


def _source(entry: dict[str, Any]) -> str:
    keys = ("data_root", "seq", "folder", "dataloader", "data", "frames")
    return ", ".join(f"{k}={entry[k]}" for k in keys if entry.get(k) is not None)
