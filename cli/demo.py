"""``vcr-odom demo``: the whole job on a built-in synthetic sequence, no dataset needed."""

from __future__ import annotations

from pathlib import Path

import click

from vcr_odom.cli.compare import print_comparison
from vcr_odom.cli.progress import console, frame_progress
from vcr_odom.evaluation.demo import run_demo
from vcr_odom.results import check_output_folder


@click.command("demo")
@click.option(
    "--frames",
    type=click.IntRange(min=10),
    default=150,
    show_default=True,
    help="Length of the synthetic sequence.",
)
@click.option(
    "--seed",
    type=int,
    default=3,
    show_default=True,
    help="Seed of the synthetic scene and drive (3 has a turn).",
)
@click.option(
    "--results-dir",
    type=click.Path(path_type=Path, file_okay=False),
    default=Path("results"),
    show_default=True,
    help="Where the synthetic data and the result folder go.",
)
def demo(frames: int, seed: int, results_dir: Path) -> None:
    """Generate a synthetic KITTI-layout sequence, run VCR-Net with both polishes and the baselines on it, print a table and write a plot."""
    check_output_folder(results_dir, "--results-dir")  # before minutes of synthesis
    console.print(f"Generating {frames} synthetic frames (seed {seed}) in {results_dir / 'demo-data'} ...")
    print_comparison(run_demo(frames, seed, results_dir, progress=frame_progress), stride=1)
