"""The paper's Table III protocol: pairwise registration of one scan against a randomly moved copy.

Why a separate benchmark: odometry pairs move < 1 m between frames, where ICP from identity works;
the paper's same-scan protocol (:mod:`vcr_odom.training.pairs`, ``protocol="same-scan"``) moves the
second down-sampled copy by yaw ±30°, roll/pitch ±5°, ±5 m horizontally and ±1 m vertically, which
is what a global method (FPFH+RANSAC, VCR-Net) must survive and local ICP cannot.

Conventions, as in the paper:

- Every method sees exactly the same pairs (each sample is drawn once, then handed to each method).
- The clouds are already ground-removed and down-sampled to N points; ICP baselines get these same
  sparse N-point clouds (the paper gives ICP nothing denser), so ICP's figures here are not its
  odometry figures.
- ICP starts from the identity (``initial_guess="identity"``, the default), as the paper's ICP(10)
  does; ``"ground-truth"`` is available as a sanity check only (it leaks the answer).
- Time per pair is ``prepare(source) + prepare(target) + register``, wall clock
  (:func:`time.perf_counter`), so global methods pay for their features and VCR-Net for its encoding.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.errors import ConfigError
from vcr_odom.jsonsafe import json_safe
from vcr_odom.metrics import PairErrors, pair_errors
from vcr_odom.registration import SEQUENTIAL_METHODS

if TYPE_CHECKING:
    from vcr_odom.data.base import LidarSequence
    from vcr_odom.registration.base import Registrar
    from vcr_odom.training.datasets import PairDataset

INITIAL_GUESSES = ("identity", "ground-truth")
DEFAULT_PAIR_METHODS = ("icp10", "fpfh", "vcr", "vcr+icp")
"""The paper's Table III rows; ``NAME+icp`` is NAME polished by ICP on the pair's own clouds
(:mod:`vcr_odom.evaluation.pairs_polish`)."""

Pair = Mapping[str, Any]
"""One pair: ``source`` / ``target`` ``(N, >=3)`` points and ``transform`` = ``T_target_source``."""


@dataclass
class PairProtocolResult:
    """One method's figures on the pair protocol: errors, time per pair, and the estimates themselves."""

    name: str
    errors: PairErrors
    ms_per_pair_mean: float
    ms_per_pair_median: float
    num_pairs: int
    initial_guess: str
    estimates: NDArray[np.float64] = field(repr=False)
    times_ms: NDArray[np.float64] = field(repr=False)

    def to_dict(self, include_arrays: bool = False) -> dict[str, Any]:
        """JSON-safe summary (per-pair arrays only when asked: they grow with the number of pairs)."""
        result: dict[str, Any] = {
            "name": self.name,
            "num_pairs": self.num_pairs,
            "initial_guess": self.initial_guess,
            "ms_per_pair_mean": self.ms_per_pair_mean,
            "ms_per_pair_median": self.ms_per_pair_median,
            "errors": self.errors.to_dict(include_arrays=include_arrays),
        }
        if include_arrays:
            result["times_ms"] = self.times_ms
            result["estimates"] = self.estimates
        return json_safe(result)


PAIR_KINDS = ("same-scan", "consecutive")
"""``same-scan``: the paper's protocol. ``consecutive``: each selected frame against the next selected
one (the stride apart) with its ground-truth motion and no random transform: what odometry asks."""


