"""One method over one sequence into a result folder: what ``vcr-odom run`` does, callable from Python.

Order matters for a user's mistakes: every input and output is checked (the sequence, the frames, the
method and its weights, ``--results-dir``, ``--save-map``) before the result folder exists, so a run
that cannot start leaves no folder behind; one that stops part-way leaves a folder marked ``partial``
(see :mod:`vcr_odom.results`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from vcr_odom.data.base import LidarSequence, Points
from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import ConfigError, VcrOdomError
from vcr_odom.geometry import Transform
from vcr_odom.mapping import VoxelMap, check_map_outside_scans, check_map_path
from vcr_odom.metrics import EvaluationReport, evaluate
from vcr_odom.odometry.chain import Consult, Odometry
from vcr_odom.odometry.engine_choice import AUTO, EngineChoice, engine_for
from vcr_odom.odometry.factory import DEFAULT_CONSULT, build_odometry, canonical_spec, parse_method_spec
from vcr_odom.odometry.frame_loop import OdometryRun, run_odometry
from vcr_odom.odometry.limits import InitialGuess
from vcr_odom.odometry.outputs import Checkpoints, ground_truth_for, run_summary, save_trajectory
from vcr_odom.plots import plot_trajectories
from vcr_odom.registration.base import SequentialOdometry
from vcr_odom.results import (
    check_output_folder,
    create_result_folder,
    deferred_interrupts,
    holds_trajectory,
    interruption_reason,
    note_kept,
    point_latest_at,
    remove_result_folder,
    result_unit,
    write_json,
    write_marker,
)
from vcr_odom.settings import Settings

Progress = Callable[[int, Transform], None]
ProgressFactory = Callable[[str, int], AbstractContextManager[Progress]]
"""``factory(title, total)`` -> a context manager yielding the per-frame callback of a progress display."""
FrameHook = Callable[[int, Transform, Points, Mapping[str, Any]], None]
"""``hook(index, pose, points, info)`` once per frame as the odometry placed it (a live 3-D view):
``info`` is the odometry's ``last_info`` then, the frame's own except within a GPU batch (the batch's last)."""


class RunSettings(Settings):
    """Everything ``vcr-odom run`` is told; dumped as the result folder's ``config.json``."""

    selection: FrameSelection = FrameSelection()
    method: str = "vcr"
    polish: str | None = None
    initial_guess: InitialGuess = InitialGuess.CONSTANT_VELOCITY
    weights: Path | None = None
    device: str = "auto"
    vcr_passes: int | None = Field(default=None, ge=1)
    vcr_points: int | None = Field(default=None, ge=4)
    consult: Consult = DEFAULT_CONSULT
    polish_voxel: float | None = Field(default=None, gt=0)
    point_to_plane: Literal["auto", "on", "off"] = "auto"
    polish_engine: EngineChoice = "kiss-icp"
    save_map: Path | None = None
    map_voxel: float = Field(default=0.5, ge=0.05)
    results_dir: Path = Path("results")

    @property
    def spec(self) -> str:
        """``method+polish`` with the default polish spelled out."""
        return canonical_spec(self.method if self.polish is None else f"{self.method}+{self.polish}")


@dataclass
class RunOutcome:
    """``folder`` is None where the run stopped before its first frame (nothing was kept)."""

    folder: Path | None
    sequence: LidarSequence
    run: OdometryRun
    report: EvaluationReport | None
    voxel_map: VoxelMap | None


def vcr_options(
    method: str, weights: Path | None, device: str, passes: int | None, points: int | None = None
) -> dict[str, object]:
    """Constructor options of ``method`` from the VCR-Net options (other methods take none)."""
    if method != "vcr":
        return {}
    return {"weights": weights, "device": device, "passes": passes, "num_points": points}


def kiss_polish_options(
    polish_voxel: float | None, point_to_plane: str, engine: str = "kiss-icp"
) -> dict[str, object]:
    """The kiss-icp polish's constructor options for ``--polish-voxel``, ``--point-to-plane`` and
    ``--polish-engine`` (``auto``, no voxel and kiss-icp's engine give none: the polish decides on the
    first frame; ``--polish-engine auto`` is chosen by :func:`engine_for` where the run's times are
    known, so here it is a default)."""
    options: dict[str, object] = {}
    if engine not in ("kiss-icp", AUTO):
        options["engine"] = engine
    if polish_voxel is not None:
        options["voxel_size"] = polish_voxel
    if point_to_plane != "auto":
        options["point_to_plane"] = point_to_plane == "on"
    return options


POLISH_FLAGS = {
    "voxel_size": "--polish-voxel",
    "point_to_plane": "--point-to-plane",
    "engine": "--polish-engine",
}
"""The option that sets each of :func:`kiss_polish_options`' constructor options."""


def polish_flags(options: dict[str, object]) -> list[str]:
    """The command-line options behind ``options`` (:func:`kiss_polish_options`' result), to name them."""
    return [flag for key, flag in POLISH_FLAGS.items() if key in options]


def polish_options(settings: RunSettings, timestamps: NDArray[np.float64] | None = None) -> dict[str, object]:
    """The polish's constructor options (:func:`kiss_polish_options`, the engine chosen by
    :func:`engine_for` from the run's frame ``timestamps``); a ConfigError naming the options where the
    odometry has no kiss-icp polish, rather than ignoring them."""
    voxel, plane = settings.polish_voxel, settings.point_to_plane
    if parse_method_spec(settings.spec)[1] == "kiss-icp":
        return kiss_polish_options(voxel, plane, engine_for(settings.polish_engine, timestamps))
    flags = polish_flags(kiss_polish_options(voxel, plane, settings.polish_engine))
    if flags:
        raise ConfigError(
            f"{', '.join(flags)} {'applies' if len(flags) == 1 else 'apply'} to the kiss-icp polish, and "
            f"{settings.spec} has none (the kiss-icp polish is the default of vcr and fpfh, or +kiss-icp)"
        )
    return {}


def method_for(
    settings: RunSettings, timestamps: NDArray[np.float64] | None = None
) -> Odometry | SequentialOdometry:
    """The odometry ``settings`` ask for (its weights loaded: a bad file fails here, before any folder);
    ``timestamps``: the run's frames', which ``--polish-engine auto`` needs."""
    return build_odometry(
        settings.spec,
        initial_guess=settings.initial_guess,
        polish_options=polish_options(settings, timestamps),
        consult=settings.consult,
        **vcr_options(
            settings.method,
            settings.weights,
            settings.device,
            settings.vcr_passes,
            settings.vcr_points,
        ),
    )


def run_sequence(
    settings: RunSettings, progress: ProgressFactory | None = None, on_frame: FrameHook | None = None
) -> RunOutcome:
    """Check everything, build the method, run it over the selected frames and write the result folder."""
    check_output_folder(settings.results_dir, "--results-dir")
    if settings.save_map is not None:
        check_map_path(settings.save_map)
    sequence = settings.selection.open()
    if settings.save_map is not None:
        check_map_outside_scans(settings.save_map, sequence)
    indices = settings.selection.indices(sequence)
    spec = settings.spec
    odometry = method_for(settings, sequence.timestamps[indices])
    folder = create_result_folder(
        settings.results_dir,
        f"run_{sequence.label}_{spec}",
        {"command": "run", "sequence": sequence.name, **settings.to_dict()},
        frames_selected=len(indices),
    )
    voxel_map = VoxelMap(voxel_size=settings.map_voxel) if settings.save_map else None
    title = f"{spec} on {sequence.name}"
    try:
        with progress(title, len(indices)) if progress is not None else nullcontext(None) as advance:
            run, report = run_and_save(
                sequence,
                odometry,
                indices,
                folder,
                progress=advance,
                voxel_map=voxel_map,
                on_saved=lambda: point_latest_at(settings.results_dir, folder),
                hook=on_frame,
            )
    except BaseException as error:
        if not holds_trajectory(folder):  # failed before its first frame: nothing worth keeping
            remove_result_folder(folder)
            note_kept(error, "no result folder was kept")
        else:
            note_kept(error, f"the partial result is kept in {folder} (result.json: partial)")
        raise
    if not run.frame_indices:
        remove_result_folder(folder)
        return RunOutcome(None, sequence, run, None, None)
    if voxel_map is not None and settings.save_map is not None:
        voxel_map.save(settings.save_map)
    return RunOutcome(folder, sequence, run, report, voxel_map)


def run_and_save(
    sequence: LidarSequence,
    method: Odometry | SequentialOdometry,
    frame_indices: Sequence[int],
    folder: Path,
    *,
    progress: Progress | None = None,
    plot_title: str = "",
    voxel_map: VoxelMap | None = None,
    on_saved: Callable[[], Any] | None = None,
    hook: FrameHook | None = None,
) -> tuple[OdometryRun, EvaluationReport | None]:
    """Run one method, publish its trajectory, metrics and plot into ``folder`` as one unit.

    Every :data:`~vcr_odom.odometry.outputs.CHECKPOINT_EVERY_FRAMES` frames the trajectory so far is
    published as ``partial``; an error or Ctrl-C part-way publishes what was done as ``partial``
    (with the reason) before it propagates, and further interrupts wait until it is written.
    ``on_saved`` runs after each publication that holds frames.
    With ``voxel_map`` each registered scan is added to it as it comes (the frame is not read twice);
    the plot then shows the trajectory over a top-down view of the map.
    """
    selected = len(frame_indices)
    checkpoints = Checkpoints(folder, sequence, selected, method=method.name, on_saved=on_saved)

    def on_frame(index: int, pose: Transform, points: Points) -> None:
        checkpoints(index, pose)
        if voxel_map is not None:
            voxel_map.add(points, pose)
        if progress is not None:
            progress(index, pose)
        if hook is not None:
            hook(index, pose, points, getattr(method, "last_info", {}))

    try:
        run = run_odometry(sequence, method, frame_indices, on_frame=on_frame)
    except BaseException as error:
        with deferred_interrupts():
            checkpoints.save(
                f"{interruption_reason(error)} (after {checkpoints.frames_done} of {selected} frames)"
            )
        if isinstance(error, Exception):
            _name_the_frame(error, method, frame_indices, checkpoints.frames_done)
        raise
    done = len(run.frame_indices)
    reason = (
        f"{run.interruption or 'interrupted'} after {done} of {selected} frames" if run.interrupted else ""
    )
    if done == 0:
        if run.interrupted:  # the folder's first marker said "started": say why it holds nothing
            with deferred_interrupts(), result_unit(folder) as unit:
                write_marker(unit, "partial", 0, selected, reason, method=run.method)
        return run, None
    # Stopped already: a further interrupt waits until what was done is written (scores, plot).
    with deferred_interrupts() if run.interrupted else nullcontext():
        return _score_and_save(run, sequence, folder, selected, reason, plot_title, voxel_map, on_saved)


def _score_and_save(
    run: OdometryRun,
    sequence: LidarSequence,
    folder: Path,
    selected: int,
    reason: str,
    plot_title: str,
    voxel_map: VoxelMap | None,
    on_saved: Callable[[], Any] | None,
) -> tuple[OdometryRun, EvaluationReport | None]:
    """Score ``run`` where there is ground truth and publish it with its metrics and plot: ``complete``
    when every one of the ``selected`` frames was done, else ``partial`` with ``reason``."""
    gt = ground_truth_for(sequence, run.frame_indices)
    report = evaluate(run.poses, gt) if gt is not None and len(run.poses) >= 2 else None
    scores = report.to_dict() if report is not None else unscored(gt is not None, len(run.poses))
    done = len(run.frame_indices)
    status = "partial" if run.interrupted or done < selected else "complete"

    def scores_and_plot(unit: Path) -> None:
        write_json(unit / "metrics.json", {"run": run_summary(run), **scores})
        plot_trajectories(
            unit / "trajectory.png",
            {run.method: run.poses},
            gt,
            title=plot_title or f"{sequence.name}: {run.method}",
            background_xy=voxel_map.top_down() if voxel_map is not None and len(voxel_map) else None,
        )

    try:
        save_trajectory(
            folder,
            run,
            sequence,
            frames_selected=selected,
            status=status,
            reason=reason,
            extras=scores_and_plot,
        )
    except BaseException as error:  # e.g. Ctrl-C while plotting: keep the trajectory, say so
        with deferred_interrupts():
            save_trajectory(
                folder,
                run,
                sequence,
                frames_selected=selected,
                status="partial",
                reason=f"{interruption_reason(error)} while writing the scores and plot",
            )
        raise
    if on_saved is not None:
        on_saved()
    return run, report


def unscored(has_ground_truth: bool, frames: int) -> dict[str, Any]:
    """``metrics.json``'s scores where there are none: no ground truth, or too few frames to score
    (a run interrupted after its first frame), which is not the same thing."""
    if not has_ground_truth:
        return {"ground_truth": None}
    return {
        "ground_truth": "available",
        "not_scored": f"too short to score: {frames} frame(s), 2 or more needed",
    }


def _name_the_frame(
    error: Exception, method: Odometry | SequentialOdometry, frame_indices: Sequence[int], done: int
) -> None:
    """Say which frame ``error`` stopped the run at: the library's own errors get it in their one-line
    message, others (a bug) as a note under the traceback. Frames come a batch at a time (VCR-Net on a
    GPU), so past the first ``done`` frames it is the next batch's."""
    batch = method.batch_size if isinstance(method, Odometry) else 1
    stuck = list(frame_indices[done : done + max(batch, 1)])
    if not stuck:
        return
    where = f"frame {stuck[0]}" if len(stuck) == 1 else f"one of frames {stuck[0]}..{stuck[-1]}"
    if isinstance(error, VcrOdomError):
        error.args = (f"{where}: {error}", *error.args[1:])
    else:
        error.add_note(f"vcr-odom: the run stopped at {where}")
