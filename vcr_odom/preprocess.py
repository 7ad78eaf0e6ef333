"""Frame pre-processing: range crop, RANSAC ground removal, down-sampling to exactly N points.

This is the input side of VCR-Net (the paper removes the ground with RANSAC and feeds N points), and
the sampler of the training-pair protocols. Every step is deterministic for a given seed and never
crashes on a poor frame: a step that would leave too few points is skipped with a ``DataWarning``,
and a frame with too few points is padded by resampling (an empty frame becomes N zero points).
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, model_validator

from vcr_odom.errors import ConfigError, DataWarning
from vcr_odom.settings import Settings

if TYPE_CHECKING:
    import open3d as o3d

    from vcr_odom.model.config import VcrConfig

DOWNSAMPLE_METHODS = ("fps", "random", "voxel")
"""``fps``: farthest point sampling (even coverage, the paper's choice for N points); ``random``:
uniform without replacement (cheapest); ``voxel``: voxel-grid centroids, then exactly N by random choice."""


class PreprocessConfig(Settings):
    """Parameters of :func:`preprocess`; the defaults suit a KITTI-like HDL-64E mounted 1.73 m high.

    Ranges (metres, 3-D distance from the sensor):
      ``min_range=2.0``: KITTI's nearest returns (< ~2 m) hit the ego car and its roof rack;
      ``max_range=80.0``: beyond ~80 m an HDL-64E scan is a few sparse, noisy rings.
    Ground removal (open3d ``segment_plane``):
      ``ground_distance_threshold=0.25``: road points scatter ~±0.1 m around one plane (camber,
      curbs, range noise of a few cm, slight slope over 80 m), so 0.2-0.3 m takes the road and little
      else; larger thresholds start eating car wheels, curbs and pole feet;
      ``ground_ransac_n=3``: three points define a plane (minimal sample, best RANSAC odds);
      ``ground_num_iterations=100``: the ground is about half of a street scan, so a clean 3-point
      sample has odds of roughly 1 in 8 and 100 tries all miss it with probability around 1e-6; the
      least-squares refit below then corrects a near miss, so more tries cost time per frame without
      moving the plane;
      ``ground_max_tilt_deg=20.0`` and plane below the sensor: the sanity check that rejects walls and
      facades (vertical) and roofs/overhangs (above the sensor); roads steeper than ~36 % do not occur;
      ``ground_max_attempts=6``: a rejected plane's inliers are set aside and RANSAC runs again; in a
      narrow street three facades can each be larger than the road (an OS1-128 old-town scan: three
      walls of 21-24 k points before a road of 20 k), and the earlier attempts are unchanged by more;
      ``ground_sample_size=10000``: RANSAC scores its hypotheses on a seeded random subset of this
      many points; the winning plane is then refitted (least squares, a few rounds) to the subset's
      points within the threshold (:func:`refit_plane`), and every point of the scan within the
      threshold of that plane is ground. Scoring costs time in proportion to the points scored, and
      thousands of road points already pin a plane, so a subset finds the same plane as the whole
      scan for a fraction of the cost.
      Reproducibility: open3d stops RANSAC early once its running odds say the plane is found, and
      with its parallel threads when that happens varies from run to run, so the hypotheses tried, and
      a few of the points removed, could vary between runs. ``probability=1.0`` turns the early stop
      off: every one of ``ground_num_iterations`` hypotheses is scored, so the result depends on the
      seed alone (a test repeats it on ray-cast scans).
    Down-sampling:
      ``n_points=1024`` (the paper's N), ``method="fps"``, ``voxel_size=0.3`` (only for ``voxel``;
      small enough that a thin pole keeps cells of its own, large enough to thin the dense near field);
      ``fps_candidates=16384``: FPS picks from a seeded random subset of this many points (None: all).
      Its cost grows with the input, while a random subset many times larger than N still samples
      every part of the scene, so FPS over the subset covers the scene as evenly, for less time.
    Fallback:
      ``min_points=None`` means ``n_points``: a crop or ground removal leaving fewer points is undone.
    ``keep_reflectance=False``: the output is xyz ``(n, 3)``; True gives ``(n, 4)`` with reflectance.
    ``seed``: seeds RANSAC, the FPS start point and random choices.
    """

    min_range: float = Field(default=2.0, ge=0)
    max_range: float = Field(default=80.0, gt=0)
    remove_ground: bool = True
    ground_distance_threshold: float = Field(default=0.25, gt=0)
    ground_ransac_n: int = Field(default=3, ge=3)
    ground_num_iterations: int = Field(default=100, ge=1)
    ground_max_tilt_deg: float = Field(default=20.0, gt=0, le=90)
    ground_max_attempts: int = Field(default=6, ge=1)
    ground_sample_size: int = Field(default=10000, ge=3)
    n_points: int = Field(default=1024, ge=1)
    method: Literal["fps", "random", "voxel"] = "fps"
    voxel_size: float = Field(default=0.3, gt=0)
    fps_candidates: int | None = Field(default=16384, ge=1)
    min_points: int | None = Field(default=None, ge=1)
    keep_reflectance: bool = False
    seed: int = 0

    @model_validator(mode="after")
    def _consistent(self) -> PreprocessConfig:
        if self.min_range >= self.max_range:
            raise ValueError(f"need min_range < max_range; got {self.min_range}, {self.max_range}")
        if self.ground_sample_size < self.ground_ransac_n:
            raise ValueError(f"ground_sample_size must be >= ground_ransac_n; got {self.ground_sample_size}")
        return self


def _as_points(points: NDArray) -> NDArray[np.float32]:
    array = np.asarray(points, dtype=np.float32)
    if array.ndim != 2 or array.shape[1] < 3:
        raise ConfigError(f"points must be an (N, >=3) array; got shape {array.shape}")
    return array


def _to_cloud(points: NDArray) -> o3d.geometry.PointCloud:
    """xyz as an open3d cloud; reflectance (if any) rides in the colour channel so it survives sampling."""
    import open3d as o3d  # here, not at the top: see remove_ground

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[:, :3].astype(np.float64)))
    if points.shape[1] > 3:
        colours = np.zeros((len(points), 3))
        colours[:, 0] = points[:, 3]
        cloud.colors = o3d.utility.Vector3dVector(colours)
    return cloud


def _from_cloud(cloud: o3d.geometry.PointCloud, columns: int) -> NDArray[np.float32]:
    xyz = np.asarray(cloud.points)
    if columns == 3:
        return xyz.astype(np.float32)
    return np.column_stack([xyz, np.asarray(cloud.colors)[:, 0]]).astype(np.float32)


def crop_range(points: NDArray, min_range: float, max_range: float) -> NDArray[np.float32]:
    """Keep points with ``min_range < |xyz| < max_range`` (3-D distance from the sensor)."""
    points = _as_points(points)
    xyz = points[:, :3]
    squared = np.einsum("ij,ij->i", xyz, xyz)  # compare squared distances: no square root per point
    return points[(squared > min_range * min_range) & (squared < max_range * max_range)]


def upward_plane(model: NDArray) -> NDArray[np.float64]:
    """Plane ``a x + b y + c z + d = 0`` scaled to a unit normal pointing up (c >= 0)."""
    model = np.asarray(model, dtype=np.float64).ravel()
    model = model / np.linalg.norm(model[:3])
    return -model if model[2] < 0 else model


def is_ground(model: NDArray[np.float64], max_tilt_deg: float) -> bool:
    """Roughly horizontal (normal within ``max_tilt_deg`` of z) and below the sensor (z at x=y=0 < 0)."""
    tilt = np.degrees(np.arccos(np.clip(model[2], -1.0, 1.0)))
    return bool(tilt <= max_tilt_deg and -model[3] / model[2] < 0.0)


def least_squares_plane(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """The upward plane through ``points`` (at least 3) that minimises their squared distances."""
    centroid = points.mean(axis=0)
    centred = points - centroid
    _, vectors = np.linalg.eigh(centred.T @ centred)  # 3x3 scatter: far cheaper than an N x 3 SVD
    return upward_plane(np.append(vectors[:, 0], -vectors[:, 0] @ centroid))


def refit_plane(
    xyz: NDArray[np.float64], plane: NDArray[np.float64], threshold: float, rounds: int = 3
) -> NDArray[np.float64]:
    """Least-squares plane of the points within ``threshold``, refitted a few rounds.

    Why: the RANSAC plane rests on three points; the plane fitted to all of its inliers is what the
    ground actually is, so the band removed follows the road rather than one triple. Fitted on
    RANSAC's subset: the whole scan would cost time in proportion to its size for the same plane.
    """
    inliers = np.abs(xyz @ plane[:3] + plane[3]) <= threshold
    for _ in range(rounds):
        points = xyz[inliers]
        if len(points) < 3:
            break
        plane = least_squares_plane(points)
        refit = np.abs(xyz @ plane[:3] + plane[3]) <= threshold
        if np.array_equal(refit, inliers):
            break
        inliers = refit
    return plane


def remove_ground(
    points: NDArray, config: PreprocessConfig | None = None
) -> tuple[NDArray[np.float32], NDArray[np.float64] | None]:
    """Drop the ground plane's inliers; returns ``(points_without_ground, plane)``.

    ``plane`` is ``(a, b, c, d)`` with a unit normal pointing up, or None when no plausible ground
    was found (then the points come back unchanged, with a ``DataWarning``). Deterministic for
    ``config.seed``: open3d's global RNG is seeded right before the search.
    """
    # open3d is imported where it is used: the network's inference on clouds already pre-processed
    # (training caches, benchmarks/device_agreement.py's pairs) then runs where it is not installed,
    # such as a GPU image without it.
    import open3d as o3d

    config = config or PreprocessConfig()
    points = _as_points(points)
    xyz = points[:, :3].astype(np.float64)
    candidates = np.arange(len(points))
    rng = np.random.default_rng(config.seed)
    o3d.utility.random.seed(int(config.seed))
    for _ in range(config.ground_max_attempts):
        if len(candidates) < max(config.ground_ransac_n, 3):
            break
        sample = candidates
        if len(candidates) > config.ground_sample_size:
            sample = np.sort(rng.choice(candidates, config.ground_sample_size, replace=False))
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz[sample]))
        model, sample_inliers = cloud.segment_plane(
            distance_threshold=config.ground_distance_threshold,
            ransac_n=config.ground_ransac_n,
            num_iterations=config.ground_num_iterations,
            probability=1.0,
        )
        if len(sample_inliers) == 0:
            break
        plane = refit_plane(xyz[sample], upward_plane(model), config.ground_distance_threshold)
        is_inlier = np.abs(xyz[candidates] @ plane[:3] + plane[3]) <= config.ground_distance_threshold
        if is_ground(plane, config.ground_max_tilt_deg):
            keep = np.ones(len(points), dtype=bool)
            keep[candidates[is_inlier]] = False
            return points[keep], plane
        candidates = candidates[~is_inlier]  # a wall or a roof: set it aside and search again
    warnings.warn(
        f"no plausible ground plane in a frame of {len(points)} points; ground kept",
        DataWarning,
        stacklevel=2,
    )
    return points, None


def _pad(points: NDArray[np.float32], n: int, rng: np.random.Generator) -> NDArray[np.float32]:
    """All points plus ``n - len`` resampled with replacement (deterministic for the generator)."""
    extra = rng.choice(len(points), size=n - len(points), replace=True)
    return np.concatenate([points, points[extra]])


def downsample(
    points: NDArray,
    n: int,
    method: str = "fps",
    seed: int = 0,
    voxel_size: float = 0.3,
    fps_candidates: int | None = None,
    pad: bool = True,
) -> NDArray[np.float32]:
    """Exactly ``n`` points (all input columns kept), deterministic for ``seed``.

    ``fps`` starts open3d's farthest point sampling at a seeded random point (its default start,
    index 0, would make two samplings of one scan identical, defeating the paper's pair protocol).
    With ``fps_candidates`` it samples from a seeded random subset of that many points (see
    :class:`PreprocessConfig`).
    Fewer than ``n`` points available: all of them plus seeded resampling with replacement, and a
    ``DataWarning``; with ``pad=False``, all of them and no more (for a consumer that takes any count:
    the network at inference, whose kNN graphs repeated points would distort). An empty frame gives
    ``n`` zero points and a ``DataWarning``.
    """
    if method not in DOWNSAMPLE_METHODS:
        raise ConfigError(f"method must be one of {', '.join(DOWNSAMPLE_METHODS)}; got {method!r}")
    if n < 1:
        raise ConfigError(f"n must be >= 1; got {n}")
    points = _as_points(points)
    rng = np.random.default_rng(seed)
    if len(points) == 0:
        warnings.warn(f"empty frame: returning {n} zero points", DataWarning, stacklevel=2)
        return np.zeros((n, points.shape[1]), dtype=np.float32)
    if method == "voxel":
        points = _from_cloud(_to_cloud(points).voxel_down_sample(voxel_size), points.shape[1])
    if len(points) < n and not pad:
        return points.copy()
    if len(points) < n:
        warnings.warn(
            f"only {len(points)} points for n={n} ({method}): padding by resampling",
            DataWarning,
            stacklevel=2,
        )
        return _pad(points, n, rng)
    if len(points) == n:
        return points.copy()
    if method == "fps":
        if fps_candidates is not None and len(points) > max(fps_candidates, n):
            points = points[np.sort(rng.choice(len(points), size=max(fps_candidates, n), replace=False))]
        start = int(rng.integers(len(points)))
        sampled = _to_cloud(points).farthest_point_down_sample(n, start_index=start)
        return _from_cloud(sampled, points.shape[1])
    return points[np.sort(rng.choice(len(points), size=n, replace=False))]


def crop_and_remove_ground(points: NDArray, config: PreprocessConfig | None = None) -> NDArray[np.float32]:
    """The expensive, deterministic half of :func:`preprocess` (finite, crop, ground), kept separate so
    training caches run RANSAC once and draw several down-samplings from its result.

    Never raises on a poor frame: non-finite points are dropped, and a crop or ground removal that
    would leave fewer than ``min_points`` is skipped; each fallback warns.
    """
    config = config or PreprocessConfig()
    points = _as_points(points)
    finite = np.isfinite(points[:, :3]).all(axis=1)
    if not finite.all():
        warnings.warn(f"dropped {int((~finite).sum())} non-finite points", DataWarning, stacklevel=2)
        points = points[finite]
    if len(points) == 0:  # nothing to crop or segment: the sampler warns and returns zeros
        return points
    min_points = config.n_points if config.min_points is None else config.min_points
    cropped = crop_range(points, config.min_range, config.max_range)
    if len(cropped) < min(min_points, len(points)):
        warnings.warn(
            f"range crop would leave {len(cropped)} < {min_points} points; crop skipped",
            DataWarning,
            stacklevel=2,
        )
    else:
        points = cropped
    if config.remove_ground:
        without_ground, plane = remove_ground(points, config)
        if plane is not None and len(without_ground) < min(min_points, len(points)):
            warnings.warn(
                f"ground removal would leave {len(without_ground)} < {min_points} points; ground kept",
                DataWarning,
                stacklevel=2,
            )
        else:
            points = without_ground
    return points


def preprocess(
    points: NDArray, config: PreprocessConfig | None = None, *, pad: bool = True
) -> NDArray[np.float32]:
    """Crop, remove the ground, down-sample: float32 ``(n_points, 3)`` (``(n, 4)`` with reflectance);
    ``pad=False``: fewer rows where the frame has fewer points (see :func:`downsample`)."""
    config = config or PreprocessConfig()
    points = crop_and_remove_ground(points, config)
    sampled = downsample(
        points, config.n_points, config.method, config.seed, config.voxel_size, config.fps_candidates, pad
    )
    return _select_columns(sampled, config)


def _select_columns(sampled: NDArray[np.float32], config: PreprocessConfig) -> NDArray[np.float32]:
    """xyz, or xyz + reflectance (zeros when the source has none)."""
    if not config.keep_reflectance:
        return np.ascontiguousarray(sampled[:, :3])
    if sampled.shape[1] >= 4:
        return np.ascontiguousarray(sampled[:, :4])
    return np.column_stack([sampled[:, :3], np.zeros(len(sampled), dtype=np.float32)])


def network_preprocess_config(config: VcrConfig, seed: int = 0) -> PreprocessConfig:
    """What the network with ``config`` is fed, in training caches and at inference alike."""
    return PreprocessConfig(
        n_points=config.num_points, max_range=config.input_max_range, method="fps", seed=seed
    )


GROUND_NEAR_M = (0.5, 20.0)
"""Horizontal range of the points used: the ground is densest near the sensor."""
GROUND_BAND_M = 0.6
"""Height above the lowest points (their 5th percentile) kept as ground candidates."""
GROUND_DISTANCE_M = 0.08
GROUND_MAX_TILT_DEG = 30.0
"""A plane tilted further from the scan's own z axis is a ramp, a wall or a wrong fit."""
GROUND_SENSOR_ABOVE_M = 0.2
"""The sensor is at least this far above the plane (a plane through it is a wrong fit)."""
GROUND_MIN_POINTS = 30
GROUND_INPUT_POINTS = 20_000
"""A dense scan is taken every k-th point down to about this many first (the cost is in the scan's size)."""
GROUND_SAMPLE_POINTS = 2000
GROUND_ITERATIONS = 100


def ground_normal(points: NDArray) -> NDArray[np.float64] | None:
    """The ground plane's upward unit normal in the scan's frame, or None where no plausible ground
    is seen (too few low points, a plane too steep or above the sensor): a pose-graph node's measured
    up (:mod:`vcr_odom.loops.gravity`). Measured on the lowest points near the sensor, where the ground
    is densest: a scan-wide fit through a sparse sensor's few rings tilts by 10-20 degrees."""
    xyz = np.asarray(points)[:, :3]
    xyz = xyz[:: max(1, len(xyz) // GROUND_INPUT_POINTS)].astype(np.float64)
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    horizontal = np.linalg.norm(xyz[:, :2], axis=1)
    xyz = xyz[(horizontal > GROUND_NEAR_M[0]) & (horizontal < GROUND_NEAR_M[1])]
    if len(xyz) < GROUND_MIN_POINTS:
        return None
    low = xyz[xyz[:, 2] < np.percentile(xyz[:, 2], 5) + GROUND_BAND_M]
    low = low[:: max(1, len(low) // GROUND_SAMPLE_POINTS)]
    if len(low) < GROUND_MIN_POINTS:
        return None
    import open3d as o3d  # loaded where used: importing this module stays light

    o3d.utility.random.seed(0)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(low))
    _, inliers = cloud.segment_plane(GROUND_DISTANCE_M, 3, GROUND_ITERATIONS, probability=1.0)
    if len(inliers) < GROUND_MIN_POINTS:
        return None
    plane = least_squares_plane(low[inliers])  # RANSAC's own model rests on three points
    if not is_ground(plane, GROUND_MAX_TILT_DEG) or plane[3] < GROUND_SENSOR_ABOVE_M:
        return None
    return plane[:3]
