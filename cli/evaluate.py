"""``vcr-odom eval``: score a trajectory file against ground truth."""

from __future__ import annotations

import json
from pathlib import Path

import click
from rich.markup import escape

from vcr_odom.cli.options import results_dir_option
from vcr_odom.cli.progress import EXIT_CODES_HELP, console, notes
from vcr_odom.cli.tables import report_table
from vcr_odom.evaluation.files import evaluate_files, write_evaluation
from vcr_odom.results import check_output_file, latest_trajectory, recorded_calibration


@click.command("eval", epilog=EXIT_CODES_HELP)
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
    default=None,
    help="Estimated poses, KITTI format (e.g. a run's trajectory_kitti.txt). Default: the latest "
    "run's, RESULTS_DIR/latest/trajectory_kitti.txt (the file scored is named).",
)
@results_dir_option(
    "Where run, map and compare wrote their result folders: its 'latest' link names the run "
    "scored when --est is not given."
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
    help="Write a top-down trajectory plot (.png) and, beside it, a per-pair error plot.",
)
def evaluate(
    gt_path: Path,
    est_path: Path | None,
    results_dir: Path,
    calib: Path | None,
    frames: str | None,
    stride: int | None,
    align: str,
    json_path: Path | None,
    plot_path: Path | None,
) -> None:
    """KITTI drift, per-pair RMSE/MAE (and the paper's DCP-style figures), ATE and RPE.

    Warns when --est comes from a run whose result.json says partial, or has no result.json.
    """
    if est_path is None:
        est_path = latest_trajectory(results_dir)
        notes.print(f"scoring the latest run: {escape(str(est_path))}", highlight=False, soft_wrap=True)
        if calib is None and (calib := recorded_calibration(est_path.parent)) is not None:
            notes.print(
                f"with the calibration it read: {escape(str(calib))}", highlight=False, soft_wrap=True
            )
    to_stdout = json_path is not None and str(json_path) == "-"
    if json_path is not None and not to_stdout:
        check_output_file(json_path, "--json")
    if plot_path is not None:
        check_output_file(plot_path, "--plot", (".png",))
    evaluation = evaluate_files(
        gt_path, est_path, calib=calib, frames=frames, stride=stride, ate_alignment=align
    )
    for note in evaluation.notes:
        notes.print(f"[dim]{note}")
    for warning in evaluation.warnings:
        notes.print(f"[yellow]warning:[/] {escape(warning)}", highlight=False)
    if to_stdout:
        click.echo(json.dumps(evaluation.report.to_dict(include_arrays=True), indent=2))
        return
    console.print(
        report_table(evaluation.report, title=f"{est_path.name} vs {gt_path.name} ({evaluation.frame})")
    )
    written = write_evaluation(evaluation, est_path.stem, json_path=json_path, plot_path=plot_path)
    if written:
        console.print(f"written: {', '.join(str(path) for path in written)}")
