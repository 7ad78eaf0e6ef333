"""The whole job on a built-in synthetic sequence: what a fresh machine can run with no dataset."""

from __future__ import annotations

from pathlib import Path

from vcr_odom.data.selection import FrameSelection
from vcr_odom.evaluation.compare import CompareSettings, Comparison, run_comparison
from vcr_odom.odometry.run import ProgressFactory
from vcr_odom.synth import generate_sequence

DEMO_METHODS = ("icp10", "icp", "kiss-icp", "vcr+none", "vcr+icp", "vcr+kiss-icp")
"""The baselines, the network alone, and the network with each polish."""


def run_demo(
    frames: int, seed: int, results_dir: Path, progress: ProgressFactory | None = None
) -> Comparison:
    """Generate ``frames`` synthetic frames under ``results_dir/demo-data`` and compare the methods."""
    data_root = Path(results_dir) / "demo-data"
    generate_sequence(data_root, seq="00", frames=frames, seed=seed)
    settings = CompareSettings(
        selection=FrameSelection(data_root=data_root, seq="00"),
        methods=DEMO_METHODS,
        results_dir=results_dir,
    )
    return run_comparison(settings, progress=progress)
