"""``vcr-odom run``: one method over one sequence, into a result folder."""

from __future__ import annotations

from pathlib import Path

import click

from vcr_odom.cli.options import (
    FrameSelection,
    describe_methods,
    initial_guess_option,
    method_options,
    results_option,
    sequence_options,
    vcr_options,
)
from vcr_odom.cli.progress import console, frame_progress
from vcr_odom.cli.tables import report_table
from vcr_odom.mapping import VoxelMap
from vcr_odom.odometry import InitialGuess
from vcr_odom.pipeline import build_odometry, run_and_save
from vcr_odom.refine import REFINE_CHOICES
from vcr_odom.registration import METHOD_NAMES
from vcr_odom.results import create_result_folder, provenance, write_json

DEFAULT_METHOD = "vcr"
DEFAULT_GLOBAL_REFINE = "kiss-icp"
"""The polish a global method (vcr, fpfh) gets unless ``--refine`` says otherwise; README "Choosing the
polish" gives the measurements behind it. Local methods (ICP, kiss-icp) get none."""


GLOBAL_METHODS = ("vcr", "fpfh")


def default_refine(method: str) -> str:
    """``--refine`` when not given: the chosen polish for a global method, none for a local one."""
    return DEFAULT_GLOBAL_REFINE if method in GLOBAL_METHODS else "none"


@click.command("run", epilog=describe_methods())
@sequence_options
@click.option(
    "--method",
    type=click.Choice(list(METHOD_NAMES)),
    default=DEFAULT_METHOD,
    show_default=True,
    help="Registration method (see the list below).",
)
@click.option(
    "--refine",
    type=click.Choice(list(REFINE_CHOICES)),
    default=None,
    help="Polish each pairwise estimate: open3d point-to-plane ICP, or kiss-icp against its local map. "
    f"Default: {DEFAULT_GLOBAL_REFINE} for the global methods (vcr, fpfh), none for the local ones.",
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
def run(
    selection: FrameSelection,
    method: str,
    refine: str | None,
    save_map: Path | None,
    map_voxel: float,
    initial_guess: str,
    weights: Path | None,
    device: str,
    vcr_passes: int | None,
    results_dir: Path,
) -> None:
    """Estimate the trajectory of a sequence and write it (KITTI + TUM), metrics and a plot."""
    sequence = selection.open()
    indices = selection.indices(sequence)
    refine = refine or default_refine(method)
    spec = method if refine == "none" else f"{method}+{refine}"
    odometry = build_odometry(
        spec, InitialGuess(initial_guess), **method_options(method, weights, device, vcr_passes)
    )
    out = create_result_folder(results_dir, f"run_{sequence.name}_{spec}")
    config = {
        "command": "run",
        "sequence": sequence.name,
        **selection.as_config(),
        "method": method,
        "refine": refine,
        "initial_guess": initial_guess,
        "weights": weights,
        "device": device,
        "vcr_passes": vcr_passes,
    }
    write_json(out / "config.json", provenance(config))
    with frame_progress(f"{spec} on {sequence.name}", len(indices)) as advance:
        voxel_map = VoxelMap(voxel_size=map_voxel) if save_map else None
        result, report = run_and_save(sequence, odometry, indices, out, progress=advance, voxel_map=voxel_map)
    if voxel_map is not None and save_map is not None:
        voxel_map.save(save_map)
        console.print(f"map of {len(voxel_map)} points ({map_voxel:g} m voxels) written to {save_map}")
    if result.interrupted:
        console.print(f"[yellow]Interrupted after {len(result.frame_indices)} frames; partial results kept.")
    if result.flagged_frames:
        console.print(
            f"[yellow]{len(result.flagged_frames)} frame(s) flagged (implausible motion replaced by the "
            f"previous one): {result.flagged_frames[:20]}; reasons in metrics.json"
        )
    if report is not None:
        console.print(report_table(report, title=f"{spec} on {sequence.name} (stride {selection.stride})"))
    else:
        console.print("No ground truth for this sequence: trajectory written without scores.")
    console.print(
        f"{len(result.frame_indices)} frames at {result.frames_per_second:.1f} fps; results in {out}"
    )
