"""``vcr-odom map``: odometry, loop closure and a pose graph over one sequence, into a result folder."""

from __future__ import annotations

import click
from rich.table import Table

from vcr_odom.cli.options import (
    describe_methods,
    initial_guess_option,
    kiss_polish_options,
    results_option,
    sequence_options,
    vcr_options,
)
from vcr_odom.cli.progress import (
    EXIT_CODES_HELP,
    console,
    exit_interrupted,
    frame_progress,
    interrupt_label,
)
from vcr_odom.cli.run import reject_unused_options, why_unscored
from vcr_odom.cli.tables import _f, ate_cell
from vcr_odom.data.selection import FrameSelection
from vcr_odom.loops.pipeline import MapOutcome, MapSettings, beyond_drift_bound, map_sequence
from vcr_odom.odometry.polish import POLISHES
from vcr_odom.registration import METHOD_NAMES

FIELDS = MapSettings.model_fields


@click.command("map", epilog=describe_methods() + "\n\n" + EXIT_CODES_HELP)
@sequence_options
@click.option(
    "--method",
    type=click.Choice(list(METHOD_NAMES)),
    default=FIELDS["method"].default,
    show_default=True,
    help="The odometry's registration method (as in run).",
)
@click.option(
    "--polish",
    type=click.Choice(list(POLISHES)),
    default=None,
    help="The odometry's polish (as in run; default kiss-icp for vcr and fpfh).",
)
@click.option(
    "--map-voxel", type=click.FloatRange(min=0.05), default=0.5, show_default=True, help="Map voxel size [m]."
)
@click.option(
    "--node-spacing",
    type=click.FloatRange(min=0.1),
    default=FIELDS["node_spacing"].default,
    show_default=True,
    help="Metres driven between pose-graph nodes (a turn of --node-angle degrees also makes one); "
    "loops join nodes, and the map is built from their scans.",
)
@click.option(
    "--node-angle", type=click.FloatRange(min=1.0), default=FIELDS["node_angle"].default, show_default=True
)
@click.option(
    "--revisit-radius",
    type=click.FloatRange(min=0.5),
    default=FIELDS["revisit_radius"].default,
    show_default=True,
    help="A place counts as revisited within this many metres, plus the drift the odometry may have "
    "gathered since (--max-drift).",
)
@click.option(
    "--min-loop-path",
    type=click.FloatRange(min=1.0),
    default=FIELDS["min_loop_path"].default,
    show_default=True,
    help="Metres driven between two visits of a place before they can close a loop.",
)
@click.option(
    "--passage-attempts",
    type=click.IntRange(min=1),
    default=FIELDS["passage_attempts"].default,
    show_default=True,
    help="At most about this many loops tried along one revisited stretch (one every 6 m on shorter "
    "ones): more close more of a long revisit where many fits are turned away, at a registration each.",
)
@click.option(
    "--max-drift",
    type=click.FloatRange(min=0, min_open=True, max=50),
    default=FIELDS["max_drift"].default,
    show_default=True,
    help=f"{FIELDS['max_drift'].description} Raise it for an odometry known to drift more.",
)
@click.option(
    "--max-heading-drift",
    type=click.FloatRange(min=0, min_open=True, max=100),
    default=FIELDS["max_heading_drift"].default,
    show_default=True,
    help=FIELDS["max_heading_drift"].description,
)
@click.option(
    "--no-loops",
    "loops",
    flag_value=False,
    default=True,
    help="Skip loop closure: the odometry and its map only (for comparison).",
)
@click.option(
    "--ground-up/--no-ground-up",
    default=FIELDS["ground_up"].default,
    show_default=True,
    help="Hold each node's tilt to the up measured in its cloud wherever the odometry's tilt drifted "
    "from it, which loops cannot see: the walls' up (used beyond 2.5 deg at 10 % of the nodes) where "
    "walls were seen, else the ground's (beyond 6 deg, a road's grade); turn off among leaning "
    "structures or on stairs.",
)
@initial_guess_option
@kiss_polish_options
@vcr_options
@results_option
@click.pass_context
def map_command(ctx: click.Context, selection: FrameSelection, **options: object) -> None:
    """Build a map that closes its loops: odometry, then places revisited, registered by VCR-Net with
    no initial guess, verified, and a pose graph.

    The result folder holds trajectory_kitti.txt / trajectory_tum.txt (the optimised poses),
    odometry_kitti.txt / odometry_tum.txt (the odometry's), loops.json (every candidate, its scores
    and why it was accepted or rejected), map.ply, metrics.json and trajectory.png.
    """
    settings = MapSettings(selection=selection, **options)
    reject_unused_options(ctx, [settings.method if settings.polish is None else settings.spec])
    outcome = map_sequence(settings, progress=frame_progress)
    if outcome.folder is None:
        exit_interrupted(f"Interrupted ({interrupt_label()}) before the first frame; no result folder kept.")
    if outcome.odometry.interrupted:
        exit_interrupted(
            f"Interrupted ({interrupt_label()}) during the odometry; its "
            f"{len(outcome.odometry.frame_indices)} frames are kept in {outcome.folder} "
            "(result.json: partial)."
        )
    accepted = [d for d in outcome.decisions if d.accepted]
    console.print(
        f"{len(outcome.decisions)} loop candidate(s), {len(accepted)} accepted; "
        f"details in {outcome.folder / 'loops.json'}"
    )
    beyond = beyond_drift_bound(outcome.decisions)
    if beyond:
        console.print(
            f"{beyond} candidate(s) fit but asked the odometry for more than its drift bound "
            f"({settings.max_drift:g} % of the path, {settings.max_heading_drift:g} deg / 100 m): look-alike "
            "places, or an odometry that drifts more (then raise --max-drift / --max-heading-drift)."
        )
    dropped = sum(d.check == "graph" for d in outcome.decisions)
    if dropped:
        console.print(
            f"{dropped} candidate(s) passed every check but the pose graph dropped them: they disagree "
            "with the other loops' cycles or with the odometry (loops.json: graph, with the reason)."
        )
    doubted = sum(d.check == "doubted_submap" for d in outcome.decisions)
    if doubted:
        console.print(
            f"{doubted} candidate(s) not registered: the odometry replaced implausible motions among the "
            f"frames of their submaps ({len(outcome.odometry.flagged_frames)} flagged frame(s) in the "
            "run), so its picture of those places may be bent (loops.json: doubted_submap)."
        )
    if outcome.report is not None and outcome.odometry_report is not None:
        console.print(_scores_table(outcome))
    else:
        console.print(why_unscored(outcome.sequence.gt_poses is not None, len(outcome.poses)))
    seconds = ", ".join(f"{phase} {value:.1f} s" for phase, value in outcome.seconds.items())
    console.print(f"{len(outcome.poses)} frames ({seconds}); results in {outcome.folder}")


def _scores_table(outcome: MapOutcome) -> Table:
    """Odometry and map side by side: the figures loop closure changes."""
    table = Table(title=f"{outcome.sequence.name}: odometry and map", header_style="bold")
    for column in ("", "ATE origin / SE(3) [m]", "end-point [%]", "t_rel [%]", "r_rel [deg/100 m]"):
        table.add_column(column, justify="right" if column else "left")
    for label, report in (("odometry", outcome.odometry_report), ("map", outcome.report)):
        if report is None:
            continue
        table.add_row(
            label,
            ate_cell(report),
            _f(report.endpoint.trans_error_percent, 2),
            _f(report.drift.t_rel_percent, 2),
            _f(report.drift.r_rel_deg_per_100m, 2),
        )
    return table
