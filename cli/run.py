"""``vcr-odom run``: one method over one sequence, into a result folder."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import click

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
from vcr_odom.cli.tables import report_table
from vcr_odom.cli.view import finish_live_view, open_live_view, pop_live_options, visualize_options
from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import ConfigError
from vcr_odom.evaluation.rows import parse_row_spec, split_loops
from vcr_odom.odometry.factory import DEFAULT_GLOBAL_POLISH, GLOBAL_METHODS, parse_method_spec
from vcr_odom.odometry.frame_loop import OdometryRun
from vcr_odom.odometry.polish import POLISHES
from vcr_odom.odometry.run import RunSettings, run_sequence
from vcr_odom.registration import METHOD_NAMES

VCR_ONLY_OPTIONS = {
    "weights": "--weights",
    "vcr_passes": "--vcr-passes",
    "vcr_points": "--vcr-points",
    "device": "--device",
}
LOOP_NETWORK_OPTIONS = ("weights", "vcr_points", "device")
"""The VCR-Net options a mapped row (``map``, a ``+loops`` row) uses whatever its odometry: its loops
are registered by VCR-Net (:func:`~vcr_odom.loops.pipeline.loop_network`)."""


def reject_unused_options(ctx: click.Context, specs: Iterable[str]) -> None:
    """A VCR-Net option given for methods that are not VCR-Net, or ``--consult`` without a polished
    global method, would be silently ignored: a usage error instead, before any work. A mapped spec
    (``kiss-icp+loops``) takes :data:`LOOP_NETWORK_OPTIONS` for its loop network."""
    specs = list(specs)
    try:
        parsed = [parse_row_spec(spec) for spec in specs]
    except ConfigError:
        return  # the method itself is the mistake; its own check says so
    mapped = any(split_loops(spec)[1] for spec in specs)
    unused = []
    if not any(name == "vcr" for name, _ in parsed):
        unused += [
            flag
            for name, flag in VCR_ONLY_OPTIONS.items()
            if given(ctx, name) and not (mapped and name in LOOP_NETWORK_OPTIONS)
        ]
    if given(ctx, "consult") and not any(n in GLOBAL_METHODS and p != "none" for n, p in parsed):
        unused.append("--consult")
    if unused:
        raise click.UsageError(
            f"{', '.join(unused)} only {'applies' if len(unused) == 1 else 'apply'} to "
            + ("a polished global method (vcr, fpfh)" if unused == ["--consult"] else "VCR-Net (vcr)")
            + f", and no method given is one: {', '.join(specs)}",
            ctx=ctx,
        )


def check_method(ctx: click.Context, spec: str) -> str:
    """A bad name or polish in ``--method NAME[+POLISH]`` is a usage error naming it, before any work."""
    try:
        parse_method_spec(spec)
    except ConfigError as error:
        raise click.BadParameter(str(error), ctx=ctx, param_hint="'--method'") from error
    return spec


def split_method(ctx: click.Context, options: dict[str, object]) -> None:
    """``--method NAME+POLISH`` as compare's ``-b`` spells it: the name, and the polish as ``--polish``
    (which, when given too, must agree)."""
    spec = str(options["method"])
    name, polish = parse_method_spec(spec)
    options["method"] = name
    if "+" not in spec:
        return
    if options.get("polish") is not None and options["polish"] != polish:
        raise click.UsageError(
            f"--method {spec} and --polish {options['polish']} disagree: give one", ctx=ctx
        )
    options["polish"] = polish


def given(ctx: click.Context, name: str) -> bool:
    """Whether the user gave option ``name`` (on the command line or from its environment variable)."""
    source = ctx.get_parameter_source(name)
    return source is not None and source not in (
        click.core.ParameterSource.DEFAULT,
        click.core.ParameterSource.DEFAULT_MAP,
    )


@click.command("run", epilog=describe_methods() + "\n\n" + EXIT_CODES_HELP)
@sequence_options
@click.option(
    "--method",
    metavar="NAME[+POLISH]",
    default=RunSettings.model_fields["method"].default,
    show_default=True,
    callback=lambda ctx, param, value: check_method(ctx, value),
    help=f"Registration method ({', '.join(METHOD_NAMES)}; the list below), with its polish in the "
    "spelling compare and the tables use (vcr+none = --method vcr --polish none).",
)
@click.option(
    "--polish",
    "--refine",
    "polish",
    type=click.Choice(list(POLISHES)),
    default=None,
    help="The local registration beside a global method: open3d point-to-plane ICP on the two frames, "
    "or kiss-icp against its local map. With --consult on-doubt (the default) it registers every frame "
    "from the motion prior and the method's estimate is a second start only where that result is in "
    "doubt; with every-frame it polishes each estimate. "
    f"Default: {DEFAULT_GLOBAL_POLISH} for the global methods (vcr, fpfh), none for the local ones. "
    "(Also spelled --refine.)",
)
@click.option(
    "--save-map",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Accumulate the registered scans into a voxel map and write it (.ply or .pcd; checked "
    "before the run starts).",
)
@click.option(
    "--map-voxel", type=click.FloatRange(min=0.05), default=0.5, show_default=True, help="Map voxel size [m]."
)
@initial_guess_option
@kiss_polish_options
@vcr_options
@results_option
@visualize_options
@click.pass_context
def run(ctx: click.Context, selection: FrameSelection, **options: object) -> None:
    """Estimate the trajectory of a sequence and write it (KITTI + TUM), metrics and a plot.

    The result folder's result.json says whether it is complete or partial (Ctrl-C, SIGTERM or SIGHUP,
    an error part-way, or a run killed after a checkpoint); the trajectory files always agree with it.
    """
    split_method(ctx, options)
    live_options = pop_live_options(ctx, options)
    settings = RunSettings(selection=selection, **options)
    reject_unused_options(ctx, [settings.method if settings.polish is None else settings.spec])
    live = open_live_view(live_options)
    outcome = run_sequence(settings, progress=frame_progress, on_frame=live)
    result, report = outcome.run, outcome.report
    if outcome.folder is None:
        exit_interrupted(f"Interrupted ({interrupt_label()}) before the first frame; no result folder kept.")
    if outcome.voxel_map is not None:
        console.print(
            f"map of {len(outcome.voxel_map)} points ({settings.map_voxel:g} m voxels) written to {settings.save_map}"
        )
    print_flagged_frames(result)
    if report is not None:
        title = f"{settings.spec} on {outcome.sequence.name} (stride {selection.stride})"
        console.print(report_table(report, title=title))
    else:
        console.print(why_unscored(outcome.sequence.gt_poses is not None, len(result.frame_indices)))
    console.print(
        f"{len(result.frame_indices)} frames at {result.frames_per_second:.1f} fps; results in {outcome.folder}"
    )
    if result.interrupted:
        exit_interrupted(
            f"Interrupted ({interrupt_label()}) after {len(result.frame_indices)} frames; the partial "
            f"result is kept in {outcome.folder} (result.json: partial)."
        )
    finish_live_view(live, outcome)


def print_flagged_frames(result: OdometryRun) -> None:
    """The frames whose estimate was replaced or is in doubt, as ``run`` and ``map`` print them: a pose
    that was not measured must not pass for one that was."""
    if result.flagged_frames:
        console.print(
            f"[yellow]{len(result.flagged_frames)} frame(s) flagged (an implausible or failed estimate: "
            f"replaced by the previous motion, or kept where the frame rate is assumed): "
            f"{result.flagged_frames[:20]}; reasons in metrics.json"
        )
    if result.single_plane_frames:
        console.print(
            f"[yellow]{len(result.single_plane_frames)} frame(s) where the scan is almost one plane (the "
            "road, a wall): motion along it cannot be measured there, so those poses may slide: "
            f"{result.single_plane_frames[:20]}; single_plane_frames in metrics.json"
        )


def why_unscored(has_ground_truth: bool, frames: int) -> str:
    """Why a trajectory has no scores: no ground truth, or too few frames to score (a run interrupted
    after its first frame), which must not read as the other."""
    if not has_ground_truth:
        return "No ground truth for this sequence: trajectory written without scores."
    return f"Not scored: {frames} frame(s) is too short to score against the ground truth (2 or more needed)."
