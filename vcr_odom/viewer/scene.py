"""The 3-D scene on polyscope: a window where there is a display, an off-screen EGL context for
``--screenshot`` (tests, the README's picture), and a camera whose projection this module computes
itself, so a test can say where a drawn trajectory must appear in the picture.

polyscope is the optional ``viz`` extra (a 14 MB wheel; kiss-icp's own visualizer uses it): it is
imported here only, and its absence is one line naming ``pip install 'vcr-odom[viz]'``.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vcr_odom.errors import ConfigError, DataError, MissingExtraError, VcrOdomError

EXTRA = "viz"
BACKGROUND = (1.0, 1.0, 1.0)
Color = tuple[float, float, float]


def polyscope() -> ModuleType:
    """The polyscope module, or a :class:`MissingExtraError` naming the ``viz`` extra."""
    try:
        import polyscope as ps
    except ImportError as error:
        raise MissingExtraError("polyscope", EXTRA, f"the 3-D view needs it: {error}") from error
    return ps


def has_display() -> bool:
    """Whether a window can open: X11 or Wayland on Linux (macOS and Windows always have one)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def check_screenshot_path(path: Path | None, option: str = "--screenshot") -> None:
    """A screenshot must be a .png in a folder that exists: checked before any work, not after it."""
    if path is None:
        return
    if path.suffix.lower() != ".png":
        raise ConfigError(f"{option} {path}: expected a .png file name")
    if not path.parent.is_dir():
        raise ConfigError(f"{option} {path}: the folder {path.parent} does not exist")
    if path.is_dir():
        raise ConfigError(f"{option} {path} is a folder; expected a .png file name")


