"""A loop candidate registered without the odometry's translation, polished, and judged.

Registration: VCR-Net on the two nodes' clouds, the later one turned by the odometry's
relative rotation first (the network is trained on headings within +-30 deg; the odometry's heading
drift is a few degrees, so any revisit heading, opposite directions included, comes within reach).
The polish: point-to-plane ICP on the nodes' 1 m voxel clouds, from the network's estimate and from
the odometry's, coarse then fine; the better fit wins. Nodes of rooms keep a finer grid
(:func:`~vcr_odom.loops.nodes.node_cloud_voxel`), and the distances below shrink with it (``scale``),
down to :data:`MIN_DISTANCE_SCALE`. A narrow field of view that comes back at another heading
registers the two nodes' submaps (:data:`SUBMAP_TURN_DEG`), where only a fit within the drift bound
may win: a crossing of two streets fits turned by 90 or 180 deg too, and the odometry tells which.

Acceptance, all of: the clouds overlap (``fitness``) and fit (``inlier_rmse``); the correction the
loop asks of the odometry is within the drift the odometry may have gathered between the visits
(:class:`DriftModel`: a look-alike place a block away asks for a block); and the two starts do not
end in two different fits of similar quality (an ambiguous, repetitive place), nor in two different
fits at all where the surfaces hardly face one direction (:func:`ambiguous`)."""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable
from typing import Any

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from vcr_odom.errors import DataWarning
from vcr_odom.geometry import Transform, invert, make_transform, motion_difference, rotation_angle
from vcr_odom.loops.candidates import LoopCandidate
from vcr_odom.loops.corroboration import corroborated
from vcr_odom.loops.decision import LoopDecision
from vcr_odom.loops.drift import DriftModel
from vcr_odom.loops.fit_information import fit_hessian, loop_information, weakest_share, weakest_translation
from vcr_odom.loops.nodes import (
    CLOUD_VOXEL_M,
    NARROW_FIELD_COVERAGE,
    Node,
    NodeNormals,
    azimuth_coverage,
    normal_cloud,
    submap_cloud,
    submap_members,
    turned_along,
)
from vcr_odom.odometry.degeneracy import WEAK_AXIS_SHARE
from vcr_odom.registration.vcr import VcrFrame, VcrRegistrar