def same_scan_pairs(
    sequence: LidarSequence,
    frame_indices: Sequence[int] | None = None,
    num_points: int = 1024,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> PairDataset:
    """The paper's protocol on any sequence: one pair per frame (two independent down-samplings of the
    ground-removed scan, the second moved by a random transform). Deterministic in ``seed``; needs
    open3d (it builds the frame cache in memory)."""
    return pair_sets(sequence, frame_indices, num_points, seed, ("same-scan",), progress)["same-scan"]


def pair_sets(
    sequence: LidarSequence,
    frame_indices: Sequence[int] | None,
    num_points: int,
    seed: int = 0,
    kinds: Sequence[str] = PAIR_KINDS,
    progress: Callable[[int, int], None] | None = None,
    max_range: float = 80.0,
) -> dict[str, PairDataset]:
    """Pairs of each kind in ``kinds`` from one frame cache (each frame pre-processed once, points
    within ``max_range`` metres: the VCR weights' ``input_max_range`` when VCR is compared).

    Consecutive pairs need the sequence's ground-truth poses and are one fewer than the frames; with
    frames ``a, a+s, a+2s, ...`` they are ``s`` frames apart."""
    from vcr_odom.data.frame_cache import build_frame_cache
    from vcr_odom.preprocess import PreprocessConfig
    from vcr_odom.training import PairConfig, PairDataset

    unknown = sorted(set(kinds) - set(PAIR_KINDS))
    if unknown or not kinds:
        raise ConfigError(f"pair kinds must be among {', '.join(PAIR_KINDS)}; got {list(kinds)}")
    frames = list(range(len(sequence))) if frame_indices is None else [int(f) for f in frame_indices]
    gaps = sorted({b - a for a, b in pairwise(frames)})
    if "consecutive" in kinds and (len(gaps) != 1 or gaps[0] < 1):
        raise ConfigError(f"consecutive pairs need evenly spaced increasing frames; got gaps {gaps}")
    crop = PreprocessConfig(n_points=num_points, max_range=max_range)
    same_scan = PairConfig(protocol="same-scan", num_points=num_points, seed=seed, preprocess=crop)
    cache = build_frame_cache(sequence, frames, same_scan, copies=2, progress=progress)
    sets: dict[str, PairDataset] = {}
    if "same-scan" in kinds:
        sets["same-scan"] = PairDataset(cache, same_scan)
    if "consecutive" in kinds:
        if cache.gt_poses is None:
            raise ConfigError(f"consecutive pairs need ground-truth poses; {sequence.name} has none")
        odometry = PairConfig(protocol="odometry", num_points=num_points, seed=seed, gaps=(gaps[0],))
        sets["consecutive"] = PairDataset(cache, odometry)
    return sets


def _as_frame(points: Any) -> NDArray[np.float32]:
    """Registrars expect frames ``(N, 4)`` (x, y, z, reflectance): pad xyz with zero reflectance."""
    array = np.asarray(points, dtype=np.float32)
    if array.ndim != 2 or array.shape[1] < 3:
        raise ConfigError(f"pair points must be (N, >=3); got shape {array.shape}")
    xyz = array[:, :3]
    return np.ascontiguousarray(np.hstack([xyz, np.zeros((len(xyz), 1), dtype=np.float32)]))


def _materialise(dataset_or_pairs: PairDataset | Iterable[Pair]) -> list[dict[str, Any]]:
    """Draw every pair once, so that each method receives the very same arrays."""
    if hasattr(dataset_or_pairs, "sample") and hasattr(dataset_or_pairs, "__len__"):
        dataset = dataset_or_pairs
        raw: Iterable[Pair] = (dataset.sample(i) for i in range(len(dataset)))  # type: ignore[arg-type]
    else:
        raw = dataset_or_pairs  # type: ignore[assignment]
    pairs = []
    for index, pair in enumerate(raw):
        try:
            transform = np.asarray(pair["transform"], dtype=np.float64)
            source, target = _as_frame(pair["source"]), _as_frame(pair["target"])
        except KeyError as error:
            raise ConfigError(f"pair {index} lacks {error}; need source, target and transform") from error
        if transform.shape != (4, 4):
            raise ConfigError(f"pair {index}: transform must be (4, 4); got {transform.shape}")
        source.setflags(write=False)
        target.setflags(write=False)
        pairs.append({"source": source, "target": target, "transform": transform})
    if not pairs:
        raise ConfigError("no pairs to evaluate")
    return pairs


def _build(name: str, options: Mapping[str, Mapping[str, Any]]) -> Registrar:
    from vcr_odom.evaluation.pairs_polish import polished_for_pairs
    from vcr_odom.odometry.factory import registrar_options
    from vcr_odom.registration import make_method

    key = name.strip().lower()
    base, _, polish = key.partition("+")
    if base in SEQUENTIAL_METHODS:
        raise ConfigError(
            f"{name!r} is a sequential odometry method (it keeps a local map across frames), not a "
            "pairwise registrar: it has no meaning on independent pairs; use it in the odometry "
            "comparison instead"
        )
    polished = bool(polish) and polish != "none"
    given = dict(options.get(base, options.get(name, {})))
    method = make_method(base, **registrar_options(base, polished, given))
    if polished:
        return polished_for_pairs(method, polish)  # type: ignore[arg-type]
    return method  # type: ignore[return-value]


def evaluate_pair_protocol(
    registrar_names: Sequence[str | Registrar],
    dataset_or_pairs: PairDataset | Iterable[Pair],
    *,
    initial_guess: str = "identity",
    options: Mapping[str, Mapping[str, Any]] | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    rot_threshold_deg: float = 2.0,
    trans_threshold_m: float = 0.5,
) -> dict[str, PairProtocolResult]:
    """Run each method on the same pairs; return ``{name: PairProtocolResult}`` in the given order.

    ``registrar_names`` are :func:`~vcr_odom.registration.make_method` names (or ready Registrar
    objects, for tests and custom setups); ``options`` maps a method name to its constructor options
    (``{"vcr": {"weights": path}}``). ``initial_guess="identity"`` is the paper's setting;
    ``progress(name, done, total)`` is called after each pair. Methods are all built before any
    runs, so a bad name or option fails at once.
    """
    if initial_guess not in INITIAL_GUESSES:
        raise ConfigError(f"initial_guess must be one of {', '.join(INITIAL_GUESSES)}; got {initial_guess!r}")
    if not registrar_names:
        raise ConfigError("name at least one method")
    options = options or {}
    methods: list[Registrar] = [
        _build(entry, options) if isinstance(entry, str) else entry for entry in registrar_names
    ]
    names = [str(method.name) for method in methods]
    if len(set(names)) != len(names):
        raise ConfigError(f"each method may appear once; got {names}")
    pairs = _materialise(dataset_or_pairs)
    gt = np.stack([pair["transform"] for pair in pairs])

    results: dict[str, PairProtocolResult] = {}
    for name, method in zip(names, methods, strict=True):
        estimates = np.empty((len(pairs), 4, 4), dtype=np.float64)
        times_ms = np.empty(len(pairs), dtype=np.float64)
        for index, pair in enumerate(pairs):
            guess = pair["transform"] if initial_guess == "ground-truth" else np.eye(4)
            start = time.perf_counter()
            source = method.prepare(pair["source"])
            target = method.prepare(pair["target"])
            result = method.register(source, target, initial_guess=guess)
            times_ms[index] = (time.perf_counter() - start) * 1000.0
            estimate = np.asarray(result.transform, dtype=np.float64)
            # A method that gives up (NaN) counts as the identity: a failure, not a crash.
            estimates[index] = estimate if np.all(np.isfinite(estimate)) else np.eye(4)
            if progress is not None:
                progress(name, index + 1, len(pairs))
        errors = pair_errors(
            estimates, gt, rot_threshold_deg=rot_threshold_deg, trans_threshold_m=trans_threshold_m
        )
        results[name] = PairProtocolResult(
            name=name,
            errors=errors,
            ms_per_pair_mean=float(np.mean(times_ms)),
            ms_per_pair_median=float(statistics.median(times_ms.tolist())),
            num_pairs=len(pairs),
            initial_guess=initial_guess,
            estimates=estimates,
            times_ms=times_ms,
        )
    return results


__all__ = [
    "DEFAULT_PAIR_METHODS",
    "INITIAL_GUESSES",
    "PAIR_KINDS",
    "PairProtocolResult",
    "evaluate_pair_protocol",
    "pair_sets",
    "same_scan_pairs",
]
