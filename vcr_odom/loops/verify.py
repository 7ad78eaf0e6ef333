"""A loop candidate measured: VCR-Net with no guess, ICP from several starts, the fit's information,
and a few physical checks.

The network registers the two nodes' clouds, the later one turned by the odometry's relative rotation
first (the network is trained on headings within +-30 deg, and the odometry's heading drift between
two visits is a few degrees). Point-to-plane ICP then polishes from the network's estimate, from the
odometry's, and from the odometry's turned and moved either way by its uncertainty; the fit that
overlaps most wins, among those the odometry's uncertainty allows. A narrow field of view that comes
back at another heading shares little with its other visit's scan, so such nodes register their
submaps (:func:`~vcr_odom.loops.nodes.submap_cloud`).

A loop is a measurement: a relative pose with its information (:func:`fit_information`, the same as
every odometry edge's), rejected by the first of :data:`CHECKS` it fails (docs/usage.md says what
each catches). ``ambiguous``: a start ends in another fit that overlaps alike. A place is recognised
where every start ends in the fit kept or in clearly worse ones (a network that misses a narrow view,
a start beyond a wall); two fits alike are a place that repeats within what the odometry knows (a
bent submap, a yard alike all round, a look-alike stretch).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import open3d as o3d
from numpy.typing import NDArray
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from vcr_odom.errors import DataWarning
from vcr_odom.geometry import Transform, adjoint, invert, make_transform, motion_difference, rotation_angle
from vcr_odom.loops.candidates import Chain, LoopCandidate, LoopEdge, chi2_gate
from vcr_odom.loops.nodes import (
    CLOUD_VOXEL_M,
    Node,
    NodeNormals,
    azimuth_coverage,
    normal_cloud,
    submap_cloud,
    submap_members,
)
from vcr_odom.loops.settings import LoopSettings
from vcr_odom.registration.vcr import VcrFrame, VcrRegistrar

CHECKS = ("points", "overlap", "fit_rmse", "odometry", "degenerate", "ambiguous", "inconsistent")
"""What a candidate can fail, in the order tried (``inconsistent``: measured and accepted here, then
left out by the pairwise consistency of the loops)."""


@dataclass
class FitScores:
    """What the verification measured of a candidate (``loops.json``)."""

    fitness: float
    inlier_rmse_m: float
    start: str
    other_start_fitness: float
    starts_apart_m: float
    starts_apart_deg: float
    correction_m: float
    correction_deg: float
    odometry_chi2: float
    weakest_share: float
    submaps: bool
    network_input_kept_ground: bool


@dataclass
class LoopDecision:
    """What became of a candidate: the verdict, what was measured (``loop``: ``T_target_source`` and its
    information, open3d's order: rotation then translation, in the target's frame) and why."""

    candidate: LoopCandidate
    source_frame: int
    target_frame: int
    accepted: bool = False
    reason: str = ""
    check: str = ""
    loop: LoopEdge | None = None
    """The measurement as the consistency check and the graph take it (a submap's placement with it)."""
    scores: FitScores | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    """What later stages add (the graph's residual of the loop)."""

    def reject(self, check: str, reason: str) -> None:
        self.accepted, self.check, self.reason = False, check, reason

    def to_dict(self) -> dict[str, Any]:
        candidate = self.candidate
        scores = {} if self.scores is None else asdict(self.scores)
        return {
            "source_node": candidate.source,
            "target_node": candidate.target,
            "source_frame": self.source_frame,
            "target_frame": self.target_frame,
            "path_between_m": round(candidate.path_m, 3),
            "frames_between": candidate.frames,
            "odometry_distance_m": round(candidate.distance_m, 3),
            "odometry_sigma_m": round(candidate.sigma_m, 3),
            "accepted": self.accepted,
            "reason": self.reason,
            "failed_check": self.check or None,
            **{k: round(v, 4) if isinstance(v, float) else v for k, v in scores.items()},
            **self.extra,
            "odometry_T_target_source": candidate.prior.tolist(),
            "measured_T_target_source": None if self.loop is None else self.loop.transform.tolist(),
        }


@dataclass(frozen=True)
class Fit:
    """A polished fit: ``transform`` (``T_target_source``), its overlap and inlier RMSE, and its
    information (open3d's order, the target's frame)."""

    transform: Transform
    fitness: float
    rmse: float
    information: NDArray[np.float64]
    weakest_share: float = 0.0
    """The smallest share of the correspondences' normals along any direction (the smallest eigenvalue
    of their mean outer product; the three add up to 1): near 0 where the fit can slide."""


def fit_information(
    source: o3d.geometry.PointCloud,
    target: o3d.geometry.PointCloud,
    transform: Transform,
    distance: float,
    settings: LoopSettings,
    points: float | None = None,
) -> Fit:
    """The fit of ``source`` on ``target`` (which has normals) at ``transform``, with correspondences
    within ``distance``: its overlap, its inlier RMSE, and its point-to-plane Gauss-Newton Hessian
    (rows ``[p x n, n]``: a corridor's walls hold nothing along it) scaled to ``points`` independent
    points (default ``information_points``) of the fit's own point-to-plane noise (at least
    ``min_fit_rmse_m``). Odometry edges and loops are weighed alike by it. Not open3d's
    ``get_information_matrix_from_point_clouds``: it is point-to-point, its translation block a count of
    points that no corridor weakens; one KD-tree query gives the correspondences, overlap and RMSE."""
    moved = np.asarray(source.points) @ transform[:3, :3].T + transform[:3, 3]
    target_points = np.asarray(target.points)
    gaps, nearest = cKDTree(target_points).query(moved, distance_upper_bound=distance)
    inliers = np.isfinite(gaps)
    if inliers.sum() < 3:
        return Fit(np.asarray(transform, dtype=np.float64), 0.0, 0.0, np.zeros((6, 6)))
    at, normals = moved[inliers], np.asarray(target.normals)[nearest[inliers]]
    residuals = np.einsum("ij,ij->i", at - target_points[nearest[inliers]], normals)
    jacobian = np.hstack([np.cross(at, normals), normals])
    noise = max(float(np.sqrt(np.mean(residuals**2))), settings.min_fit_rmse_m)
    points = settings.information_points if points is None else points
    information = jacobian.T @ jacobian * (points / len(at)) / noise**2
    rmse = float(np.sqrt(np.mean(gaps[inliers] ** 2)))
    share = float(np.linalg.eigvalsh(normals.T @ normals / len(normals))[0])
    return Fit(np.asarray(transform, dtype=np.float64), float(inliers.mean()), rmse, information, share)


def polish(
    source: o3d.geometry.PointCloud,
    target: o3d.geometry.PointCloud,
    start: Transform,
    scale: float,
    settings: LoopSettings,
) -> Fit:
    """Point-to-plane ICP from ``start``, coarse then fine (distances times ``scale``), and its fit."""
    registration = o3d.pipelines.registration
    transform = np.asarray(start, dtype=np.float64)
    for distance in (settings.coarse_distance_m, settings.fine_distance_m):
        result = registration.registration_icp(
            source,
            target,
            distance * scale,
            transform,
            registration.TransformationEstimationPointToPlane(),
            registration.ICPConvergenceCriteria(1e-6, 1e-6, settings.icp_iterations),
        )
        transform = np.asarray(result.transformation)
    distance = settings.fine_distance_m * scale
    return fit_information(source, target, transform, distance, settings, settings.loop_information_points)


def distance_scale(node: Node) -> float:
    """The factor on the fit distances for a node grid finer than 1 m (rooms), down to half: the coarse
    stage must still cover the network's error, which does not shrink indoors."""
    return max(node.cloud_voxel / CLOUD_VOXEL_M, 0.5)


class LoopVerifier:
    """Measures and judges candidates; keeps each target's encoding and cloud for the next candidate."""

    def __init__(
        self, network: VcrRegistrar, chain: Chain, settings: LoopSettings, normals: NodeNormals
    ) -> None:
        self.network, self.chain, self.settings, self.normals = network, chain, settings, normals
        self._targets: dict[_CloudKey, tuple[VcrFrame, o3d.geometry.PointCloud]] = {}
        self._clouds: dict[_CloudKey, NDArray[np.float32]] = {}

    def verify(self, candidate: LoopCandidate, nodes: list[Node]) -> LoopDecision:
        settings = self.settings
        source, target = nodes[candidate.source], nodes[candidate.target]
        decision = LoopDecision(candidate, source.frame_index, target.frame_index)
        coverage = min(azimuth_coverage(source.cloud), azimuth_coverage(target.cloud))
        narrow = coverage < settings.narrow_field_coverage
        turned = math.degrees(float(rotation_angle(candidate.prior[:3, :3])))
        submaps = narrow and turned >= settings.submap_turn_deg
        source_key = self._key(candidate.source, candidate.target, nodes, submaps)
        target_key = self._key(candidate.target, candidate.source, nodes, submaps)
        source_points = self._cloud(source_key, nodes)
        if min(len(source_points), len(self._cloud(target_key, nodes))) < settings.min_cloud_points:
            decision.reject("points", "rejected: too few points to register")
            return decision
        target_frame, target_cloud = self._target(target_key, nodes)
        turn = make_transform(candidate.prior[:3, :3], np.zeros(3))
        source_input, kept_ground = self._network_points(source_points)
        (source_frame,) = self.network.encode_inputs([(source_input @ turn[:3, :3].T).astype(np.float32)])
        network = self.network.register(source_frame, target_frame)
        source_cloud = self._normal_cloud(source_key, nodes)
        scale = distance_scale(source)
        placement = None
        if submaps:
            placement = self.chain.submap_placement(*source_key) + self.chain.submap_placement(*target_key)
        starts = {"network": network.transform @ turn, **self._odometry_starts(candidate, placement)}
        fits = {
            name: polish(source_cloud, target_cloud, start, scale, settings) for name, start in starts.items()
        }
        ends = candidate.source, candidate.target
        loops = {
            name: LoopEdge(*ends, fit.transform, fit.information, placement) for name, fit in fits.items()
        }
        chi2 = {name: self.chain.loop_chi2(loop) for name, loop in loops.items()}
        gate = chi2_gate(settings.odometry_confidence, 6)
        best = max(fits, key=lambda name: (chi2[name] <= gate, fits[name].fitness))
        fit, agree_m = fits[best], settings.starts_agree_m * scale
        apart = {name: motion_difference(other.transform, fit.transform) for name, other in fits.items()}
        elsewhere = [n for n, (m, deg) in apart.items() if m > agree_m or deg > settings.starts_agree_deg]
        rival = max(elsewhere or [n for n in fits if n != best], key=lambda name: fits[name].fitness)
        other, (apart_m, apart_deg) = fits[rival], apart[rival]
        correction_m, correction_deg = motion_difference(candidate.prior, fit.transform)
        decision.loop = loops[best]
        decision.scores = FitScores(
            fitness=fit.fitness,
            inlier_rmse_m=fit.rmse,
            start=best,
            other_start_fitness=other.fitness,
            starts_apart_m=apart_m,
            starts_apart_deg=apart_deg,
            correction_m=correction_m,
            correction_deg=correction_deg,
            odometry_chi2=chi2[best],
            weakest_share=fit.weakest_share,
            submaps=submaps,
            network_input_kept_ground=kept_ground,
        )
        min_overlap = settings.min_overlap_narrow if narrow else settings.min_overlap
        max_rmse = settings.max_fit_rmse_m * scale
        if fit.fitness < min_overlap:
            decision.reject("overlap", f"rejected: overlap {fit.fitness:.2f} < {min_overlap}")
        elif fit.rmse > max_rmse:
            decision.reject("fit_rmse", f"rejected: fit RMSE {fit.rmse:.2f} m > {max_rmse:.2f} m")
        elif chi2[best] > gate:
            decision.reject(
                "odometry",
                f"rejected: asks the odometry for {correction_m:.2f} m / {correction_deg:.1f} deg over "
                f"{candidate.path_m:.0f} m of path, beyond its uncertainty (chi2 {chi2[best]:.1f} > {gate:.1f})",
            )
        elif fit.weakest_share < settings.min_normal_share:
            decision.reject(
                "degenerate",
                f"rejected: degenerate: {fit.weakest_share:.3f} of its surfaces' normals along its weakest "
                f"direction (< {settings.min_normal_share}): the fit can slide along it",
            )
        elif rival in elsewhere and fit.fitness - other.fitness < settings.ambiguity_overlap_gap:
            decision.reject(
                "ambiguous",
                f"rejected: ambiguous: the {best}'s start and the {rival}'s end {apart_m:.1f} m / "
                f"{apart_deg:.0f} deg apart (overlap {fit.fitness:.2f}, the other {other.fitness:.2f})",
            )
        else:
            decision.accepted, decision.reason = True, "accepted"
        return decision

    def _odometry_starts(
        self, candidate: LoopCandidate, placement: NDArray[np.float64] | None
    ) -> dict[str, Transform]:
        """The odometry's start, and it turned and moved ``spread_start_sigmas`` of its uncertainty
        either way: about the world's up (the heading, which neither gravity nor the ground holds) and
        along the level direction the later node's position is least sure of (the odometry's covariance
        between the two ends, a submap's placement with it)."""
        spread = self.chain.world_covariance(candidate.target, candidate.source)
        spread = spread if placement is None else spread + placement
        target, source = self.chain.poses[candidate.target], self.chain.poses[candidate.source]
        at_source = adjoint(invert(source))  # the source's position in its own axes, then the world's
        position = source[:3, :3] @ (at_source @ spread @ at_source.T)[3:, 3:] @ source[:3, :3].T
        variances, directions = np.linalg.eigh(position[:2, :2])  # level: the world's x and y
        sigmas = self.settings.spread_start_sigmas
        angle = sigmas * math.sqrt(max(float(spread[2, 2]), 0.0))
        step = sigmas * math.sqrt(max(float(variances[-1]), 0.0)) * target[:2, :3].T @ directions[:, -1]
        starts = {"odometry": candidate.prior}
        for sign in (-1.0, 1.0):
            turned, moved = candidate.prior.copy(), candidate.prior.copy()
            turned[:3, :3] = Rotation.from_rotvec(sign * angle * target[2, :3]).as_matrix() @ turned[:3, :3]
            moved[:3, 3] += sign * step
            starts[f"odometry turned {sign * sigmas:+g} sigma"] = turned
            starts[f"odometry moved {sign * sigmas:+g} sigma"] = moved
        return starts

    def _network_points(self, cloud: NDArray[np.float32]) -> tuple[NDArray[np.float32], bool]:
        """The network's input from a node's cloud or submap, and whether pre-processing had to keep
        the ground (a sparse sensor's 1 m cloud can hold too few points off it)."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", DataWarning)
            points = self.network.network_input(cloud)
        return points, any(issubclass(w.category, DataWarning) for w in caught)

    def _target(self, key: _CloudKey, nodes: list[Node]) -> tuple[VcrFrame, o3d.geometry.PointCloud]:
        if key not in self._targets:
            (frame,) = self.network.encode_inputs([self._network_points(self._cloud(key, nodes))[0]])
            self._targets[key] = (frame, self._normal_cloud(key, nodes))
        return self._targets[key]

    def _normal_cloud(self, key: _CloudKey, nodes: list[Node]) -> o3d.geometry.PointCloud:
        """A node's own cloud with the normals estimated once for it, or a submap with its own."""
        if key[1] is None:
            return self.normals.cloud(key[0])
        return normal_cloud(self._cloud(key, nodes), nodes[key[0]].cloud_voxel)

    def _cloud(self, key: _CloudKey, nodes: list[Node]) -> NDArray[np.float32]:
        index, members = key
        if members is None:
            return nodes[index].cloud
        if key not in self._clouds:
            self._clouds[key] = submap_cloud(nodes, index, members, self.settings.submap_radius_m)
        return self._clouds[key]

    def _key(self, index: int, other: int, nodes: list[Node], submaps: bool) -> _CloudKey:
        """Node ``index``'s own cloud, or its submap apart from node ``other``'s (no node in both)."""
        if not submaps:
            return index, None
        return index, submap_members(nodes, index, other, self.settings.submap_half_path_m)


_CloudKey = tuple[int, tuple[int, ...] | None]


def odometry_information(
    nodes: list[Node], normals: NodeNormals, settings: LoopSettings
) -> list[NDArray[np.float64]]:
    """Each odometry edge's information: the fit of the next node's cloud on this node's at the
    odometry's relative pose (:func:`fit_information`), so that the graph and the candidates weigh the
    odometry by what its scans measured: weakly along a corridor, weakly where they fit poorly. Plus a
    prior of the nodes' own spacing (``node_angle_deg``, ``node_spacing_m`` as one sigma): the odometry
    measured the motion between two nodes even where their coarse clouds share nothing, and a
    direction no edge holds would leave the graph singular beyond the last loop."""
    rotation, translation = math.radians(settings.node_angle_deg) ** -2, settings.node_spacing_m**-2
    spacing_prior = np.diag([rotation] * 3 + [translation] * 3)
    informations = []
    for k in range(len(nodes) - 1):
        motion = np.linalg.inv(nodes[k].pose) @ nodes[k + 1].pose
        distance = settings.fine_distance_m * distance_scale(nodes[k])
        fit = fit_information(normals.cloud(k + 1), normals.cloud(k), motion, distance, settings)
        informations.append(fit.information + spacing_prior)
    return informations
