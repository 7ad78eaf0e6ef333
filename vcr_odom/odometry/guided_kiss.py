"""kiss-icp's frame registration with a second start: the one piece that reaches into kiss-icp.

Every step is kiss-icp's own library piece, in its order (preprocess, voxelize, adaptive threshold,
``align_points_to_map``, model-deviation update, map update); what is added is a second start for the
registration, the choice between the two results, and a split of the work: what depends on the frame
alone (:func:`kiss_frame`) may run ahead of the chain, and the registration from kiss-icp's own
prediction (:meth:`GuidedKissICP.from_prediction`) can be looked at before deciding whether a second
start is needed (:meth:`GuidedKissICP.finish`). With ``engine="vgicp"`` the registration step is
small_gicp's instead (:mod:`~vcr_odom.odometry.gaussian_map`), with ``"vgicp-start"`` it starts from
small_gicp's where kiss-icp's predictions err by metres; the rest stays kiss-icp's. These are
kiss-icp internals, not its public API, so the supported versions are bounded in pyproject.toml and
:func:`check_kiss_internals` names what is missing if a release moves them, instead of failing mid-run.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import open3d as o3d
from kiss_icp.config import KISSConfig
from kiss_icp.kiss_icp import KissICP, get_preprocessor, voxel_down_sample
from kiss_icp.mapping import VoxelHashMap
from scipy.spatial import cKDTree

from vcr_odom.errors import ConfigError
from vcr_odom.geometry import Transform, project_to_se3
from vcr_odom.odometry.agreement import MARKEDLY_WORSE, within_basin
from vcr_odom.odometry.degeneracy import WEAK_AXIS_SHARE, hold_along, weak_axes
from vcr_odom.odometry.gaussian_map import GaussianMap
from vcr_odom.odometry.plane_refinement import refine_point_to_plane, registration_normals
from vcr_odom.registration.base import MIN_REGISTRATION_POINTS

NORMAL_RADIUS_VOXELS = 4.5
"""Surface normals for the weak axes are estimated within this many map voxels: three cells of the
registration's own grid (1.5 voxels), so a normal spans a few of the points it is fitted to."""

ENGINES: dict[str, str] = {
    "kiss-icp": "kiss-icp's own point-to-point registration to its voxel map",
    "vgicp": "small_gicp's voxelized GICP to a Gaussian voxel map on the same grid: converges in a few "
    "iterations from far starts (docs/benchmarks.md)",
    "vgicp-start": "kiss-icp's own registration, started from VGICP's result where kiss-icp's adaptive "
    "threshold exceeds its initial one (its predictions err by metres: keyframes, low rates); "
    "elsewhere exactly kiss-icp's (docs/benchmarks.md)",
}
"""The polish's registration engines (``--polish-engine``)."""
PolishEngine = Literal["kiss-icp", "vgicp", "vgicp-start"]

KISS_INTERNALS = ("preprocessor", "voxelize", "adaptive_threshold", "registration", "local_map")


def check_kiss_internals(odometry: KissICP) -> None:
    """ConfigError naming the kiss-icp attributes this polish needs and the installed release lacks."""
    missing = [name for name in KISS_INTERNALS if not hasattr(odometry, name)]
    if not hasattr(getattr(odometry, "registration", None), "align_points_to_map"):
        missing.append("registration.align_points_to_map")
    if missing:
        import kiss_icp

        raise ConfigError(
            f"the kiss-icp polish needs kiss-icp 1.x internals ({', '.join(missing)} missing in "
            f"kiss-icp {getattr(kiss_icp, '__version__', '?')}); install kiss-icp>=1.0,<2 or use --polish icp"
        )


@dataclass
class KissFrame:
    """A frame as kiss-icp registers it. Without deskewing, pre-processing and voxelization depend on
    the frame alone, so they are done here once (``raw`` is then None); with deskewing they need the
    last motion and wait for the chain. ``tree`` indexes ``source`` for the frame-to-frame fit."""

    raw: np.ndarray | None
    source: np.ndarray | None = None
    downsample: np.ndarray | None = None
    tree: cKDTree | None = None


class KissFramePreparer:
    """:func:`kiss_frame` for one configuration (kiss-icp's pre-processor is built once)."""

    def __init__(self, config: KISSConfig) -> None:
        self.config = config
        self.preprocessor = get_preprocessor(config)

    def __call__(self, frame: np.ndarray) -> KissFrame:
        if self.config.data.deskew:
            return KissFrame(raw=frame)
        source, downsample = voxelize(
            self.config, self.preprocessor.preprocess(frame, np.array([]), np.eye(4))
        )
        return KissFrame(None, source, downsample, cKDTree(source) if len(source) else None)


