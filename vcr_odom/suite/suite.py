"""A whole suite into one folder: which cells still need to run, running them, and the summary after
each, so the folder always says what is done (resumable after anything, SIGKILL included).

Layout: ``<folder>/suite.json`` (the suite as read), ``cells/<dataset>/<method>_stride<K>/`` (each a
``run``/``map`` result folder per attempt), ``summary.json``, ``summary.md``, ``plots/``."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vcr_odom.errors import ConfigError
from vcr_odom.io import atomic_write_text
from vcr_odom.results import check_output_folder, write_json
from vcr_odom.suite.cells import Cell, cells_of, read_row
from vcr_odom.suite.executors import run_here, run_on_pool, run_on_ray
from vcr_odom.suite.spec import SuiteSpec, load_suite
from vcr_odom.suite.summary import write_plots, write_summary

CellProgress = Callable[[Cell, dict[str, Any]], None]


@dataclass
class SuiteOutcome:
    folder: Path
    rows: list[dict[str, Any]]
    ran: list[str] = field(default_factory=list)
    """Keys of the cells run this time (complete ones are skipped)."""
    skipped: list[str] = field(default_factory=list)
    interrupted: bool = False


def plan(suite_file: Path, folder: Path) -> tuple[SuiteSpec, list[Cell], list[Cell]]:
    """The suite, all its cells, and those not complete in ``folder`` (checked before anything runs)."""
    suite = load_suite(suite_file)
    folder = check_output_folder(folder, "--out")
    _check_same_suite(folder, suite)
    cells = cells_of(suite)
    todo = [cell for cell in cells if read_row(cell, folder)["status"] != "complete"]
    return suite, cells, todo


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
    suite, cells, todo = plan(suite_file, folder)
    folder.mkdir(parents=True, exist_ok=True)
    write_json(folder / "suite.json", suite.to_dict())
    atomic_write_text(folder / "suite.toml", suite_file.read_text(encoding="utf-8"))
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
