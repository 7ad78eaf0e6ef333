"""Keyframe nodes of the pose graph, recorded while the odometry runs, with what loop closure needs
of each: its odometry pose, the path driven to it, the network's input and a coarse cloud.

Why record during the odometry: every frame is read once (a recording may not seek cheaply), and a
node keeps ~100 KB (a 1 m voxel cloud), so memory grows with the path driven, not with every scan.
The network's input is made from that cloud only for the nodes a candidate needs: made from every
node's raw scan it would cost the odometry half its speed, and the network lands the same from the
cloud as from the raw scan (docs/benchmarks.md, "Maps that close their loops").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from vcr_odom.data.base import Points
from vcr_odom.geometry import Transform, invert, rotation_angle
from vcr_odom.odometry.polish_voxel import reach_voxel
from vcr_odom.preprocess import ground_normal
from vcr_odom.registration.open3d_icp import prepare_cloud

NODE_SPACING_M = 3.0
NODE_SPACING_DEG = 20.0
"""A new node where the sensor moved this far or turned this much since the last one."""
CLOUD_VOXEL_M = 1.0
CLOUD_MAX_RANGE_M = 60.0
"""The node cloud kept for the polish: kiss-icp's voxel for a 100 m scanner, far points dropped; a
scan of rooms gets a finer one (:func:`node_cloud_voxel`)."""
CLOUD_INPUT_POINTS = 30_000


@dataclass
class Node:
    """One keyframe: ``position`` in the run's frame list, ``pose`` the odometry's (frame 0 world),
    ``path_m`` the distance driven from the first frame, ``cloud`` the coarse voxel cloud (float32 xyz)
    on a grid of ``cloud_voxel`` m, ``ground`` the ground's upward normal in the node's frame (None
    where none was seen)."""

    position: int
    frame_index: int
    pose: Transform
    path_m: float
    cloud: NDArray[np.float32]
    ground: NDArray[np.float64] | None = None
    cloud_voxel: float = CLOUD_VOXEL_M


def voxel_cloud(points: Points, voxel: float = CLOUD_VOXEL_M) -> NDArray:
    """``points`` cropped to 1-:data:`CLOUD_MAX_RANGE_M` m and voxel-down-sampled, as float32 xyz. A
    dense scan is first taken every k-th point down to ~:data:`CLOUD_INPUT_POINTS` (a 1 m voxel of a
    64-beam scan holds tens of points): a third of the cost, recorded at every node during the odometry."""
    if len(points) > 2 * CLOUD_INPUT_POINTS:
        points = points[:: len(points) // CLOUD_INPUT_POINTS]
    cloud = prepare_cloud(points, 1.0, CLOUD_MAX_RANGE_M, voxel, normals=False)
    return np.asarray(cloud.points, dtype=np.float32)


def normal_cloud(points: NDArray[np.float32], voxel: float) -> o3d.geometry.PointCloud:
    """A node cloud (or submap) with normals from 2.5 voxels around, as point-to-plane fits need."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.astype(np.float64)))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * voxel, max_nn=20))
    return cloud


class NodeNormals:
    """Each node's cloud with its normals (:func:`normal_cloud`), estimated once for the loop phase:
    the odometry edges' information, the verification and the walls' up all read them. Held for the
    loop phase only: twice the memory of the nodes' float32 clouds."""

    def __init__(self, nodes: Sequence[Node]) -> None:
        self.nodes = nodes
        self._normals: dict[int, NDArray[np.float64]] = {}

    def normals(self, index: int) -> NDArray[np.float64]:
        """Node ``index``'s normals, one per point of its cloud."""
        if index not in self._normals:
            node = self.nodes[index]
            self._normals[index] = np.asarray(normal_cloud(node.cloud, node.cloud_voxel).normals)
        return self._normals[index]

    def cloud(self, index: int) -> o3d.geometry.PointCloud:
        """Node ``index``'s cloud with its normals, as point-to-plane fits need."""
        points = self.nodes[index].cloud.astype(np.float64)
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        cloud.normals = o3d.utility.Vector3dVector(self.normals(index))
        return cloud


def node_cloud_voxel(points: Points) -> float:
    """:data:`CLOUD_VOXEL_M` for a street scan; for a scan of rooms the finer grid the polish takes
    there (:func:`~vcr_odom.odometry.polish_voxel.reach_voxel`): 1 m voxels, with normals from 2.5 m
    around, round off a corridor's walls."""
    xyz = np.asarray(points, dtype=np.float64)[:, :3]
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    return CLOUD_VOXEL_M if len(xyz) == 0 else reach_voxel(xyz, CLOUD_VOXEL_M)


