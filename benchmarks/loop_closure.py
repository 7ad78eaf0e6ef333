"""``vcr-odom map`` against its own odometry on sequences with ground truth: ATE, revisits closed,
false closures, wall time and memory. Not a test: run

    .venv/bin/python benchmarks/loop_closure.py --sequence runs/loops/synth/sequences/801 \
        [--sequence ...] [--stride K] [--method vcr+kiss-icp] [--json out.json] [--markdown table.md]

Per sequence:

- **ATE** (SE(3)-aligned, evo, as kiss-icp and KISS-SLAM report it) of the odometry and of the
  map's optimised trajectory, and their ratio; the JSON also has the origin-aligned ATE (a heading
  error at the first frame turns the whole run, and no loop can see it).
- **Revisits**: nodes whose true position lies within 5 m of a node driven at least ``min_loop_path_m``
  metres before (ground truth decides, not the odometry). They come in passages (consecutive revisit
  nodes); a passage is closed when an accepted loop starts in it. Nodes within 10 m of path of an
  accepted loop's source count as *covered*.
- **False closures**: accepted loops whose measured transform is more than 1 m / 3 deg off the true
  one (a loop between places truly 15 m apart, measured right, is a true constraint; the JSON gives
  the farthest accepted loop); the JSON lists the right ones' errors too (``right_loop_errors``, each
  with whether it was a fit of submaps), and for each its error's squared Mahalanobis distance under
  the information the graph gave it (``error_chi2``, loops.json's ``information``): a submap loop
  claims metres and degrees, so one beyond 1 m / 3 deg can still be right by its own account (below
  chi-square's 99.9 % on 6 dof, 22.5). **max change**: how far the map moved any frame from the
  odometry (drives without revisits must stay within 1 cm).
- **Time**: ``run`` (the odometry alone, same method, same process, its folder written) against
  ``map`` (its folder written); **memory**: the nodes' bytes and the process's peak RSS.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from vcr_odom.data.selection import FrameSelection
from vcr_odom.evaluation.revisits import true_revisits
from vcr_odom.geometry import invert, motion_difference, twist
from vcr_odom.map_command import MapOutcome, MapSettings, map_sequence
from vcr_odom.metrics.evo_errors import ate_rpe
from vcr_odom.odometry.outputs import ground_truth_for
from vcr_odom.odometry.run import RunSettings, run_sequence

TRUE_RADIUS_M = 5.0
COVER_M = 10.0
FALSE_M, FALSE_DEG = 1.0, 3.0


def revisit_passages(gt: np.ndarray, node_positions: list[int], min_path: float) -> list[list[int]]:
    """Runs of consecutive nodes (indices into the node list) that truly revisit an earlier place
    (:func:`~vcr_odom.evaluation.revisits.true_revisits` on every frame's ground truth)."""
    revisiting_frames = {pair.source for pair in true_revisits(gt, TRUE_RADIUS_M, min_path)}
    passages: list[list[int]] = []
    for j, position in enumerate(node_positions):
        if position not in revisiting_frames:
            continue
        if passages and j == passages[-1][-1] + 1:
            passages[-1].append(j)
        else:
            passages.append([j])
    return passages


def loop_error(
    gt: np.ndarray, frame_position: dict[int, int], loop: dict[str, Any], transform: str
) -> tuple[float, float]:
    """How far a candidate's ``transform`` (``measured_T_target_source`` or ``odometry_T_target_source``
    of loops.json) is from the truth's: metres and degrees."""
    a, b = frame_position[loop["source_frame"]], frame_position[loop["target_frame"]]
    return motion_difference(invert(gt[b]) @ gt[a], np.asarray(loop[transform]))


def error_chi2(gt: np.ndarray, frame_position: dict[int, int], loop: dict[str, Any]) -> float | None:
    """A kept loop's error against the truth as a squared Mahalanobis distance under the information the
    graph gave it (``information`` of loops.json: on a left perturbation in the target's frame, rotation
    then translation); None for a loop the graph did not take."""
    if loop.get("information") is None or loop.get("measured_T_target_source") is None:
        return None
    a, b = frame_position[loop["source_frame"]], frame_position[loop["target_frame"]]
    error = twist(np.asarray(loop["measured_T_target_source"]) @ invert(invert(gt[b]) @ gt[a]))
    return float(error @ np.asarray(loop["information"]) @ error)


def candidates_against_truth(
    gt: np.ndarray, frame_indices: list[int], loops: dict[str, Any]
) -> list[dict[str, Any]]:
    """Every candidate of ``loops`` (as loops.json holds it: its verdict and the verification's scores,
    without the transforms) with how far its measured transform, where there is one, and the odometry's
    are from the truth: why a revisit stayed open, or which check a false fit passed."""
    frame_position = {f: k for k, f in enumerate(frame_indices)}
    rows = []
    for loop in loops["candidates"]:
        row = {key: value for key, value in loop.items() if not key.endswith("_T_target_source")}
        row["odometry_error_m"], row["odometry_error_deg"] = (
            round(value, 3) for value in loop_error(gt, frame_position, loop, "odometry_T_target_source")
        )
        if loop.get("measured_T_target_source") is not None:
            row["error_m"], row["error_deg"] = (
                round(value, 3) for value in loop_error(gt, frame_position, loop, "measured_T_target_source")
            )
            row["error_chi2"] = error_chi2(gt, frame_position, loop)
        rows.append(row)
    return rows


def score_loops(
    gt: np.ndarray,
    frame_indices: list[int],
    loops: dict[str, Any],
    odometry_poses: np.ndarray,
    map_poses: np.ndarray,
    min_loop_path_m: float,
) -> dict[str, Any]:
    """ATE, revisits closed and false closures of one map (see the module doc): ``loops`` as
    ``loops.json`` holds it, ``gt`` every frame's true pose (frames ``frame_indices``)."""
    frame_position = {f: k for k, f in enumerate(frame_indices)}
    nodes = [(frame_position[n["frame"]], n["path_m"]) for n in loops["nodes"]]
    passages = revisit_passages(gt, [p for p, _ in nodes], min_loop_path_m)
    accepted = [c for c in loops["candidates"] if c["accepted"]]
    false, right, farthest = [], [], 0.0
    for loop in accepted:
        a, b = frame_position[loop["source_frame"]], frame_position[loop["target_frame"]]
        apart = float(np.linalg.norm(gt[a][:3, 3] - gt[b][:3, 3]))
        error_m, error_deg = loop_error(gt, frame_position, loop, "measured_T_target_source")
        farthest = max(farthest, apart)
        chi2 = error_chi2(gt, frame_position, loop)
        if error_m <= FALSE_M and error_deg <= FALSE_DEG:
            right.append(
                {
                    "error_m": error_m,
                    "error_deg": error_deg,
                    "submaps": bool(loop.get("submaps")),
                    "error_chi2": chi2,
                }
            )
        else:
            false.append(
                {
                    "frames": [loop["source_frame"], loop["target_frame"]],
                    "true_distance_m": round(apart, 2),
                    "error_m": round(error_m, 3),
                    "error_deg": round(error_deg, 3),
                    "error_chi2": None if chi2 is None else round(chi2, 2),
                    "fitness": loop["fitness"],
                }
            )
    sources = {loop["source_node"] for loop in accepted}
    closed = sum(any(j in sources for j in passage) for passage in passages)
    node_paths = np.array([d for _, d in nodes])
    source_paths = node_paths[sorted(sources)] if sources else np.zeros(0)
    revisit_nodes = [j for passage in passages for j in passage]
    covered = sum(
        bool(len(source_paths)) and np.abs(source_paths - node_paths[j]).min() <= COVER_M
        for j in revisit_nodes
    )
    odometry_ate = ate_rpe(odometry_poses, gt, alignment="se3").ate_trans_rmse_m
    map_ate = ate_rpe(map_poses, gt, alignment="se3").ate_trans_rmse_m
    return {
        "frames": len(map_poses),
        "path_m": round(float(node_paths[-1]), 1) if len(node_paths) else 0.0,
        "odometry_ate_m": odometry_ate,
        "map_ate_m": map_ate,
        "ate_ratio": map_ate / odometry_ate if odometry_ate > 0 else float("nan"),
        "odometry_ate_origin_m": ate_rpe(odometry_poses, gt).ate_trans_rmse_m,
        "map_ate_origin_m": ate_rpe(map_poses, gt).ate_trans_rmse_m,
        "revisit_passages": len(passages),
        "passages_closed": closed,
        "revisit_nodes": len(revisit_nodes),
        "revisit_nodes_covered": int(covered),
        "candidates": len(loops["candidates"]),
        "accepted": len(accepted),
        "false_closures": len(false),
        "false_closure_details": false,
        "right_loop_errors": right,
        "farthest_loop_m": round(farthest, 2),
        "max_change_m": float(np.linalg.norm(map_poses[:, :3, 3] - odometry_poses[:, :3, 3], axis=1).max()),
    }


def score(
    outcome: MapOutcome, settings: MapSettings, odometry_seconds: float, map_seconds: float
) -> dict[str, Any]:
    """The row of one sequence (see the module doc)."""
    gt = ground_truth_for(outcome.sequence, outcome.odometry.frame_indices)
    if gt is None:
        raise SystemExit(f"{outcome.sequence.name}: no ground truth")
    folder = outcome.folder
    loops = json.loads((folder / "loops.json").read_text())
    metrics = json.loads((folder / "metrics.json").read_text())
    row = score_loops(
        gt,
        outcome.odometry.frame_indices,
        loops,
        outcome.odometry.poses,
        outcome.poses,
        settings.min_loop_path_m,
    )
    return {
        "sequence": outcome.sequence.name,
        **row,
        "odometry_seconds": odometry_seconds,
        "map_seconds": map_seconds,
        "time_ratio": map_seconds / odometry_seconds,
        "phase_seconds": outcome.seconds,
        "ground_up": metrics["loops"].get("ground_up"),
        "nodes": metrics["memory"]["nodes"],
        "node_mib": metrics["memory"]["node_bytes"] / 2**20,
        "peak_rss_mib": metrics["memory"]["peak_rss_bytes"] / 2**20,
        "folder": str(folder),
    }


def kiss_slam_row(outcome: MapOutcome, odometry_seconds: float) -> dict[str, Any]:
    """KISS-SLAM on the map's frames: SE(3)-aligned ATE, closures, wall time (against the odometry's).
    Its closures are counted, not scored: KISS-SLAM keeps no measured transform per closure."""
    from vcr_odom.evaluation.kiss_slam import run_kiss_slam

    gt = ground_truth_for(outcome.sequence, outcome.odometry.frame_indices)
    started = time.perf_counter()
    slam = run_kiss_slam(outcome.sequence, outcome.odometry.frame_indices)
    seconds = time.perf_counter() - started
    return {
        "kiss_slam_ate_m": ate_rpe(slam.poses, gt, alignment="se3").ate_trans_rmse_m,
        "kiss_slam_closures": slam.num_closures,
        "kiss_slam_seconds": seconds,
        "kiss_slam_time_ratio": seconds / odometry_seconds,
    }


COLUMNS = (
    ("sequence", "sequence", "{}"),
    ("frames", "frames", "{}"),
    ("path [m]", "path_m", "{:.0f}"),
    ("odometry ATE [m]", "odometry_ate_m", "{:.3f}"),
    ("map ATE [m]", "map_ate_m", "{:.3f}"),
    ("ratio", "ate_ratio", "{:.2f}"),
    ("passages closed", None, None),
    ("loops (false)", None, None),
    ("max change [m]", "max_change_m", "{:.3f}"),
    ("time map/odometry", "time_ratio", "{:.2f}"),
    ("node MiB / peak RSS MiB", None, None),
)


SLAM_COLUMNS = ("KISS-SLAM ATE [m]", "KISS-SLAM closures", "time KISS-SLAM/odometry")
"""Added when KISS-SLAM ran (``--kiss-slam``)."""


def headers(rows: list[dict[str, Any]]) -> list[str]:
    slam = any("kiss_slam_ate_m" in row for row in rows)
    return [h for h, _, _ in COLUMNS] + (list(SLAM_COLUMNS) if slam else [])


def cells(row: dict[str, Any]) -> list[str]:
    out = []
    for _, key, fmt in COLUMNS:
        if key is not None:
            out.append(fmt.format(row[key]))
    out.insert(6, f"{row['passages_closed']}/{row['revisit_passages']}")
    out.insert(7, f"{row['accepted']} ({row['false_closures']})")
    out.append(f"{row['node_mib']:.1f} / {row['peak_rss_mib']:.0f}")
    if "kiss_slam_ate_m" in row:
        out += [
            f"{row['kiss_slam_ate_m']:.3f}",
            str(row["kiss_slam_closures"]),
            f"{row['kiss_slam_time_ratio']:.2f}",
        ]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sequence", type=Path, action="append", required=True, help="sequences/<id> folder")
    parser.add_argument(
        "--name",
        action="append",
        default=[],
        help="what each --sequence is (e.g. 'HDL-64E loop'), shown after its id; one per --sequence or none",
    )
    parser.add_argument("--stride", type=int, default=1)
    parser.add_argument("--method", default="vcr")
    parser.add_argument(
        "--kiss-slam", action="store_true", help="also run KISS-SLAM (vcr-odom[slam]) on the same frames"
    )
    parser.add_argument("--json", type=Path)
    parser.add_argument("--markdown", type=Path)
    args = parser.parse_args()
    if args.name and len(args.name) != len(args.sequence):
        parser.error(
            f"--name: {len(args.name)} given for {len(args.sequence)} --sequence; give one each or none"
        )
    if args.kiss_slam and importlib.util.find_spec("kiss_slam") is None:
        parser.error("--kiss-slam: kiss-slam is not installed (pip install 'vcr-odom[slam]')")
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for index, folder in enumerate(args.sequence):
            root, seq = folder.parent.parent, folder.name
            selection = FrameSelection(data_root=root, seq=seq, stride=args.stride)
            started = time.perf_counter()
            run_sequence(RunSettings(selection=selection, method=args.method, results_dir=Path(scratch)))
            odometry_seconds = time.perf_counter() - started
            settings = MapSettings(selection=selection, method=args.method, results_dir=Path(scratch))
            started = time.perf_counter()
            outcome = map_sequence(settings)
            map_seconds = time.perf_counter() - started
            row = score(outcome, settings, odometry_seconds, map_seconds)
            if args.name:
                row["sequence"] = f"{seq} {args.name[index]}"
            if args.kiss_slam:
                row.update(kiss_slam_row(outcome, odometry_seconds))
            rows.append(row)
    table = Table(title="vcr-odom map against its odometry")
    for header in headers(rows):
        table.add_column(header)
    for row in rows:
        table.add_row(*cells(row))
    Console().print(table)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    if args.markdown:
        names = headers(rows)
        lines = ["| " + " | ".join(names) + " |", "|" + "---|" * len(names)]
        lines += ["| " + " | ".join(cells(row)) + " |" for row in rows]
        args.markdown.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
