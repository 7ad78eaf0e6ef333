"""Which frames of which sequences leave motion unmeasured (docs/benchmarks.md, "Single-plane scans"
and "Directions a scan cannot measure"): per sequence, the thinnest scan and the frames under the
single-plane threshold, and the weakest direction's share of the surface normals, as the kiss-icp
polish sees the scan (its voxel grid), and the frames where the polish holds a direction.

    .venv/bin/python benchmarks/degeneracy_survey.py --sequence WORK/synth/sequences/805 \
        --sequence ../shared/data/kitti-sample/sequences/00 [--every 4]

``--sequence``: a KITTI-layout ``sequences/<id>`` folder (repeatable). ``--every K``: every K-th frame
of sequences longer than 400 frames (all frames of shorter ones).
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from vcr_odom.data import open_sequence
from vcr_odom.odometry.degeneracy import SINGLE_PLANE_M, WEAK_AXIS_SHARE, normal_shares, plane_thickness
from vcr_odom.odometry.guided_kiss import NORMAL_RADIUS_VOXELS
from vcr_odom.odometry.polish import KissIcpPolish


def frames_named(frames: list[int]) -> str:
    return f"{len(frames)} ({frames[0]}-{frames[-1]})" if frames else "0"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sequence", type=Path, action="append", required=True)
    parser.add_argument("--every", type=int, default=4)
    args = parser.parse_args()
    warnings.simplefilter("ignore")  # "no times.txt, 10 Hz assumed" and the like: frames are all we read
    print(
        f"| sequence | frames looked at | thinnest [m] | frames under {SINGLE_PLANE_M} m "
        f"| weakest normal share | frames under {WEAK_AXIS_SHARE} |"
    )
    print("|---|---|---|---|---|---|")
    for folder in args.sequence:
        sequence = open_sequence(folder.name, data_root=folder.parent.parent)
        frames = range(0, len(sequence), 1 if len(sequence) <= 400 else args.every)
        polish = KissIcpPolish()  # its first frame picks the voxel, as in a run
        thickness, weakest = {}, {}
        for i in frames:
            points = sequence.frame(i)
            thickness[i] = plane_thickness(points)
            source = polish.prepare(points).source
            weakest[i] = float(normal_shares(source, NORMAL_RADIUS_VOXELS * polish.voxel_size)[0][0])
        flat = [i for i, t in thickness.items() if t < SINGLE_PLANE_M]
        weak = [i for i, share in weakest.items() if share < WEAK_AXIS_SHARE]
        print(
            f"| {folder.name} | {len(frames)} | {min(thickness.values()):.2f} | {frames_named(flat)} "
            f"| {min(weakest.values()):.4f} | {frames_named(weak)} |"
        )


if __name__ == "__main__":
    main()
