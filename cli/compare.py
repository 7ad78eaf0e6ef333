"""``vcr-odom compare``: several methods on the same frames, side by side (odometry and/or the paper's pairs)."""

from __future__ import annotations

import click
from rich.markup import escape

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
from vcr_odom.cli.run import given, reject_unused_options
from vcr_odom.cli.tables import ComparisonRow, comparison_table, pair_protocol_table
from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import ConfigError
from vcr_odom.evaluation.compare import DEFAULT_BASELINES, CompareSettings, Comparison, run_comparison
from vcr_odom.evaluation.pairs import PAIR_KINDS
from vcr_odom.evaluation.rows import parse_row_spec
from vcr_odom.model.weights import MAX_NETWORK_POINTS


def _check_specs(ctx: click.Context, param: click.Parameter, specs: tuple[str, ...]) -> tuple[str, ...]:
    for spec in specs:
        try:
            parse_row_spec(spec)
        except ConfigError as error:
            raise click.BadParameter(str(error), ctx=ctx, param=param) from error
    return specs


PAIRS_ONLY_OPTIONS = {"pair_points": "--pair-points", "pair_kind": "--pairs", "seed": "--seed"}


def reject_bad_combinations(ctx: click.Context, protocol: str, specs: tuple[str, ...]) -> None:
    """Options the chosen protocol would ignore are usage errors, found before any work."""
    if protocol == "odometry":
        ignored = [flag for name, flag in PAIRS_ONLY_OPTIONS.items() if given(ctx, name)]
        if ignored:
            raise click.UsageError(
                f"{', '.join(ignored)} only {'applies' if len(ignored) == 1 else 'apply'} to the pairs "
                "protocol; add --protocol pairs (or both)",
                ctx=ctx,
            )
    reject_unused_options(ctx, specs)


@click.command("compare", epilog=describe_methods() + "\n\n" + EXIT_CODES_HELP)
@sequence_options
@click.option(
    "--baseline",
    "-b",
    "baselines",
    multiple=True,
    callback=_check_specs,
    help="A method as run spells it (vcr = VCR-Net with its default polish, vcr+none = alone, "
    "fpfh+icp, kiss-slam = KISS-SLAM with its loop closures, from the optional extra "
    "vcr-odom[slam], vcr+loops = vcr then vcr-odom map's loop closure, ...); repeat for several. "
    f"Default: {', '.join(DEFAULT_BASELINES)}.",
)
@click.option(
    "--protocol",
    type=click.Choice(["odometry", "pairs", "both"]),
    default="odometry",
    show_default=True,
    help="odometry: chain the frames; pairs: the paper's Table III (each scan against an independently "
    "down-sampled copy of itself moved by yaw ±30°, tilt ±5°, ±5 m, ±1 m; local methods from identity; "
    "a polish only where written out, +icp on the pair's own clouds).",
)
@click.option(
    "--pair-points",
    type=click.IntRange(min=64, max=MAX_NETWORK_POINTS),
    default=None,
    help="Points per cloud in the pairs protocol. Default: --vcr-points, else the VCR weights' N when "
    "a VCR row is compared, else 1024 (the paper's).",
)
@click.option(
    "--pairs",
    "pair_kind",
    type=click.Choice(["same-scan", "consecutive", "both"]),
    default="both",
    show_default=True,
    help="Pairs protocol: the paper's same-scan pairs, consecutive frames (the stride apart, ground-truth "
    "motion, no random move), or a table for each.",
)
@click.option(
    "--seed", type=int, default=0, show_default=True, help="Seed of the pairs protocol's transforms."
)
@initial_guess_option
@vcr_options
@kiss_polish_options
@results_option
@click.pass_context
def compare(
    ctx: click.Context,
    selection: FrameSelection,
    baselines: tuple[str, ...],
    pair_kind: str,
    **options: object,
) -> None:
    """Run the methods on the same frames and print one table per protocol.

    Ctrl-C stops the method in progress and skips the rest: the table shows what finished, the folder
    is marked partial and the command exits 130.
    """
    methods = baselines or DEFAULT_BASELINES
    reject_bad_combinations(ctx, str(options["protocol"]), methods)
    settings = CompareSettings(
        selection=selection,
        methods=methods,
        pair_kinds=PAIR_KINDS if pair_kind == "both" else (pair_kind,),
        **options,
    )
    print_comparison(run_comparison(settings, progress=frame_progress), selection.stride)


def print_comparison(comparison: Comparison, stride: int) -> None:
    """The odometry table, then one table per pair kind, then where the results are."""
    indices, name = comparison.frame_indices, comparison.sequence.name
    if comparison.odometry:
        rows = [
            ComparisonRow(
                o.method,
                o.needs_initial_guess,
                o.report,
                o.run.frames_per_second,
                o.run.interrupted,
                len(o.run.flagged_frames),
                o.run.slam.get("loop_closures"),
                o.status,
            )
            for o in comparison.odometry
        ]
        span = f"frames {indices[0]}..{indices[-1]}, stride {stride}, {len(indices)} frames"
        console.print(comparison_table(rows, title=f"{name} odometry: {span}"))
        first = next((o.report for o in comparison.odometry if o.report is not None), None)
        if first is not None and first.drift.short_sequence:
            console.print(f"[dim]drift columns: {first.drift.label}")
        for outcome in comparison.odometry:
            if outcome.status:
                console.print(f"[dim]{escape(outcome.method)}: {escape(outcome.status)}")
    for note in comparison.notes:
        console.print(f"[dim]{note}")
    for kind, results in comparison.pairs.items():
        label = "paper Table III" if kind == "same-scan" else f"frames {stride} apart"
        pairs = next(iter(results.values())).num_pairs if results else 0
        title = f"{name} {kind} pairs ({label}): {pairs} pairs of {comparison.pair_points} points"
        console.print(pair_protocol_table(results, title))
    console.print(f"Results in {comparison.folder}")
    if comparison.interrupted:
        exit_interrupted(
            f"Interrupted ({interrupt_label()}): the methods not shown were stopped or not run; the "
            f"partial result is kept in {comparison.folder} (result.json: partial)."
        )
