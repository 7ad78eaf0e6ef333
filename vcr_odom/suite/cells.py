"""One cell of a suite (a dataset, a method, a stride): run it into its own folder, and read its row
back from what is on disk.

Why rows are read from disk, never kept in memory: a suite killed at any moment (SIGKILL included)
must be summarised and resumed from its folders alone. A cell's folder ``cells/<dataset>/<method>_stride<K>``
holds ``run``'s (or ``map``'s) transactional result folders, one per attempt, and ``failure.json``
when its last attempt failed before publishing anything; the row comes from the attempt's
``result.json`` and ``metrics.json``."""

from __future__ import annotations

import json
import math
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vcr_odom.errors import VcrOdomError
from vcr_odom.results import read_marker, write_json
from vcr_odom.suite.spec import DatasetEntry, SuiteSpec

FAILURE_FILE = "failure.json"


@dataclass(frozen=True)
class Cell:
    """What one cell runs: picklable and small (it travels to a pool process or a Ray worker; the
    frames are read where it runs)."""

    dataset: DatasetEntry
    method: str
    stride: int
    consult: str | None = None
    device: str = "cpu"

    @property
    def key(self) -> str:
        """``<dataset>/<method>_stride<K>``: the cell's folder under ``cells/`` and its id."""
        method = self.method.replace("+", "_").replace("/", "_")
        return f"{self.dataset.name}/{method}_stride{self.stride}"

    @property
    def mapped(self) -> bool:
        return self.method.endswith("+loops")


def cells_of(suite: SuiteSpec) -> list[Cell]:
    """Every cell, dataset by dataset, then method, then stride (the summary's order)."""
    return [
        Cell(dataset, method, stride, suite.consult, suite.device)
        for dataset in suite.dataset
        for method in suite.methods
        for stride in suite.strides
    ]


def cell_folder(suite_folder: Path, cell: Cell) -> Path:
    return suite_folder / "cells" / cell.key


def run_cell(cell: Cell, suite_folder: Path) -> dict[str, Any]:
    """Run ``cell`` as ``vcr-odom run`` (or ``map`` for ``+loops``) would, into its folder; return its row.

    A failure is recorded in ``failure.json`` (with the reason) and returned as a ``failed`` row rather
    than raised: one cell's bad data must not stop the others. Ctrl-C / SIGTERM propagate (the attempt
    keeps what it did, marked partial, as ``run`` does)."""
    folder = cell_folder(suite_folder, cell)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / FAILURE_FILE).unlink(missing_ok=True)
    try:
        _run(cell, folder)
    except Exception as error:  # any error fails this cell alone, with its reason
        reason = str(error) if isinstance(error, VcrOdomError) else f"{type(error).__name__}: {error}"
        details = None if isinstance(error, VcrOdomError) else traceback.format_exc()
        record_failure(cell, suite_folder, reason, details)
    return read_row(cell, suite_folder)


def record_failure(cell: Cell, suite_folder: Path, reason: str, details: str | None = None) -> dict[str, Any]:
    """Mark ``cell`` failed (its process or node was lost, or its data is bad) and return its row."""
    folder = cell_folder(suite_folder, cell)
    folder.mkdir(parents=True, exist_ok=True)
    write_json(folder / FAILURE_FILE, {"reason": reason, "traceback": details})
    return read_row(cell, suite_folder)


def _run(cell: Cell, folder: Path) -> None:
    from vcr_odom.evaluation.rows import split_loops
    from vcr_odom.odometry.factory import parse_method_spec

    base, mapped = split_loops(cell.method)
    method, polish = parse_method_spec(base)
    options: dict[str, Any] = {
        "selection": cell.dataset.selection(cell.stride),
        "method": method,
        "polish": polish,
        "results_dir": folder,
    }
    if method == "vcr":
        options["device"] = cell.device
    if cell.consult is not None and polish != "none" and method in ("vcr", "fpfh"):
        options["consult"] = cell.consult
    if mapped:
        from vcr_odom.map_command import MapSettings, map_sequence

        map_sequence(MapSettings(**options))
    else:
        from vcr_odom.odometry.run import RunSettings, run_sequence

        run_sequence(RunSettings(**options))


def attempts(folder: Path) -> list[tuple[Path, dict[str, Any]]]:
    """The cell's result folders with their markers, oldest first."""
    found = []
    for path in sorted(folder.iterdir()) if folder.is_dir() else []:
        if path.is_dir() and not path.is_symlink() and not path.name.startswith("."):
            marker = read_marker(path)
            if marker is not None:
                found.append((path, marker))
    return sorted(found, key=lambda item: (item[1].get("written", ""), item[0].name))


def read_row(cell: Cell, suite_folder: Path) -> dict[str, Any]:
    """The cell's row from its folder: the complete attempt if there is one, else the newest; ``failed``
    where the last attempt failed, ``pending`` where none ran."""
    folder = cell_folder(suite_folder, cell)
    row: dict[str, Any] = {
        "dataset": cell.dataset.name,
        "method": cell.method,
        "stride": cell.stride,
        "status": "pending",
        "frames": 0,
        "frames_selected": None,
        "t_rel_pct": None,
        "r_rel_deg_per_100m": None,
        "drift_segments": None,
        "drift_label": None,
        "ate_m": None,
        "end_point_pct": None,
        "fps": None,
        "folder": None,
        "reason": "",
    }
    found = attempts(folder)
    complete = [item for item in found if item[1]["status"] == "complete"]
    chosen = complete[0] if complete else (found[-1] if found else None)
    if chosen is not None:
        path, marker = chosen
        row |= {
            "status": marker["status"],
            "frames": marker.get("frames_done", 0),
            "frames_selected": marker.get("frames_selected"),
            "folder": str(path.relative_to(suite_folder)),
            "reason": marker.get("reason", ""),
            **_scores(path),
        }
    failure = folder / FAILURE_FILE
    if not complete and failure.is_file():
        row |= {"status": "failed", "reason": _failure_reason(failure)}
    return row


def _failure_reason(path: Path) -> str:
    try:
        return str(json.loads(path.read_text(encoding="utf-8"))["reason"])
    except (OSError, ValueError, KeyError, TypeError):
        return f"failed ({path} unreadable)"


def _scores(path: Path) -> dict[str, Any]:
    """The row's figures from an attempt's metrics.json (absent in a partial attempt: None)."""
    try:
        metrics = json.loads((path / "metrics.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    drift = metrics.get("drift") or {}
    run = metrics.get("run") or {}
    seconds = metrics.get("seconds")  # a map cell: every phase, not only the odometry
    frames = run.get("frames_processed") or 0
    wall = sum(seconds.values()) if isinstance(seconds, dict) else run.get("wall_seconds")
    return {
        "t_rel_pct": _number(drift.get("t_rel_percent")),
        "r_rel_deg_per_100m": _number(drift.get("r_rel_deg_per_100m")),
        "drift_segments": drift.get("num_segments"),
        "drift_label": drift.get("label"),
        "ate_m": _number((metrics.get("ate_rpe") or {}).get("ate_se3_trans_rmse_m")),
        "end_point_pct": _number((metrics.get("endpoint_drift") or {}).get("trans_error_percent")),
        "fps": frames / wall if wall else None,
    }


FIGURE_DECIMALS = 6
"""Figures are rounded to 1e-6 (of a %, a metre, a degree): far below what they can tell apart, and above
the last-digit differences of threaded sums, so a cell gives the same row wherever it runs."""


def _number(value: Any) -> float | None:
    if not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return round(float(value), FIGURE_DECIMALS)