@dataclass(frozen=True)
class Camera:
    """A perspective camera as polyscope renders it (OpenGL: looking down -z of its view matrix)."""

    eye: NDArray[np.float64]
    target: NDArray[np.float64]
    width: int
    height: int
    fov_vertical_deg: float = 45.0
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)

    @property
    def look_dir(self) -> NDArray[np.float64]:
        direction = np.asarray(self.target, float) - np.asarray(self.eye, float)
        return direction / np.linalg.norm(direction)

    def view_matrix(self) -> NDArray[np.float64]:
        """World to camera (right, up, -forward), as glm::lookAt builds it."""
        forward = self.look_dir
        right = np.cross(forward, self.up)
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        view = np.eye(4)
        view[0, :3], view[1, :3], view[2, :3] = right, up, -forward
        view[:3, 3] = -view[:3, :3] @ np.asarray(self.eye, float)
        return view

    def project(self, points: ArrayLike) -> NDArray[np.float64]:
        """Pixel coordinates (column, row; row 0 at the top) of world ``points`` (N x 3); NaN behind
        the camera."""
        points = np.atleast_2d(np.asarray(points, dtype=np.float64))
        in_camera = points @ self.view_matrix()[:3, :3].T + self.view_matrix()[:3, 3]
        depth = -in_camera[:, 2]
        focal = 1.0 / np.tan(np.radians(self.fov_vertical_deg) / 2.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = focal * self.height / self.width * in_camera[:, 0] / depth
            y = focal * in_camera[:, 1] / depth
        pixels = np.column_stack([(x + 1.0) / 2.0 * self.width, (1.0 - y) / 2.0 * self.height])
        pixels[depth <= 0] = np.nan
        return pixels


def overview_camera(
    points: ArrayLike,
    width: int,
    height: int,
    *,
    azimuth_deg: float = -60.0,
    elevation_deg: float = 55.0,
    fov_vertical_deg: float = 45.0,
    margin: float = 1.08,
) -> Camera:
    """A camera that sees every one of ``points`` (the trajectories, the loops), looking down at
    ``elevation_deg`` from ``azimuth_deg``: deterministic, so a picture made twice is the same."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) == 0:
        points = np.zeros((1, 3))
    low, high = points.min(axis=0), points.max(axis=0)
    centre = (low + high) / 2.0
    radius = max(float(np.linalg.norm(points - centre, axis=1).max()), 1.0)
    azimuth, elevation = np.radians(azimuth_deg), np.radians(elevation_deg)
    back = np.array(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)]
    )
    half_vertical = np.radians(fov_vertical_deg) / 2.0
    half_horizontal = np.arctan(np.tan(half_vertical) * width / height)
    distance = margin * radius / np.sin(min(half_vertical, half_horizontal))
    return Camera(centre + distance * back, centre, width, height, fov_vertical_deg)


def follow_camera(pose: NDArray[np.float64], width: int, height: int, distance_m: float = 60.0) -> Camera:
    """Behind and above the sensor, looking at it along its heading (the live view's default)."""
    heading = pose[:3, 0].copy()
    heading[2] = 0.0
    norm = np.linalg.norm(heading)
    heading = heading / norm if norm > 1e-9 else np.array([1.0, 0.0, 0.0])
    position = pose[:3, 3]
    eye = position - 0.8 * distance_m * heading + np.array([0.0, 0.0, 0.6 * distance_m])
    return Camera(eye, position + 0.25 * distance_m * heading, width, height)


class Scene:
    """One polyscope scene: named point clouds, paths and segments, a camera, a picture or a window.

    ``headless``: render off-screen (EGL) for :meth:`screenshot`; otherwise a window opens, which
    needs a display (checked here, before any work, with the way out in the message).
    """

    def __init__(self, *, headless: bool, width: int = 1280, height: int = 720) -> None:
        ps = polyscope()
        if not headless and not has_display():
            raise ConfigError(
                "the 3-D view needs a display and none is set (DISPLAY / WAYLAND_DISPLAY): run where "
                "one is, or add --screenshot FILE.png to render off-screen"
            )
        self.ps = ps
        self.headless = headless
        self.width, self.height = width, height
        self.camera: Camera | None = None
        self._names: dict[str, None] = {}
        self._init()

    def _init(self) -> None:
        ps = self.ps
        if ps.is_initialized():
            if self.headless != ps.is_headless():
                raise VcrOdomError(
                    f"the 3-D view was opened {'off-screen' if ps.is_headless() else 'in a window'} "
                    "earlier in this process and cannot switch (polyscope has one OpenGL context)"
                )
            ps.remove_all_structures()
        else:
            ps.set_verbosity(0)
            ps.set_program_name("vcr-odom")
            ps.set_use_prefs_file(False)
            ps.set_allow_headless_backends(self.headless)
            try:
                ps.init("openGL3_egl" if self.headless else "auto")
            except RuntimeError as error:
                detail = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
                how = (
                    "an off-screen OpenGL (EGL) driver is needed: install libegl1 and libgl1-mesa-dri "
                    "(Debian/Ubuntu)"
                    if self.headless
                    else "check that the display works, or add --screenshot FILE.png to render off-screen"
                )
                raise VcrOdomError(f"the 3-D view could not start OpenGL ({detail}): {how}") from error
            ps.imgui.GetIO().IniFilename = ""  # no imgui.ini left in the user's working folder
        ps.set_up_dir("z_up")
        ps.set_front_dir("x_front")
        ps.set_ground_plane_mode("none")
        ps.set_background_color(BACKGROUND)
        ps.set_window_size(self.width, self.height)

    # -- what is drawn -------------------------------------------------------------------------------

    def points(
        self, name: str, points: ArrayLike, color: Color | NDArray[np.float64], radius_m: float
    ) -> None:
        """A point cloud (``color`` one RGB or one per point), or nothing where ``points`` is empty."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(points) == 0:
            self.remove(name)
            return
        colors = np.asarray(color, dtype=np.float64)
        single = colors.ndim == 1
        cloud = self.ps.register_point_cloud(
            name, points, color=tuple(colors) if single else None, material="flat", point_render_mode="quad"
        )
        cloud.set_radius(radius_m, relative=False)
        self._names[name] = None
        if not single:
            cloud.add_color_quantity("colour", colors, enabled=True)

    def path(self, name: str, points: ArrayLike, color: Color, radius_m: float) -> None:
        """A polyline through ``points`` (a trajectory), or nothing where it has under two points."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(points) < 2:
            self.remove(name)
            return
        curve = self.ps.register_curve_network(name, points, "line", color=color, material="flat")
        curve.set_radius(radius_m, relative=False)
        self._names[name] = None

    def polylines(self, name: str, lines: list[NDArray[np.float64]], color: Color, radius_m: float) -> None:
        """Separate polylines in one structure (the loops' arcs), or nothing where there are none."""
        lines = [np.asarray(line, dtype=np.float64).reshape(-1, 3) for line in lines]
        lines = [line for line in lines if len(line) >= 2]
        if not lines:
            self.remove(name)
            return
        nodes = np.concatenate(lines)
        starts = np.cumsum([0] + [len(line) for line in lines[:-1]])
        edges = np.concatenate(
            [
                np.column_stack([first + np.arange(len(line) - 1), first + np.arange(1, len(line))])
                for first, line in zip(starts, lines, strict=True)
            ]
        )
        curve = self.ps.register_curve_network(name, nodes, edges, color=color, material="flat")
        curve.set_radius(radius_m, relative=False)
        self._names[name] = None

    def remove(self, name: str) -> None:
        if not name:
            return
        self._names.pop(name, None)
        if self.ps.has_point_cloud(name):
            self.ps.remove_point_cloud(name)
        if self.ps.has_curve_network(name):
            self.ps.remove_curve_network(name)

    def names(self) -> list[str]:
        """The structures drawn now, in the order first drawn (for the summary line and tests)."""
        return list(self._names)

    # -- camera and output -----------------------------------------------------------------------------

    def look(self, camera: Camera) -> None:
        """Put polyscope's camera exactly where ``camera`` says (so :meth:`Camera.project` holds)."""
        self.camera = camera
        ps = self.ps
        ps.set_view_camera_parameters(
            ps.CameraParameters(
                ps.CameraIntrinsics(
                    fov_vertical_deg=camera.fov_vertical_deg, aspect=camera.width / camera.height
                ),
                ps.CameraExtrinsics(root=camera.eye, look_dir=camera.look_dir, up_dir=camera.up),
            )
        )

    def render(self) -> NDArray[np.uint8]:
        """The picture as it is now: height x width x 3, uint8, off-screen."""
        buffer = self.ps.screenshot_to_buffer(transparent_bg=False)
        return np.ascontiguousarray(buffer[..., :3])

    def screenshot(self, path: Path, legend: list[tuple[str, Color]] | None = None) -> Path:
        """Write the picture (with a ``legend`` of colours drawn in its corner) to ``path`` (.png)."""
        from PIL import Image

        image = Image.fromarray(self.render())
        if legend:
            draw_legend(image, legend)
        try:
            image.save(path, format="PNG")
        except OSError as error:
            raise DataError(f"--screenshot {path}: could not write it ({error.strerror or error})") from error
        return path

    def tick(self) -> None:
        """Let a window draw itself and take the user's input (a live view, once per frame)."""
        if not self.headless:
            self.ps.frame_tick()

    def show(self) -> None:
        """Hand the window to the user until it is closed (after a run, or for ``view``)."""
        if not self.headless:
            self.ps.show()


def draw_legend(image: Any, legend: list[tuple[str, Color]]) -> None:
    """Colour swatches and their names in the top-left corner of a PIL ``image``: a picture read
    outside the viewer (the README) must say which line is which."""
    from PIL import ImageDraw, ImageFont

    size = max(12, image.height // 40)
    try:
        font = ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: a fixed bitmap font
        font = ImageFont.load_default()
    draw = ImageDraw.Draw(image)
    pad, line = size // 2, int(size * 1.5)
    width = max(int(draw.textlength(text, font=font)) for text, _ in legend) + 3 * size
    draw.rectangle(
        (pad, pad, pad + width + pad, pad + line * len(legend) + pad),
        fill=(255, 255, 255),
        outline=(200, 200, 200),
    )
    for row, (text, color) in enumerate(legend):
        top = pad + pad + row * line
        rgb = tuple(round(255 * c) for c in color)
        draw.rectangle((2 * pad, top + size // 4, 2 * pad + size, top + size // 4 + size // 2 + 2), fill=rgb)
        draw.text((2 * pad + int(1.5 * size), top), text, fill=(30, 30, 30), font=font)