MIN_FITNESS = 0.5
MIN_FITNESS_NARROW = 0.4
MAX_INLIER_RMSE_M = 0.6
"""Overlap and fit at the fine stage's 1 m correspondence distance on 1 m voxels (metres here and below
scale with a finer node grid). Real KITTI frames 5-10 m apart: fitness 0.84-0.91, RMSE 0.43-0.47 m
(1 m voxels quantise); the same frames aligned 30 m off along the street, or turned round: fitness
0.29-0.39. Two 1 m voxelisations of the same surface are about 0.5-0.6 m apart however well aligned
(Mid-360 passages measured to 1-4 cm fit at RMSE 0.55-0.60 m on tuning seed 541), so the RMSE only
rejects what is worse than that; overlap, the drift bound and the two starts are what tell a wrong fit.

A narrow field of view (either node under :data:`~vcr_odom.loops.nodes.NARROW_FIELD_COVERAGE`) needs
:data:`MIN_FITNESS_NARROW`: two visits of one place see it from view cones that overlap in part, so a
right fit overlaps less. On the Avia courtyard walks right fits were rejected at 0.47 and 0.40 (944,
measured within 0.04 m), and at 0.4 944, 947 and the 2600-frame walk 871 closed 2-3 more loops, none
false, the old-town crossing of drive 563 closed, and 832 and 843 changed by a loop or two (843's lost
one 1.03 m off); one more false fit (931, 12.5 m off) passed, which the pose graph drops
(docs/benchmarks.md, "Replaying the loop phase")."""
MIN_CLOUD_POINTS = 50
"""Fewer 1 m voxels than this in either node cloud: nothing to register (a blocked or empty scan)."""
POLISH_STAGES = ((3.0, 30), (1.0, 30))
"""(max correspondence distance m, iterations): coarse enough for the network's error, then fine."""
AMBIGUITY = (1.0, 5.0, 0.15)
"""Two polished starts that end more than 1 m or 5 deg apart with fitness within 0.15 of each other.
On tuning seed 542 (Avia figure eight) a look-alike 7.5 m off passed 0.1 by 0.003 (fitness 0.66
against 0.56); the closest true loop with two such starts on seeds 532-543 was 0.22 apart."""
PROBE_M, PROBE_RETURN_M, PROBE_FITNESS = 2.0, 0.5, 0.05
"""The degeneracy probe: starts 2 m off along the weakest direction must end within 0.5 m, unless
their fit is worse by more than 0.05."""
MIN_DISTANCE_SCALE = 0.5
"""The distances above (correspondences, RMSE cap, probe, ambiguity) follow a finer node grid down to
half their street values, no further: the coarse stage must still cover the network's error, which does
not shrink with the rooms, and the probe must push past where ICP comes back. On synthetic indoor walks
(node pairs 3-6 m apart and 40-75 deg turned, the prior 1.5 m / 4 deg off; seeds 902 and 911) accepted
fits off by more than 0.2 m or 1 deg: 1 m grid 7 of 14 and 17 of 25; the reach's grid with distances
scaled all the way (0.18 m grid) 0 of 12 and 3 of 13, slid 1.4-5.7 m along corridors; at half, 0 of 15
and 0 of 24 (docs/benchmarks.md, "Loops indoors")."""
SUBMAP_TURN_DEG = 45.0
"""Narrow fields of view (:data:`~vcr_odom.loops.nodes.NARROW_FIELD_COVERAGE`) turned this much
between the visits register the nodes' submaps: a 70 deg Avia field crossing a street at 90 deg
shares no point with the other visit's scan (ICP from the true pose finds no correspondence)."""
SUBMAP_PROBE_RETURN_M = 0.1
"""A submap fit must come back from the probe this close: a crossing's submaps are nearly symmetric and
fit well in several places. On tuning seeds 561-568 (Avia) the right crossing fits came back within
0.03 m, the two accepted wrong ones (3.3 m / 10 deg and, on a drive whose odometry had failed, 16 m)
from 0.22 and 0.28 m."""
CROSSING_TURN_DEG = 45.0
"""A submap fit beyond the drift bound and turned this much from the one within it is the crossing's
other arm, not a second answer: it does not make the place ambiguous. One shifted without such a turn
does (a walk whose odometry failed, synthetic 884: the fit within the bound 7.8 m off the truth at
overlap 0.61, the other start's 0.72)."""
BENT_SUBMAP_DEG = 3.0
"""A submap fit whose submaps may be bent more than this (a loop this far off in heading is false) stands
only where the source's own scan confirms it (:data:`OWN_SCAN_FITNESS`). Walk submaps turn 280-700 deg
(6-14 deg at the drift model's 2 %): two of the three walk fits the own scan could not confirm were
false (956, 950); car crossings' turn 6-16 deg, and their own scans overlap under 0.3 on right fits."""
OWN_SCAN_FITNESS = 0.3
"""An accepted submap fit is polished once more with the source node's own cloud on the target submap,
and that fit is the loop's where this share of the cloud overlaps (and it stays within the drift bound).
The source's submap is placed by the odometry round it, and a walk's odometry errs in heading at
turns: unseen courtyard walks 884 and 899 (Avia) had submap fits 3.5 and 5.2 deg off the truth, their
own-scan fits 1.1 and 0.45 deg (overlap 0.73 and 0.55). On Avia crossings (807) the own scan overlaps
0.37 or less and errs where it overlaps under 0.2 (0.3-13 deg). An own cloud that overlaps this much
but slides beyond the drift bound from the submap fit sees too little to check the submaps' heading,
and the loop is rejected: on unseen walk 923 the source saw one wall, slid 10 m / 72 deg, and the submap
fit it could not check was 5.8 deg off the truth."""
MAX_SUBMAP_FLAGGED = 2
"""A submap is the odometry's picture of a place: where the odometry replaced more implausible motions
than this among the frames a submap is made of (``flagged``), it slid or turned there and the submap is
bent, and a bent submap fits a look-alike as well as the place. On tuning walk 871 (2600 frames, Avia)
both false loops registered such submaps (5-10 flagged frames in each of their four), 28.3 and 3.5 m
off the truth; every right submap loop on the courtyard walks and car drives (884, 894, 899, 807) had
0 or 1 in each. Unseen 2600-frame walks 1001 and 1003: three false submap loops (20-33 m off), 4-9 in
one submap of each, rejected; no right loop lost."""
CHECKS = (
    "points",
    "doubted_submap",
    "overlap",
    "fit_rmse",
    "drift_bound",
    "ambiguous",
    "degenerate",
    "graph",
)
"""What a candidate can fail, in the order tried (``LoopDecision.check``; ``graph``: accepted here, then
dropped by the pose graph). ``drift_bound`` alone means the fit passed overlap and RMSE: a look-alike
place, or odometry that drifts more than the bound allows (``map`` says how many, and the options that
widen it)."""


