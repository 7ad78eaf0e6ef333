"""``vcr-odom eval``: score a trajectory file against ground truth."""

from __future__ import annotations

import json
from pathlib import Path

import click

from vcr_odom.cli.progress import console, notes
from vcr_odom.cli.tables import report_table
from vcr_odom.evaluation import evaluate_files
from vcr_odom.plots import plot_pair_errors, plot_trajectories
from vcr_odom.results import write_json


@click.command("eval")
@click.option(
    "--gt",
    "gt_path",
    type=click.Path(path_type=Path, exists=True, dir_okay=False),
    required=True,
    help="Ground-truth poses, KITTI format.",
)
@click.option(
    "--est",
    "est_path",
    type=click.Path(path_type=Path, exists=True, dir_okay=False),
    required=True,
    help="Estimated poses, KITTI format (e.g. a run's trajectory_kitti.txt).",
)
@click.option(
    "--calib",
    type=click.Path(path_type=Path, exists=True, dir_okay=False),
    help="KITTI calib.txt: both files are camera-frame poses; evaluate in the LiDAR frame.",
)
@click.option(
    "--frames",
    default=None,
    metavar="A:B",
    help="Ground-truth frames the estimate covers (as given to run). Default: from frames.json "
    "beside --est when present, else all.",
)
@click.option(
    "--stride",
    type=click.IntRange(min=1),
    default=None,
    help="Ground-truth stride the estimate used (as given to run).",
)
@click.option(
    "--align",
    type=click.Choice(["origin", "se3", "none"]),
    default="origin",
    show_default=True,
    help="Alignment before ATE: first poses made equal (KITTI convention), evo's Umeyama SE(3), or none.",
)
@click.option(
    "--json",
    "json_path",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Write all figures (and per-pair errors) to this JSON file; '-' prints it.",
)
@click.option(
    "--plot",
    "plot_path",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Write a top-down trajectory plot (PNG) and, beside it, a per-pair error plot.",
)
def evaluate(
    gt_path: Path,
    est_path: Path,
    calib: Path | None,
    frames: str | None,
    stride: int | None,
    align: str,
    json_path: Path | None,
    plot_path: Path | None,
) -> None:
    """KITTI drift, per-pair RMSE/MAE (and the paper's DCP-style figures), ATE and RPE."""
    evaluation = evaluate_files(
        gt_path, est_path, calib=calib, frames=frames, stride=stride, ate_alignment=align
    )
    for note in evaluation.notes:
        notes.print(f"[dim]{note}")
    if json_path is not None and str(json_path) == "-":
        click.echo(json.dumps(evaluation.report.to_dict(include_arrays=True), indent=2))
        return
    console.print(
        report_table(evaluation.report, title=f"{est_path.name} vs {gt_path.name} ({evaluation.frame})")
    )
    if json_path is not None:
        write_json(json_path, evaluation.report.to_dict(include_arrays=True))
        console.print(f"figures written to {json_path}")
    if plot_path is not None:
        plot_trajectories(plot_path, {est_path.stem: evaluation.est}, evaluation.gt, title=est_path.name)
        errors_path = plot_path.with_name(plot_path.stem + "_pair_errors.png")
        pairs = evaluation.report.pairs
        plot_pair_errors(
            errors_path, {est_path.stem: pairs.rot_errors_deg}, {est_path.stem: pairs.trans_errors_m}
        )
        console.print(f"plots written to {plot_path} and {errors_path}")