class NodeRecorder:
    """The odometry's per-frame hook: keeps every frame's pose and makes a node of the frames that
    moved or turned enough since the last node (the first frame always; :meth:`finish` adds the last).
    ``cloud_voxel``: the nodes' grid; None chooses it on the first frame (:func:`node_cloud_voxel`),
    one grid for the run, because the verification's distances follow it.
    """

    def __init__(
        self,
        spacing_m: float = NODE_SPACING_M,
        spacing_deg: float = NODE_SPACING_DEG,
        cloud_voxel: float | None = None,
    ) -> None:
        self.cloud_voxel = cloud_voxel
        self.spacing_m = spacing_m
        self.spacing_rad = math.radians(spacing_deg)
        self.nodes: list[Node] = []
        self.poses: list[Transform] = []
        self.frame_indices: list[int] = []
        self.path: list[float] = []
        self._last_points: Points | None = None

    def __call__(self, index: int, pose: Transform, points: Points) -> None:
        pose = np.asarray(pose, dtype=np.float64)
        step = float(np.linalg.norm(pose[:3, 3] - self.poses[-1][:3, 3])) if self.poses else 0.0
        self.path.append((self.path[-1] if self.path else 0.0) + step)
        self.poses.append(pose)
        self.frame_indices.append(index)
        if not self.nodes or self._far_from_last_node(pose):
            self._add(len(self.poses) - 1, points)
            self._last_points = None
        else:
            self._last_points = points

    def finish(self) -> list[Node]:
        """The nodes, the last frame among them (the graph then spans the whole run)."""
        if self._last_points is not None:
            self._add(len(self.poses) - 1, self._last_points)
            self._last_points = None
        return self.nodes

    @property
    def nbytes(self) -> int:
        """Memory held by the nodes (the loop closure's state besides the trajectory)."""
        return sum(
            n.cloud.nbytes + n.pose.nbytes + (0 if n.ground is None else n.ground.nbytes) for n in self.nodes
        )

    def _far_from_last_node(self, pose: Transform) -> bool:
        motion = invert(self.nodes[-1].pose) @ pose
        moved = float(np.linalg.norm(motion[:3, 3]))
        return moved >= self.spacing_m or float(rotation_angle(motion[:3, :3])) >= self.spacing_rad

    def _add(self, position: int, points: Points) -> None:
        if self.cloud_voxel is None:
            self.cloud_voxel = node_cloud_voxel(points)
        self.nodes.append(
            Node(
                position=position,
                frame_index=self.frame_indices[position],
                pose=self.poses[position],
                path_m=self.path[position],
                cloud=voxel_cloud(points, self.cloud_voxel),
                ground=ground_normal(points),
                cloud_voxel=self.cloud_voxel,
            )
        )


AZIMUTH_SECTORS = 36


def azimuth_coverage(cloud: NDArray) -> float:
    """The fraction of 10 deg azimuth sectors holding a point: ~0.2 for a 70 deg solid-state field of
    view, ~1 for a spinning LiDAR or a Mid-360, whatever the scene."""
    azimuth = np.arctan2(cloud[:, 1], cloud[:, 0])
    sectors = np.floor((azimuth + math.pi) / (2 * math.pi) * AZIMUTH_SECTORS).astype(int) % AZIMUTH_SECTORS
    return len(np.unique(sectors)) / AZIMUTH_SECTORS


def submap_members(nodes: list[Node], index: int, other: int | None, half_path_m: float) -> tuple[int, ...]:
    """The nodes making node ``index``'s submap: those within ``half_path_m`` of path either side and,
    against the other visit's node ``other``, only those nearer along the path to this visit. Two
    visits less than twice ``half_path_m`` apart would otherwise share the nodes between them, placed by
    the same odometry: the two submaps then fit each other wherever the odometry put them."""
    centre = nodes[index].path_m
    apart = None if other is None else nodes[other].path_m
    return tuple(
        k
        for k, node in enumerate(nodes)
        if abs(node.path_m - centre) <= half_path_m
        and (apart is None or abs(node.path_m - centre) < abs(node.path_m - apart))
    )


def submap_cloud(
    nodes: list[Node], index: int, members: tuple[int, ...], radius_m: float
) -> NDArray[np.float32]:
    """The ``members``' clouds in node ``index``'s frame, on its grid, within ``radius_m`` of it: a
    narrow field of view's picture of a place, placed by the odometry (so it carries the odometry's
    drift over that path), cropped to the place itself, not the streets running away from it."""
    centre = nodes[index]
    to_centre = invert(centre.pose)
    parts = []
    for k in members:
        relative = to_centre @ nodes[k].pose
        placed = nodes[k].cloud.astype(np.float64) @ relative[:3, :3].T + relative[:3, 3]
        parts.append(placed[np.linalg.norm(placed[:, :2], axis=1) <= radius_m])
    merged = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.concatenate(parts)))
    return np.asarray(merged.voxel_down_sample(centre.cloud_voxel).points, dtype=np.float32)