class LoopVerifier:
    """Registers and judges candidates; keeps each node's encoding and cloud for the next candidate."""

    def __init__(
        self,
        network: VcrRegistrar,
        drift: DriftModel | None = None,
        flagged_frames: Iterable[int] = (),
        normals: NodeNormals | None = None,
    ) -> None:
        """``flagged_frames``: the frames whose motion the odometry replaced as implausible
        (``OdometryRun.flagged_frames``); none where the odometry does not say (a benchmark's drift).
        ``normals``: the nodes' normals, shared with the pose graph (made here for other nodes)."""
        self.normals = NodeNormals([]) if normals is None else normals
        self.network = network
        self.drift = drift or DriftModel()
        self.flagged_frames = np.sort(np.fromiter(flagged_frames, dtype=np.int64))
        self._targets: dict[_CloudKey, tuple[VcrFrame, o3d.geometry.PointCloud]] = {}
        self._submaps: dict[_CloudKey, NDArray[np.float32]] = {}
        self.ground_kept = 0

    def verify(self, candidate: LoopCandidate, nodes: list[Node]) -> LoopDecision:
        source, target = nodes[candidate.source], nodes[candidate.target]
        if self.normals.nodes is not nodes:
            self.normals = NodeNormals(nodes)
        decision = LoopDecision(candidate, source.frame_index, target.frame_index)
        if min(len(source.cloud), len(target.cloud)) < MIN_CLOUD_POINTS:  # an empty or near-empty scan
            decision.reject("points", f"rejected: too few points ({len(source.cloud)}, {len(target.cloud)})")
            return decision
        kept_before = self.ground_kept
        scale = distance_scale(source)
        narrow = _either_narrow(source, target)
        submaps = self._needs_submaps(candidate, narrow)
        source_key = _cloud_key(candidate.source, candidate.target, nodes, submaps)
        target_key = _cloud_key(candidate.target, candidate.source, nodes, submaps)
        source_points = self._cloud(source_key, nodes)
        if min(len(source_points), len(self._cloud(target_key, nodes))) < MIN_CLOUD_POINTS:
            decision.reject("points", "rejected: too few points within the submaps' radius")
            return decision
        if submaps:
            flagged = (self._flagged_within(source_key, nodes), self._flagged_within(target_key, nodes))
            if max(flagged) > MAX_SUBMAP_FLAGGED:
                decision.reject(
                    "doubted_submap",
                    f"rejected: the odometry replaced {flagged[0]} and {flagged[1]} implausible motions "
                    f"among the frames of the two submaps (more than {MAX_SUBMAP_FLAGGED}): a bent submap "
                    "fits a look-alike place",
                )
                return decision
        target_frame, target_cloud = self._target(target_key, nodes)
        turn = make_transform(candidate.prior[:3, :3], np.zeros(3))
        turned = (self._network_points(source_points) @ turn[:3, :3].T).astype(np.float32)
        (source_frame,) = self.network.encode_inputs([turned])
        network = self.network.register(source_frame, target_frame)
        if submaps:
            source_cloud = normal_cloud(source_points, source.cloud_voxel)
        else:  # the node's own cloud: its normals are the loop phase's
            source_cloud = self.normals.cloud(candidate.source)
        starts = {"network": network.transform @ turn, "odometry": candidate.prior}
        fits = {name: polish(source_cloud, target_cloud, start, scale) for name, start in starts.items()}
        started_m, started_deg = motion_difference(starts["network"], starts["odometry"])
        ranked = sorted(fits, key=lambda name: fits[name].fitness, reverse=True)
        if submaps:  # a crossing's submaps fit turned by 90 or 180 deg too: the odometry tells which
            ranked.sort(key=lambda name: not self._within_bound(candidate, fits[name].transformation))
        best = ranked[0]
        fit = fits[best]
        measured = np.asarray(fit.transformation, dtype=np.float64).copy()
        correction_m, correction_deg = _correction(candidate, measured)
        other = fits["odometry" if best == "network" else "network"]
        apart_m, apart_deg = motion_difference(np.asarray(other.transformation), measured)
        decision.measured = measured
        decision.scores = {
            "fitness": round(float(fit.fitness), 4),
            "inlier_rmse_m": round(float(fit.inlier_rmse), 4),
            "start": best,
            "other_start_fitness": round(float(other.fitness), 4),
            "starts_apart_m": round(apart_m, 3),
            "correction_m": round(correction_m, 3),
            "correction_deg": round(correction_deg, 3),
            "bound_m": round(self.drift.translation_bound(candidate.path_m, candidate.frames), 3),
            "bound_deg": round(self.drift.rotation_bound_deg(candidate.path_m, candidate.turned_deg), 3),
            "network_input_kept_ground": self.ground_kept > kept_before,
            "submaps": submaps,
            "starts_before_m": round(started_m, 3),
            "starts_before_deg": round(started_deg, 2),
        }
        if (
            submaps
            and apart_deg >= CROSSING_TURN_DEG
            and not self._within_bound(candidate, other.transformation)
        ):
            other = None  # another arm of a crossing, not a fit the odometry could have drifted to
        if not submaps:  # a submap's normals are the ground's, whatever its walls hold
            decision.scores["weakest_share"] = round(weakest_share(target_cloud, fit), 4)
        min_overlap = MIN_FITNESS_NARROW if narrow else MIN_FITNESS
        decision.check, decision.reason = self._judge(decision, fit, other, apart_deg, scale, min_overlap)
        distance = POLISH_STAGES[-1][0] * scale
        if not decision.check:  # an accepted loop passed here: its information reads the same Hessian
            hessian = fit_hessian(source_cloud, target_cloud, decision.measured, distance)
            returns_m = (SUBMAP_PROBE_RETURN_M if submaps else PROBE_RETURN_M) * scale
            decision.check, decision.reason = self._probe(
                decision, source_cloud, target_cloud, fit, scale, returns_m, hessian
            )
        if not decision.check and submaps:
            turned = max(turned_along(nodes, key[1] or (key[0],)) for key in (source_key, target_key))
            bend_deg = self.drift.rotation_per_turned * turned  # the drift model's heading share
            decision.check, decision.reason = self._on_own_scan(
                decision, self.normals.cloud(candidate.source), target_cloud, scale, bend_deg
            )
        decision.accepted = not decision.check
        if decision.accepted and not submaps:
            decision.corroborated = corroborated(decision.scores, PROBE_RETURN_M * scale)
        if decision.accepted:  # the submaps' geometry, also where the source's own cloud measured the fit
            if decision.scores.get("own_scan"):  # that fit replaced the one the probe measured
                hessian = fit_hessian(source_cloud, target_cloud, decision.measured, distance)
            decision.information = loop_information(hessian, fit.inlier_rmse)
        return decision

    def _on_own_scan(
        self,
        decision: LoopDecision,
        cloud: o3d.geometry.PointCloud,
        target: o3d.geometry.PointCloud,
        scale: float,
        bend_deg: float,
    ) -> tuple[str, str]:
        """The source node's own ``cloud`` polished on the target submap from the submap fit: the source's
        submap was placed by the odometry round it and carries its heading error into the fit. Where
        the own cloud overlaps (:data:`OWN_SCAN_FITNESS`), its fit is the loop's (``decision.measured``
        and its correction are set) if it stays within the drift bound; if it slides beyond, the scan
        cannot tell the submap fit's heading, and the check failed is returned as by :meth:`_judge`.
        Where it does not overlap, the submap fit stands, unless the submaps may be bent more than
        :data:`BENT_SUBMAP_DEG` (``bend_deg``): then nothing measured the fit's heading but the bend."""
        own = polish(cloud, target, decision.measured, scale)
        overlaps = own.fitness >= OWN_SCAN_FITNESS
        within = self._within_bound(decision.candidate, own.transformation)
        decision.scores["own_scan_fitness"] = round(float(own.fitness), 4)
        decision.scores["own_scan"] = overlaps and within
        if not overlaps and bend_deg > BENT_SUBMAP_DEG:
            return "doubted_submap", (
                f"rejected: the submaps turned so much along their path that they may be bent "
                f"{bend_deg:.0f} deg, and the source's own scan overlaps {own.fitness:.2f} only"
            )
        if not overlaps:
            return "", "accepted"
        if not within:
            slid_m, slid_deg = motion_difference(decision.measured, np.asarray(own.transformation))
            return "degenerate", (
                f"rejected: degenerate: the source's own scan (overlap {own.fitness:.2f}) slides "
                f"{slid_m:.1f} m / {slid_deg:.0f} deg from its submap's fit, beyond the drift bound"
            )
        decision.measured = np.asarray(own.transformation, dtype=np.float64).copy()
        correction_m, correction_deg = _correction(decision.candidate, decision.measured)
        decision.scores |= {
            "correction_m": round(correction_m, 3),
            "correction_deg": round(correction_deg, 3),
        }
        return "", "accepted"

    def _judge(
        self,
        decision: LoopDecision,
        fit: Any,
        other: Any | None,
        apart_deg: float,
        scale: float,
        min_overlap: float = MIN_FITNESS,
    ) -> tuple[str, str]:
        """The check failed (empty if none) and the reason ``loops.json`` gives; ``apart_deg``: the
        turn between the two starts' fits."""
        scores = decision.scores
        if fit.fitness < min_overlap:
            return "overlap", f"rejected: overlap {fit.fitness:.2f} < {min_overlap}"
        if fit.inlier_rmse > MAX_INLIER_RMSE_M * scale:
            return (
                "fit_rmse",
                f"rejected: fit RMSE {fit.inlier_rmse:.2f} m > {MAX_INLIER_RMSE_M * scale:.2f} m",
            )
        candidate = decision.candidate
        if not self._within_bound(candidate, decision.measured):
            return "drift_bound", (
                f"rejected: asks the odometry for {scores['correction_m']:.2f} m / "
                f"{scores['correction_deg']:.1f} deg, beyond its drift over {candidate.path_m:.0f} m / "
                f"{candidate.frames} frames ({scores['bound_m']:.2f} m / {scores['bound_deg']:.1f} deg)"
            )
        if other is not None and ambiguous(scores, fit.fitness - other.fitness, apart_deg, scale):
            share = scores.get("weakest_share", 1.0)
            sliding = f" along a direction its surfaces hardly face (weakest share {share:.3f})"
            return "ambiguous", (
                f"rejected: ambiguous: the two starts end {scores['starts_apart_m']:.1f} m apart with "
                f"fitness {fit.fitness:.2f} and {other.fitness:.2f}"
                + (sliding if share < WEAK_AXIS_SHARE else "")
            )
        return "", "accepted"

    def _probe(
        self,
        decision: LoopDecision,
        source: o3d.geometry.PointCloud,
        target: o3d.geometry.PointCloud,
        fit: Any,
        scale: float,
        returns_m: float,
        hessian: NDArray[np.float64],
    ) -> tuple[str, str]:
        """Starts pushed :data:`PROBE_M` both ways along the fit's weakest translation (of its ICP
        ``hessian``) must come back within ``returns_m``: along a street seen by a narrow field of view,
        ICP slides as far as pushed, and a loop there would pin the map where the scans tell no place."""
        measured = np.asarray(decision.measured)
        direction = weakest_translation(hessian)
        worst = 0.0
        for sign in (1.0, -1.0):
            start = measured.copy()
            start[:3, 3] += sign * PROBE_M * scale * direction
            ended = polish(source, target, start, scale)
            if ended.fitness >= fit.fitness - PROBE_FITNESS:
                away = invert(np.asarray(ended.transformation)) @ measured
                worst = max(worst, float(np.linalg.norm(away[:3, 3])))
        decision.scores["probe_m"] = round(worst, 3)
        if worst > returns_m:
            return "degenerate", (
                f"rejected: degenerate: a start {PROBE_M * scale:g} m along the weakest direction ends "
                f"{worst:.2f} m away with as good a fit"
            )
        return "", "accepted"

    def _network_points(self, cloud: NDArray[np.float32]) -> NDArray[np.float32]:
        """The network's input from a node's cloud or submap. A sparse sensor's 1 m cloud can hold fewer than
        N points off the ground, and pre-processing then keeps the ground with a warning: recorded in
        the candidate's ``network_input_kept_ground`` instead of one console line per candidate."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", DataWarning)
            points = self.network.network_input(cloud)
        self.ground_kept += any(issubclass(w.category, DataWarning) for w in caught)
        return points

    def _target(self, key: _CloudKey, nodes: list[Node]) -> tuple[VcrFrame, o3d.geometry.PointCloud]:
        if key not in self._targets:
            cloud = self._cloud(key, nodes)
            (frame,) = self.network.encode_inputs([self._network_points(cloud)])
            own = key[1] is None  # a node's own cloud: its normals are the loop phase's
            normals = self.normals.cloud(key[0]) if own else normal_cloud(cloud, nodes[key[0]].cloud_voxel)
            self._targets[key] = (frame, normals)
        return self._targets[key]

    def _cloud(self, key: _CloudKey, nodes: list[Node]) -> NDArray[np.float32]:
        """A node's cloud, or its submap (kept: a crossing's candidates share their target's)."""
        index, members = key
        if members is None:
            return nodes[index].cloud
        if key not in self._submaps:
            self._submaps[key] = submap_cloud(nodes, index, members)
        return self._submaps[key]

    def _flagged_within(self, key: _CloudKey, nodes: list[Node]) -> int:
        """Flagged frames from the first to the last node of the submap ``key``."""
        members = key[1] or (key[0],)
        first, last = nodes[min(members)].frame_index, nodes[max(members)].frame_index
        return int(
            np.searchsorted(self.flagged_frames, last, side="right")
            - np.searchsorted(self.flagged_frames, first)
        )

    @staticmethod
    def _needs_submaps(candidate: LoopCandidate, narrow: bool) -> bool:
        """Narrow fields of view that meet at :data:`SUBMAP_TURN_DEG` or more see almost nothing of
        each other's scan (a 70 deg field crossing a street at 90 deg: no overlap at all)."""
        turned = math.degrees(float(rotation_angle(candidate.prior[:3, :3])))
        return narrow and turned >= SUBMAP_TURN_DEG

    def _within_bound(self, candidate: LoopCandidate, measured: Any) -> bool:
        metres, degrees = _correction(candidate, measured)
        path = candidate.path_m
        bound_m = self.drift.translation_bound(path, candidate.frames)
        return metres <= bound_m and degrees <= self.drift.rotation_bound_deg(path, candidate.turned_deg)


