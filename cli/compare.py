"""``vcr-odom compare``: several methods on the same frames, side by side."""

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
from vcr_odom.cli.tables import ComparisonRow, comparison_table
from vcr_odom.odometry import InitialGuess
from vcr_odom.pipeline import MethodOutcome, compare_methods
from vcr_odom.registration import METHOD_NAMES
from vcr_odom.results import create_result_folder, provenance, write_json

DEFAULT_BASELINES = ("icp10", "icp", "fpfh", "kiss-icp")


@click.command("compare", epilog=describe_methods())
@sequence_options
@click.option(
    "--baseline",
    "-b",
    "baselines",
    type=click.Choice(list(METHOD_NAMES)),
    multiple=True,
    help=f"A method to run; repeat for several. Default: {', '.join(DEFAULT_BASELINES)}.",
)
@initial_guess_option
@vcr_options
@results_option
def compare(
    selection: FrameSelection,
    baselines: tuple[str, ...],
    initial_guess: str,
    weights: Path | None,
    device: str,
    results_dir: Path,
) -> None:
    """Run the methods on the same frames and print one table (per-pair errors, drift, speed)."""
    methods = list(dict.fromkeys(baselines or DEFAULT_BASELINES))
    options = {"vcr": method_options("vcr", weights, device)}
    compare_sequence(selection, methods, initial_guess, results_dir, options)


def compare_sequence(
    selection: FrameSelection,
    methods: list[str],
    initial_guess: str,
    results_dir: Path,
    options: dict[str, dict[str, Any]] | None = None,
) -> list[MethodOutcome]:
    """Shared by ``compare`` and ``demo``: run, print the table, say where the files are."""
    sequence = selection.open()
    indices = selection.indices(sequence)
    out = create_result_folder(results_dir, f"compare_{sequence.name}_stride{selection.stride}")
    config = {
        "command": "compare",
        "sequence": sequence.name,
        **selection.as_config(),
        "methods": methods,
        "initial_guess": initial_guess,
        "method_options": options or {},
    }
    write_json(out / "config.json", provenance(config))
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
    span = f"frames {indices[0]}..{indices[-1]}, stride {selection.stride}, {len(indices)} frames"
    console.print(comparison_table(rows, title=f"{sequence.name}: {span}"))
    if outcomes and outcomes[0].report is not None and outcomes[0].report.drift.short_sequence:
        console.print(f"[dim]drift column: {outcomes[0].report.drift.label}")
    console.print(f"Per-method folders, compare.json and trajectories.png in {out}")
    return outcomes
