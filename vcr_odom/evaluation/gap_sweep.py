"""Gap sweep: how each registration method copes as the motion between two frames grows.

Why: odometry meets consecutive frames (< 1 m apart); a global method that only works there, or that
systematically under-estimates the motion (a learned network regressing towards its training
motions), shows it once the gap between the frames grows. For each gap ``d`` every pair
``(i, i + d)`` of the selected frames is registered, source = the later frame ``i + d``, target = the
earlier frame ``i`` (the odometry convention: ``T_target_source``), against the ground truth
``T_i_(i+d) = inv(P_i) @ P_(i+d)`` of the sequence's LiDAR-frame poses.

Methods receive the raw frames, as ``run`` hands them over: each does its own pre-processing in
``prepare``. Each frame is prepared once per method and reused by every pair it belongs to, and no
initial guess is given. Time per pair is the prepare time of the frames a gap's pairs use divided by
its number of pairs, plus the mean register time.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.errors import ConfigError
from vcr_odom.jsonsafe import json_safe
from vcr_odom.metrics import PairErrors, pair_errors

if TYPE_CHECKING:
    from vcr_odom.data.base import LidarSequence
    from vcr_odom.registration.base import Registrar
    from vcr_odom.synth import SynthSequence

DEFAULT_GAPS = (1, 2, 5, 10, 15)
RATIO_MIN_MOTION_M = 0.2
"""Pairs that move less than this get no per-pair length ratio (dividing by ~0 says nothing)."""

Progress = Callable[[str, int, int], None]
"""``progress(stage, done, total)``: called after each prepared frame and each registered pair."""


@dataclass
class GapRow:
    """One method at one gap: motion lengths, their ratio, pose errors and time per pair."""

    method: str
    gap: int
    num_pairs: int
    true_length_mean_m: float
    est_length_mean_m: float
    length_ratio: float  # mean |t_est| / mean |t_true|
    length_ratio_median: float  # per-pair median of |t_est| / |t_true| over pairs moving > 0.2 m
    ratio_pairs: int  # pairs in that median
    ms_per_pair: float  # prepare (amortised) + register
    prepare_ms_per_pair: float
    register_ms_per_pair: float
    num_failed: int  # pairs whose estimate was not finite (counted as the identity)
    errors: PairErrors = field(repr=False)
    pairs: list[tuple[int, int]] = field(repr=False)  # (target, source) frame indices
    estimates: NDArray[np.float64] = field(repr=False)

    def to_dict(self, include_arrays: bool = False) -> dict[str, Any]:
        """JSON-safe figures (per-pair arrays only when asked)."""
        skip = {"errors", "pairs", "estimates"}
        result = {key: value for key, value in self.__dict__.items() if key not in skip}
        result["errors"] = self.errors.to_dict(include_arrays=include_arrays)
        if include_arrays:
            result["pairs"] = self.pairs
            result["estimates"] = self.estimates
        return json_safe(result)


@dataclass
class GapSweep:
    """Every row of one sweep, with what it ran on."""

    sequence: str
    frames: list[int]
    gaps: list[int]
    rows: list[GapRow]
    rot_threshold_deg: float
    trans_threshold_m: float

    def to_dict(self, include_arrays: bool = False) -> dict[str, Any]:
        return json_safe(
            {
                "sequence": self.sequence,
                "frames": self.frames,
                "gaps": self.gaps,
                "success_rot_threshold_deg": self.rot_threshold_deg,
                "success_trans_threshold_m": self.trans_threshold_m,
                "ratio_min_motion_m": RATIO_MIN_MOTION_M,
                "rows": [row.to_dict(include_arrays) for row in self.rows],
            }
        )


# ------------------------------------------------------------------------------------------- pairs


def gap_pairs(frames: Sequence[int], gap: int) -> list[tuple[int, int]]:
    """``(target i, source i + gap)`` for every selected ``i`` whose ``i + gap`` is selected too."""
    selected = set(frames)
    return [(i, i + gap) for i in sorted(selected) if i + gap in selected]


def check_gaps(frames: Sequence[int], gaps: Sequence[int]) -> list[int]:
    """The gaps, deduplicated in order; a ConfigError naming ``--gap`` for one that forms no pair."""
    if not gaps:
        raise ConfigError("--gap: give at least one gap (frames between source and target)")
    span = max(frames) - min(frames) if frames else 0
    for gap in gaps:
        if int(gap) != gap or gap < 1:
            raise ConfigError(f"--gap must be a positive integer number of frames; got {gap!r}")
        if not gap_pairs(frames, int(gap)):
            raise ConfigError(
                f"--gap {gap} forms no pair in the {len(frames)} selected frames "
                f"({min(frames, default='-')}..{max(frames, default='-')}, span {span}); "
                "use a smaller --gap or select more frames"
            )
    return list(dict.fromkeys(int(gap) for gap in gaps))


def true_motions(gt_poses: NDArray[np.float64], pairs: Sequence[tuple[int, int]]) -> NDArray[np.float64]:
    """``T_target_source = inv(P_target) @ P_source`` for each pair, ``(M, 4, 4)``."""
    targets = np.stack([gt_poses[t] for t, _ in pairs])
    sources = np.stack([gt_poses[s] for _, s in pairs])
    return np.linalg.solve(targets, sources)


def length_ratios(estimates: NDArray[np.float64], truths: NDArray[np.float64]) -> tuple[float, float, int]:
    """(mean |t_est| / mean |t_true|, per-pair median ratio over pairs moving > 0.2 m, that count).

    The ratio of means says whether a method shortens the motion overall; the median of per-pair
    ratios is robust to a few wild failures. NaN where a figure has no pair to stand on."""
    est = np.linalg.norm(estimates[:, :3, 3], axis=1)
    true = np.linalg.norm(truths[:, :3, 3], axis=1)
    ratio = float(est.mean() / true.mean()) if true.mean() > 0 else math.nan
    moving = true > RATIO_MIN_MOTION_M
    median = float(np.median(est[moving] / true[moving])) if moving.any() else math.nan
    return ratio, median, int(moving.sum())


# ------------------------------------------------------------------------------------------ the run


def check_names(registrars: Sequence[Registrar]) -> list[str]:
    """The registrars' names; a ConfigError when there is none or two share a name (rows are keyed by it)."""
    names = [str(r.name) for r in registrars]
    if not names:
        raise ConfigError("--method: name at least one method")
    if len(set(names)) != len(names):
        raise ConfigError(f"each method row needs its own name; got {names}")
    return names


