"""Score trajectory files: load, put both in one frame, match frames, then :func:`metrics.evaluate`.

A score that looks right but is not is worse than an error, so what would silently skew it is an
error naming the file (a calibration whose ``Tr`` is not rigid, a file that is not text), and an
estimate from a run that did not finish gets a warning (its folder's result marker).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.scans import read_tr
from vcr_odom.data.selection import select_frames
from vcr_odom.errors import DataError
from vcr_odom.geometry import camera_to_lidar_poses, normalise_to_first
from vcr_odom.io import read_kitti_poses
from vcr_odom.metrics import AteAlignment, EvaluationReport, evaluate
from vcr_odom.plots import plot_pair_errors, plot_trajectories
from vcr_odom.results import MARKER, read_marker, write_json

T = TypeVar("T")


@dataclass
class FileEvaluation:
    report: EvaluationReport
    est: NDArray[np.float64]
    gt: NDArray[np.float64]
    frame: str
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    """What makes the figures doubtful (an estimate from a run marked partial, or with no marker)."""


def evaluate_files(
    gt_path: Path,
    est_path: Path,
    *,
    calib: Path | None = None,
    frames: str | None = None,
    stride: int | None = None,
    ate_alignment: AteAlignment = "origin",
) -> FileEvaluation:
    """Evaluate a KITTI-format estimate against KITTI-format ground truth.

    When the estimate covers only some ground-truth frames (``run --frames/--stride``), say which with
    ``frames``/``stride``, or keep the run's ``frames.json`` beside the estimate and it is used.
    """
    gt = read_kitti_poses(gt_path)
    est = read_kitti_poses(est_path)
    notes: list[str] = []
    warnings = estimate_warnings(est_path)
    indices = _frame_indices(len(gt), est_path, frames, stride, notes)
    gt = gt[indices]
    if len(est) != len(gt):
        raise DataError(
            f"{est_path} has {len(est)} poses but {gt_path} has {len(gt)} for the chosen frames; "
            "pass --frames/--stride as given to run (or keep frames.json beside the estimate)"
        )
    frame = "as given (no --calib)"
    if calib is not None:
        # The same check as run's: a Tr that is not rigid (a typo, an all-zero line) would give
        # plausible-looking but wrong figures.
        tr = read_tr(calib, required=True)
        assert tr is not None
        gt, est = camera_to_lidar_poses(gt, tr), camera_to_lidar_poses(est, tr)
        frame = "LiDAR frame"
    return FileEvaluation(
        report=evaluate(normalise_to_first(est), normalise_to_first(gt), ate_alignment=ate_alignment),
        est=normalise_to_first(est),
        gt=normalise_to_first(gt),
        frame=frame,
        notes=notes,
        warnings=warnings,
    )


def estimate_warnings(est_path: Path) -> list[str]:
    """Why the estimate may not be a finished run's: its folder's result marker says ``partial``, or
    there is none (not written by ``vcr-odom run``, or by a version before markers)."""
    folder = est_path.parent
    try:
        marker = read_marker(folder)
    except DataError as error:
        return [f"{error}; cannot tell whether {est_path.name} is a finished run's"]
    if marker is None:
        return [
            f"{os.path.join(folder, MARKER)} not found: cannot tell whether {est_path.name} is a finished "
            "run's (it was not written by this version of vcr-odom run)"
        ]
    if marker["status"] != "complete":
        done, selected = marker.get("frames_done"), marker.get("frames_selected")
        return [
            f"{est_path} is from a run marked partial ({done} of {selected} frames): "
            f"{marker.get('reason') or 'no reason given'}"
        ]
    return []


def _frame_indices(
    gt_length: int, est_path: Path, frames: str | None, stride: int | None, notes: list[str]
) -> list[int]:
    if frames is not None or stride is not None:
        return select_frames(gt_length, frames, stride or 1)
    sidecar = est_path.parent / "frames.json"
    if sidecar.is_file():
        try:
            indices = [int(i) for i in json.loads(sidecar.read_text())["frame_indices"]]
        except (ValueError, KeyError, TypeError) as error:
            raise DataError(f"{sidecar}: expected {{'frame_indices': [int, ...]}}") from error
        if indices and max(indices) >= gt_length:
            raise DataError(
                f"{sidecar} names frame {max(indices)} but the ground truth has {gt_length} poses"
            )
        notes.append(f"frames taken from {sidecar} ({len(indices)} frames)")
        return indices
    return list(range(gt_length))


def write_evaluation(
    evaluation: FileEvaluation, label: str, *, json_path: Path | None = None, plot_path: Path | None = None
) -> list[Path]:
    """Every figure (per-pair errors included) as JSON, and a trajectory plot with a per-pair error
    plot beside it; returns the files written."""
    written: list[Path] = []
    if json_path is not None:
        written.append(write_json(json_path, evaluation.report.to_dict(include_arrays=True)))
    if plot_path is not None:
        plot_trajectories(plot_path, {label: evaluation.est}, evaluation.gt, title=label)
        errors_path = plot_path.with_name(plot_path.stem + "_pair_errors.png")
        pairs = evaluation.report.pairs
        plot_pair_errors(errors_path, {label: pairs.rot_errors_deg}, {label: pairs.trans_errors_m})
        written += [plot_path, errors_path]
    return written
