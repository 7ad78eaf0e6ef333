"""A global map of registered scans, voxel-down-sampled so memory grows with the area driven, not
with the number of frames.

Each scan is cropped to ``max_range`` (far points are sparse and noisy), moved into the frame-0 world
with its pose (``pose[t]`` maps frame-t LiDAR points into the world, as every trajectory in the
library does), voxel-down-sampled, and queued. When the queue holds as many points as the map,
queue and map are merged and down-sampled again, so every voxel holds one point (the mean of what
fell in it) and the work stays amortised linear. open3d's tensor ``voxel_down_sample`` bins on a
grid anchored at the origin (``floor(p / v)``), so the same place always lands in the same voxel
however the map's bounds grow.

Reflectance rides along as a per-point intensity (averaged per voxel) and is written as a grey colour.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import open3d as o3d
from numpy.typing import ArrayLike, NDArray

from vcr_odom.errors import ConfigError, DataError
from vcr_odom.io import check_free_space, replacing
from vcr_odom.results import check_output_file

MAP_SUFFIXES = (".ply", ".pcd")
"""Extensions :meth:`VoxelMap.save` writes; open3d picks the format from the extension."""

_MAP_POINT_BYTES = 27
"""Bytes a point takes in the binary .ply open3d writes (3 doubles, 3 colour bytes; .pcd takes 16)."""
_MAP_HEADER_BYTES = 4096

_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2}
_PLY_SIZES |= {"uint16": 2, "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4}
_PLY_SIZES |= {"double": 8, "float64": 8}

_MIN_MERGE = 100_000
"""Queue size below which merging is not worth its cost (avoids re-sorting a small map every frame)."""


def check_map_path(path: str | os.PathLike[str], option: str = "--save-map") -> Path:
    """Where :meth:`VoxelMap.save` will write, checked before a run starts (extension, a folder that
    can be written): a wrong ``--save-map`` found after an hour's run would waste the run."""
    return check_output_file(path, option, MAP_SUFFIXES)


def check_map_outside_scans(
    path: str | os.PathLike[str], sequence: object, option: str = "--save-map"
) -> None:
    """ConfigError where the map would be written inside the folder its scans are read from: a
    ``map.ply`` among ``--folder``'s scans becomes a scan of the next run there (and the folder's last
    frame, a cloud of the whole drive). ``sequence`` is the opened input (its ``velodyne_path`` or
    ``path``, whichever it has)."""
    target = Path(path).expanduser().resolve()
    for attribute in ("velodyne_path", "path"):
        folder = getattr(sequence, attribute, None)
        if isinstance(folder, Path) and folder.is_dir():
            scans = folder.resolve()
            if target.is_relative_to(scans):
                raise ConfigError(
                    f"{option} {path}: inside the scan folder {folder}, where the map would be read "
                    "as a scan by the next run; write it outside that folder"
                )
            return


