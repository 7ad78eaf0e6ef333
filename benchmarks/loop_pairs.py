"""Loop verification on node pairs with a real walk's revisit geometry (docs/benchmarks.md, "Loops
indoors"): every pair of a sequence's nodes (made from its ground truth, as `map` makes them from the
odometry) standing 3-6 m apart and turned 40-75 deg, verified from a prior off by a drift (4 deg,
1.5 m), with a drift bound of 100 m of path. Counts the fits accepted right (within 0.2 m and 1 deg),
accepted off, accepted false (beyond 1 m or 3 deg, as benchmarks/loop_closure.py counts a false loop)
and rejected, as a Markdown table. Not a test.

    .venv/bin/python benchmarks/loop_pairs.py --data-root WORK/indoor --seq 902 --seq 911 \
        [--node-voxel 1.0] [--distance-floor 0.0]

``--node-voxel``: force the nodes' grid (default: chosen on the first frame, as `map` does).
``--distance-floor``: the verification's distances follow the grid down to this fraction
(``vcr_odom.loops.verify.MIN_DISTANCE_SCALE``, patched for the run).
"""

from __future__ import annotations

import argparse
import math
import warnings
from pathlib import Path
from unittest import mock

import numpy as np

from vcr_odom.data import open_sequence
from vcr_odom.geometry import Transform, invert, make_transform, rotation_angle, rotation_from_euler_zyx
from vcr_odom.loops import verify
from vcr_odom.loops.candidates import LoopCandidate
from vcr_odom.loops.nodes import Node, NodeRecorder
from vcr_odom.registration.vcr import VcrRegistrar

DRIFT = make_transform(rotation_from_euler_zyx(math.radians(4.0), 0.0, 0.0), [1.5, -1.0, 0.2])


def ground_truth_nodes(data_root: Path, seq: str, node_voxel: float | None) -> list[Node]:
    sequence = open_sequence(seq, data_root=data_root)
    recorder = NodeRecorder(cloud_voxel=node_voxel)
    for index in range(len(sequence)):
        recorder(index, sequence.gt_poses[index], sequence.frame(index))
    return recorder.finish()


def revisit_pairs(nodes: list[Node]) -> list[tuple[int, int, Transform]]:
    """(later, earlier, true relative pose) of the node pairs 3-6 m apart and turned 40-75 deg."""
    pairs = []
    for earlier in range(len(nodes)):
        for later in range(earlier + 1, len(nodes)):
            truth = invert(nodes[earlier].pose) @ nodes[later].pose
            apart = float(np.linalg.norm(truth[:3, 3]))
            turned = math.degrees(float(rotation_angle(truth[:3, :3])))
            if 3.0 <= apart <= 6.0 and 40.0 <= turned <= 75.0:
                pairs.append((later, earlier, truth))
    return pairs


def score(nodes: list[Node], verifier: verify.LoopVerifier) -> dict[str, int]:
    counts = {"pairs": 0, "right": 0, "off": 0, "false": 0, "rejected": 0}
    for later, earlier, truth in revisit_pairs(nodes):
        counts["pairs"] += 1
        candidate = LoopCandidate(later, earlier, DRIFT @ truth, 100.0, float(np.linalg.norm(truth[:3, 3])))
        decision = verifier.verify(candidate, nodes)
        if not decision.accepted:
            counts["rejected"] += 1
            continue
        error = invert(truth) @ decision.measured
        error_m = float(np.linalg.norm(error[:3, 3]))
        error_deg = math.degrees(float(rotation_angle(error[:3, :3])))
        counts["right" if error_m < 0.2 and error_deg < 1.0 else "off"] += 1
        counts["false"] += error_m > 1.0 or error_deg > 3.0
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data-root", type=Path, required=True)
    parser.add_argument("--seq", action="append", required=True)
    parser.add_argument("--node-voxel", type=float, default=None)
    parser.add_argument("--distance-floor", type=float, default=verify.MIN_DISTANCE_SCALE)
    args = parser.parse_args()
    warnings.simplefilter("ignore")  # "no times.txt" and the like
    network = VcrRegistrar(device="cpu")
    print("| sequence | node grid [m] | pairs | accepted right | accepted off | of which false | rejected |")
    print("|---|---|---|---|---|---|---|")
    with mock.patch.object(verify, "MIN_DISTANCE_SCALE", args.distance_floor):
        for seq in args.seq:
            nodes = ground_truth_nodes(args.data_root, seq, args.node_voxel)
            c = score(nodes, verify.LoopVerifier(network))
            print(
                f"| {seq} | {nodes[0].cloud_voxel:.3f} | {c['pairs']} | {c['right']} | {c['off']} | "
                f"{c['false']} | {c['rejected']} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
