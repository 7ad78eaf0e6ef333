"""Which frames of which sequences are single-plane scans (docs/benchmarks.md, "Single-plane scans"):
the thinnest scan of each sequence and the frames under the threshold, as a Markdown table.

    .venv/bin/python benchmarks/single_plane_survey.py --sequence WORK/synth/sequences/805 \
        --sequence ../shared/data/kitti-sample/sequences/00 [--every 4]

``--sequence``: a KITTI-layout ``sequences/<id>`` folder (repeatable). ``--every K``: every K-th frame
of sequences longer than 400 frames (all frames of shorter ones).
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from vcr_odom.data import open_sequence
from vcr_odom.odometry.degeneracy import SINGLE_PLANE_M, plane_thickness


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sequence", type=Path, action="append", required=True)
    parser.add_argument("--every", type=int, default=4)
    args = parser.parse_args()
    warnings.simplefilter("ignore")  # "no times.txt, 10 Hz assumed" and the like: frames are all we read
    print(f"| sequence | frames looked at | thinnest [m] | frames under {SINGLE_PLANE_M} m |")
    print("|---|---|---|---|")
    for folder in args.sequence:
        sequence = open_sequence(folder.name, data_root=folder.parent.parent)
        frames = range(0, len(sequence), 1 if len(sequence) <= 400 else args.every)
        thickness = {i: plane_thickness(sequence.frame(i)) for i in frames}
        flat = [i for i, t in thickness.items() if t < SINGLE_PLANE_M]
        where = f"{len(flat)} ({flat[0]}-{flat[-1]})" if flat else "0"
        print(f"| {folder.name} | {len(frames)} | {min(thickness.values()):.2f} | {where} |")


if __name__ == "__main__":
    main()
