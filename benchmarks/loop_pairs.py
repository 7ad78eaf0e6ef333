"""Loop verification on node pairs with a real walk's revisit geometry (docs/benchmarks.md, "Loops
indoors"): every pair of a sequence's nodes (made from its ground truth, as `map` makes them from the
odometry) standing 3-6 m apart and turned 40-75 deg, verified from a prior off by a drift (4 deg,
1.5 m). The odometry between the two nodes is as uncertain as ``--path`` metres (default 100) of the
sequence's own edges: each edge's covariance from the fit of its two nodes' clouds
(:func:`~vcr_odom.loops.verify.odometry_information`), their mean per metre driven times the path.
Counts the fits accepted right (within 0.2 m and 1 deg), accepted off, accepted false (beyond 1 m or
3 deg, as benchmarks/loop_closure.py counts a false loop) and rejected, as a Markdown table. Not a test.

    .venv/bin/python benchmarks/loop_pairs.py --data-root WORK/indoor --seq 902 --seq 911 \
        [--node-voxel 1.0] [--path 100] [--set NAME=VALUE ...]

``--node-voxel``: force the nodes' grid (default: chosen on the first frame, as `map` does).
``--set``: a loop setting (a ``LoopSettings`` field, as benchmarks/loop_replay.py takes them).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import warnings
from pathlib import Path

import numpy as np

from vcr_odom.data import open_sequence
from vcr_odom.geometry import Transform, invert, make_transform, rotation_angle, rotation_from_euler_zyx
from vcr_odom.loops import verify
from vcr_odom.loops.candidates import Chain, LoopCandidate, covariance
from vcr_odom.loops.nodes import Node, NodeNormals, NodeRecorder
from vcr_odom.loops.settings import LoopSettings
from vcr_odom.registration.vcr import VcrRegistrar

sys.path.insert(0, str(Path(__file__).parent))
from loop_replay import add_set_option, loop_options_set

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


def odometry_covariance_per_metre(nodes: list[Node], settings: LoopSettings) -> np.ndarray:
    """The sequence's odometry edges' mean covariance per metre driven (each edge's from the fit of its
    two nodes' clouds, in its first node's frame: as :class:`Chain` takes them)."""
    edges = verify.odometry_information(nodes, NodeNormals(nodes), settings)
    metres = sum(nodes[k + 1].path_m - nodes[k].path_m for k in range(len(edges)))
    return sum(covariance(info) for info in edges) / max(metres, 1e-9)


def score(
    nodes: list[Node], network: VcrRegistrar, settings: LoopSettings, per_metre: np.ndarray, path_m: float
) -> dict[str, int]:
    """Each revisit pair verified as a loop candidate: the later node placed where the drifted prior
    puts it, the odometry between the two as uncertain as ``path_m`` of the sequence's edges."""
    counts = {"pairs": 0, "right": 0, "off": 0, "false": 0, "rejected": 0}
    information = np.linalg.inv(per_metre * path_m)
    for later, earlier, truth in revisit_pairs(nodes):
        counts["pairs"] += 1
        prior = DRIFT @ truth
        pair = [
            dataclasses.replace(nodes[earlier], pose=np.eye(4)),
            dataclasses.replace(nodes[later], pose=prior),
        ]
        chain = Chain(np.stack([node.pose for node in pair]), [information])
        verifier = verify.LoopVerifier(network, chain, settings, NodeNormals(pair))
        candidate = LoopCandidate(1, 0, prior, path_m, float(np.linalg.norm(prior[:3, 3])))
        decision = verifier.verify(candidate, pair)
        if not decision.accepted:
            counts["rejected"] += 1
            continue
        error = invert(truth) @ decision.loop.transform
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
    parser.add_argument("--path", type=float, default=100.0, help="metres driven between the two visits")
    add_set_option(parser)
    args = parser.parse_args()
    if not args.path > 0:
        parser.error(f"--path {args.path}: expected a path above 0 m")
    settings = LoopSettings(**loop_options_set(args.options_set, parser))
    warnings.simplefilter("ignore")  # "no times.txt" and the like
    network = VcrRegistrar(device="cpu")
    print("| sequence | node grid [m] | pairs | accepted right | accepted off | of which false | rejected |")
    print("|---|---|---|---|---|---|---|")
    for seq in args.seq:
        nodes = ground_truth_nodes(args.data_root, seq, args.node_voxel)
        per_metre = odometry_covariance_per_metre(nodes, settings)
        c = score(nodes, network, settings, per_metre, args.path)
        print(
            f"| {seq} | {nodes[0].cloud_voxel:.3f} | {c['pairs']} | {c['right']} | {c['off']} | "
            f"{c['false']} | {c['rejected']} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
