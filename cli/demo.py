"""``vcr-odom demo``: the whole job on a built-in synthetic sequence, no dataset needed."""

from __future__ import annotations

from pathlib import Path

import click

from vcr_odom.cli.compare import run_comparison
from vcr_odom.cli.options import FrameSelection
from vcr_odom.cli.progress import console
from vcr_odom.data.synth import generate_sequence

DEMO_METHODS = ["icp10", "icp", "kiss-icp", "vcr+icp", "vcr+kiss-icp"]


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
    data_root = results_dir / "demo-data"
    console.print(f"Generating {frames} synthetic frames (seed {seed}) in {data_root} ...")
    generate_sequence(data_root, seq="00", frames=frames, seed=seed)
    selection = FrameSelection(data_root, "00", folder=None, poses=None, calib=None, frames=None, stride=1)
    run_comparison(selection, DEMO_METHODS, "constant-velocity", results_dir)
