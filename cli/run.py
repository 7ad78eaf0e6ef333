"""``vcr-odom run``: one method over one sequence, into a result folder."""

from __future__ import annotations

from pathlib import Path

import click

from vcr_odom.cli.options import (
    describe_methods,
    initial_guess_option,
    results_option,
    sequence_options,
    vcr_options,
)
from vcr_odom.cli.progress import console, frame_progress
from vcr_odom.cli.tables import report_table
from vcr_odom.data.selection import FrameSelection
from vcr_odom.odometry.factory import DEFAULT_GLOBAL_POLISH
from vcr_odom.odometry.polish import POLISHES
from vcr_odom.odometry.run import RunSettings, run_sequence
from vcr_odom.registration import METHOD_NAMES


@click.command("run", epilog=describe_methods())
@sequence_options
@click.option(
    "--method",
    type=click.Choice(list(METHOD_NAMES)),
    default=RunSettings.model_fields["method"].default,
    show_default=True,
    help="Registration method (see the list below).",
)
@click.option(
    "--polish",
    "--refine",
    "polish",
    type=click.Choice(list(POLISHES)),
    default=None,
    help="Polish each pairwise estimate: open3d point-to-plane ICP, or kiss-icp against its local map. "
    f"Default: {DEFAULT_GLOBAL_POLISH} for the global methods (vcr, fpfh), none for the local ones. "
    "(--refine is the same option's older name.)",
)
@click.option(
    "--save-map",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Accumulate the registered scans into a voxel map and write it (.ply or .pcd).",
)
@click.option(
    "--map-voxel", type=click.FloatRange(min=0.05), default=0.5, show_default=True, help="Map voxel size [m]."
)
@initial_guess_option
@vcr_options
@results_option
def run(selection: FrameSelection, **options: object) -> None:
    """Estimate the trajectory of a sequence and write it (KITTI + TUM), metrics and a plot."""
    settings = RunSettings(selection=selection, **options)
    outcome = run_sequence(settings, progress=frame_progress)
    result, report = outcome.run, outcome.report
    if outcome.voxel_map is not None:
        console.print(
            f"map of {len(outcome.voxel_map)} points ({settings.map_voxel:g} m voxels) written to {settings.save_map}"
        )
    if result.interrupted:
        console.print(f"[yellow]Interrupted after {len(result.frame_indices)} frames; partial results kept.")
    if result.flagged_frames:
        console.print(
            f"[yellow]{len(result.flagged_frames)} frame(s) flagged (implausible motion replaced by the "
            f"previous one): {result.flagged_frames[:20]}; reasons in metrics.json"
        )
    if report is not None:
        title = f"{settings.spec} on {outcome.sequence.name} (stride {selection.stride})"
        console.print(report_table(report, title=title))
    else:
        console.print("No ground truth for this sequence: trajectory written without scores.")
    console.print(
        f"{len(result.frame_indices)} frames at {result.frames_per_second:.1f} fps; results in {outcome.folder}"
    )