class VoxelMap:
    """Accumulates registered scans into one voxel-down-sampled cloud in the frame-0 world."""

    def __init__(self, voxel_size: float = 0.5, max_range: float | None = 60.0) -> None:
        if isinstance(voxel_size, bool) or not isinstance(voxel_size, int | float):
            raise ConfigError(f"voxel_size must be a number of metres, got {voxel_size!r}")
        if not math.isfinite(voxel_size) or voxel_size <= 0:
            raise ConfigError(f"voxel_size must be a positive finite number of metres, got {voxel_size!r}")
        if max_range is not None:
            if isinstance(max_range, bool) or not isinstance(max_range, int | float):
                raise ConfigError(f"max_range must be a number of metres or None, got {max_range!r}")
            if math.isnan(max_range) or max_range <= 0:
                raise ConfigError(f"max_range must be positive (or None for no crop), got {max_range!r}")
        self.voxel_size = float(voxel_size)
        self.max_range = None if max_range is None or math.isinf(max_range) else float(max_range)
        self._xyz = np.empty((0, 3), dtype=np.float64)
        self._intensity = np.empty(0, dtype=np.float64)
        self._queue: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
        self._queued = 0
        self.scans = 0

    # ------------------------------------------------------------------------------------------

    def add(self, points: ArrayLike, pose: ArrayLike) -> None:
        """Add one scan: ``points`` (N, 3) or (N, 4+) in its own LiDAR frame (column 3 = reflectance),
        ``pose`` the 4x4 transform from that frame into the world."""
        cloud = np.asarray(points)
        if cloud.ndim != 2 or cloud.shape[1] < 3:
            raise DataError(f"scan must be an (N, 3) or (N, 4) array, got shape {cloud.shape}")
        transform = np.asarray(pose, dtype=np.float64)
        if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
            raise DataError(f"pose must be a finite 4x4 matrix, got shape {transform.shape}")
        xyz = cloud[:, :3].astype(np.float64)
        intensity = cloud[:, 3].astype(np.float64) if cloud.shape[1] > 3 else np.zeros(len(cloud))
        keep = np.all(np.isfinite(xyz), axis=1) & np.isfinite(intensity)
        if self.max_range is not None:
            keep &= np.einsum("ij,ij->i", xyz, xyz) <= self.max_range**2
        xyz = xyz[keep] @ transform[:3, :3].T + transform[:3, 3]
        self.scans += 1
        if len(xyz) == 0:
            return
        xyz, intensity = self._down_sample(xyz, intensity[keep])
        self._queue.append((xyz, intensity))
        self._queued += len(xyz)
        if self._queued >= max(len(self._xyz), _MIN_MERGE):
            self._merge()

    def points(self) -> NDArray[np.float64]:
        """The map's points, (M, 3) float64, one per occupied voxel."""
        self._merge()
        return self._xyz.copy()

    def intensities(self) -> NDArray[np.float64]:
        """Mean reflectance per map point, aligned with :meth:`points` (0 for scans that had none)."""
        self._merge()
        return self._intensity.copy()

    def __len__(self) -> int:
        self._merge()
        return len(self._xyz)

    def top_down(self, max_points: int = 200_000) -> NDArray[np.float64]:
        """An (K, 2) xy sample of the map, K <= max_points, for drawing behind a trajectory; the same map
        always gives the same sample (sorted, then a fixed-seed subset), so plots are reproducible."""
        if isinstance(max_points, bool) or not isinstance(max_points, int | np.integer) or max_points < 1:
            raise ConfigError(f"max_points must be a positive integer, got {max_points!r}")
        self._merge()
        order = np.lexsort((self._xyz[:, 1], self._xyz[:, 0]))
        xy = self._xyz[order, :2]
        if len(xy) > max_points:
            chosen = np.random.default_rng(0).choice(len(xy), size=int(max_points), replace=False)
            xy = xy[np.sort(chosen)]
        return xy

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the map as .ply or .pcd (chosen by extension) atomically: a temporary file with the same
        extension beside ``path``, renamed into place only once it is known whole, so a reader never
        sees half a map and a failed write leaves whatever was at ``path`` before.

        Why the checks: open3d's writer reports a full disk on stderr and still returns True, so the
        free space is checked first and the written file's size against its own header after."""
        target = Path(path)
        suffix = target.suffix.lower()
        if suffix not in MAP_SUFFIXES:
            raise DataError(
                f"{target}: a map is written as .ply or .pcd, not {target.suffix or 'no extension'!r}"
            )
        self._merge()
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self._xyz))
        grey = np.clip(self._intensity, 0.0, 1.0)
        cloud.colors = o3d.utility.Vector3dVector(np.repeat(grey[:, None], 3, axis=1))
        try:
            with replacing(target, suffix) as temporary:
                needed = _MAP_HEADER_BYTES + _MAP_POINT_BYTES * len(self._xyz)
                check_free_space(temporary, needed, "the map", named=target)
                if not o3d.io.write_point_cloud(str(temporary), cloud, write_ascii=False, compressed=False):
                    raise DataError(f"{target}: open3d could not write the map; nothing was written there")
                _check_written(temporary, target, len(self._xyz))
        except OSError as error:
            raise DataError(f"{target}: could not write the map: {error.strerror or error}") from error
        return target

    # ------------------------------------------------------------------------------------------

    def _down_sample(
        self, xyz: NDArray[np.float64], intensity: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(xyz))
        cloud.point.intensity = o3d.core.Tensor(intensity[:, None])
        down = cloud.voxel_down_sample(self.voxel_size)
        return down.point.positions.numpy(), down.point.intensity.numpy()[:, 0]

    def _merge(self) -> None:
        """Fold the queued scans into the map so each voxel holds one point again."""
        if not self._queue:
            return
        xyz = np.concatenate([self._xyz, *(q[0] for q in self._queue)])
        intensity = np.concatenate([self._intensity, *(q[1] for q in self._queue)])
        self._queue.clear()
        self._queued = 0
        self._xyz, self._intensity = self._down_sample(xyz, intensity)


def _check_written(written: Path, target: Path, points: int) -> None:
    """DataError unless ``written`` is as long as its header says (header + points x row size) and
    holds ``points`` points: a disk that filled up mid-write leaves a shorter file, which open3d does
    not report. ``fsync`` first, so that a file system that allocates late reports it here."""
    with open(written, "rb+") as handle:
        os.fsync(handle.fileno())
        head = handle.read(_MAP_HEADER_BYTES)
    layout = _binary_layout(head)
    if layout is None:
        raise DataError(
            f"{target}: open3d wrote a map whose header cannot be read; nothing was written there"
        )
    header, count, row = layout
    expected, size = header + count * row, written.stat().st_size
    if count != points or size != expected:
        raise DataError(
            f"{target}: the map was cut short while writing ({size} of {expected} bytes, {count} of "
            f"{points} points; is the disk full?); nothing was written there"
        )


def _binary_layout(head: bytes) -> tuple[int, int, int] | None:
    """(header bytes, points, bytes per point) of a binary .ply or .pcd header, or None."""
    for end in (b"end_header\n", b"DATA binary\n"):
        at = head.find(end)
        if at >= 0:
            header = at + len(end)
            lines = [line.split() for line in head[:at].decode("ascii", "replace").splitlines()]
            layout = _ply_layout(lines) if end.startswith(b"end") else _pcd_layout(lines)
            return None if layout is None else (header, *layout)
    return None


def _ply_layout(lines: list[list[str]]) -> tuple[int, int] | None:
    """Vertex count and row size of a PLY header whose only element is ``vertex`` (what open3d writes)."""
    counts = [line[2] for line in lines if line[:1] == ["element"] and len(line) == 3]
    types = [line[1] for line in lines if line[:1] == ["property"] and len(line) == 3]
    if len(counts) != 1 or not counts[0].isdigit() or not types or any(t not in _PLY_SIZES for t in types):
        return None
    return int(counts[0]), sum(_PLY_SIZES[name] for name in types)


def _pcd_layout(lines: list[list[str]]) -> tuple[int, int] | None:
    """Point count and row size of a PCD header (``POINTS``, ``SIZE``, ``COUNT``)."""
    fields = {line[0]: line[1:] for line in lines if line and not line[0].startswith("#")}
    try:
        sizes = [int(value) for value in fields["SIZE"]]
        counts = [int(value) for value in fields.get("COUNT", ["1"] * len(sizes))]
        return int(fields["POINTS"][0]), sum(a * b for a, b in zip(sizes, counts, strict=True))
    except (KeyError, IndexError, ValueError):
        return None
