"""Which first frames the polish's reach rule changes (docs/benchmarks.md, "The polish voxel indoors"):
for each synthetic drive of a grid (or each given sequence), the first frame's reach and the polish voxel
with the rule and without it, as a Markdown table. Only the first frame counts: it fixes the voxel.

    .venv/bin/python benchmarks/polish_voxel_survey.py [--seed 11 --seed 12] \
        [--sequence ../shared/data/kitti-sample/sequences/00 ...]

Without ``--sequence``: every sensor x street scene x motion of ``vcr-odom synth`` for each ``--seed``
(400-frame drives, only their first frame cast), then the indoor walk on the OS0 (180 frames at 2 Hz,
as docs/benchmarks.md makes them: the walk's start depends on its length).
"""

from __future__ import annotations

import argparse
import itertools
import warnings
from collections.abc import Iterator
from pathlib import Path
from unittest import mock

import numpy as np
from kiss_icp.kiss_icp import get_preprocessor

from vcr_odom.data import open_sequence
from vcr_odom.odometry import polish_voxel
from vcr_odom.odometry.polish import polish_kiss_config
from vcr_odom.synth import SensorConfig, SynthSequence

SENSORS = ("hdl64", "hdl32", "vlp16", "os128", "os0", "avia", "mid360")
SCENES = ("suburban", "avenue", "highway", "oldtown")
MOTIONS = ("car", "handheld")


def synthetic_first_frames(seeds: list[int]) -> Iterator[tuple[str, np.ndarray]]:
    for seed, sensor, scene, motion in itertools.product(seeds, SENSORS, SCENES, MOTIONS):
        drive = SynthSequence(
            frames=400, seed=seed, sensor=SensorConfig.model(sensor), scene=scene, motion=motion
        )
        yield f"{sensor} {scene} {motion} seed {seed}", drive.frame(0)
    for seed in seeds:
        walk = SynthSequence(
            frames=180, seed=seed, sensor=SensorConfig.model("os0"), scene="indoor", motion="handheld",
            route="loop", frame_period=0.5,
        )  # fmt: skip
        yield f"os0 indoor handheld seed {seed}", walk.frame(0)


def sequence_first_frames(folders: list[Path]) -> Iterator[tuple[str, np.ndarray]]:
    for folder in folders:
        yield str(folder), np.asarray(open_sequence(folder.name, data_root=folder.parent.parent).frame(0))


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seed", type=int, action="append", help="synthetic seeds (default 11, 12)")
    parser.add_argument("--sequence", type=Path, action="append", help="sequences/<id> folders instead")
    args = parser.parse_args()
    warnings.simplefilter("ignore")  # "no times.txt" and the like: the first frame is all we read
    config = polish_kiss_config()
    frames = (
        sequence_first_frames(args.sequence)
        if args.sequence
        else synthetic_first_frames(args.seed or [11, 12])
    )
    print("| first frame of | reach [m] | voxel without the reach rule [m] | voxel [m] |")
    print("|---|---|---|---|")
    changed = 0
    for name, points in frames:
        xyz = np.asarray(points)[:, :3].astype(np.float64)
        cropped = get_preprocessor(config).preprocess(xyz, np.array([]), np.eye(4))
        voxel = polish_voxel.density_voxel(xyz, config)
        with mock.patch.object(polish_voxel, "reach_voxel", lambda _points, kiss_voxel: kiss_voxel):
            without = polish_voxel.density_voxel(xyz, config)
        changed += voxel != without
        mark = " **changed**" if voxel != without else ""
        print(
            f"| {name} | {polish_voxel.reach(cropped):.1f} | {without:.3f} | {voxel:.3f}{mark} |", flush=True
        )
    print(f"\n{changed} first frame(s) changed by the reach rule.")


if __name__ == "__main__":
    main()
