"""Polishes: a local method that refines a global estimate, behind one small interface.

A global method (VCR-Net, FPFH+RANSAC) needs no motion prior but is only decimetre-accurate; a local
method (ICP, kiss-icp) is centimetre-accurate but only when started near the answer. Chained, the
global estimate is the local method's start. Each polish also keeps a second start (the motion
prior), because a global estimate that is metres off on one pair lies outside the local basin where
the constant-velocity guess often does not; docs/usage.md "Choosing the polish" has the measurements.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from kiss_icp.config import KISSConfig

from vcr_odom.data.base import Points
from vcr_odom.errors import ConfigError, DataWarning
from vcr_odom.geometry import Transform, invert, motion_difference
from vcr_odom.odometry.agreement import within_basin
from vcr_odom.odometry.degeneracy import WEAK_AXIS_SHARE
from vcr_odom.odometry.guided_kiss import (
    MIN_SOURCE_POINTS,
    GuidedKissICP,
    KissAttempt,
    KissFrame,
    KissFramePreparer,
    PolishEngine,
    frame_to_frame_fit,
)
from vcr_odom.odometry.polish_voxel import density_voxel, raw_sparse_scan, with_voxel
from vcr_odom.registration.base import TOO_FEW_POINTS, RegistrationResult
from vcr_odom.registration.kiss import kiss_config, kiss_input
from vcr_odom.registration.open3d_icp import Open3dIcp

POLISHES: dict[str, str] = {
    "none": "the global registrar's estimate as it is",
    "icp": "open3d point-to-plane ICP on the two frames, started from the global estimate and from the "
    "last motion: the better fit wins",
    "kiss-icp": "kiss-icp's adaptive-threshold registration to its local map, from its own prediction and, "
    "where that result disagrees with the global estimate, from the estimate too: the estimate's result "
    "wins where it fits the map markedly better",
}
"""Polish name -> one-line description (for ``--help`` and error messages)."""


@dataclass
class PolishResult:
    """The polished relative motion ``T_t_(t+1)`` and what happened (``polish_start``: which start won)."""

    motion: Transform
    info: dict[str, Any] = field(default_factory=dict)
    fit: float | None = None
    """How well the result fits (as :attr:`PriorAttempt.fit`); set by ``finish``."""


@dataclass
class PriorAttempt:
    """The frame registered from the motion prior alone, not yet committed: its relative motion, how
    well it fits (``fit``: a share of points with a partner, comparable between frames of one run),
    and what the polish needs to finish it."""

    motion: Transform
    fit: float
    state: Any = None
    correction: tuple[float, float] = (0.0, 0.0)
    """How far the local method moved from its start (m, deg): a start outside its basin may have
    slid into a wrong minimum that still fits well."""


class Polish(Protocol):
    """``prepare`` is per-frame work without state (it may run ahead of the chain); ``start`` begins a
    run at its first frame; ``from_prior`` registers a frame from the motion prior without committing
    it, so that the global estimate is asked for only where that result is in doubt; ``finish`` commits
    a frame: the prior's result (``coarse`` None), or the better of it and the result from the global
    estimate (``attempt`` None: the estimate alone, with the prior as the second start where the polish
    keeps one); ``from_rest`` is a second start from standing still; ``restart`` recovers after a
    divergence."""

    name: str
    prepare_ahead: bool
    """Whether ``prepare`` gains from running in a second thread (not where it holds the GIL)."""

    def prepare(self, points: Points) -> Any: ...

    def start(self, frame: Any) -> None: ...

    def from_prior(
        self, frame: Any, previous: Any, *, pose: Transform, last_motion: Transform
    ) -> PriorAttempt: ...

    def finish(
        self,
        attempt: PriorAttempt | None,
        frame: Any,
        previous: Any,
        coarse: Transform | None,
        *,
        pose: Transform,
        last_motion: Transform,
    ) -> PolishResult: ...

    def from_rest(self, attempt: PriorAttempt, frame: Any, previous: Any) -> Transform: ...

    def restart(self, frame: Any, pose: Transform, motion: Transform) -> None: ...


def polish_icp() -> Open3dIcp:
    """Point-to-plane ICP stopped when fitness and RMSE change by < 1e-4 (at most 30 iterations):
    as accurate as running it to convergence from a start this close, at a fraction of the time."""
    return Open3dIcp(
        variant="point_to_plane",
        max_iterations=30,
        relative_fitness=1e-4,
        relative_rmse=1e-4,
        name="icp-polish",
    )


class IcpPolish:
    """open3d ICP between the two frames (voxel-down-sampled, ground kept).

    ``second_start``: where the last motion lies outside the global estimate's basin, ICP also runs
    from it, and the result with the higher fitness wins (``polish_start``: ``global`` or ``last motion``).
    """

    name = "icp"
    prepare_ahead = True
    """open3d releases the GIL: the ICP cloud of the next frame is built while this one is polished."""

    def __init__(self, icp: Open3dIcp | None = None, second_start: bool = True) -> None:
        self.icp = icp or polish_icp()
        self.second_start = second_start

    def prepare(self, points: Points) -> Any:
        return self.icp.prepare(points)

    def start(self, frame: Any) -> None:
        """Nothing to set up: ICP keeps no state between pairs."""

    def from_prior(
        self, frame: Any, previous: Any, *, pose: Transform, last_motion: Transform
    ) -> PriorAttempt:
        """ICP from the last motion; ``fit`` is ICP's fitness (share of points with a partner)."""
        result = self.icp.register(frame, previous, last_motion)
        motion = np.asarray(result.transform, dtype=np.float64)
        return PriorAttempt(motion, float(result.fitness), result, motion_difference(last_motion, motion))

    def from_rest(self, attempt: PriorAttempt, frame: Any, previous: Any) -> Transform:
        """The relative motion ICP reaches from standing still (a second start beside the prior's)."""
        return np.asarray(self.icp.register(frame, previous, np.eye(4)).transform, dtype=np.float64)

    def finish(
        self,
        attempt: PriorAttempt | None,
        frame: Any,
        previous: Any,
        coarse: Transform | None,
        *,
        pose: Transform,
        last_motion: Transform,
    ) -> PolishResult:
        """The prior's result, or (given a global estimate) the better fit of it and ICP from the
        estimate, the estimate's on a tie. Without an attempt, ICP from the last motion is run here, and
        only where it can end elsewhere (``second_start``, the last motion outside the estimate's basin)."""
        if attempt is None:
            if coarse is None:
                raise ValueError("finish() needs a global estimate where there is no prior attempt")
            if not self.second_start or within_basin(coarse, last_motion):
                return _icp_result(self.icp.register(frame, previous, coarse), "global")
        result = self.icp.register(frame, previous, last_motion) if attempt is None else attempt.state
        start = "last motion"
        if coarse is not None:
            from_global = self.icp.register(frame, previous, coarse)
            if from_global.fitness >= result.fitness:
                result, start = from_global, "global"
        polished = _icp_result(result, start)
        polished.fit = float(result.fitness)
        return polished

    def restart(self, frame: Any, pose: Transform, motion: Transform) -> None:
        """Nothing to restart."""


