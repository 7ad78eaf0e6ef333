"""Rich tables for evaluation reports and method comparisons (angles in degrees, distances in metres)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from rich.markup import escape
from rich.table import Table

from vcr_odom.evaluation.pairs import PairProtocolResult
from vcr_odom.metrics import EvaluationReport


def _f(value: float, digits: int = 3) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


ALIGNMENT_NAMES = {
    "origin": "first poses aligned, KITTI convention",
    "se3": "SE(3)-aligned, as evo_ape -a and kiss-icp",
    "none": "no alignment",
}
"""How a table names each ATE alignment: the same trajectory reads differently under each."""

ATE_CAPTION = (
    "ATE origin / SE(3): RMSE with the first poses aligned (KITTI convention) / after evo's SE(3) "
    "Umeyama alignment (what evo_ape -a and kiss-icp report)"
)


def report_table(report: EvaluationReport, title: str = "Evaluation") -> Table:
    """One method against ground truth, every figure with its unit."""
    table = Table(title=title, show_header=True, header_style="bold")
    table.add_column("metric")
    table.add_column("value", justify="right")
    drift, end, pairs, dcp, ate = (
        report.drift,
        report.endpoint,
        report.pairs,
        report.pairs.dcp,
        report.ate_rpe,
    )
    rows = [
        ("poses / path length", f"{report.num_poses} / {report.path_length_m:.1f} m"),
        ("drift over short segments (see below)" if drift.short_sequence else drift.label, ""),
        ("  t_rel [%]", _f(drift.t_rel_percent)),
        ("  r_rel [deg/100 m]", _f(drift.r_rel_deg_per_100m)),
        ("  segments", str(drift.num_segments)),
        ("end-point drift [% of path]", _f(end.trans_error_percent)),
        ("end-point error [m] / [deg]", f"{_f(end.trans_error_m)} / {_f(end.rot_error_deg)}"),
        (f"per-pair errors ({pairs.num_pairs} pairs, stride {pairs.stride})", ""),
        ("  rotation RMSE / MAE [deg]", f"{_f(pairs.rot_rmse_deg)} / {_f(pairs.rot_mae_deg)}"),
        ("  translation RMSE / MAE [m]", f"{_f(pairs.trans_rmse_m)} / {_f(pairs.trans_mae_m)}"),
        (
            f"  success (< {pairs.success_rot_threshold_deg:g} deg and < {pairs.success_trans_threshold_m:g} m)",
            f"{100 * pairs.success_rate:.1f} %",
        ),
        ("DCP-style (paper Table III)", ""),
        ("  Euler RMSE / MAE [deg]", f"{_f(dcp.euler_rmse_deg)} / {_f(dcp.euler_mae_deg)}"),
        ("  translation MSE / MAE [m², m]", f"{_f(dcp.trans_mse_m2, 5)} / {_f(dcp.trans_mae_m)}"),
        (f"ATE RMSE [m] ({ALIGNMENT_NAMES[ate.ate_alignment]})", _f(ate.ate_trans_rmse_m)),
        *(
            [(f"ATE RMSE [m] ({ALIGNMENT_NAMES['se3']})", _f(ate.ate_se3_trans_rmse_m))]
            if ate.ate_alignment != "se3"
            else []
        ),
        (
            f"RPE RMSE (delta {ate.rpe_delta_frames}) [m] / [deg]",
            f"{_f(ate.rpe_trans_rmse_m)} / {_f(ate.rpe_rot_rmse_deg)}",
        ),
    ]
    if drift.short_sequence:
        table.caption = drift.label
    for name, value in rows:
        table.add_row(escape(name), value)  # names hold units in [brackets], not markup
    return table


@dataclass
class ComparisonRow:
    """``closures``: loop closures of a SLAM method (None for odometry); ``status``: why a row has no
    figures (``not installed: pip install ...``; the table shows the part before the colon)."""

    method: str
    needs_initial_guess: bool
    report: EvaluationReport | None
    frames_per_second: float
    interrupted: bool = False
    flagged: int = 0
    closures: int | None = None
    status: str = ""


def comparison_table(rows: Sequence[ComparisonRow], title: str) -> Table:
    """Methods side by side on the same frames; a method that loses track shows it in every column.
    A ``closures`` column appears when a SLAM method (KISS-SLAM) is among the rows."""
    table = Table(title=title, header_style="bold", caption=ATE_CAPTION)
    slam = any(row.closures is not None for row in rows)
    headers = (
        "method",
        "prior",
        "rot RMSE / MAE [deg]",
        "trans RMSE / MAE [m]",
        "success",
        "t_rel [%]",
        "r_rel [deg/100m]",
        "end-point [%]",
        "ATE origin / SE(3) [m]",
        "flagged",
        *(("closures",) if slam else ()),
        "fps",
    )
    for header in headers:
        table.add_column(escape(header), justify="left" if header in ("method", "prior") else "right")
    for row in rows:
        prior = "init guess" if row.needs_initial_guess else "none (global)"
        name = row.method + (" (interrupted)" if row.interrupted else "")
        closures = (("–" if row.closures is None else str(row.closures)),) if slam else ()
        if row.status:  # "not installed: pip install ..." -> "(not installed)"; the caller prints the rest
            table.add_row(f"{name} ({row.status.partition(':')[0]})", "–", *["–"] * 8, *closures, "–")
            continue
        if row.report is None:
            table.add_row(name, prior, *["–"] * 7, str(row.flagged), *closures, _f(row.frames_per_second, 1))
            continue
        pairs, drift = row.report.pairs, row.report.drift
        table.add_row(
            name,
            prior,
            f"{_f(pairs.rot_rmse_deg)} / {_f(pairs.rot_mae_deg)}",
            f"{_f(pairs.trans_rmse_m)} / {_f(pairs.trans_mae_m)}",
            f"{100 * pairs.success_rate:.0f} %",
            _f(drift.t_rel_percent, 2),
            _f(drift.r_rel_deg_per_100m, 2),
            _f(row.report.endpoint.trans_error_percent, 2),
            ate_cell(row.report),
            str(row.flagged),
            *closures,
            _f(row.frames_per_second, 1),
        )
    return table


def ate_cell(report: EvaluationReport) -> str:
    """``first-pose-aligned / SE(3)-aligned`` ATE RMSE (a compare row is always aligned at the first
    pose; a report from elsewhere with another alignment still shows its SE(3) figure second)."""
    ate = report.ate_rpe
    first = ate.ate_trans_rmse_m if ate.ate_alignment == "origin" else None
    return f"{_f(first)} / {_f(ate.ate_se3_trans_rmse_m)}"


def pair_protocol_table(results: Mapping[str, PairProtocolResult], title: str) -> Table:
    """The paper's Table III layout: one row per method on the same randomly moved pairs."""
    table = Table(title=title, header_style="bold")
    headers = ("method", "rot RMSE / MAE [deg]", "trans RMSE / MAE [m]", "success", "ms / pair")
    for header in headers:
        table.add_column(escape(header), justify="left" if header == "method" else "right")
    for name, result in results.items():
        errors = result.errors
        table.add_row(
            name,
            f"{_f(errors.rot_rmse_deg)} / {_f(errors.rot_mae_deg)}",
            f"{_f(errors.trans_rmse_m)} / {_f(errors.trans_mae_m)}",
            f"{100 * errors.success_rate:.0f} %",
            _f(result.ms_per_pair_mean, 1),
        )
    return table