def prepare_frames(
    sequence: LidarSequence,
    frames: Sequence[int],
    registrars: Sequence[Registrar],
    progress: Progress | None = None,
) -> tuple[list[dict[int, Any]], list[dict[int, float]]]:
    """Each frame read once and prepared once by each method: (prepared, prepare ms) per method.

    Frames are the outer loop so that only the prepared forms, not the raw frames, stay in memory."""
    prepared: list[dict[int, Any]] = [{} for _ in registrars]
    times_ms: list[dict[int, float]] = [{} for _ in registrars]
    for done, index in enumerate(frames, start=1):
        points = sequence.frame(index)
        for k, registrar in enumerate(registrars):
            start = time.perf_counter()
            prepared[k][index] = registrar.prepare(points)
            times_ms[k][index] = (time.perf_counter() - start) * 1000.0
        if progress is not None:
            progress("preparing frames", done, len(frames))
    return prepared, times_ms


def register_pairs(
    registrar: Registrar,
    prepared: dict[int, Any],
    pairs: Sequence[tuple[int, int]],
    tick: Callable[[], None],
) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """Each ``(target, source)`` pair registered with no initial guess: estimates ``(M, 4, 4)``,
    register ms per pair, and how many gave no finite estimate (counted as the identity)."""
    estimates = np.empty((len(pairs), 4, 4), dtype=np.float64)
    times_ms = np.empty(len(pairs), dtype=np.float64)
    failed = 0
    for n, (target, source) in enumerate(pairs):
        start = time.perf_counter()
        result = registrar.register(prepared[source], prepared[target])
        times_ms[n] = (time.perf_counter() - start) * 1000.0
        estimate = np.asarray(result.transform, dtype=np.float64)
        finite = estimate.shape == (4, 4) and bool(np.all(np.isfinite(estimate)))
        # A method that gives up counts as the identity: a failure, not a crash (as pair_benchmark).
        estimates[n] = estimate if finite else np.eye(4)
        failed += not finite
        tick()
    return estimates, times_ms, failed


def _row(
    name: str,
    gap: int,
    pairs: list[tuple[int, int]],
    truths: NDArray[np.float64],
    estimates: NDArray[np.float64],
    register_ms: NDArray[np.float64],
    prepare_ms: dict[int, float],
    failed: int,
    thresholds: tuple[float, float],
) -> GapRow:
    ratio, median, ratio_pairs = length_ratios(estimates, truths)
    used = {frame for pair in pairs for frame in pair}
    prepare_per_pair = sum(prepare_ms[f] for f in used) / len(pairs)
    register_per_pair = float(register_ms.mean())
    return GapRow(
        method=name,
        gap=gap,
        num_pairs=len(pairs),
        true_length_mean_m=float(np.linalg.norm(truths[:, :3, 3], axis=1).mean()),
        est_length_mean_m=float(np.linalg.norm(estimates[:, :3, 3], axis=1).mean()),
        length_ratio=ratio,
        length_ratio_median=median,
        ratio_pairs=ratio_pairs,
        ms_per_pair=prepare_per_pair + register_per_pair,
        prepare_ms_per_pair=prepare_per_pair,
        register_ms_per_pair=register_per_pair,
        num_failed=failed,
        errors=pair_errors(
            estimates, truths, rot_threshold_deg=thresholds[0], trans_threshold_m=thresholds[1], stride=gap
        ),
        pairs=pairs,
        estimates=estimates,
    )