def _icp_result(result: RegistrationResult, start: str) -> PolishResult:
    info = {"polish_fitness": result.fitness, "polish_inlier_rmse": result.inlier_rmse, "polish_start": start}
    if result.info.get("status") == TOO_FEW_POINTS:  # not registered: its start kept
        info["polish_status"] = TOO_FEW_POINTS
    return PolishResult(np.asarray(result.transform, dtype=np.float64), info)


POLISH_CONVERGENCE = 1e-3
"""kiss-icp's registration stops when its update is below this (kiss-icp's own default: 1e-4, which
the baseline keeps). On the sample the polish is as accurate at 1e-3, with about 30 % less CPU a frame;
docs/results.md "Benchmarks and speed" has the figures, kiss-icp's own at 1e-3 beside them."""


COARSE_FACTOR = 2.0
"""The coarse map's voxel over a polish map made finer than kiss-icp's own (keyframe sets, sparse
scans), never coarser than kiss-icp's own: on sparse keyframe sets far starts then take 1.1-1.4x less
time in kiss-icp's registration at the same accuracy; kiss-icp's own voxel as the coarse grid lost an
Avia keyframe walk, and a grid coarser than kiss-icp's left a spinning drive's far start 0.2 m off
(docs/benchmarks.md, "A coarse stage for far starts")."""


