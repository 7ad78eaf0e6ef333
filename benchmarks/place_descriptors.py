"""Place descriptors against the position search: which finds more truly revisited places, and at what
cost in false ones. Not a test: run

    .venv/bin/python benchmarks/place_descriptors.py --sequence runs/loops/synth/sequences/803 \
        [--sequence ...] [--method vcr] [--json out.json] [--markdown table.md]

``vcr-odom map`` proposes a loop candidate where the odometry's position for a node, with its
uncertainty propagated along the path from a node driven 30 m or more before (each odometry edge's
from its clouds' fit), allows a revisit within 5 m (a chi-square gate, ``candidate_confidence``).
Beyond the gate only appearance can propose one. Two descriptors are measured on the same nodes (the
map's: one every 3 m or 20 deg, each a 1 m voxel cloud), each node's earlier nodes searched for its best
match at least 30 m of path before:

- **map-closures** (KISS-SLAM's: ORB features of a bird's-eye density image, matched with RANSAC;
  ``vcr-odom[slam]``), on local submaps: the node clouds within 20 m of path joined by the odometry.
- **VCR-Net's own features**: the encoder's features (which see only relative geometry, so a heading
  changes nothing) of the node's cloud, mean- and max-pooled and compared by cosine similarity.

A proposal is true when ground truth puts the two nodes within 10 m (close enough to register), false
otherwise (a look-alike block). For each acceptance threshold: true and false proposals, the revisited
nodes reached (a node truly within 5 m of one 30 m of path before, with a true proposal), and those of
them the position search cannot reach (``beyond_gate``: the gate turns away every truly close node).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from vcr_odom.data.selection import FrameSelection
from vcr_odom.geometry import invert
from vcr_odom.loops.candidates import Chain, chi2_gate, find_candidates, revisit_chi2
from vcr_odom.loops.nodes import Node, NodeNormals, NodeRecorder
from vcr_odom.loops.settings import LoopSettings
from vcr_odom.loops.verify import odometry_information
from vcr_odom.odometry.frame_loop import run_odometry
from vcr_odom.odometry.outputs import ground_truth_for
from vcr_odom.odometry.run import RunSettings, method_for
from vcr_odom.registration.vcr import VcrRegistrar

TRUE_PLACE_M = 10.0
"""A proposal between nodes truly this close is a real revisit (registrable), farther a false one."""
SUBMAP_PATH_M = 20.0
"""A map-closures submap: the node clouds within this path of the node (KISS-SLAM's are 100 m)."""
SETTINGS = LoopSettings()
"""``map``'s loop settings: its revisit radius, loop path and candidate gate."""
INLIER_THRESHOLDS = (5, 10, 20, 40)
SIMILARITY_THRESHOLDS = (0.95, 0.98, 0.99, 0.995)


@dataclass
class Proposal:
    source: int
    target: int
    score: float


def nodes_of(folder: Path, method: str) -> tuple[list[Node], NDArray[np.float64]]:
    """The map's nodes over the sequence, recorded during an odometry run as ``map`` records them (the
    poses in the scans' own frame), and each node's true pose."""
    selection = FrameSelection(data_root=folder.parent.parent, seq=folder.name)
    sequence = selection.open()
    indices = selection.indices(sequence)
    recorder = NodeRecorder(SETTINGS.node_spacing_m, SETTINGS.node_angle_deg)
    run_odometry(
        sequence, method_for(RunSettings(selection=selection, method=method)), indices, on_frame=recorder
    )
    nodes = recorder.finish()
    gt = ground_truth_for(sequence, recorder.frame_indices)
    if gt is None:
        raise SystemExit(f"{folder}: no ground-truth poses")
    return nodes, gt[[node.position for node in nodes]]


def odometry_chain(nodes: list[Node]) -> Chain:
    """The nodes' odometry with each edge's uncertainty, as ``map``'s loop phase builds it."""
    information = odometry_information(nodes, NodeNormals(nodes), SETTINGS)
    return Chain(np.stack([node.pose for node in nodes]), information)


def earlier(nodes: list[Node], j: int) -> NDArray[np.int64]:
    path = np.array([node.path_m for node in nodes])
    return np.flatnonzero(path <= nodes[j].path_m - SETTINGS.min_loop_path_m)


def submap(nodes: list[Node], j: int) -> NDArray[np.float64]:
    """The node clouds within :data:`SUBMAP_PATH_M` of node ``j``'s path, in its frame."""
    into = invert(nodes[j].pose)
    parts = []
    for node in nodes:
        if abs(node.path_m - nodes[j].path_m) <= SUBMAP_PATH_M:
            move = into @ node.pose
            parts.append(node.cloud.astype(np.float64) @ move[:3, :3].T + move[:3, 3])
    return np.concatenate(parts)


def map_closures_proposals(nodes: list[Node]) -> list[Proposal]:
    from map_closures.map_closures import MapClosures

    detector = MapClosures()
    proposals = []
    for j in range(len(nodes)):
        closures = detector.get_closures(j, submap(nodes, j))
        allowed = set(earlier(nodes, j).tolist())
        best = max(
            (c for c in closures if c.source_id in allowed or (c.target_id in allowed and c.source_id == j)),
            key=lambda c: c.number_of_inliers,
            default=None,
        )
        if best is not None:
            other = best.source_id if best.source_id != j else best.target_id
            proposals.append(Proposal(j, int(other), float(best.number_of_inliers)))
    return proposals


@torch.inference_mode()
def network_proposals(nodes: list[Node], network: VcrRegistrar) -> list[Proposal]:
    descriptors = []
    for node in nodes:
        points = network.network_input(node.cloud)
        tensor = torch.as_tensor(points[None], dtype=torch.float32, device=network.device)
        features = network.model.encode(tensor)[0]
        vector = torch.cat([features.mean(0), features.max(0).values])
        descriptors.append((vector / vector.norm()).cpu().numpy())
    stack = np.stack(descriptors)
    proposals = []
    for j in range(len(nodes)):
        before = earlier(nodes, j)
        if len(before):
            similarity = stack[before] @ stack[j]
            best = int(np.argmax(similarity))
            proposals.append(Proposal(j, int(before[best]), float(similarity[best])))
    return proposals


def position_proposals(nodes: list[Node], chain: Chain) -> list[Proposal]:
    return [Proposal(c.source, c.target, 1.0) for c in find_candidates(nodes, chain, SETTINGS)]


def within_gate(chain: Chain, i: int, j: int) -> bool:
    """Whether the candidates' chi-square gate lets node ``j`` be a revisit of node ``i`` (as
    :func:`~vcr_odom.loops.candidates.find_candidates` tests it)."""
    score, _ = revisit_chi2(chain, i, j, SETTINGS.revisit_radius_m)
    return score <= chi2_gate(SETTINGS.candidate_confidence, 3)


def score(
    name: str,
    proposals: list[Proposal],
    thresholds: tuple[float, ...],
    nodes: list[Node],
    gt: NDArray,
    chain: Chain,
) -> list[dict[str, Any]]:
    truth = gt[:, :3, 3]
    revisits, unreachable = set(), set()
    for j in range(len(nodes)):
        before = earlier(nodes, j)
        if len(before) == 0:
            continue
        close = before[np.linalg.norm(truth[before] - truth[j], axis=1) <= SETTINGS.revisit_radius_m]
        if len(close):
            revisits.add(j)
            # The position search reaches j where its gate lets through some truly close node.
            if not any(within_gate(chain, int(i), j) for i in close):
                unreachable.add(j)
    rows = []
    for threshold in thresholds:
        kept = [p for p in proposals if p.score >= threshold]
        true = [p for p in kept if np.linalg.norm(truth[p.source] - truth[p.target]) <= TRUE_PLACE_M]
        reached = {p.source for p in true} & revisits
        rows.append(
            {
                "descriptor": name,
                "threshold": threshold,
                "proposals": len(kept),
                "true": len(true),
                "false": len(kept) - len(true),
                "revisit_nodes": len(revisits),
                "reached": len(reached),
                "beyond_gate": len(unreachable),
                "beyond_gate_reached": len(reached & unreachable),
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sequence", type=Path, action="append", required=True, help="sequences/<id> folder")
    parser.add_argument("--method", default="vcr", help="the odometry whose nodes are searched")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--markdown", type=Path)
    args = parser.parse_args()
    if importlib.util.find_spec("map_closures") is None:
        parser.error("map-closures is not installed (pip install 'vcr-odom[slam]')")
    network = VcrRegistrar()
    rows = []
    for folder in args.sequence:
        nodes, gt = nodes_of(folder, args.method)
        chain = odometry_chain(nodes)
        for name, proposals, thresholds in (
            ("position (map)", position_proposals(nodes, chain), (1.0,)),
            ("map-closures", map_closures_proposals(nodes), INLIER_THRESHOLDS),
            ("VCR-Net features", network_proposals(nodes, network), SIMILARITY_THRESHOLDS),
        ):
            for row in score(name, proposals, thresholds, nodes, gt, chain):
                rows.append({"sequence": folder.name, **row})
                print(json.dumps(rows[-1]), flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    if args.markdown:
        keys = list(rows[0])
        lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
        lines += ["| " + " | ".join(str(row[k]) for k in keys) + " |" for row in rows]
        args.markdown.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