def pair_ticker(progress: Progress | None, total: int) -> Callable[[], None]:
    """A callback that reports one more registered pair of ``total`` (to :func:`register_pairs`)."""
    done = 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress("registering pairs", done, total)

    return tick


def run_gap_sweep(
    sequence: LidarSequence,
    frames: Sequence[int],
    registrars: Sequence[Registrar],
    gaps: Sequence[int] = DEFAULT_GAPS,
    *,
    progress: Progress | None = None,
    rot_threshold_deg: float = 2.0,
    trans_threshold_m: float = 0.5,
) -> GapSweep:
    """Register every pair ``(i, i + gap)`` of ``frames`` with every registrar; one row per (method, gap).

    ``registrars`` are ready objects (``make_method`` builds them by name) with distinct names; rows
    come method by method, gaps in the given order. Needs the sequence's ground-truth poses."""
    names = check_names(registrars)
    frames = sorted({int(f) for f in frames})
    gaps = check_gaps(frames, gaps)
    gt = sequence.gt_poses
    if gt is None:
        raise ConfigError(f"the gap sweep needs ground-truth poses; {sequence.name} has none")
    gt = np.asarray(gt, dtype=np.float64)
    pairs_by_gap = {gap: gap_pairs(frames, gap) for gap in gaps}
    used = sorted({f for pairs in pairs_by_gap.values() for pair in pairs for f in pair})
    prepared, prepare_ms = prepare_frames(sequence, used, registrars, progress)

    tick = pair_ticker(progress, len(registrars) * sum(len(p) for p in pairs_by_gap.values()))

    rows = []
    for k, (name, registrar) in enumerate(zip(names, registrars, strict=True)):
        for gap, pairs in pairs_by_gap.items():
            truths = true_motions(gt, pairs)
            estimates, register_ms, failed = register_pairs(registrar, prepared[k], pairs, tick)
            thresholds = (rot_threshold_deg, trans_threshold_m)
            rows.append(
                _row(name, gap, pairs, truths, estimates, register_ms, prepare_ms[k], failed, thresholds)
            )
    return GapSweep(str(sequence.name), frames, gaps, rows, rot_threshold_deg, trans_threshold_m)


# ------------------------------------------------------------------------------------------ output


def _figure(value: float, digits: int) -> str:
    return "-" if not math.isfinite(value) else f"{value:.{digits}f}"


def markdown_table(sweep: GapSweep) -> str:
    """One markdown table, rows method x gap, the columns the sweep reports."""
    rot, trans = sweep.rot_threshold_deg, sweep.trans_threshold_m
    lines = [
        "| method | gap | pairs | true motion [m] | est/true length | median ratio (>0.2 m) "
        f"| rot RMSE / MAE [deg] | trans RMSE / MAE [m] | success (<{rot:g}°, <{trans:g} m) | ms / pair |",
        "|---|---:|---:|---:|---:|---:|---|---|---:|---:|",
    ]
    for row in sweep.rows:
        e = row.errors
        lines.append(
            f"| {row.method} | {row.gap} | {row.num_pairs} | {row.true_length_mean_m:.2f} "
            f"| {_figure(row.length_ratio, 3)} | {_figure(row.length_ratio_median, 3)} "
            f"| {e.rot_rmse_deg:.3f} / {e.rot_mae_deg:.3f} | {e.trans_rmse_m:.3f} / {e.trans_mae_m:.3f} "
            f"| {100 * e.success_rate:.0f} % | {row.ms_per_pair:.1f} |"
        )
    return "\n".join(lines)


# ------------------------------------------------------------------------------ synthetic sequences


def synth_sequence(
    seed: int, frames: int, speed: float, sensor: str | None = None, scene: str = "suburban"
) -> SynthSequence:
    """A synthetic drive; ``sensor`` names a :meth:`SensorConfig.model` (None: the default HDL-64E)."""
    from vcr_odom.synth import SynthSequence

    return SynthSequence(frames=frames, seed=seed, speed=speed, sensor=sensor, scene=scene)
