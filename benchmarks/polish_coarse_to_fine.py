"""What the kiss-icp polish's coarse stage for far starts costs and changes. Not a test: run

    .venv/bin/python benchmarks/polish_coarse_to_fine.py --data-root WORK/synth --seq 714 --seq 718 \
        [--frames 0:400]

On keyframe sets the polish registers against a local map on a voxel finer than kiss-icp's own
(``vcr_odom.odometry.polish_voxel``), and kiss-icp's ``align_points_to_map`` then takes most of a
frame's time: about 20 iterations a call from a start a metre off. The polish's coarse stage
(``KissIcpPolish(coarse_start=True)``, the default) registers a start outside the prediction's basin
on a map twice as coarse first (at most kiss-icp's own voxel). Each sequence runs the default method
(``vcr+kiss-icp``) without and with it, in this process one after the other; the table gives frames,
the seconds inside ``align_points_to_map``, the wall time, the SE(3)-aligned ATE, the RPE (1 frame)
and the end-point drift. Speed from one process beside whatever else runs: compare within a sequence
only.

An earlier version of this script patched in a coarse map on twice the polish's voxel for every
start, the prediction's too (``git show 8a473a2:benchmarks/polish_coarse_to_fine.py``): less time,
but accuracy moved both ways. kiss-icp's own voxel as the coarse grid lost an Avia keyframe walk
(714: 3.2 m ATE against 0.09 m), as kiss-icp alone does there.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import kiss_icp.registration as kiss_registration

from vcr_odom.data import open_sequence
from vcr_odom.data.selection import select_frames
from vcr_odom.metrics.drift import endpoint_drift
from vcr_odom.metrics.evo_errors import ate_rpe
from vcr_odom.odometry import build_odometry, run_odometry


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


def measure(root: Path, seq: str, frames: str | None, coarse_start: bool) -> dict[str, float]:
    sequence = open_sequence(seq, data_root=root)
    indices = select_frames(len(sequence), frames, 1)
    truth = sequence.gt_poses
    if truth is None:
        raise SystemExit(f"{root}/sequences/{seq}: no ground truth to score against")
    truth = truth[indices]
    method = build_odometry("vcr+kiss-icp", polish_options={"coarse_start": coarse_start})
    with align_seconds() as calls:
        started = time.perf_counter()
        run = run_odometry(sequence, method, indices)
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


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data-root", type=Path, required=True)
    parser.add_argument("--seq", action="append", required=True)
    parser.add_argument("--frames", default=None)
    args = parser.parse_args()
    print("| sequence | coarse stage | frames | align [s] | wall [s] | ATE m (SE3) | RPE m | end-point % |")
    print("|---|---|---|---|---|---|---|---|")
    for seq in args.seq:
        for coarse_start in (False, True):
            row = measure(args.data_root, seq, args.frames, coarse_start)
            name = "far starts on a coarser map first" if coarse_start else "none"
            print(
                f"| {seq} | {name} | {row['frames']} | {row['align_s']:.1f} | {row['wall_s']:.1f} | "
                f"{row['ate_m']:.4f} | {row['rpe_m']:.4f} | {row['end_point_pct']:.3f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