_CloudKey = tuple[int, tuple[int, ...] | None]
"""A node and the nodes its submap is made of (None: the node's own cloud)."""


def _cloud_key(index: int, other: int, nodes: list[Node], submaps: bool) -> _CloudKey:
    """Node ``index``'s cloud or, for ``submaps``, its submap apart from node ``other``'s (no node in
    both)."""
    return index, submap_members(nodes, index, other) if submaps else None


def _correction(candidate: LoopCandidate, measured: Any) -> tuple[float, float]:
    """How far (m, deg) a measured ``T_target_source`` moves the odometry's."""
    return motion_difference(candidate.prior, np.asarray(measured, dtype=np.float64))


def polish(
    source: o3d.geometry.PointCloud, target: o3d.geometry.PointCloud, start: Transform, scale: float
) -> o3d.pipelines.registration.RegistrationResult:
    """Point-to-plane ICP through :data:`POLISH_STAGES`, distances times ``scale``, from ``start``."""
    registration = o3d.pipelines.registration
    transform = np.asarray(start, dtype=np.float64)
    result = None
    for distance, iterations in POLISH_STAGES:
        result = registration.registration_icp(
            source,
            target,
            distance * scale,
            transform,
            registration.TransformationEstimationPointToPlane(),
            registration.ICPConvergenceCriteria(1e-6, 1e-6, iterations),
        )
        transform = np.asarray(result.transformation)
    return result


