"""What the best pose graph with perfect loops can make of an odometry whose steps err at random:
the bound on what loop closure can do, whatever its loops. Not a test: run

    .venv/bin/python benchmarks/loop_bound.py [--trials 100] [--seed 0] [--json out.json]

Each trial drives one of three routes in the plane, a node every 3 m (a 150 x 100 m block once round
and 30 m on; a figure eight of two 100 x 100 m lobes; 250 m out and back 3 m to the side), and makes
an odometry from the truth's steps, each given an error drawn anew: a heading error (yaw, degrees), a
translation error (metres on each of x and y), a constant heading bias (degrees per step) and a scale
bias (a share of the step's length, along it). The pose
graph is open3d's, weighted with the very sigmas the errors were drawn from (the best weighting there
is), and its loops are perfect: every second node within 5 m of a node passed at least 30 m of path
before, measured by the truth to 1 cm / 0.03 deg. Per regime and route, over the trials: the
odometry's ATE, the map's as a share of it (SE(3)-aligned, as everywhere in vcr-odom), how many
trials reach a third, and the rotation share of the odometry's error (``odometry_error_split.py``,
the column ``loop_replay.py replay --truth-loops`` prints for recorded drives).

Why: an odometry's heading error turns everything after it, a loop sees it and the graph undoes it;
a translation error between two revisits leaves the loop only its sum, so no graph can place it; and
a scale error leaves a route that comes back still coming back, so no loop sees it at all.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import open3d as o3d
from numpy.typing import NDArray
from odometry_error_split import error_split  # beside this script
from rich.console import Console
from rich.progress import track
from rich.table import Table

from vcr_odom.geometry import invert, make_transform, rotation_from_euler_zyx
from vcr_odom.io import replacing
from vcr_odom.metrics.evo_errors import ate_rpe

STEP_M = 3.0
REVISIT_M = 5.0
MIN_LOOP_PATH_M = 30.0
LOOP_SIGMAS = (0.01, math.radians(0.03))
"""A perfect loop's sigmas (metres, radians): tight, so that the loops hold and the odometry bends."""
ROUTES: dict[str, list[tuple[float, float]]] = {
    "loop": [(0, 0), (150, 0), (150, 100), (0, 100), (0, 0), (30, 0)],
    "figure eight": [(0, 50), (200, 50), (200, 150), (100, 150), (100, -50), (0, -50), (0, 50), (30, 50)],
    "return": [(0, 0), (250, 0), (250, 3), (0, 3)],
}


@dataclass(frozen=True)
class Regime:
    """Per-step odometry errors: heading sigma and bias in degrees, translation sigma in metres, and
    a scale bias (each step's translation measured ``1 + scale_bias`` times its length)."""

    name: str
    heading_sigma_deg: float
    translation_sigma_m: float
    heading_bias_deg: float = 0.0
    scale_bias: float = 0.0


REGIMES = (
    Regime("heading noise 0.1 deg", 0.1, 0.002),
    Regime("translation noise 3 cm", 0.001, 0.03),
    Regime("both", 0.1, 0.03),
    Regime("heading bias 0.05 deg + noise 0.05 deg", 0.05, 0.002, 0.05),
    Regime("scale bias -3 % + heading noise 0.01 deg", 0.01, 0.002, scale_bias=-0.03),
)


def route_poses(corners: Sequence[tuple[float, float]], step_m: float = STEP_M) -> NDArray[np.float64]:
    """Poses every ``step_m`` along the straight legs between ``corners``, heading along the leg."""
    points: list[NDArray[np.float64]] = []
    for start, end in itertools.pairwise(corners):
        a, b = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
        count = max(1, round(float(np.linalg.norm(b - a)) / step_m))
        points += [a + (b - a) * i / count for i in range(count)]
    points.append(np.asarray(corners[-1], dtype=float))
    xy = np.array(points)
    headings = np.arctan2(*np.diff(xy, axis=0)[:, ::-1].T)
    headings = np.append(headings, headings[-1])
    return np.stack(
        [
            make_transform(rotation_from_euler_zyx(h, 0.0, 0.0), [x, y, 0.0])
            for (x, y), h in zip(xy, headings, strict=True)
        ]
    )


def noisy_odometry(
    truth: NDArray[np.float64], regime: Regime, rng: np.random.Generator
) -> NDArray[np.float64]:
    """The truth's steps, each followed by a fresh error of ``regime``, chained from the first pose."""
    poses = [truth[0]]
    for k in range(len(truth) - 1):
        step = invert(truth[k]) @ truth[k + 1]
        heading = math.radians(rng.normal(regime.heading_bias_deg, regime.heading_sigma_deg))
        shift = np.array([*rng.normal(0.0, regime.translation_sigma_m, 2), 0.0])
        shift += regime.scale_bias * step[:3, :3].T @ step[:3, 3]  # along the step, in its end's frame
        error = make_transform(rotation_from_euler_zyx(heading, 0.0, 0.0), shift)
        poses.append(poses[-1] @ step @ error)
    return np.stack(poses)


