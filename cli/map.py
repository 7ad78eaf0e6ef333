"""``vcr-odom map``: odometry, loop closure and a pose graph over one sequence, into a result folder."""

from __future__ import annotations

from pathlib import Path

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
from vcr_odom.cli.run import print_flagged_frames, reject_unused_options, why_unscored
from vcr_odom.cli.tables import _f, ate_cell
from vcr_odom.cli.view import finish_live_view, open_live_view, pop_live_options, visualize_options
from vcr_odom.data.selection import FrameSelection
from vcr_odom.evaluation.rows import LOOPS_SUFFIX
from vcr_odom.loops.settings import LoopSettings
from vcr_odom.map_command import MapOutcome, MapSettings, map_sequence
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
    "--config",
    "config_file",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="A TOML file of loop-closure settings (start one with --dump-config); options given here win.",
)
@click.option(
    "--dump-config",
    is_flag=True,
    default=False,
    help="Print every loop-closure setting (with --config's values) as TOML, and exit.",
)
@click.option(
    "--map-voxel",
    "map_voxel_m",
    type=click.FloatRange(min=0.05),
    default=FIELDS["map_voxel_m"].default,
    show_default=True,
    help="Map voxel size [m].",
)
@click.option(
    "--node-spacing",
    "node_spacing_m",
    type=click.FloatRange(min=0.1),
    default=FIELDS["node_spacing_m"].default,
    show_default=True,
    help="Metres driven between pose-graph nodes (a turn of --node-angle degrees also makes one); "
    "loops join nodes, and the map is built from their scans.",
)
@click.option(
    "--node-angle",
    "node_angle_deg",
    type=click.FloatRange(min=1.0),
    default=FIELDS["node_angle_deg"].default,
    show_default=True,
)
@click.option(
    "--revisit-radius",
    "revisit_radius_m",
    type=click.FloatRange(min=0.5),
    default=FIELDS["revisit_radius_m"].default,
    show_default=True,
    help="Two nodes this close see the same place; a later node is tried against an earlier one where "
    "the odometry's uncertainty between them allows that.",
)
@click.option(
    "--min-loop-path",
    "min_loop_path_m",
    type=click.FloatRange(min=1.0),
    default=FIELDS["min_loop_path_m"].default,
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
    help="Hold each node's tilt to the up measured in its cloud (its walls', else its ground's) where "
    "the odometry's tilt drifted from it beyond the measurement's noise, which loops cannot see; turn "
    "off among leaning structures or on stairs.",
)
@initial_guess_option
@kiss_polish_options
@vcr_options
@results_option
@visualize_options
@click.pass_context
def map_command(ctx: click.Context, selection: FrameSelection, **options: object) -> None:
    """Build a map that closes its loops: odometry, then places revisited, registered by VCR-Net with
    no initial guess, verified, and a pose graph.

    The result folder holds trajectory_kitti.txt / trajectory_tum.txt (the optimised poses),
    odometry_kitti.txt / odometry_tum.txt (the odometry's), loops.json (every candidate, its scores
    and why it was accepted or rejected), map.ply, metrics.json and trajectory.png.
    """
    config_file = options.pop("config_file")
    dump = options.pop("dump_config")
    live_options = pop_live_options(ctx, options)
    from_file = LoopSettings.from_toml(config_file) if config_file is not None else {}
    merged = dict(options)
    for name, value in from_file.items():  # the file's, where the command line left the default
        if name not in options or ctx.get_parameter_source(name) is click.core.ParameterSource.DEFAULT:
            merged[name] = value
    if dump:
        chosen = {name: merged[name] for name in LoopSettings.model_fields if name in merged}
        click.echo(LoopSettings(**chosen).dump_toml(), nl=False)
        return
    settings = MapSettings(selection=selection, **merged)
    spec = settings.method if settings.polish is None else settings.spec
    reject_unused_options(ctx, [f"{spec}{LOOPS_SUFFIX}" if settings.loops else spec])
    live = open_live_view(live_options, mapping=True)
    outcome = map_sequence(settings, progress=frame_progress, on_frame=live)
    if outcome.folder is None:
        exit_interrupted(f"Interrupted ({interrupt_label()}) before the first frame; no result folder kept.")
    if outcome.odometry.interrupted:
        exit_interrupted(
            f"Interrupted ({interrupt_label()}) during the odometry; its "
            f"{len(outcome.odometry.frame_indices)} frames are kept in {outcome.folder} "
            "(result.json: partial)."
        )
    print_flagged_frames(outcome.odometry)
    accepted = [d for d in outcome.decisions if d.accepted]
    console.print(
        f"{len(outcome.decisions)} loop candidate(s), {len(accepted)} accepted; "
        f"details in {outcome.folder / 'loops.json'}"
    )
    beyond = sum(d.check == "odometry" for d in outcome.decisions)
    if beyond:
        console.print(
            f"{beyond} candidate(s) fit but asked the odometry for more than its uncertainty allows: "
            "look-alike places, or an odometry that drifts more than its scans and the other loops say "
            "(loops.json: odometry)."
        )
    inconsistent = sum(d.check == "inconsistent" for d in outcome.decisions)
    if inconsistent:
        console.print(
            f"{inconsistent} loop(s) passed every check of their own but close no cycle with the loops "
            "kept (loops.json: inconsistent)."
        )
    if outcome.report is not None and outcome.odometry_report is not None:
        console.print(_scores_table(outcome))
    else:
        console.print(why_unscored(outcome.sequence.gt_poses is not None, len(outcome.poses)))
    seconds = ", ".join(f"{phase} {value:.1f} s" for phase, value in outcome.seconds.items())
    console.print(f"{len(outcome.poses)} frames ({seconds}); results in {outcome.folder}")
    finish_live_view(live, outcome)


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