def polish_kiss_config() -> KISSConfig:
    """kiss-icp's configuration for the polish: its default, with :data:`POLISH_CONVERGENCE`."""
    return kiss_config(convergence_criterion=POLISH_CONVERGENCE)


class KissIcpPolish:
    """kiss-icp's registration against its local voxel map (:class:`GuidedKissICP`).

    ``keep_prediction``: kiss-icp's constant-velocity prediction stays a start and the global estimate
    is a second one (``polish_start``: ``prediction`` or ``global``); False: the global estimate
    replaces the prediction. ``adapt_voxel``: the first frame picks the map voxel from its density
    (:func:`~vcr_odom.odometry.polish_voxel.density_voxel`); False keeps ``config``'s. ``voxel_size``:
    this map voxel for the run instead (``--polish-voxel``; the density is not asked). ``weak_share``:
    a result keeps its start's position along the directions its frame cannot measure
    (:func:`~vcr_odom.odometry.degeneracy.weak_axes`; 0 turns it off, and the polish fed its own
    prediction is kiss-icp's). ``point_to_plane``: each fit is finished point to plane
    (:mod:`~vcr_odom.odometry.plane_refinement`); None: where the first frame is a raw sparse scan
    (:func:`~vcr_odom.odometry.polish_voxel.raw_sparse_scan`: solid-state, neither a spinning sensor's
    rings nor a keyframe cloud thinned on a grid), whose point-to-point fit slides back; never with the
    ``vgicp`` engine, whose fit pairs surfaces already (docs/benchmarks.md, "A Gaussian voxel map for
    the polish").
    ``coarse_start``: where the map is finer than kiss-icp's own voxel, a start far from the prediction
    is registered on a map :data:`COARSE_FACTOR` times coarser first, at most kiss-icp's own voxel
    (:class:`GuidedKissICP`'s ``coarse_voxel``). ``engine``: what registers a frame to the map
    (:data:`~vcr_odom.odometry.guided_kiss.ENGINES`).
    """

    name = "kiss-icp"
    prepare_ahead = False
    """kiss-icp's pre-processing holds Python's GIL: done in a second thread it only slows the chain.
    Nor does a second process gain on two cores: kiss-icp's registration already keeps both busy."""

    def __init__(
        self,
        config: KISSConfig | None = None,
        keep_prediction: bool = True,
        adapt_voxel: bool = True,
        weak_share: float = WEAK_AXIS_SHARE,
        voxel_size: float | None = None,
        point_to_plane: bool | None = None,
        coarse_start: bool = True,
        engine: PolishEngine = "kiss-icp",
    ) -> None:
        self.engine = engine  # checked where the first map is made, below
        self.config = config or polish_kiss_config()
        self.coarse_start = coarse_start
        self._kiss_own_config = self.config
        if voxel_size is not None:
            if not voxel_size > 0:
                raise ConfigError(f"the kiss-icp polish's voxel must be positive, got {voxel_size!r} m")
            self.config, adapt_voxel = with_voxel(self.config, voxel_size), False
        self.keep_prediction = keep_prediction
        self.weak_share = weak_share
        self.point_to_plane = bool(point_to_plane)
        self.kiss = self._new_map()
        self._preparer = KissFramePreparer(self.config)
        self._voxel_open = adapt_voxel
        self._plane_open = point_to_plane is None

    def prepare(self, points: Points) -> KissFrame:
        """Finite xyz as float64 (as :class:`KissIcpOdometry` feeds kiss-icp), pre-processed and
        voxelized as kiss-icp would, and indexed for the frame-to-frame fit."""
        frame = kiss_input(points)
        if len(frame) == 0:
            warnings.warn(
                "kiss-icp polish: empty frame, the global estimate is kept", DataWarning, stacklevel=3
            )
        elif self._plane_open or self._voxel_open:
            self._decide_on_first_frame(frame)
        return self._preparer(frame)

    def _decide_on_first_frame(self, frame: np.ndarray) -> None:
        """The first non-empty frame fixes the map voxel (kiss-icp's map keeps one grid) and whether
        fits are finished point to plane, for the whole run."""
        if self._plane_open:
            point_fit = self.engine != "vgicp"  # VGICP's fit pairs surfaces already
            self.point_to_plane = point_fit and raw_sparse_scan(frame, self._kiss_own_config)
        if self._voxel_open:
            self.config = with_voxel(self.config, density_voxel(frame, self.config))
            self._preparer = KissFramePreparer(self.config)
        self._plane_open = self._voxel_open = False
        self.kiss = self._new_map()

    def _new_map(self) -> GuidedKissICP:
        fine, own = self.config.mapping.voxel_size, self._kiss_own_config.mapping.voxel_size
        coarse = min(COARSE_FACTOR * fine, own) if self.coarse_start else 0.0
        return GuidedKissICP(self.config, self.weak_share, self.point_to_plane, coarse, self.engine)

    @property
    def voxel_size(self) -> float:
        """The map voxel in use (chosen on the first frame unless ``adapt_voxel=False``)."""
        return float(self.config.mapping.voxel_size)

    def start(self, frame: KissFrame) -> None:
        """A new map, seeded with the first frame at the identity."""
        self.kiss = self._new_map()
        self.kiss.seed(frame, np.eye(4))

    def from_prior(
        self, frame: KissFrame, previous: KissFrame, *, pose: Transform, last_motion: Transform
    ) -> PriorAttempt:
        """kiss-icp from its own prediction; ``fit``: share of its registration points within a map voxel
        of the previous frame's (frame to frame: a KD-tree of the map would cost more than the check)."""
        attempt = self.kiss.from_prediction(frame)
        assert attempt.pose is not None
        motion = invert(pose) @ attempt.pose
        fit = frame_to_frame_fit(attempt.source, motion, previous, self.config.mapping.voxel_size)
        return PriorAttempt(motion, fit, attempt, motion_difference(attempt.prediction, attempt.pose))

    def finish(
        self,
        attempt: PriorAttempt | None,
        frame: KissFrame,
        previous: KissFrame,
        coarse: Transform | None,
        *,
        pose: Transform,
        last_motion: Transform,
    ) -> PolishResult:
        """kiss-icp's :meth:`GuidedKissICP.finish` with the global estimate as the second start; without
        an attempt, the frame is registered from the prediction here (``keep_prediction``; else the
        estimate replaces it) and ``fit`` is not measured."""
        guess = None if coarse is None else pose @ coarse
        if attempt is None:
            return self._finished(self.kiss.from_prediction(frame, align=self.keep_prediction), guess, pose)
        polished = self._finished(attempt.state, guess, pose)
        polished.fit = attempt.fit
        if polished.info["polish_start"] != "prediction":
            distance = self.config.mapping.voxel_size
            polished.fit = frame_to_frame_fit(attempt.state.source, polished.motion, previous, distance)
        return polished

    def from_rest(self, attempt: PriorAttempt, frame: KissFrame, previous: KissFrame) -> Transform:
        """The relative motion kiss-icp reaches against its map from standing still (the last pose), a
        second start beside its prediction; nothing is committed."""
        last_pose = self.kiss.last_pose
        return invert(last_pose) @ self.kiss.held_align(attempt.state, last_pose)

    def _finished(self, attempt: KissAttempt, guess: Transform | None, pose: Transform) -> PolishResult:
        new_pose, start = self.kiss.finish(attempt, guess)
        info = {
            "kiss_sigma": self.kiss.last_sigma,
            "kiss_source_points": self.kiss.last_source_points,
            "polish_start": start,
        }
        if self.kiss.last_weak_axes:
            info["weak_axes"] = self.kiss.last_weak_axes
        if self.kiss.last_source_points < MIN_SOURCE_POINTS:  # not registered: its start kept
            info["polish_status"] = TOO_FEW_POINTS
        return PolishResult(invert(pose) @ new_pose, info)

    def restart(self, frame: KissFrame, pose: Transform, motion: Transform) -> None:
        """A diverged map would drag every later frame: start a new one at ``pose @ motion``."""
        self.kiss = self._new_map()
        self.kiss.seed(frame, pose @ motion, motion)


def make_polish(name: str, **options: Any) -> Polish | None:
    """The polish called ``name`` (``none`` -> None); ``options`` go to its constructor."""
    if name == "none":
        return None
    if name == "icp":
        return IcpPolish(**options)
    if name == "kiss-icp":
        return KissIcpPolish(**options)
    raise ConfigError(f"unknown polish {name!r}; valid choices: {', '.join(POLISHES)}")
