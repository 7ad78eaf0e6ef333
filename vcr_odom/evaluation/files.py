"""Score trajectory files: load, put both in one frame, match frames, then :func:`metrics.evaluate`.

A score that looks right but is not is worse than an error, so what would silently skew it is an
error naming the file (a calibration whose ``Tr`` is not rigid, a file that is not text), and an
estimate from a run that did not finish gets a warning (its folder's result marker).
"""

from __future__ import annotations

import itertools
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.scans import read_tr
from vcr_odom.data.selection import select_frames
from vcr_odom.errors import ConfigError, DataError
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
    recorded = read_frames_file(est_path.parent / FRAMES_FILE, len(gt))
    indices = _frame_indices(len(gt), recorded, frames, stride, notes)
    gt = gt[indices]
    if len(est) != len(gt):
        raise DataError(
            f"{est_path} has {len(est)} poses but {gt_path} has {len(gt)} for the chosen frames; "
            "pass --frames/--stride as given to run (or keep frames.json beside the estimate)"
        )
    frame = "as given (no --calib)"
    if calib is not None:
        gt, est = _to_lidar_frame(gt, est, calib, recorded, notes)
        frame = "LiDAR frame"
    elif recorded is not None and recorded.poses_frame == "lidar":
        notes.append(
            f"{recorded.path} says the estimate is in the LiDAR frame: the ground truth is scored as "
            "given (pass --calib if it is camera-frame, as KITTI's poses/XX.txt are)"
        )
    return FileEvaluation(
        report=evaluate(normalise_to_first(est), normalise_to_first(gt), ate_alignment=ate_alignment),
        est=normalise_to_first(est),
        gt=normalise_to_first(gt),
        frame=frame,
        notes=notes,
        warnings=warnings,
    )


def _to_lidar_frame(
    gt: NDArray[np.float64],
    est: NDArray[np.float64],
    calib: Path,
    recorded: FramesFile | None,
    notes: list[str],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Both trajectories in the LiDAR frame: ``--calib`` says the ground truth is camera-frame, and
    the estimate is converted too unless its ``frames.json`` says it already is LiDAR-frame (converting
    it again would score a trajectory conjugated by ``Tr`` twice)."""
    # The same check as run's: a Tr that is not rigid (a typo, an all-zero line) would give
    # plausible-looking but wrong figures.
    tr = read_tr(calib, required=True)
    assert tr is not None
    if recorded is not None and recorded.poses_frame == "lidar":
        notes.append(
            f"{recorded.path} says the estimate is in the LiDAR frame: --calib converts the ground truth only"
        )
        return camera_to_lidar_poses(gt, tr), est
    return camera_to_lidar_poses(gt, tr), camera_to_lidar_poses(est, tr)


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


FRAMES_FILE = "frames.json"
POSES_FRAMES = ("camera", "lidar")


@dataclass(frozen=True)
class FramesFile:
    """A run's ``frames.json``: which ground-truth frames its estimate holds, and in which frame
    (``camera`` or ``lidar``; None in files written before it was recorded)."""

    path: Path
    indices: list[int]
    poses_frame: str | None


def read_frames_file(path: Path, gt_length: int) -> FramesFile | None:
    """``frames.json`` beside an estimate, checked: every index an integer ``0 <= i < gt_length``
    (Python would read -1 as the last pose), strictly increasing, and a known ``poses_frame``."""
    if not path.is_file():
        return None
    expected = f"expected {{'frame_indices': [int, ...], 'poses_frame': {' or '.join(POSES_FRAMES)}}}"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        raw = data["frame_indices"]
        poses_frame = data.get("poses_frame")
    except (ValueError, KeyError, TypeError, AttributeError) as error:
        raise DataError(f"{path}: {expected}") from error
    if not isinstance(raw, list) or not all(isinstance(i, int) and not isinstance(i, bool) for i in raw):
        raise DataError(f"{path}: 'frame_indices' must be a list of integers; {expected}")
    bad = [i for i in raw if not 0 <= i < gt_length]
    if bad:
        raise DataError(
            f"{path} names frame {bad[0]} but the ground truth has {gt_length} poses "
            f"(expected indices 0 to {gt_length - 1})"
        )
    if any(b <= a for a, b in itertools.pairwise(raw)):
        raise DataError(f"{path}: 'frame_indices' must be strictly increasing (one pose per frame)")
    if poses_frame is not None and poses_frame not in POSES_FRAMES:
        raise DataError(f"{path}: 'poses_frame' is {poses_frame!r}; {expected}")
    return FramesFile(path, list(raw), poses_frame)


def _frame_indices(
    gt_length: int,
    recorded: FramesFile | None,
    frames: str | None,
    stride: int | None,
    notes: list[str],
) -> list[int]:
    """The ground-truth frames the estimate covers: ``--frames/--stride`` or its ``frames.json``; both
    given, they must agree, since one of them is then wrong about the estimate."""
    if frames is not None or stride is not None:
        chosen = select_frames(gt_length, frames, stride or 1)
        if recorded is not None and chosen != recorded.indices:
            raise ConfigError(
                f"{_options(frames, stride)} selects {_span(chosen)} but "
                f"{recorded.path} (beside --est) lists {_span(recorded.indices)}: drop the options or "
                "give the ones the run was given"
            )
        return chosen
    if recorded is not None:
        notes.append(f"frames taken from {recorded.path} ({len(recorded.indices)} frames)")
        return recorded.indices
    return list(range(gt_length))


def _options(frames: str | None, stride: int | None) -> str:
    """The frame options as given, for an error line."""
    given = [f"--frames {frames}" if frames is not None else "", f"--stride {stride}" if stride else ""]
    return " ".join(option for option in given if option)


def _span(indices: list[int]) -> str:
    """``N frames (A..B)``, short enough for one error line."""
    return f"{len(indices)} frames ({indices[0]}..{indices[-1]})" if indices else "no frames"


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
