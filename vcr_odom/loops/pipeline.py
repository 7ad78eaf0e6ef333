"""The loop phase of ``vcr-odom map``: candidates, verification, consistency and the graph on the nodes
recorded along an odometry (:func:`close_loops`), and what ``loops.json`` says of them. The command
around it (odometry, result folder, map) is :mod:`vcr_odom.map_command`.
"""

from __future__ import annotations

import copy
import time
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vcr_odom.loops.candidates import Chain, find_candidates
from vcr_odom.loops.graph import correct_frames, optimise, residual_chi2, select_loops
from vcr_odom.loops.gravity import up_priors
from vcr_odom.loops.nodes import Node, NodeNormals
from vcr_odom.loops.settings import LoopSettings
from vcr_odom.loops.verify import LoopDecision, LoopVerifier, odometry_information
from vcr_odom.odometry.chain import Odometry
from vcr_odom.odometry.run import ProgressFactory
from vcr_odom.registration.base import SequentialOdometry
from vcr_odom.registration.vcr import VcrRegistrar, default_passes


def loop_network(
    weights: Path | None,
    device: str,
    points: int | None,
    odometry: Odometry | SequentialOdometry | None = None,
) -> VcrRegistrar:
    """The network that registers loop candidates (loaded before any folder: a bad file fails first).

    Where the odometry already runs VCR-Net from the same options, its loaded network is shared (one
    copy of the weights in memory, one load) with the weights' own number of passes: the odometry's
    polished pairs run one, a loop with no guess takes what the weights default to."""
    registrar = getattr(odometry, "registrar", None)
    if isinstance(registrar, VcrRegistrar):
        shared = copy.copy(registrar)
        shared.passes = default_passes(shared.config)
        return shared
    return VcrRegistrar(weights=weights, device=device, num_points=points)


class Phases:
    """One progress bar per phase (or none) and each phase's wall time."""

    def __init__(self, progress: ProgressFactory | None) -> None:
        self.progress = progress
        self.seconds: dict[str, float] = {}

    def __call__(self, title: str, total: int) -> Any:
        if self.progress is None:
            return nullcontext(lambda *_: None)
        return self.progress(title, total)


@dataclass
class ClosedLoops:
    """What the loop phase made of an odometry: every candidate's decision, every frame's optimised
    pose, and what the graph made of the measured up."""

    decisions: list[LoopDecision]
    poses: np.ndarray
    ground_up: dict[str, Any]
    odometry_scale: float = 1.0
    """The factor the loops measured on the odometry's covariance (:func:`~vcr_odom.loops.graph.odometry_scale`)."""


def close_loops(
    settings: LoopSettings,
    network: VcrRegistrar | None,
    nodes: list[Node],
    odometry_poses: np.ndarray,
    phase: Phases | None = None,
) -> ClosedLoops:
    """The loop phase on nodes recorded along ``odometry_poses`` (every frame's, as the
    :class:`NodeRecorder` saw them): ``map``'s, and a benchmark's on a recorded or drifted odometry."""
    phase = phase or Phases(None)
    if not settings.loops:  # the baseline: the odometry as it is
        phase.seconds |= {"loops": 0.0, "graph": 0.0}
        return ClosedLoops([], np.array(odometry_poses, copy=True), {"used": False})
    if network is None:
        raise ValueError("close_loops needs a network to register loops (settings.loops is on)")
    started = time.perf_counter()
    normals = NodeNormals(nodes)  # read by the odometry edges, the verification and the walls
    node_poses = np.stack([node.pose for node in nodes])
    edge_information = odometry_information(nodes, normals, settings)
    chain = Chain(node_poses, edge_information)
    decisions: list[LoopDecision] = []
    candidates = find_candidates(nodes, chain, settings)
    verifier = LoopVerifier(network, chain, settings, normals)
    with phase("loop candidates", len(candidates)) as advance:
        for candidate in candidates:
            decisions.append(verifier.verify(candidate, nodes))
            advance(candidate.source, candidate.prior)
    measured = [d for d in decisions if d.accepted]
    edges = [d.loop for d in measured]
    selection = select_loops(edges, chain, settings)
    for decision, verdict in zip(measured, selection.verdicts, strict=True):
        if verdict:
            decision.reject(*verdict)
    phase.seconds["loops"] = time.perf_counter() - started
    started = time.perf_counter()
    kept = [(d, edge) for d, edge in zip(measured, edges, strict=True) if d.accepted]
    kept_edges = [chain.weighted(edge, selection.odometry_scale) for _, edge in kept]
    up = up_priors(nodes, normals, settings) if kept_edges else None
    after = optimise(node_poses, edge_information, kept_edges, up, selection.odometry_scale)
    for (decision, _), edge in zip(kept, kept_edges, strict=True):  # what the graph took and made of it
        decision.extra |= {
            "graph_chi2": round(residual_chi2(after, edge), 3),
            "information": edge.information.tolist(),
        }
    if kept_edges:
        poses = correct_frames(odometry_poses, [n.position for n in nodes], node_poses, after)
    else:
        poses = np.array(odometry_poses, copy=True)
    phase.seconds["graph"] = time.perf_counter() - started
    up_summary = {"used": False} if up is None else up.to_dict()
    return ClosedLoops(decisions, poses, up_summary, selection.odometry_scale)


def loops_json(decisions: list[LoopDecision], nodes: list[Node]) -> dict[str, Any]:
    """``loops.json``: every node (frame, path) and every candidate's decision."""
    return {
        "nodes": [
            {"node": k, "frame": n.frame_index, "path_m": round(n.path_m, 3)} for k, n in enumerate(nodes)
        ],
        "candidates": [d.to_dict() for d in decisions],
    }
