"""Revisit pairs: frames a few metres apart in space, not necessarily in time, with a heading change.

Why: relocalisation and loop closure hand a registration method two scans of the same place taken
from different spots and headings, with no initial guess; the odometry gap sweep never meets that
(its pairs all face the same way). The acceptance reads: pairs 3-6 m apart with a heading change up
to 90 deg, >= 90 % within 0.5 m / 2 deg.

Selection works on the sequence's ground-truth LiDAR-frame poses ``P`` (world = frame 0):

- distance: the 3-D distance between the sensor positions ``|t_i - t_j|``, in ``[min_m, max_m]``;
- heading change: the difference of the sensor's yaw about the world's vertical axis (the azimuth of
  its x axis, ``atan2(R[1, 0], R[0, 0])``), wrapped to [0, 180] deg, at most ``max_heading_deg``.
  Yaw, not the geodesic angle, because a hand-held sensor's tilt would otherwise count as a turn;
  the geodesic angle of ``inv(P_i) @ P_j`` is reported beside it;
- ``j - i >= min_frame_gap`` (1: any two distinct frames), and at least ``min_path_m`` metres of
  travel between them (0: no such bound).

:func:`true_revisits` lists every pair within a radius after some travel, whatever the heading: the
places a loop closure should recognise (synthetic routes that come back, ``vcr-odom synth --route``).

A long drive gives thousands of such pairs, so at most ``limit`` are kept: the limit is shared
between heading bins (0-30, 30-60, 60-90 deg by default) as evenly as their sizes allow, and
inside a bin one pair is drawn (seeded) from each of ``quota`` equal slices of the pairs sorted by
distance, so the sample spans the distance range too.

Evaluation reuses the gap sweep's machinery: each frame of the kept pairs is prepared once per
method, every pair registered with source = the later frame j, target = the earlier frame i and no
initial guess, against the truth ``inv(P_i) @ P_j``; success is under both thresholds (2 deg and
0.5 m by default), also per heading bin.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vcr_odom.errors import ConfigError
from vcr_odom.evaluation.gap_sweep import (
    Progress,
    check_names,
    pair_ticker,
    prepare_frames,
    register_pairs,
    true_motions,
)
from vcr_odom.geometry import rotation_angle
from vcr_odom.jsonsafe import json_safe
from vcr_odom.metrics import PairErrors, pair_errors
from vcr_odom.metrics.checks import as_poses

if TYPE_CHECKING:
    from vcr_odom.data.base import LidarSequence
    from vcr_odom.registration.base import Registrar


BOUND_TOLERANCE = 1e-9
"""Metres or degrees: a pose turned by exactly 90 deg reads 90.00000000001 after atan2; it still counts."""


@dataclass(frozen=True)
class RevisitOptions:
    """Which pairs count as revisits and how many to keep; each bad value raises a ConfigError
    naming the benchmark option that sets it."""

    min_m: float = 3.0
    max_m: float = 6.0
    max_heading_deg: float = 90.0
    min_frame_gap: int = 1
    limit: int | None = 60  # None: every pair
    seed: int = 0
    bin_deg: float = 30.0  # width of the heading bins the limit is shared between
    min_path_m: float = 0.0  # travel between the two frames, summed over every frame in between

    def __post_init__(self) -> None:
        for option, value in (
            ("--min-m", self.min_m),
            ("--max-m", self.max_m),
            ("--max-heading", self.max_heading_deg),
            ("--heading-bin", self.bin_deg),
            ("min_path_m", self.min_path_m),
        ):
            if not isinstance(value, int | float) or not math.isfinite(value):
                raise ConfigError(f"{option} must be a finite number; got {value!r}")
        if self.min_m < 0:
            raise ConfigError(f"--min-m must be >= 0 m; got {self.min_m}")
        if self.max_m <= 0:
            raise ConfigError(f"--max-m must be positive; got {self.max_m}")
        if self.min_m > self.max_m:
            raise ConfigError(f"--min-m {self.min_m} is more than --max-m {self.max_m}")
        if not 0 < self.max_heading_deg <= 180:
            raise ConfigError(f"--max-heading must be in (0, 180] deg; got {self.max_heading_deg}")
        if self.bin_deg <= 0:
            raise ConfigError(f"--heading-bin must be positive; got {self.bin_deg}")
        if self.min_path_m < 0:
            raise ConfigError(f"min_path_m must be >= 0 m; got {self.min_path_m}")
        for option, value in (("--min-frame-gap", self.min_frame_gap), ("--limit", self.limit)):
            if value is not None and (not isinstance(value, int | np.integer) or value < 1):
                raise ConfigError(f"{option} must be a positive integer; got {value!r}")
        if not isinstance(self.seed, int | np.integer) or self.seed < 0:
            raise ConfigError(f"--seed must be a non-negative integer; got {self.seed!r}")

    def heading_edges(self) -> list[float]:
        """Bin edges from 0 to ``max_heading_deg`` in steps of ``bin_deg`` (the last one may be shorter)."""
        edges = list(np.arange(0.0, self.max_heading_deg, self.bin_deg))
        return [float(edge) for edge in edges] + [float(self.max_heading_deg)]


@dataclass(frozen=True)
class RevisitPair:
    """Target frame i, source frame j (i < j) and how far apart they are."""

    target: int
    source: int
    distance_m: float  # |t_i - t_j|, 3-D
    heading_deg: float  # yaw change about the world's vertical axis, [0, 180]
    rotation_deg: float  # geodesic angle of inv(P_i) @ P_j


def heading_bin(heading_deg: float, edges: Sequence[float]) -> int:
    """Index of the bin ``[edges[k], edges[k + 1])`` holding a heading; the last bin includes its end."""
    return int(np.clip(np.searchsorted(edges, heading_deg, side="right") - 1, 0, len(edges) - 2))


def bin_labels(edges: Sequence[float]) -> list[str]:
    return [f"{lo:g}-{hi:g}" for lo, hi in itertools.pairwise(edges)]


# --------------------------------------------------------------------------------------- selection


def yaw_angles(poses: ArrayLike) -> NDArray[np.float64]:
    """Each pose's yaw (radians) about the world's vertical axis: the azimuth of its x axis."""
    poses = np.asarray(poses, dtype=np.float64)
    return np.arctan2(poses[:, 1, 0], poses[:, 0, 0])


def candidate_pairs(
    poses: ArrayLike, options: RevisitOptions = RevisitOptions(), frames: Sequence[int] | None = None
) -> list[RevisitPair]:
    """Every pair (i, j) of ``frames`` (default: all) inside the options' bounds, ordered by (i, j).

    Row by row rather than one N x N matrix, so a 4500-frame KITTI drive stays a few MB."""
    poses = as_poses(poses, "ground-truth poses")
    frames = sorted({int(f) for f in (range(len(poses)) if frames is None else frames)})
    if frames and not 0 <= frames[0] <= frames[-1] < len(poses):
        raise ConfigError(f"frames {frames[0]}..{frames[-1]} fall outside the {len(poses)} poses")
    index = np.asarray(frames, dtype=np.int64)
    positions = poses[index, :3, 3]
    yaws = yaw_angles(poses[index])
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    travelled = np.concatenate([[0.0], np.cumsum(steps)])[index]
    found: list[tuple[int, int, float, float]] = []
    for a in range(len(index) - 1):
        later = np.arange(a + 1, len(index))
        distance = np.linalg.norm(positions[later] - positions[a], axis=1)
        heading = np.abs((np.degrees(yaws[later] - yaws[a]) + 180.0) % 360.0 - 180.0)
        keep = (
            (distance >= options.min_m - BOUND_TOLERANCE)
            & (distance <= options.max_m + BOUND_TOLERANCE)
            & (heading <= options.max_heading_deg + BOUND_TOLERANCE)
            & (index[later] - index[a] >= options.min_frame_gap)
            & (travelled[later] - travelled[a] >= options.min_path_m - BOUND_TOLERANCE)
        )
        for n in np.flatnonzero(keep):
            found.append((int(index[a]), int(index[later[n]]), float(distance[n]), float(heading[n])))
    if not found:
        return []
    truths = true_motions(poses, [(i, j) for i, j, _, _ in found])
    rotations = np.degrees(np.atleast_1d(rotation_angle(truths)))
    return [
        RevisitPair(i, j, float(distance), float(heading), float(rotation))
        for (i, j, distance, heading), rotation in zip(found, rotations, strict=True)
    ]


def true_revisits(
    poses: ArrayLike | LidarSequence,
    radius_m: float = 5.0,
    min_path_m: float = 30.0,
    min_frame_gap: int = 1,
) -> list[RevisitPair]:
    """Every pair of frames (i, j), i < j, whose sensors are at most ``radius_m`` apart after at least
    ``min_path_m`` metres of travel (and ``min_frame_gap`` frames) between them, with the heading
    change (any, up to 180 deg), ordered by (i, j): the revisits a loop closure should find.

    Why travel and not only frames: a car standing at a light or a walker pausing stays within the
    radius for many frames without having left and come back. ``poses`` are 4x4 poses in one frame
    (world or first-frame), or a sequence with ground truth (its ``gt_poses``)."""
    if hasattr(poses, "gt_poses"):
        if poses.gt_poses is None:
            raise ConfigError(f"true revisits need ground-truth poses; {poses.name} has none")
        poses = poses.gt_poses
    if not (isinstance(radius_m, int | float) and math.isfinite(radius_m) and radius_m > 0):
        raise ConfigError(f"radius_m must be a positive number of metres; got {radius_m!r}")
    options = RevisitOptions(
        min_m=0.0,
        max_m=radius_m,
        max_heading_deg=180.0,
        min_frame_gap=min_frame_gap,
        limit=None,
        min_path_m=min_path_m,
    )
    return candidate_pairs(poses, options)


def share_limit(limit: int, sizes: Sequence[int]) -> list[int]:
    """Split ``limit`` between bins as evenly as their sizes allow: small bins give all they have,
    the rest goes to the larger ones (deterministic; the remainder to the largest)."""
    quotas = [0] * len(sizes)
    left = limit
    order = sorted(range(len(sizes)), key=lambda k: (sizes[k], k))
    for n, k in enumerate(order):
        quotas[k] = min(sizes[k], left // (len(order) - n))
        left -= quotas[k]
    return quotas


def stratified_sample(
    pairs: Sequence[RevisitPair], options: RevisitOptions = RevisitOptions()
) -> list[RevisitPair]:
    """At most ``options.limit`` pairs, shared between heading bins and spread over distance.

    Within a bin, the pairs sorted by distance are cut into ``quota`` slices and one pair drawn from
    each with ``options.seed``: the same seed gives the same pairs. Returned ordered by (i, j)."""
    if options.limit is None or len(pairs) <= options.limit:
        return sorted(pairs, key=lambda p: (p.target, p.source))
    edges = options.heading_edges()
    bins: list[list[RevisitPair]] = [[] for _ in edges[:-1]]
    for pair in pairs:
        bins[heading_bin(pair.heading_deg, edges)].append(pair)
    quotas = share_limit(options.limit, [len(members) for members in bins])
    rng = np.random.default_rng(options.seed)
    chosen: list[RevisitPair] = []
    for members, quota in zip(bins, quotas, strict=True):
        if quota == 0:
            continue
        members = sorted(members, key=lambda p: (p.distance_m, p.target, p.source))
        cuts = (np.arange(quota + 1) * len(members)) // quota  # each slice holds >= 1 pair
        chosen += [members[int(rng.integers(lo, hi))] for lo, hi in itertools.pairwise(cuts)]
    return sorted(chosen, key=lambda p: (p.target, p.source))


def select_revisits(
    poses: ArrayLike, options: RevisitOptions = RevisitOptions(), frames: Sequence[int] | None = None
) -> tuple[list[RevisitPair], int]:
    """The kept revisit pairs and how many candidates they were drawn from."""
    candidates = candidate_pairs(poses, options, frames)
    return stratified_sample(candidates, options), len(candidates)


# -------------------------------------------------------------------------------------- evaluation


@dataclass
class RevisitRow:
    """One method on the revisit pairs of one sequence (or several pooled): success, overall and per
    heading bin, pose errors and time per pair."""

    sequence: str
    method: str
    pairs: list[RevisitPair]
    truths: NDArray[np.float64] = field(repr=False)
    estimates: NDArray[np.float64] = field(repr=False)
    register_ms: NDArray[np.float64] = field(repr=False)
    prepare_ms_total: float  # the frames these pairs use, each prepared once
    num_failed: int  # pairs whose estimate was not finite (counted as the identity)
    edges: list[float]
    errors: PairErrors = field(repr=False)

    @property
    def num_pairs(self) -> int:
        return len(self.pairs)

    @property
    def success_rate(self) -> float:
        return self.errors.success_rate

    @property
    def ms_per_pair(self) -> float:
        return (self.prepare_ms_total + float(self.register_ms.sum())) / self.num_pairs

    def success_by_bin(self) -> dict[str, tuple[int, float]]:
        """Heading bin label -> (pairs, success rate); NaN for a bin with no pair."""
        bins = np.array([heading_bin(p.heading_deg, self.edges) for p in self.pairs])
        result = {}
        for k, label in enumerate(bin_labels(self.edges)):
            inside = bins == k
            rate = float(self.errors.success[inside].mean()) if inside.any() else math.nan
            result[label] = (int(inside.sum()), rate)
        return result

    def to_dict(self, include_arrays: bool = False) -> dict[str, Any]:
        """JSON-safe figures (per-pair lists only when asked)."""
        result: dict[str, Any] = {
            "sequence": self.sequence,
            "method": self.method,
            "num_pairs": self.num_pairs,
            "success_rate": self.success_rate,
            "success_by_heading_deg": {
                label: {"pairs": n, "success_rate": rate}
                for label, (n, rate) in self.success_by_bin().items()
            },
            "ms_per_pair": self.ms_per_pair,
            "prepare_ms_total": self.prepare_ms_total,
            "register_ms_per_pair": float(self.register_ms.mean()),
            "num_failed": self.num_failed,
            "errors": self.errors.to_dict(include_arrays=include_arrays),
        }
        if include_arrays:
            result["pairs"] = [pair.__dict__ for pair in self.pairs]
            result["estimates"] = self.estimates
        return json_safe(result)


def summarise(
    sequence: str,
    method: str,
    pairs: list[RevisitPair],
    truths: NDArray[np.float64],
    estimates: NDArray[np.float64],
    register_ms: NDArray[np.float64],
    prepare_ms_total: float,
    num_failed: int,
    edges: list[float],
    thresholds: tuple[float, float],
) -> RevisitRow:
    """A row from per-pair results; ``thresholds`` = (rotation deg, translation m) for success."""
    errors = pair_errors(estimates, truths, rot_threshold_deg=thresholds[0], trans_threshold_m=thresholds[1])
    return RevisitRow(
        sequence, method, pairs, truths, estimates, register_ms, prepare_ms_total, num_failed, edges, errors
    )


def pool_rows(rows: Sequence[RevisitRow], sequence: str = "all") -> list[RevisitRow]:
    """One row per method over every row of that method (several sequences), in first-seen order."""
    pooled = []
    for method in dict.fromkeys(row.method for row in rows):
        mine = [row for row in rows if row.method == method]
        edges = mine[0].edges
        if any(row.edges != edges for row in mine):
            raise ConfigError(f"cannot pool {method}: its rows use different heading bins")
        thresholds = (mine[0].errors.success_rot_threshold_deg, mine[0].errors.success_trans_threshold_m)
        pooled.append(
            summarise(
                sequence,
                method,
                [pair for row in mine for pair in row.pairs],
                np.concatenate([row.truths for row in mine]),
                np.concatenate([row.estimates for row in mine]),
                np.concatenate([row.register_ms for row in mine]),
                sum(row.prepare_ms_total for row in mine),
                sum(row.num_failed for row in mine),
                edges,
                thresholds,
            )
        )
    return pooled


@dataclass
class RevisitRun:
    """The revisit evaluation of one sequence: its pairs and one row per method."""

    sequence: str
    num_frames: int
    num_candidates: int
    options: RevisitOptions
    pairs: list[RevisitPair]
    rows: list[RevisitRow]

    def to_dict(self, include_arrays: bool = False) -> dict[str, Any]:
        return json_safe(
            {
                "sequence": self.sequence,
                "num_frames": self.num_frames,
                "num_candidates": self.num_candidates,
                "options": self.options.__dict__,
                "heading_definition": "yaw change about the world vertical axis; geodesic angle per pair too",
                "rows": [row.to_dict(include_arrays) for row in self.rows],
            }
        )


def run_revisits(
    sequence: LidarSequence,
    registrars: Sequence[Registrar],
    options: RevisitOptions = RevisitOptions(),
    *,
    frames: Sequence[int] | None = None,
    progress: Progress | None = None,
    rot_threshold_deg: float = 2.0,
    trans_threshold_m: float = 0.5,
) -> RevisitRun:
    """Select the revisit pairs of ``frames`` (default: all) and register them with each registrar.

    Needs ground-truth poses; a ConfigError names the options to widen when no pair qualifies.
    Pairs are checked before any frame is read."""
    names = check_names(registrars)
    if sequence.gt_poses is None:
        raise ConfigError(f"revisit pairs need ground-truth poses; {sequence.name} has none")
    gt = np.asarray(sequence.gt_poses, dtype=np.float64)
    frames = list(range(len(gt))) if frames is None else sorted({int(f) for f in frames})
    pairs, num_candidates = select_revisits(gt, options, frames)
    if not pairs:
        raise ConfigError(
            f"no two of the {len(frames)} selected frames of {sequence.name} are {options.min_m:g}-"
            f"{options.max_m:g} m apart with a heading change <= {options.max_heading_deg:g} deg and "
            f">= {options.min_frame_gap} frame(s) apart; widen --min-m/--max-m/--max-heading, "
            "lower --min-frame-gap or select more --frames"
        )
    index_pairs = [(p.target, p.source) for p in pairs]
    used = sorted({f for pair in index_pairs for f in pair})
    prepared, prepare_ms = prepare_frames(sequence, used, registrars, progress)
    truths = true_motions(gt, index_pairs)

    tick = pair_ticker(progress, len(registrars) * len(pairs))

    rows = []
    edges = options.heading_edges()
    for k, (name, registrar) in enumerate(zip(names, registrars, strict=True)):
        estimates, register_ms, failed = register_pairs(registrar, prepared[k], index_pairs, tick)
        prepare_total = sum(prepare_ms[k].values())
        rows.append(
            summarise(
                str(sequence.name),
                name,
                pairs,
                truths,
                estimates,
                register_ms,
                prepare_total,
                failed,
                edges,
                (rot_threshold_deg, trans_threshold_m),
            )
        )
    return RevisitRun(str(sequence.name), len(frames), num_candidates, options, pairs, rows)


# ------------------------------------------------------------------------------------------ output


def _percent(rate: float) -> str:
    return "-" if not math.isfinite(rate) else f"{100 * rate:.0f} %"


def markdown_table(rows: Sequence[RevisitRow]) -> str:
    """Rows sequence x method: pairs, success overall and per heading bin (with its pair count),
    rotation / translation RMSE and ms per pair. Every row must share the heading bins."""
    if not rows:
        raise ConfigError("no revisit rows to tabulate")
    edges = rows[0].edges
    errors = rows[0].errors
    rot, trans = errors.success_rot_threshold_deg, errors.success_trans_threshold_m
    labels = bin_labels(edges)
    lines = [
        f"| sequence | method | pairs | success (<{rot:g}°, <{trans:g} m) | "
        + " | ".join(f"{label}° (pairs)" for label in labels)
        + " | rot RMSE [deg] | trans RMSE [m] | ms / pair |",
        "|---|---|---:|---:|" + "---:|" * len(labels) + "---:|---:|---:|",
    ]
    for row in rows:
        if row.edges != edges:
            raise ConfigError("every row of one table must use the same heading bins")
        by_bin = row.success_by_bin()
        cells = " | ".join(f"{_percent(rate)} ({n})" for n, rate in by_bin.values())
        lines.append(
            f"| {row.sequence} | {row.method} | {row.num_pairs} | {_percent(row.success_rate)} | {cells} "
            f"| {row.errors.rot_rmse_deg:.3f} | {row.errors.trans_rmse_m:.3f} | {row.ms_per_pair:.1f} |"
        )
    return "\n".join(lines)
