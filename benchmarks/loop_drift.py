"""How much odometry drift `map`'s loop closure survives: ground truth with a drift added, then the
loop phase and the graph of ``vcr-odom map``. Not a test: run

    .venv/bin/python benchmarks/loop_drift.py --sequence WORK/indoor/sequences/902 \
        [--sequence ...] [--scale 0.02 --yaw 0.05 --pitch 0.01] \
        [--set candidate_confidence=0.999 --set odometry_confidence=0.9999 ...] [--json out.json]

Why: the synthetic drives' own odometry drifts 0.01-0.5 % of the path, real recordings 1-3 % (the
team's Avia campus loops: ATE 0.77 and 1.69 m on ~60 m). The drift added is systematic, the way a
scan matcher's drifts: every step's translation scaled by ``1 + scale`` and turned by ``yaw`` (and
``pitch``) degrees per metre driven. Each (scale, yaw, pitch) given runs on the same frames; the
nodes are recorded once per drift from the drifted poses, as ``map`` records them from its odometry,
and the loop phase runs on them with ``map``'s loop settings (``--set NAME=VALUE`` replaces one, a
field of ``LoopSettings``, as in ``benchmarks/loop_replay.py``): the candidates and the verification
judge a loop by the odometry's own propagated uncertainty, which an added drift it does not know of
exceeds.

One row per sequence and drift: the drifted trajectory's ATE (SE(3)-aligned) and its end-point error
against the path (the drift the loops must undo), the map's ATE, revisit passages closed, loops
accepted and false (more than 1 m / 3 deg off the truth) and the worst false one's error, how many
candidates asked the odometry for more than its uncertainty allows (``odometry``) and the factor the
loops measured on the odometry's covariance. With no drift the odometry is the truth and the ratio is
left out (nan).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.progress import track
from rich.table import Table

from vcr_odom.data import open_sequence
from vcr_odom.geometry import (
    Transform,
    invert,
    make_transform,
    motion_difference,
    rotation_angle,
    rotation_from_euler_zyx,
)
from vcr_odom.loops import pipeline
from vcr_odom.loops.nodes import Node, NodeRecorder
from vcr_odom.loops.settings import LoopSettings
from vcr_odom.metrics.evo_errors import ate_rpe
from vcr_odom.registration.vcr import VcrRegistrar

sys.path.insert(0, str(Path(__file__).parent))
from loop_closure import FALSE_DEG, FALSE_M, revisit_passages
from loop_replay import add_set_option, loop_options_set


def drifted(truth: np.ndarray, scale: float, yaw_deg_per_m: float, pitch_deg_per_m: float) -> np.ndarray:
    """``truth``'s steps, each scaled and turned in the sensor's frame by the drift per metre."""
    poses = [truth[0].copy()]
    for previous, current in itertools.pairwise(truth):
        step = invert(previous) @ current
        metres = float(np.linalg.norm(step[:3, 3]))
        error = rotation_from_euler_zyx(
            math.radians(yaw_deg_per_m * metres), math.radians(pitch_deg_per_m * metres), 0.0
        )
        moved = make_transform(step[:3, :3] @ error, step[:3, 3] * (1.0 + scale))
        poses.append(poses[-1] @ moved)
    return np.stack(poses)


def record_nodes(sequence: Any, odometry: np.ndarray, options: LoopSettings) -> list[Node]:
    recorder = NodeRecorder(options.node_spacing_m, options.node_angle_deg)
    for position in range(len(sequence)):
        recorder(position, odometry[position], sequence.frame(position))
    return recorder.finish()


def _error(decision: Any, truth: np.ndarray) -> tuple[float, float]:
    """How far (m, deg) a loop's measured transform is from the truth's."""
    expected: Transform = invert(truth[decision.target_frame]) @ truth[decision.source_frame]
    return motion_difference(expected, decision.loop.transform)


def measure(
    path: Path, drift: tuple[float, float, float], options: LoopSettings, network: VcrRegistrar
) -> dict[str, Any]:
    """The row of one drive with ``drift`` added (scale, yaw and pitch deg / m), closed with ``options``."""
    sequence = open_sequence(path.name, data_root=path.parent.parent)
    truth = sequence.gt_poses
    if truth is None:
        raise SystemExit(f"{path}: no ground truth")
    odometry = drifted(truth, *drift)
    nodes = record_nodes(sequence, odometry, options)
    started = time.perf_counter()
    closed = pipeline.close_loops(options, network, nodes, odometry)
    row = _row(truth, odometry, nodes, closed.decisions, closed.poses, options.min_loop_path_m)
    return {
        "sequence": path.name,
        "scale": drift[0],
        "yaw_deg_per_m": drift[1],
        "pitch_deg_per_m": drift[2],
        **row,
        "odometry_covariance_scale": closed.odometry_scale,
        "seconds": time.perf_counter() - started,
    }


def _row(
    truth: np.ndarray,
    odometry: np.ndarray,
    nodes: list[Node],
    decisions: list,
    poses: np.ndarray,
    min_loop_path_m: float = LoopSettings().min_loop_path_m,
) -> dict:
    steps = np.linalg.norm(np.diff(truth[:, :3, 3], axis=0), axis=1)
    passages = revisit_passages(truth, [node.position for node in nodes], min_loop_path_m)
    accepted = [d for d in decisions if d.accepted]
    errors = [_error(d, truth) for d in accepted]
    false_m = [metres for metres, degrees in errors if metres > FALSE_M or degrees > FALSE_DEG]
    sources = {d.candidate.source for d in accepted}
    odometry_ate = ate_rpe(odometry, truth, alignment="se3").ate_trans_rmse_m
    map_ate = ate_rpe(poses, truth, alignment="se3").ate_trans_rmse_m
    end_error = invert(truth[-1]) @ odometry[-1]
    return {
        "path_m": round(float(steps.sum()), 1),
        "end_error_m": round(float(np.linalg.norm(end_error[:3, 3])), 3),
        "end_error_deg": round(math.degrees(float(rotation_angle(end_error[:3, :3]))), 2),
        "odometry_ate_m": odometry_ate,
        "map_ate_m": map_ate,
        "ate_ratio": map_ate / odometry_ate if odometry_ate > 1e-3 else float("nan"),
        "revisit_passages": len(passages),
        "passages_closed": sum(any(j in sources for j in passage) for passage in passages),
        "candidates": len(decisions),
        "accepted": len(accepted),
        "false_closures": len(false_m),
        "worst_false_m": max(false_m, default=0.0),
        "rejected_for_odometry": sum(d.check == "odometry" for d in decisions),
        "inconsistent": sum(d.check == "inconsistent" for d in decisions),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sequence", type=Path, action="append", required=True)
    parser.add_argument("--scale", type=float, action="append", help="translation scale error (0.02 = 2 %%)")
    parser.add_argument("--yaw", type=float, action="append", help="heading drift, deg per metre")
    parser.add_argument("--pitch", type=float, action="append", help="pitch drift, deg per metre")
    add_set_option(parser)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    scales, yaws = args.scale or [0.0], args.yaw or [0.0]
    pitches = args.pitch or [0.0] * max(len(scales), len(yaws))
    count = max(len(scales), len(yaws), len(pitches))
    if {len(scales), len(yaws), len(pitches)} - {1, count}:
        raise SystemExit("--scale, --yaw and --pitch: give each once or as often as the longest of them")
    drifts = [(scales[k % len(scales)], yaws[k % len(yaws)], pitches[k % len(pitches)]) for k in range(count)]
    options_set = loop_options_set(args.options_set, parser)
    options = LoopSettings(**options_set)
    network = VcrRegistrar()
    rows = [
        measure(path, drift, options, network) | {"options_set": options_set}
        for path in track(args.sequence, "drives")
        for drift in drifts
    ]
    table = Table(title="loop closure under added drift")
    columns = [
        ("sequence", "sequence"), ("scale", "scale"), ("yaw_deg_per_m", "yaw deg/m"),
        ("pitch_deg_per_m", "pitch deg/m"), ("path_m", "path m"), ("end_error_m", "end error m"),
        ("end_error_deg", "end error deg"), ("odometry_ate_m", "drifted ATE m"), ("map_ate_m", "map ATE m"),
        ("ate_ratio", "ratio"), ("passages_closed", "closed"), ("revisit_passages", "passages"),
        ("accepted", "loops"), ("false_closures", "false"), ("worst_false_m", "worst false m"),
        ("rejected_for_odometry", "beyond odometry"), ("inconsistent", "inconsistent"),
        ("odometry_covariance_scale", "covariance scale"),
    ]  # fmt: skip
    for _, title in columns:
        table.add_column(title)
    for row in rows:
        table.add_row(
            *[f"{row[key]:.3f}" if isinstance(row[key], float) else str(row[key]) for key, _ in columns]
        )
    Console(width=220).print(table)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
