"""Whether an odometry's errors have the shape and the growth the loop phase's chain assumes. Not a
test: run

    .venv/bin/python benchmarks/odometry_error_growth.py REC.pkl [REC.pkl ...] [--json out.json]

on recordings of ``loop_replay.py record`` (their sequences need ground truth). Per recording:

- **shape**: each odometry edge's error against the truth (``T_odo T_true^-1``, a perturbation in its
  earlier node's frame, where its fit information is stated) normalised by the edge's fit covariance
  (:func:`~vcr_odom.loops.verify.odometry_information`), the rotation block and the translation
  block apart (``d_r^T Cov_rr^-1 d_r``, ``d_t^T Cov_tt^-1 d_t``, 3 dof each): the median of each and
  their ratio. One covariance scale for the whole odometry (``graph.odometry_scale``) assumes the
  ratio near 1.
- **growth**: non-overlapping stretches of 4, 16 and 64 edges, each stretch's error at its last node
  (that node's frame) normalised by the chain's covariance for it (the sum of its edges', as
  :class:`~vcr_odom.loops.candidates.Chain` propagates them), blocks apart; the median as a multiple
  of the same for single edges. Independent edge errors keep it near 1 at every length; below 1 the
  errors cancel over a stretch (an odometry that corrects itself against its map), above 1 they add
  up like a bias.

Why: the loops measure the odometry over long stretches, the chain predicts those from single edges;
where the two disagree, the graph spreads a loop's correction along the wrong directions
(docs/benchmarks.md, "Does the fit information have the odometry's error shape?").
"""

from __future__ import annotations

import argparse
import json
import statistics
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from loop_replay import load_recording, recorded_options  # beside this script
from numpy.typing import NDArray
from rich.console import Console
from rich.table import Table

from vcr_odom.geometry import adjoint, invert, twist
from vcr_odom.io import replacing
from vcr_odom.loops.candidates import Chain, LoopEdge, covariance
from vcr_odom.loops.nodes import Node, NodeNormals
from vcr_odom.loops.settings import LoopSettings
from vcr_odom.loops.verify import odometry_information

LENGTHS = (4, 16, 64)
"""Stretch lengths in edges (nodes are about 3 m apart: 12 m to 200 m)."""


def block_chi2(error: NDArray[np.float64], cov: NDArray[np.float64]) -> tuple[float, float]:
    """The rotation block's and the translation block's normalised squared error (3 dof each)."""
    rotation = float(error[:3] @ np.linalg.solve(cov[:3, :3], error[:3]))
    translation = float(error[3:] @ np.linalg.solve(cov[3:, 3:], error[3:]))
    return rotation, translation


def edge_shape(
    nodes: Sequence[Node], truth: NDArray[np.float64], information: Sequence[NDArray[np.float64]]
) -> tuple[list[float], list[float]]:
    """Per edge, its blocks' normalised squared errors against the truth (see the module doc)."""
    rotation, translation = [], []
    for k, edge_information in enumerate(information):
        odometry = invert(nodes[k].pose) @ nodes[k + 1].pose
        true = invert(truth[nodes[k].position]) @ truth[nodes[k + 1].position]
        r, t = block_chi2(twist(odometry @ invert(true)), covariance(edge_information))
        rotation.append(r)
        translation.append(t)
    return rotation, translation


def stretch_growth(
    nodes: Sequence[Node], truth: NDArray[np.float64], chain: Chain, length: int
) -> tuple[list[float], list[float]]:
    """Per non-overlapping stretch of ``length`` edges, its blocks' normalised squared errors at its
    last node."""
    rotation, translation = [], []
    for first in range(0, len(nodes) - length, length):
        last = first + length
        true = invert(truth[nodes[first].position]) @ truth[nodes[last].position]
        error = chain.correction(LoopEdge(last, first, true, np.eye(6)))  # world frame
        to_last = adjoint(invert(chain.poses[last]))
        r, t = block_chi2(to_last @ error, to_last @ chain.world_covariance(first, last) @ to_last.T)
        rotation.append(r)
        translation.append(t)
    return rotation, translation


def measure(path: Path) -> dict[str, Any]:
    """Shape and growth of one recording's odometry (see the module doc)."""
    recording, truth = load_recording(path)
    nodes = recording["nodes"]
    information = odometry_information(nodes, NodeNormals(nodes), LoopSettings(**recorded_options(recording)))
    chain = Chain(np.stack([node.pose for node in nodes]), list(information))
    rotation, translation = edge_shape(nodes, truth, information)
    row: dict[str, Any] = {
        "sequence": Path(recording["sequence"]).name,
        "edges": len(rotation),
        "rotation_median": statistics.median(rotation),
        "translation_median": statistics.median(translation),
        "growth": {},
    }
    row["shape_ratio"] = row["rotation_median"] / max(row["translation_median"], 1e-12)
    one_rotation, one_translation = stretch_growth(nodes, truth, chain, 1)
    for length in LENGTHS:
        stretch_rotation, stretch_translation = stretch_growth(nodes, truth, chain, length)
        if len(stretch_rotation) >= 3:
            row["growth"][length] = {
                "stretches": len(stretch_rotation),
                "rotation": statistics.median(stretch_rotation) / max(statistics.median(one_rotation), 1e-12),
                "translation": statistics.median(stretch_translation)
                / max(statistics.median(one_translation), 1e-12),
            }
    return row


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("recordings", type=Path, nargs="+", help="loop_replay.py recordings (.pkl)")
    parser.add_argument("--json", type=Path, help="write every row here")
    args = parser.parse_args()
    missing = [str(path) for path in args.recordings if not path.is_file()]
    if missing:
        parser.error(f"no such recording: {', '.join(missing)}")
    rows = [measure(path) for path in args.recordings]
    table = Table(title="odometry errors against the truth, normalised by the chain's covariance")
    for column in ("sequence", "edges", "rotation / translation, one edge"):
        table.add_column(column)
    for length in LENGTHS:
        table.add_column(f"growth over {length} edges, rotation / translation")
    for row in rows:
        cells = [row["sequence"], str(row["edges"]), f"{row['shape_ratio']:.2f}"]
        for length in LENGTHS:
            grown = row["growth"].get(length)
            cells.append(f"{grown['rotation']:.2f} / {grown['translation']:.2f}" if grown else "-")
        table.add_row(*cells)
    Console().print(table)
    if args.json is not None:
        with replacing(args.json) as temporary:
            temporary.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
