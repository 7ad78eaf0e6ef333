"""Where to look for loops: places the odometry says it came back to, within its own uncertainty.

Each node is compared with the nodes driven at least ``min_loop_path_m`` before it; the nearest one
by odometry position is a candidate when it lies within ``revisit_radius_m`` plus the drift the
odometry may have gathered between the two visits (:class:`DriftModel`). One candidate every
``attempt_spacing_m`` of path at most, and at most one every 1/``max_passage_attempts`` of a longer
passage's length: a revisit is a passage of many nodes, a few loops along it pin it, and each
candidate costs a registration (a 370 m return attempted every 6 m took 49 loops where 15 left its
map within 1 cm of theirs). A passage's attempts start at its node closest to
the earlier visit and go outwards: where two streets cross, the passage is a few nodes long and only
the node at the crossing sees enough of the other street's scan (one taken from where the drift
bound first admits a node may be 10-20 m short of it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vcr_odom.geometry import Transform, invert
from vcr_odom.loops.drift import DriftModel
from vcr_odom.loops.nodes import Node

REVISIT_RADIUS_M = 5.0
MIN_LOOP_PATH_M = 30.0
ATTEMPT_SPACING_M = 6.0
MAX_PASSAGE_ATTEMPTS = 20


@dataclass(frozen=True)
class LoopCandidate:
    """Node ``source`` (the later visit) against node ``target`` (the earlier one); ``prior`` is the
    odometry's ``T_target_source``, ``path_m`` the distance driven between them, ``frames`` the
    registrations between them, ``turned_deg`` the angle the sensor turned between them (each
    registration's rotation, summed)."""

    source: int
    target: int
    prior: Transform
    path_m: float
    distance_m: float
    frames: int = 0
    turned_deg: float = 0.0


def find_candidates(
    nodes: list[Node],
    drift: DriftModel | None = None,
    revisit_radius_m: float = REVISIT_RADIUS_M,
    min_loop_path_m: float = MIN_LOOP_PATH_M,
    attempt_spacing_m: float = ATTEMPT_SPACING_M,
    max_passage_attempts: int = MAX_PASSAGE_ATTEMPTS,
) -> list[LoopCandidate]:
    """The candidates in the order of the later visit (see the module doc)."""
    drift = drift or DriftModel()
    if len(nodes) < 2:
        return []
    positions = np.stack([node.pose[:3, 3] for node in nodes])
    path = np.array([node.path_m for node in nodes])
    positions_in_run = np.array([node.position for node in nodes])
    nearest: dict[int, LoopCandidate] = {}
    for j, node in enumerate(nodes):
        earlier = np.flatnonzero(path <= node.path_m - min_loop_path_m)
        if len(earlier) == 0:
            continue
        distances = np.linalg.norm(positions[earlier] - positions[j], axis=1)
        best = int(np.argmin(distances))
        i = int(earlier[best])
        travelled = float(node.path_m - path[i])
        frames = int(node.position - positions_in_run[i])
        if distances[best] <= revisit_radius_m + drift.translation_bound(travelled, frames):
            prior = invert(nodes[i].pose) @ node.pose
            turned = node.turned_deg - nodes[i].turned_deg
            nearest[j] = LoopCandidate(j, i, prior, travelled, float(distances[best]), frames, turned)
    chosen: list[LoopCandidate] = []
    for passage in _passages(sorted(nearest)):
        picked: list[float] = []
        length = float(path[passage[-1]] - path[passage[0]])
        spacing = max(attempt_spacing_m, length / max_passage_attempts)
        for j in sorted(passage, key=lambda k: nearest[k].distance_m):
            if all(abs(path[j] - other) >= spacing for other in picked):
                picked.append(float(path[j]))
                chosen.append(nearest[j])
    return sorted(chosen, key=lambda candidate: candidate.source)


def _passages(indices: list[int]) -> list[list[int]]:
    """Runs of consecutive node indices: the nodes of one revisit, attempted from its closest node."""
    runs: list[list[int]] = []
    for j in indices:
        if runs and j == runs[-1][-1] + 1:
            runs[-1].append(j)
        else:
            runs.append([j])
    return runs
