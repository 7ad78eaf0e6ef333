"""``vcr-odom compare``: several methods on the same frames, side by side (odometry and/or the paper's pairs)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

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
from vcr_odom.cli.tables import ComparisonRow, comparison_table, pair_protocol_table
from vcr_odom.data.base import LidarSequence
from vcr_odom.errors import ConfigError
from vcr_odom.model.weights import default_weights_path, read_weights
from vcr_odom.odometry import InitialGuess
from vcr_odom.pair_benchmark import PAIR_KINDS, evaluate_pair_protocol, pair_sets
from vcr_odom.pipeline import MethodOutcome, compare_methods, parse_method_spec
from vcr_odom.preprocess import PreprocessConfig
from vcr_odom.registration.polish import PAIR_POLISHES
from vcr_odom.results import create_result_folder, provenance, write_json

DEFAULT_BASELINES = ("icp10", "icp", "fpfh", "kiss-icp")


def _check_specs(ctx: click.Context, param: click.Parameter, specs: tuple[str, ...]) -> tuple[str, ...]:
    for spec in specs:
        try:
            parse_method_spec(spec)
        except ConfigError as error:
            raise click.BadParameter(str(error), ctx=ctx, param=param) from error
    return specs


@click.command("compare", epilog=describe_methods())
@sequence_options
@click.option(
    "--baseline",
    "-b",
    "baselines",
    multiple=True,
    callback=_check_specs,
    help="A method, optionally with a polish (e.g. fpfh+icp, vcr+kiss-icp); repeat for several. "
    f"Default: {', '.join(DEFAULT_BASELINES)}.",
)
@click.option(
    "--protocol",
    type=click.Choice(["odometry", "pairs", "both"]),
    default="odometry",
    show_default=True,
    help="odometry: chain the frames; pairs: the paper's Table III (each scan against an independently "
    "down-sampled copy of itself moved by yaw ±30°, tilt ±5°, ±5 m, ±1 m; local methods from identity).",
)
@click.option(
    "--pair-points",
    type=click.IntRange(min=64),
    default=None,
    help="Points per cloud in the pairs protocol. Default: the VCR weights' N when a VCR row is "
    "compared (512 for the shipped default, 1024 for the paper's configuration), else 1024 (the paper's).",
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
@results_option
def compare(
    selection: FrameSelection,
    baselines: tuple[str, ...],
    protocol: str,
    pair_points: int | None,
    pair_kind: str,
    seed: int,
    initial_guess: str,
    weights: Path | None,
    device: str,
    vcr_passes: int | None,
    results_dir: Path,
) -> None:
    """Run the methods on the same frames and print one table per protocol."""
    methods = list(dict.fromkeys(baselines or DEFAULT_BASELINES))
    options = {
        spec: method_options(parse_method_spec(spec)[0], weights, device, vcr_passes) for spec in methods
    }
    if pair_points is None:
        pair_points = default_pair_points(methods, weights)
    kinds = PAIR_KINDS if pair_kind == "both" else (pair_kind,)
    run_comparison(
        selection, methods, initial_guess, results_dir, options, protocol, pair_points, seed, kinds
    )


def run_comparison(
    selection: FrameSelection,
    methods: list[str],
    initial_guess: str,
    results_dir: Path,
    options: dict[str, dict[str, Any]] | None = None,
    protocol: str = "odometry",
    pair_points: int = 1024,
    seed: int = 0,
    pair_kinds: tuple[str, ...] = PAIR_KINDS,
) -> None:
    """Shared by ``compare`` and ``demo``: one result folder, one table per protocol (and pair kind)."""
    sequence = selection.open()
    indices = selection.indices(sequence)
    out = create_result_folder(results_dir, f"compare_{sequence.name}_stride{selection.stride}")
    config = {
        "command": "compare",
        "sequence": sequence.name,
        **selection.as_config(),
        "methods": methods,
        "protocol": protocol,
        "pair_points": pair_points,
        "pair_kinds": list(pair_kinds),
        "seed": seed,
        "initial_guess": initial_guess,
        "method_options": options or {},
    }
    write_json(out / "config.json", provenance(config))
    if protocol in ("odometry", "both"):
        compare_odometry(sequence, indices, selection.stride, methods, initial_guess, out, options)
    if protocol in ("pairs", "both"):
        compare_pairs(sequence, indices, methods, out, options, pair_points, seed, pair_kinds)
    console.print(f"Results in {out}")


def compare_odometry(
    sequence: LidarSequence,
    indices: list[int],
    stride: int,
    methods: list[str],
    initial_guess: str,
    out: Path,
    options: dict[str, dict[str, Any]] | None,
) -> list[MethodOutcome]:
    outcomes = compare_methods(
        sequence,
        methods,
        indices,
        out,
        initial_guess=InitialGuess(initial_guess),
        progress=frame_progress,
        options=options,
    )
    rows = [
        ComparisonRow(
            o.method,
            o.needs_initial_guess,
            o.report,
            o.run.frames_per_second,
            o.run.interrupted,
            len(o.run.flagged_frames),
        )
        for o in outcomes
    ]
    span = f"frames {indices[0]}..{indices[-1]}, stride {stride}, {len(indices)} frames"
    console.print(comparison_table(rows, title=f"{sequence.name} odometry: {span}"))
    if outcomes and outcomes[0].report is not None and outcomes[0].report.drift.short_sequence:
        console.print(f"[dim]drift columns: {outcomes[0].report.drift.label}")
    return outcomes


def compare_pairs(
    sequence: LidarSequence,
    indices: list[int],
    methods: list[str],
    out: Path,
    options: dict[str, dict[str, Any]] | None,
    pair_points: int,
    seed: int,
    kinds: tuple[str, ...] = PAIR_KINDS,
) -> None:
    """One table per pair kind; ``pairs.json`` maps kind -> method -> figures."""
    pairwise = [m for m in methods if _works_on_pairs(m)]
    if len(pairwise) < len(methods):
        left_out = ", ".join(m for m in methods if m not in pairwise)
        console.print(
            f"[dim]left out of the pairs protocol: {left_out} (kiss-icp, as a method or a polish, "
            "needs a sequence's local map)."
        )
    if "consecutive" in kinds and sequence.gt_poses is None:
        console.print(f"[dim]no consecutive-pairs table: {sequence.name} has no ground-truth poses")
        kinds = tuple(k for k in kinds if k != "consecutive")
    if not kinds:
        return
    with frame_progress(f"building pairs ({pair_points} points)", len(indices)) as advance:
        pair_datasets = pair_sets(
            sequence,
            indices,
            pair_points,
            seed,
            kinds,
            progress=lambda *_: advance(),
            max_range=pair_input_range(pairwise, options),
        )
    report: dict[str, Any] = {}
    for kind, pairs in pair_datasets.items():
        with frame_progress(f"registering {kind} pairs", len(pairs) * len(pairwise)) as advance:
            results = evaluate_pair_protocol(pairwise, pairs, options=options, progress=lambda *_: advance())
        report[kind] = {name: result.to_dict() for name, result in results.items()}
        label = "paper Table III" if kind == "same-scan" else f"frames {indices[1] - indices[0]} apart"
        title = f"{sequence.name} {kind} pairs ({label}): {len(pairs)} pairs of {pair_points} points"
        console.print(pair_protocol_table(results, title))
    write_json(out / "pairs.json", report)


def _works_on_pairs(spec: str) -> bool:
    name, refine = parse_method_spec(spec)
    return name != "kiss-icp" and refine in ("none", *PAIR_POLISHES)


def pair_input_range(methods: list[str], options: dict[str, dict[str, Any]] | None) -> float:
    """The VCR weights' input range when a VCR row is compared (every method then sees the clouds the
    network was trained on), else ``run``'s 80 m crop."""
    for spec in methods:
        if parse_method_spec(spec)[0] == "vcr":
            weights = (options or {}).get(spec, {}).get("weights")
            return read_weights(weights or default_weights_path("default"))[1].input_max_range
    return PreprocessConfig().max_range


def default_pair_points(methods: list[str], weights: Path | None) -> int:
    """The VCR weights' N when a VCR row is compared (the network is trained on N-point clouds), else
    the paper's 1024."""
    if any(parse_method_spec(spec)[0] == "vcr" for spec in methods):
        return read_weights(weights or default_weights_path("default"))[1].num_points
    return 1024
