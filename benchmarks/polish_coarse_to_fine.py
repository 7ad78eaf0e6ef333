"""Would a coarse-to-fine kiss-icp polish keep the default's accuracy at less cost? Not a test: run

    .venv/bin/python benchmarks/polish_coarse_to_fine.py --data-root WORK/synth --seq 714 --seq 718 \
        [--factor 2] [--frames 0:400]

On keyframe sets the polish registers against a local map on a voxel finer than kiss-icp's own
(``vcr_odom.odometry.polish_voxel``), and kiss-icp's ``align_points_to_map`` then takes most of a
frame's time: about 20 iterations a call from a start a metre off. The variant registers a coarser
copy of the frame against a second local map on a voxel ``--factor`` times coarser first, then the
full frame against the fine map from there (both maps updated with every frame). It is patched in for
the measurement (the library has no such option): each sequence runs once as the default, once as the
variant, in this process one after the other, and the table gives frames, the seconds inside
``align_points_to_map``, the wall time, the SE(3)-aligned ATE, the RPE (1 frame) and the end-point
drift. Speed from one process beside whatever else runs: compare within a row only.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import kiss_icp.registration as kiss_registration
import numpy as np
from kiss_icp.mapping import VoxelHashMap
from kiss_icp.voxelization import voxel_down_sample

from vcr_odom.data import open_sequence
from vcr_odom.data.selection import select_frames
from vcr_odom.metrics.drift import endpoint_drift
from vcr_odom.metrics.evo_errors import ate_rpe
from vcr_odom.odometry import build_odometry, guided_kiss, run_odometry


class _TwoMaps:
    """The fine local map, with a coarse copy updated alongside it."""

    def __init__(self, fine: VoxelHashMap, coarse: VoxelHashMap, coarse_voxel: float) -> None:
        self.fine, self.coarse, self.coarse_voxel = fine, coarse, coarse_voxel

    def update(self, points: np.ndarray, pose: np.ndarray) -> None:
        self.fine.update(points, pose)
        self.coarse.update(voxel_down_sample(points, 0.5 * self.coarse_voxel), pose)

    def __getattr__(self, name: str) -> object:
        return getattr(self.fine, name)


@contextmanager
def coarse_to_fine(factor: float) -> Iterator[None]:
    """``GuidedKissICP`` registering coarse then fine while the block runs."""
    cls = guided_kiss.GuidedKissICP
    original_init, original_align = cls.__init__, cls._align

    def init(self, config, *args, **kwargs) -> None:
        original_init(self, config, *args, **kwargs)
        voxel = factor * config.mapping.voxel_size
        coarse = VoxelHashMap(voxel, config.data.max_range, config.mapping.max_points_per_voxel)
        self.local_map = _TwoMaps(self.local_map, coarse, voxel)

    def align(self, source: np.ndarray, guess: np.ndarray, sigma: float) -> np.ndarray:
        maps = self.local_map
        start = guided_kiss.project_to_se3(guess)
        for points, voxel_map in (
            (voxel_down_sample(source, 1.5 * maps.coarse_voxel), maps.coarse),
            (source, maps.fine),
        ):
            start = self.registration.align_points_to_map(
                points=points,
                voxel_map=voxel_map,
                initial_guess=start,
                max_correspondance_distance=3 * sigma,
                kernel=sigma,
            )
        return start

    cls.__init__, cls._align = init, align
    try:
        yield
    finally:
        cls.__init__, cls._align = original_init, original_align


@contextmanager
def align_seconds() -> Iterator[list[float]]:
    """The seconds of every ``align_points_to_map`` call made while the block runs."""
    calls: list[float] = []
    original = kiss_registration.Registration.align_points_to_map

    def timed(self, *args, **kwargs):
        started = time.perf_counter()
        try:
            return original(self, *args, **kwargs)
        finally:
            calls.append(time.perf_counter() - started)

    kiss_registration.Registration.align_points_to_map = timed
    try:
        yield calls
    finally:
        kiss_registration.Registration.align_points_to_map = original


def measure(root: Path, seq: str, frames: str | None, factor: float | None) -> dict[str, float]:
    sequence = open_sequence(seq, data_root=root)
    indices = select_frames(len(sequence), frames, 1)
    truth = sequence.gt_poses
    if truth is None:
        raise SystemExit(f"{root}/sequences/{seq}: no ground truth to score against")
    truth = truth[indices]
    variant = coarse_to_fine(factor) if factor else _nothing()
    with variant, align_seconds() as calls:
        started = time.perf_counter()
        run = run_odometry(sequence, build_odometry("vcr+kiss-icp"), indices)
        wall = time.perf_counter() - started
    errors = ate_rpe(run.poses, truth, alignment="se3")
    return {
        "frames": len(indices),
        "align_s": sum(calls),
        "wall_s": wall,
        "ate_m": errors.ate_trans_rmse_m,
        "rpe_m": errors.rpe_trans_rmse_m,
        "end_point_pct": endpoint_drift(run.poses, truth).trans_error_percent,
    }


@contextmanager
def _nothing() -> Iterator[None]:
    yield


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data-root", type=Path, required=True)
    parser.add_argument("--seq", action="append", required=True)
    parser.add_argument("--frames", default=None)
    parser.add_argument(
        "--factor", type=float, default=2.0, help="the coarse map's voxel over the fine one's"
    )
    args = parser.parse_args()
    print("| sequence | polish | frames | align [s] | wall [s] | ATE m (SE3) | RPE m | end-point % |")
    print("|---|---|---|---|---|---|---|---|")
    for seq in args.seq:
        for name, factor in (("default", None), (f"coarse x{args.factor:g}, then fine", args.factor)):
            row = measure(args.data_root, seq, args.frames, factor)
            print(
                f"| {seq} | {name} | {row['frames']} | {row['align_s']:.1f} | {row['wall_s']:.1f} | "
                f"{row['ate_m']:.4f} | {row['rpe_m']:.4f} | {row['end_point_pct']:.3f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