def revisits(truth: NDArray[np.float64]) -> list[tuple[int, int]]:
    """(source, target) node pairs a loop joins: every second node within ``REVISIT_M`` of an earlier
    one at least ``MIN_LOOP_PATH_M`` of path before, with the nearest such."""
    positions = truth[:, :3, 3]
    path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))])
    pairs = []
    for source in range(0, len(truth), 2):
        distances = np.linalg.norm(positions[:source] - positions[source], axis=1)
        near = (distances < REVISIT_M) & (path[source] - path[:source] >= MIN_LOOP_PATH_M)
        if near.any():
            pairs.append((source, int(np.flatnonzero(near)[np.argmin(distances[near])])))
    return pairs


def _information(translation_sigma_m: float, rotation_sigma_rad: float) -> NDArray[np.float64]:
    """open3d's order: rotation first, then translation."""
    return np.diag([rotation_sigma_rad**-2] * 3 + [translation_sigma_m**-2] * 3)


def perfect_loop_map(
    truth: NDArray[np.float64], odometry: NDArray[np.float64], regime: Regime
) -> tuple[NDArray[np.float64], int]:
    """The odometry's poses optimised with its steps (weighted by ``regime``'s own sigmas) and a
    perfect loop on every pair of :func:`revisits`; also the number of loops."""
    pipelines = o3d.pipelines.registration
    graph = pipelines.PoseGraph()
    for pose in odometry:
        graph.nodes.append(pipelines.PoseGraphNode(pose))
    step_information = _information(
        max(regime.translation_sigma_m, 1e-4), math.radians(max(regime.heading_sigma_deg, 1e-4))
    )
    for k in range(len(odometry) - 1):  # an edge (source, target, T) holds T = pose_target^-1 pose_source
        step = invert(odometry[k]) @ odometry[k + 1]
        graph.edges.append(pipelines.PoseGraphEdge(k + 1, k, step, step_information, uncertain=False))
    pairs = revisits(truth)
    for source, target in pairs:
        measured = invert(truth[target]) @ truth[source]
        graph.edges.append(
            pipelines.PoseGraphEdge(source, target, measured, _information(*LOOP_SIGMAS), uncertain=True)
        )
    option = pipelines.GlobalOptimizationOption(
        max_correspondence_distance=1.0,
        edge_prune_threshold=0.0,
        reference_node=0,
        preference_loop_closure=1.0,
    )
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        pipelines.global_optimization(
            graph,
            pipelines.GlobalOptimizationLevenbergMarquardt(),
            pipelines.GlobalOptimizationConvergenceCriteria(),
            option,
        )
    return np.stack([np.asarray(node.pose) for node in graph.nodes]), len(pairs)


@dataclass(frozen=True)
class Trial:
    odometry_ate_m: float
    map_ate_m: float
    loops: int
    rotation_share: float


def trial(truth: NDArray[np.float64], regime: Regime, rng: np.random.Generator) -> Trial:
    odometry = noisy_odometry(truth, regime, rng)
    mapped, loops = perfect_loop_map(truth, odometry, regime)
    return Trial(
        odometry_ate_m=ate_rpe(odometry, truth, alignment="se3").ate_trans_rmse_m,
        map_ate_m=ate_rpe(mapped, truth, alignment="se3").ate_trans_rmse_m,
        loops=loops,
        rotation_share=error_split(odometry, truth).rotation_share,
    )


def summary(regime: Regime, route: str, trials: Sequence[Trial]) -> dict[str, float | int | str]:
    ratios = np.array([t.map_ate_m / t.odometry_ate_m for t in trials])
    return {
        "regime": regime.name,
        "route": route,
        "trials": len(trials),
        "loops": trials[0].loops,
        "odometry_ate_median_m": float(np.median([t.odometry_ate_m for t in trials])),
        "rotation_share_median": float(np.median([t.rotation_share for t in trials])),
        "ratio_median": float(np.median(ratios)),
        "ratio_p10": float(np.percentile(ratios, 10)),
        "ratio_p90": float(np.percentile(ratios, 90)),
        "share_within_third": float(np.mean(ratios <= 1 / 3)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--trials", type=int, default=100, help="odometries drawn per regime and route")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    if args.trials < 1:
        parser.error(f"--trials {args.trials}: expected at least 1")
    rng = np.random.default_rng(args.seed)
    rows = []
    for regime in REGIMES:
        for route, corners in ROUTES.items():
            truth = route_poses(corners)
            trials = [trial(truth, regime, rng) for _ in track(range(args.trials), f"{regime.name}, {route}")]
            rows.append(summary(regime, route, trials))
    table = Table(
        title=f"perfect loops on a random-walk odometry ({args.trials} trials each, seed {args.seed})"
    )
    for header in (
        "regime",
        "route",
        "loops",
        "odometry ATE [m]",
        "rotation share",
        "map / odometry",
        "<= 1/3",
    ):
        table.add_column(header)
    for row in rows:
        table.add_row(
            str(row["regime"]),
            str(row["route"]),
            str(row["loops"]),
            f"{row['odometry_ate_median_m']:.3f}",
            f"{row['rotation_share_median']:.2f}",
            f"{row['ratio_median']:.2f} ({row['ratio_p10']:.2f}-{row['ratio_p90']:.2f})",
            f"{row['share_within_third']:.0%}",
        )
    Console().print(table)
    print("medians over the trials; map / odometry: median (10th-90th percentile)")
    if args.json:
        with replacing(args.json) as temporary:
            temporary.write_text(
                json.dumps(
                    {"regimes": [asdict(r) for r in REGIMES], "rows": rows, "seed": args.seed}, indent=1
                )
            )


if __name__ == "__main__":
    main()