def ambiguous(scores: dict[str, Any], fitness_gap: float, apart_deg: float, scale: float) -> bool:
    """Whether the two starts ended in two fits (:data:`AMBIGUITY` apart, ``apart_deg`` the turn
    between them) that overlap cannot tell apart: ``fitness_gap`` (the better's over the other's)
    within its margin, or, on the nodes' own clouds, any gap where the fit's surfaces hardly face one
    direction (``weakest_share`` under the polish's :data:`~vcr_odom.odometry.degeneracy.WEAK_AXIS_SHARE`):
    along it, overlap says nothing. On the courtyard walks and car crossings it was chosen on, every
    such fit whose starts ended apart was false (walk 971: 6.3 m off at overlaps 0.87 and 0.71; 561,
    892, 896, 926), and every right one had both starts end in one fit (891, 941, 942, 947, 957, 561,
    841); on walks made since, it also took a loop 0.72 m off (998; docs/benchmarks.md, "Two fits on
    a footpath")."""
    if one_fit((scores["starts_apart_m"], apart_deg), scale):
        return False
    close_fitness = AMBIGUITY[2]
    sliding = scores.get("weakest_share", 1.0) < WEAK_AXIS_SHARE
    return sliding or fitness_gap < close_fitness


def one_fit(apart: tuple[float, float], scale: float) -> bool:
    """Whether two fits ``apart`` (m, deg: :func:`~vcr_odom.geometry.motion_difference`) are one: within
    :data:`AMBIGUITY`'s distance (times ``scale``) and turn."""
    far_m, far_deg, _ = AMBIGUITY
    return apart[0] <= far_m * scale and apart[1] <= far_deg


def distance_scale(source: Node) -> float:
    """The factor on the verification's distances for ``source``'s node grid (:data:`MIN_DISTANCE_SCALE`)."""
    return max(source.cloud_voxel / CLOUD_VOXEL_M, MIN_DISTANCE_SCALE)


def _either_narrow(source: Node, target: Node) -> bool:
    """Either node's scan covers less than :data:`~vcr_odom.loops.nodes.NARROW_FIELD_COVERAGE` of the
    azimuth: a solid-state field of view."""
    return min(azimuth_coverage(source.cloud), azimuth_coverage(target.cloud)) < NARROW_FIELD_COVERAGE
