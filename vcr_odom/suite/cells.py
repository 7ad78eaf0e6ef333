"""One cell of a suite (a dataset, a method, a stride): run it into its own folder, and read its row
back from what is on disk.

Why rows are read from disk, never kept in memory: a suite killed at any moment (SIGKILL included)
must be summarised and resumed from its folders alone. A cell's folder ``cells/<dataset>/<method>_stride<K>``
holds ``run``'s (or ``map``'s) transactional result folders, one per attempt, and ``failure.json``
when its last attempt failed before publishing anything; the row comes from the attempt's
``result.json`` and ``metrics.json``.

Why a cell is keyed by a digest of its settings and not only by its folder's name: the folder names a
dataset, a method and a stride, but a suite's ``consult`` or ``device`` (or a newer default of ``run``)
changes the result too. Each attempt's ``config.json`` records the settings it ran with; only attempts
whose settings digest is the cell's count, so an edited suite reruns the cells it changes (the older
attempts stay on disk) and leaves the others alone. A complete attempt whose ``metrics.json`` does not
parse counts for nothing either: its figures are lost, so the cell is rerun, and its row says why."""

from __future__ import annotations

import hashlib
import json
import math
import traceback
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

from vcr_odom.errors import VcrOdomError
from vcr_odom.results import read_marker, write_json
from vcr_odom.suite.spec import DatasetEntry, SuiteSpec

FAILURE_FILE = "failure.json"
CONFIG_FILE = "config.json"
UNSETTLED = ("command", "sequence", "results_dir")
"""Keys of an attempt's ``config.json`` that are not its settings: the command (the method says it),
the sequence's name (its source says it) and where it was written."""


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
    """Mark ``cell`` failed (its process or node was lost, or its data is bad) and return its row. The
    failure carries the cell's digest: once the suite changes the cell, it no longer applies."""
    folder = cell_folder(suite_folder, cell)
    folder.mkdir(parents=True, exist_ok=True)
    write_json(folder / FAILURE_FILE, {"reason": reason, "traceback": details, "digest": cell_digest(cell)})
    return read_row(cell, suite_folder)


def cell_settings(cell: Cell) -> Any:
    """The ``RunSettings`` (or ``MapSettings`` for ``+loops``) the cell runs with, into its folder
    ``results_dir`` left at its default (the caller sets it)."""
    from vcr_odom.evaluation.rows import split_loops
    from vcr_odom.odometry.factory import parse_method_spec

    base, mapped = split_loops(cell.method)
    method, polish = parse_method_spec(base)
    options: dict[str, Any] = {
        "selection": cell.dataset.selection(cell.stride),
        "method": method,
        "polish": polish,
    }
    if method == "vcr" or mapped:  # a map cell's loop network runs on the suite's device too
        options["device"] = cell.device
    if cell.consult is not None and polish != "none" and method in ("vcr", "fpfh"):
        options["consult"] = cell.consult
    if mapped:
        from vcr_odom.map_command import MapSettings

        return MapSettings(**options)
    from vcr_odom.odometry.run import RunSettings

    return RunSettings(**options)


@cache
def expected_settings(cell: Cell) -> dict[str, Any]:
    """What a current attempt's ``config.json`` says of its settings (JSON types, as read back)."""
    settings = json.loads(json.dumps(cell_settings(cell).to_dict()))
    return {key: value for key, value in settings.items() if key not in UNSETTLED}


def settings_digest(settings: dict[str, Any]) -> str:
    """A short digest of ``settings`` (key order ignored)."""
    text = json.dumps(settings, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def cell_digest(cell: Cell) -> str:
    """The digest of everything that changes the cell's result: its run's (or map's) settings."""
    return settings_digest(expected_settings(cell))


def attempt_settings(path: Path) -> dict[str, Any] | None:
    """The settings an attempt ran with, from its ``config.json`` (None where it cannot be read)."""
    try:
        config = json.loads((path / CONFIG_FILE).read_text(encoding="utf-8"))["config"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not isinstance(config, dict):
        return None
    return {key: value for key, value in config.items() if key not in UNSETTLED}


def _run(cell: Cell, folder: Path) -> None:
    settings = cell_settings(cell).with_changes(results_dir=folder)
    if cell.mapped:
        from vcr_odom.map_command import map_sequence

        map_sequence(settings)
    else:
        from vcr_odom.odometry.run import run_sequence

        run_sequence(settings)


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
    where the last attempt failed, ``pending`` where none ran. Only attempts run with the cell's
    settings (its digest) and, if complete, with a ``metrics.json`` that parses, count; where others
    exist, a ``pending`` row's reason says why they do not (the cell is to be rerun)."""
    folder = cell_folder(suite_folder, cell)
    digest = cell_digest(cell)
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
        "digest": digest,
    }
    found, set_aside = [], []
    for path, marker in attempts(folder):
        why = _not_current(cell, path, marker)
        if why is None:
            found.append((path, marker))
        else:
            set_aside.append(f"{path.name}: {why}")
    complete = [item for item in found if item[1]["status"] == "complete"]
    chosen = complete[0] if complete else (found[-1] if found else None)
    if chosen is None and set_aside:
        row["reason"] = f"rerun: {set_aside[-1]}"
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
        reason = _failure_reason(failure, digest)
        if reason is not None:
            row |= {"status": "failed", "reason": reason}
    return row


def _not_current(cell: Cell, path: Path, marker: dict[str, Any]) -> str | None:
    """Why an attempt does not count for the cell now (None: it does)."""
    settings = attempt_settings(path)
    if settings is None:
        return f"its {CONFIG_FILE} does not parse, so what it ran is unknown"
    expected = expected_settings(cell)
    if settings_digest(settings) != settings_digest(expected):
        return f"run with other settings ({_differences(settings, expected)})"
    if marker["status"] == "complete":
        metrics = path / "metrics.json"
        try:
            parsed = json.loads(metrics.read_text(encoding="utf-8"))
        except (OSError, ValueError) as error:
            return f"its metrics.json does not parse ({type(error).__name__})"
        if not isinstance(parsed, dict):
            return "its metrics.json does not parse (not a JSON object)"
    return None


def _differences(before: dict[str, Any], now: dict[str, Any], prefix: str = "") -> str:
    """``consult: 'on-doubt' -> 'every-frame'`` for each setting that differs (the first three)."""
    changes = []
    for key in sorted(set(before) | set(now)):
        old, new = before.get(key), now.get(key)
        if isinstance(old, dict) and isinstance(new, dict):
            inner = _differences(old, new, f"{prefix}{key}.")
            changes += [inner] if inner else []
        elif old != new:
            changes.append(f"{prefix}{key}: {old!r} -> {new!r}")
    return ", ".join(changes[:3]) + (", ..." if len(changes) > 3 else "")


def _failure_reason(path: Path, digest: str) -> str | None:
    """The recorded failure's reason; None where it was a failure of other settings (a suite since
    edited). A failure.json written before digests were recorded applies."""
    try:
        failure = json.loads(path.read_text(encoding="utf-8"))
        if failure.get("digest", digest) != digest:
            return None
        return str(failure["reason"])
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
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