def voxelize(config: KISSConfig, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """kiss-icp's ``KissICP.voxelize`` for a configuration, without an instance (the per-frame work runs
    ahead of the chain): the registration's source and the map's down-sampled frame."""
    return voxelize_at(frame, config.mapping.voxel_size)


def voxelize_at(frame: np.ndarray, voxel_size: float) -> tuple[np.ndarray, np.ndarray]:
    """kiss-icp's two grids for a map voxel of ``voxel_size``: half of it for the map, 1.5x for the source."""
    downsample = voxel_down_sample(frame, voxel_size * 0.5)
    return voxel_down_sample(downsample, voxel_size * 1.5), downsample


@dataclass
class KissAttempt:
    """A frame registered from kiss-icp's own prediction, not yet committed to the map."""

    frame: KissFrame
    source: np.ndarray
    downsample: np.ndarray
    sigma: float
    prediction: Transform
    pose: Transform | None
    weak_axes: np.ndarray
    normals: np.ndarray | None = None
    """Surface normals at ``source`` where the fit is finished point to plane, else None."""


MIN_SOURCE_POINTS = MIN_REGISTRATION_POINTS
"""Fewer registration points than this (a frame of one point, or of 5,000 copies of one) leave
kiss-icp's solve undetermined, a different pose on every run: such a frame keeps its start, as open3d
ICP's does (``too few points``)."""


class GuidedKissICP(KissICP):
    """``KissICP`` whose frames may also start from a pose given by a global method, and whose results
    keep their start's position along the directions the frame cannot measure
    (:func:`~vcr_odom.odometry.degeneracy.weak_axes` under ``weak_share``; 0 turns that off).

    ``point_to_plane``: each registration is finished point to plane
    (:func:`~vcr_odom.odometry.plane_refinement.refine_point_to_plane`), for scans whose point-to-point fit
    slides back at small steps.

    ``coarse_voxel``: where it is coarser than ``config``'s voxel (kiss-icp's own, for a polish map
    made finer for keyframe sets or sparse scans: :mod:`~vcr_odom.odometry.polish_voxel`), a start
    outside the basin of kiss-icp's prediction (:func:`within_basin`: the second start from standing
    still, a global estimate) is registered against a second local map on that voxel first, then
    against the fine map from there: from a start a metre off the fine map alone takes ~20 iterations.
    A start within the basin registers as before (docs/benchmarks.md, "A coarse stage for far
    starts").

    ``engine``: :data:`ENGINES`. ``vgicp`` registers against a
    :class:`~vcr_odom.odometry.gaussian_map.GaussianMap` of the same frames on the same grid instead
    (kiss-icp's map is still kept: the point-to-plane finish and the fit are measured on it), and
    needs no coarse stage. ``vgicp-start`` keeps kiss-icp's registration on its own map but, where
    kiss-icp's adaptive threshold (the spread of its predictions' errors so far) exceeds its initial
    threshold, starts it from VGICP's result on a Gaussian map begun then from kiss-icp's map and kept
    while the threshold stays there: from a start metres off kiss-icp's point-to-point fit crawls,
    with a gate so wide that every point finds a partner, where VGICP converges in a few iterations;
    kiss-icp's registration still places every frame.

    With ``weak_share=0``, ``point_to_plane=False``, the ``kiss-icp`` engine and fed its own prediction
    as the guess, it reproduces kiss-icp's poses exactly (a test holds it to that).
    """

    def __init__(
        self,
        config: KISSConfig,
        weak_share: float = WEAK_AXIS_SHARE,
        point_to_plane: bool = False,
        coarse_voxel: float = 0.0,
        engine: PolishEngine = "kiss-icp",
    ) -> None:
        if engine not in ENGINES:
            raise ConfigError(f"unknown polish engine {engine!r}; valid choices: {', '.join(ENGINES)}")
        super().__init__(config)
        check_kiss_internals(self)
        self.engine = engine
        self.gaussian_map = self._new_gaussian_map() if engine == "vgicp" else None
        if engine == "vgicp":
            coarse_voxel = 0.0
        self.weak_share = weak_share
        self.point_to_plane = point_to_plane
        self.coarse_voxel = coarse_voxel
        self.coarse_map = (
            VoxelHashMap(coarse_voxel, config.data.max_range, config.mapping.max_points_per_voxel)
            if coarse_voxel > config.mapping.voxel_size
            else None
        )
        self.motion_known = False
        self.last_sigma = float("nan")
        self.last_source_points = 0
        self.last_weak_axes = 0

    def seed(self, frame: KissFrame, pose: Transform, last_delta: Transform | None = None) -> None:
        """Start (or restart) the local map with ``frame`` at ``pose``, without registering it against
        an empty map; ``last_delta`` is the motion into this frame (the next prediction's velocity),
        None where no motion is known yet (the prediction then stands still, on no evidence)."""
        _, downsample = self._voxelized(frame, np.eye(4))
        pose = project_to_se3(pose)
        self._update_maps(downsample, pose)
        self.last_pose = pose
        self.last_delta = np.eye(4) if last_delta is None else project_to_se3(last_delta)
        self.motion_known = last_delta is not None

    def from_prediction(self, frame: KissFrame, align: bool = True) -> KissAttempt:
        """The frame registered from kiss-icp's constant-velocity prediction (``align=False``: not
        registered yet, for a guess that replaces the prediction). Nothing is committed."""
        source, downsample = self._voxelized(frame, self.last_delta)
        sigma = float(self.adaptive_threshold.get_threshold())
        prediction = self.last_pose @ self.last_delta
        axes = weak_axes(source, NORMAL_RADIUS_VOXELS * self.config.mapping.voxel_size, self.weak_share)
        normals = registration_normals(source, downsample) if self.point_to_plane else None
        attempt = KissAttempt(frame, source, downsample, sigma, prediction, None, axes, normals)
        if align:
            attempt.pose = self.held_align(attempt, prediction)
        return attempt

    def finish(self, attempt: KissAttempt, guess: Transform | None = None) -> tuple[Transform, str]:
        """Commit the frame: the prediction's result, or the result from ``guess`` (the frame's pose by
        the global method) where that fits the local map markedly better (:data:`MARKEDLY_WORSE`); the
        prediction wins the ties because it carries the motion so far, so before any motion is known
        (a run's first pair) the better fit wins. Returns the pose and the start that won
        (``"prediction"`` or ``"global"``).

        ``guess`` is tried only where the prediction's result lies outside its basin (else it would end
        there too). Fit is open3d's ``evaluate_registration`` fitness within half a map voxel: kiss-icp's
        own 3-sigma gate grows to metres after a large motion, where every start fits. The adaptive
        threshold learns the deviation from the start that won, so it stays kiss-icp's own wherever
        the prediction wins. Guesses are projected onto SE(3): kiss-icp's Sophus aborts the process on
        a rotation that is orthonormal only to float32 precision.
        """
        new_pose, start, start_pose = attempt.pose, "prediction", attempt.prediction
        if guess is not None:
            guess = project_to_se3(guess)
            if new_pose is None:
                new_pose, start, start_pose = self.held_align(attempt, guess), "global", guess
            elif not within_basin(new_pose, guess):
                from_guess = self.held_align(attempt, guess)
                ratio = MARKEDLY_WORSE if self.motion_known else 1.0
                if self._fits_better(attempt.source, from_guess, new_pose, ratio):
                    new_pose, start, start_pose = from_guess, "global", guess
        if new_pose is None:
            raise ValueError("finish() needs a guess for an attempt made without the prediction")
        self.adaptive_threshold.update_model_deviation(np.linalg.inv(start_pose) @ new_pose)
        self._update_maps(attempt.downsample, new_pose)
        self.last_delta = np.linalg.inv(self.last_pose) @ new_pose
        self.last_pose = new_pose
        self.motion_known = True
        self.last_sigma = attempt.sigma
        self.last_source_points = len(attempt.source)
        self.last_weak_axes = len(attempt.weak_axes)
        return np.asarray(new_pose, dtype=np.float64), start

    def register_frame_with_guess(
        self, frame: KissFrame, guess: Transform, keep_prediction: bool = True
    ) -> tuple[Transform, str]:
        """Register ``frame`` from the prediction and, where needed, from ``guess`` (see :meth:`finish`);
        ``keep_prediction=False``: ``guess`` replaces the prediction."""
        return self.finish(self.from_prediction(frame, align=keep_prediction), guess)

    def _voxelized(self, frame: KissFrame, last_delta: Transform) -> tuple[np.ndarray, np.ndarray]:
        if frame.raw is None:
            assert frame.source is not None and frame.downsample is not None
            return frame.source, frame.downsample
        return self.voxelize(self.preprocessor.preprocess(frame.raw, np.array([]), last_delta))

    def held_align(self, attempt: KissAttempt, guess: Transform) -> Transform:
        """The registration from ``guess`` (finished point to plane where the attempt has normals),
        holding its position along the frame's weak axes; ``guess`` itself where the frame has fewer
        than :data:`MIN_SOURCE_POINTS` (see there)."""
        if len(attempt.source) < MIN_SOURCE_POINTS:
            return project_to_se3(guess)
        pose = self._align(attempt.source, guess, attempt.sigma)
        if attempt.normals is not None:
            pose = refine_point_to_plane(
                pose, attempt.source, attempt.normals, self.local_map.point_cloud(), attempt.sigma
            )
        return hold_along(pose, guess, attempt.weak_axes)

    def _align(self, source: np.ndarray, guess: Transform, sigma: float) -> Transform:
        """kiss-icp's registration step, as its ``register_frame`` calls it; from a far start, after a
        coarse one (``coarse_voxel``), or after VGICP's (``engine="vgicp-start"``, where kiss-icp's
        threshold is beyond its initial one); or the Gaussian map's alone (``engine="vgicp"``)."""
        start = project_to_se3(guess)
        if self.engine == "vgicp":
            assert self.gaussian_map is not None
            return project_to_se3(self.gaussian_map.align(source, start))
        if self.engine == "vgicp-start":
            if sigma <= self.config.adaptive_threshold.initial_threshold:
                self.gaussian_map = None  # kiss-icp's predictions hold: its engine alone, no map to feed
            else:
                if self.gaussian_map is None:  # kept beside kiss-icp's map while its predictions err
                    self.gaussian_map = self._new_gaussian_map()
                    self.gaussian_map.insert(self.local_map.point_cloud(), np.eye(4))
                start = project_to_se3(self.gaussian_map.align(source, start))
                return self._align_to(self.local_map, source, start, sigma)
        if self.coarse_map is not None and not within_basin(start, self.last_pose @ self.last_delta):
            coarse = voxel_down_sample(source, 1.5 * self.coarse_voxel)
            if len(coarse) >= MIN_SOURCE_POINTS:
                start = self._align_to(self.coarse_map, coarse, start, sigma)
        return self._align_to(self.local_map, source, start, sigma)

    def _new_gaussian_map(self) -> GaussianMap:
        return GaussianMap(self.config.mapping.voxel_size, self.config.registration.max_num_threads)

    def _align_to(
        self, voxel_map: VoxelHashMap, source: np.ndarray, start: Transform, sigma: float
    ) -> Transform:
        return self.registration.align_points_to_map(
            points=source,
            voxel_map=voxel_map,
            initial_guess=start,
            max_correspondance_distance=3 * sigma,
            kernel=sigma,
        )

    def _update_maps(self, downsample: np.ndarray, pose: Transform) -> None:
        self.local_map.update(downsample, pose)
        if self.gaussian_map is not None:
            self.gaussian_map.insert(downsample, pose)
        if self.coarse_map is not None:
            self.coarse_map.update(voxel_down_sample(downsample, 0.5 * self.coarse_voxel), pose)

    def _fits_better(self, source: np.ndarray, pose: Transform, than: Transform, ratio: float) -> bool:
        """Whether ``source`` placed at ``than`` has less than ``ratio`` times the share of points within
        half a map voxel of the local map that it has at ``pose`` (``ratio=1``: any better fit)."""
        registration = o3d.pipelines.registration
        distance = 0.5 * self.config.mapping.voxel_size
        source_cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(source)))
        map_cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.local_map.point_cloud()))
        fitness = [
            registration.evaluate_registration(source_cloud, map_cloud, distance, candidate).fitness
            for candidate in (pose, than)
        ]
        return bool(fitness[1] < ratio * fitness[0])


def frame_to_frame_fit(source: np.ndarray, motion: Transform, previous: KissFrame, distance: float) -> float:
    """Share of ``source`` (this frame's registration points) that, moved by ``motion`` into the previous
    frame, lie within ``distance`` of that frame's: a cheap check of a registration without the map."""
    if previous.tree is None or len(source) == 0:
        return 0.0
    moved = source @ motion[:3, :3].T + motion[:3, 3]
    distances, _ = previous.tree.query(moved, distance_upper_bound=distance)
    return float(np.mean(np.isfinite(distances)))
