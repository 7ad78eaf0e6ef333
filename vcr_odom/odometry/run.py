"""One method over one sequence into a result folder: what ``vcr-odom run`` does, callable from Python."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from pathlib import Path

from pydantic import Field

from vcr_odom.data.base import LidarSequence, Points
from vcr_odom.data.selection import FrameSelection
from vcr_odom.geometry import Transform
from vcr_odom.mapping import VoxelMap
from vcr_odom.metrics import EvaluationReport, evaluate
from vcr_odom.odometry.chain import Consult, Odometry
from vcr_odom.odometry.factory import DEFAULT_CONSULT, build_odometry, canonical_spec
from vcr_odom.odometry.limits import InitialGuess
from vcr_odom.odometry.loop import OdometryRun, run_odometry
from vcr_odom.odometry.outputs import checkpointing, ground_truth_for, run_summary, save_trajectory
from vcr_odom.plots import plot_trajectories
from vcr_odom.registration.base import SequentialOdometry
from vcr_odom.results import create_result_folder, provenance, write_json
from vcr_odom.settings import Settings

Progress = Callable[[int, Transform], None]
ProgressFactory = Callable[[str, int], AbstractContextManager[Progress]]
"""``factory(title, total)`` -> a context manager yielding the per-frame callback of a progress display."""


class RunSettings(Settings):
    """Everything ``vcr-odom run`` is told; dumped as the result folder's ``config.json``."""

    selection: FrameSelection = FrameSelection()
    method: str = "vcr"
    polish: str | None = None
    initial_guess: InitialGuess = InitialGuess.CONSTANT_VELOCITY
    weights: Path | None = None
    device: str = "auto"
    vcr_passes: int | None = Field(default=None, ge=1)
    consult: Consult = DEFAULT_CONSULT
    save_map: Path | None = None
    map_voxel: float = Field(default=0.5, ge=0.05)
    results_dir: Path = Path("results")

    @property
    def spec(self) -> str:
        """``method+polish`` with the default polish spelled out."""
        return canonical_spec(self.method if self.polish is None else f"{self.method}+{self.polish}")


@dataclass
class RunOutcome:
    folder: Path
    sequence: LidarSequence
    run: OdometryRun
    report: EvaluationReport | None
    voxel_map: VoxelMap | None


def vcr_options(method: str, weights: Path | None, device: str, passes: int | None) -> dict[str, object]:
    """Constructor options of ``method`` from the VCR-Net options (other methods take none)."""
    return {"weights": weights, "device": device, "passes": passes} if method == "vcr" else {}


def run_sequence(settings: RunSettings, progress: ProgressFactory | None = None) -> RunOutcome:
    """Build the method, run it over the selected frames and write the result folder."""
    sequence = settings.selection.open()
    indices = settings.selection.indices(sequence)
    spec = settings.spec
    odometry = build_odometry(
        spec,
        initial_guess=settings.initial_guess,
        consult=settings.consult,
        **vcr_options(spec.partition("+")[0], settings.weights, settings.device, settings.vcr_passes),
    )
    folder = create_result_folder(settings.results_dir, f"run_{sequence.name}_{spec}")
    write_json(
        folder / "config.json",
        provenance({"command": "run", "sequence": sequence.name, **settings.to_dict()}),
    )
    voxel_map = VoxelMap(voxel_size=settings.map_voxel) if settings.save_map else None
    title = f"{spec} on {sequence.name}"
    with progress(title, len(indices)) if progress is not None else nullcontext(None) as advance:
        run, report = run_and_save(sequence, odometry, indices, folder, progress=advance, voxel_map=voxel_map)
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
) -> tuple[OdometryRun, EvaluationReport | None]:
    """Run one method, write its trajectory, metrics and plot into ``folder``.

    With ``voxel_map`` each registered scan is added to it as it comes (the frame is not read twice);
    the plot then shows the trajectory over a top-down view of the map.
    """
    checkpoint = checkpointing(folder, sequence)

    def on_frame(index: int, pose: Transform, points: Points) -> None:
        checkpoint(index, pose)
        if voxel_map is not None:
            voxel_map.add(points, pose)
        if progress is not None:
            progress(index, pose)

    run = run_odometry(sequence, method, frame_indices, on_frame=on_frame)
    if len(run.poses) == 0:
        return run, None
    save_trajectory(folder, run, sequence)
    gt = ground_truth_for(sequence, run.frame_indices)
    report = evaluate(run.poses, gt) if gt is not None and len(run.poses) >= 2 else None
    scores = report.to_dict() if report is not None else {"ground_truth": None}
    write_json(folder / "metrics.json", {"run": run_summary(run), **scores})
    plot_trajectories(
        folder / "trajectory.png",
        {run.method: run.poses},
        gt,
        title=plot_title or f"{sequence.name}: {run.method}",
        background_xy=voxel_map.top_down() if voxel_map is not None and len(voxel_map) else None,
    )
    return run, report
