"""Are the loop phase's information matrices calibrated? Not a test: run

    .venv/bin/python benchmarks/loop_calibration.py REC/801.pkl REC/803.pkl ... [--set NAME=VALUE ...]

on recordings of ``benchmarks/loop_replay.py record``. For every accepted loop, its error against the
truth (a twist, open3d's order, in the target's frame) weighed by its own information (normalised
estimation error squared, NEES); for every odometry edge, the same with its fit information. Calibrated
informations give NEES that follow chi-square on 6 dof (median 5.35). The loops' absolute scale matters
(it weighs them against the gravity priors and sets what the odometry check and the drift estimate
allow); the odometry edges' is measured per run by the loops (``odometry_scale``), so their NEES says
only how far that factor must go. Loops on the nodes' own clouds give the ``loop_information_points``
that puts their pooled median NEES at 5.35; submap loops are weighed as the graph weighs them, their
fit's information and the odometry's placement of the submaps at the run's measured drift.

Per revisit passage (its loops register the same surfaces a few metres apart), the NEES of the loops'
information-weighted mean error (in the world frame) under their summed information: where their
errors are independent it follows chi-square on 6 dof too; where they were one shared error it would
be as many times larger as the passage has loops ("shared": the same divided by that count).
"""

from __future__ import annotations

import argparse
import pickle
from pathlib import Path

import numpy as np
from loop_replay import add_set_option, loop_options_set  # beside this script

from vcr_odom.data.selection import FrameSelection
from vcr_odom.geometry import adjoint, invert, twist
from vcr_odom.loops.candidates import Chain
from vcr_odom.loops.nodes import NodeNormals
from vcr_odom.loops.pipeline import close_loops, loop_network
from vcr_odom.loops.settings import LoopSettings
from vcr_odom.loops.verify import odometry_information
from vcr_odom.odometry.outputs import ground_truth_for

CHI2_MEDIAN_6 = 5.348


def nees(information: np.ndarray, measured: np.ndarray, true: np.ndarray) -> float:
    """``e^T I e`` of a measured ``T_target_source`` against the true one, ``e`` the left error in the
    target's frame (open3d's convention for fit information)."""
    error = twist(true @ invert(measured))
    return float(error @ information @ error)


def passage_nees(loops: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """The NEES of the information-weighted mean of world-frame errors ``(error, information)``."""
    summed = sum(information for _, information in loops)
    mean = np.linalg.solve(summed, sum(information @ error for error, information in loops))
    return float(mean @ summed @ mean)


def calibrate(
    path: Path, settings: LoopSettings
) -> tuple[dict[bool, list[float]], list[float], list[tuple[int, float]]]:
    """The NEES of every accepted loop (by whether it registered submaps), of every odometry edge, and
    of every revisit passage's loops together (with how many loops it has) of one recording."""
    with path.open("rb") as handle:
        recording = pickle.load(handle)  # the caller's own recording (see loop_replay.py)
    folder = Path(recording["sequence"])
    selection = FrameSelection(data_root=folder.parent.parent, seq=folder.name, stride=recording["stride"])
    gt = ground_truth_for(selection.open(), recording["frame_indices"])
    if gt is None:
        raise SystemExit(f"{path}: {folder} has no ground truth to score against")
    nodes = recording["nodes"]
    edge_information = odometry_information(nodes, NodeNormals(nodes), settings)
    edges = [
        nees(information, invert(a.pose) @ b.pose, invert(gt[a.position]) @ gt[b.position])
        for a, b, information in zip(nodes[:-1], nodes[1:], edge_information, strict=True)
    ]
    chain = Chain(np.stack([node.pose for node in nodes]), edge_information)
    network = loop_network(*(recording["network"][k] for k in ("weights", "device", "vcr_points")))
    closed = close_loops(settings, network, nodes, recording["poses"])
    loops: dict[bool, list[float]] = {False: [], True: []}
    passages: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for d in closed.decisions:
        if not d.accepted:
            continue
        target = gt[nodes[d.candidate.target].position]
        true = invert(target) @ gt[nodes[d.candidate.source].position]
        information = chain.weighted(d.loop, closed.odometry_scale).information  # as the graph weighs it
        loops[d.loop.placement is not None].append(nees(information, d.loop.transform, true))
        lever, back = adjoint(target), adjoint(invert(target))
        world_error = lever @ twist(true @ invert(d.loop.transform))
        passages.setdefault(d.candidate.passage, []).append((world_error, back.T @ information @ back))
    return loops, edges, [(len(group), passage_nees(group)) for group in passages.values()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recordings", type=Path, nargs="+")
    add_set_option(parser)
    args = parser.parse_args()
    settings = LoopSettings(**loop_options_set(args.options_set, parser))
    pooled: dict[bool, list[float]] = {False: [], True: []}
    passages: list[tuple[int, float]] = []
    for path in args.recordings:
        loops, edges, groups = calibrate(path, settings)
        for submaps, values in loops.items():
            pooled[submaps] += values
        passages += groups
        every = loops[False] + loops[True]
        loop_text = f"loops {len(every)}, NEES median {np.median(every):.2f}" if every else "no loop"
        print(f"{path.stem}: {loop_text}; odometry edges {len(edges)}, NEES median {np.median(edges):.3f}")
    if pooled[False]:
        median = float(np.median(pooled[False]))
        suggested = settings.loop_information_points * CHI2_MEDIAN_6 / median
        print(
            f"own clouds: {len(pooled[False])} loops, NEES median {median:.2f} (calibrated: {CHI2_MEDIAN_6}); "
            f"loop_information_points {settings.loop_information_points:g} -> {suggested:.0f}"
        )
    if pooled[True]:
        print(
            f"submaps: {len(pooled[True])} loops, NEES median {np.median(pooled[True]):.2f} under the fit's "
            "information and the odometry's placement of the submaps"
        )
    if passages:
        independent = float(np.median([value for _, value in passages]))
        shared = float(np.median([value / count for count, value in passages]))
        print(
            f"passages: {len(passages)} ({sum(c for c, _ in passages)} loops), NEES of each passage's mean "
            f"median {independent:.2f} as independent loops, {shared:.2f} as one shared measurement "
            f"(calibrated: {CHI2_MEDIAN_6})"
        )


if __name__ == "__main__":
    main()
