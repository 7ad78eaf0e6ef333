"""The 3-D view, off-screen: ``map --visualize`` and ``run --visualize`` on the 8-frame synthetic drive,
``view`` on the folder the map wrote, each checked by what polyscope holds and by the picture's
pixels where the trajectories, loops and markers must appear (projected with the camera used)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from vcr_odom.cli.main import cli

pytest.importorskip("polyscope", reason="the viz extra (pip install 'vcr-odom[viz]') is not installed")

from vcr_odom.viewer import live, result
from vcr_odom.viewer.scene import Camera, overview_camera

WIDTH, HEIGHT = 640, 400
TRACK = [result.ESTIMATE, result.GROUND_TRUTH, result.ODOMETRY, result.LOOP, result.NETWORK, result.FLAGGED]
"""What is drawn along a drive: its trajectories, and the loops and markers on them."""
SIZE = f"{WIDTH}x{HEIGHT}"


@pytest.fixture(scope="module", autouse=True)
def offscreen_opengl(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Off-screen OpenGL (EGL, Mesa's software renderer will do) is a system library, not a wheel."""
    probe = "import polyscope as ps; ps.set_verbosity(0); ps.set_allow_headless_backends(True); ps.init('openGL3_egl')"
    started = subprocess.run(  # in a scratch folder: imgui writes its imgui.ini where it runs
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path_factory.mktemp("egl-probe"),
    )
    if started.returncode != 0:
        pytest.skip(f"no off-screen OpenGL (EGL) here: {started.stderr.strip().splitlines()[-1:]}")


def rgb(colour: tuple[float, float, float]) -> np.ndarray:
    return np.round(255 * np.asarray(colour)).astype(int)


def near(
    picture: np.ndarray, pixel: np.ndarray, colours: list[tuple[float, float, float]], reach: int = 3
) -> bool:
    """Whether one of ``colours`` is drawn within ``reach`` pixels of ``pixel`` (column, row)."""
    if not np.isfinite(pixel).all():
        return False
    column, row = np.round(pixel).astype(int)
    window = picture[max(row - reach, 0) : row + reach + 1, max(column - reach, 0) : column + reach + 1]
    return any((np.abs(window.astype(int) - rgb(c)).max(axis=-1) <= 2).any() for c in colours)


def count(picture: np.ndarray, colour: tuple[float, float, float]) -> int:
    return int((np.abs(picture.astype(int) - rgb(colour)).max(axis=-1) <= 2).sum())


def share_near(picture: np.ndarray, camera: Camera, points: np.ndarray, colours: list) -> float:
    pixels = camera.project(points)
    return float(np.mean([near(picture, p, colours) for p in pixels]))


def camera_used() -> Camera:
    """The camera polyscope drew the last picture with, as a :class:`Camera` (its own projection)."""
    import polyscope as ps

    parameters = ps.get_view_camera_parameters()
    view = parameters.get_view_mat()
    eye = -view[:3, :3].T @ view[:3, 3]
    forward = -view[2, :3]
    return Camera(eye, eye + forward, WIDTH, HEIGHT, parameters.get_fov_vertical_deg(), tuple(view[1, :3]))


def drawn(points: list[str], curves: list[str]) -> bool:
    """Whether polyscope holds these point clouds and curve networks now (the entities drawn)."""
    import polyscope as ps

    return all(ps.has_point_cloud(n) for n in points) and all(ps.has_curve_network(n) for n in curves)


@pytest.fixture(scope="module")
def mapped(small_synthetic_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """``map --visualize`` off-screen, loops allowed after 1 m of path so that the short drive closes one."""
    out = tmp_path_factory.mktemp("view")
    picture = out / "live_map.png"
    ran = CliRunner().invoke(
        cli,
        [
            "map",
            "--data-root",
            str(small_synthetic_root),
            "--seq",
            "00",
            "--results-dir",
            str(out / "results"),
            "--min-loop-path",
            "1",
            "--revisit-radius",
            "8",
            "--visualize",
            "--screenshot",
            str(picture),
            "--size",
            SIZE,
        ],
    )
    assert ran.exit_code == 0, ran.output
    assert f"picture of the live view written to {picture}" in ran.output.replace("\n", "")
    (folder,) = [p for p in (out / "results").iterdir() if p.name.startswith("20")]
    return folder, picture


def test_map_visualize_draws_the_drive_its_markers_and_the_map_it_made(mapped: tuple[Path, Path]) -> None:
    folder, picture = mapped
    image = np.asarray(Image.open(picture).convert("RGB"))
    assert image.shape == (HEIGHT, WIDTH, 3)
    data = result.read_result(folder, with_map=False)
    accepted = [loop for loop in data.loops if loop.accepted]
    assert accepted, "the 8-frame drive with 1 m loops closes at least one"
    camera = camera_used()
    assert drawn(
        ["scan", "local map", "network asked (1)"],
        ["odometry", "ground truth", "map (optimised)", f"loops accepted ({len(accepted)})"],
    )
    # the live structures and what the map added at the end
    assert count(image, live.SCAN) > 500
    assert share_near(image, camera, data.odometry[:, :3, 3], TRACK) >= 0.8
    assert count(image, result.ODOMETRY) > 0 and count(image, result.ESTIMATE) > 0
    assert count(image, result.LOOP) > 0, "the loop's arc (placed exactly: the view's test)"
    assert count(image, result.NETWORK) > 0, "vcr asks the network for the first pair at least"
    assert (image == 255).all(axis=-1).mean() > 0.3, "a drawing, not a fill: most of it background"


def test_view_draws_the_result_folder(mapped: tuple[Path, Path], tmp_path: Path) -> None:
    """A copy of the map's folder with one more (rejected) candidate and a flagged frame, as loops.json
    and metrics.json write them: every one drawn where it is, in its colour."""
    folder = tmp_path / "result"
    shutil.copytree(mapped[0], folder, symlinks=True)
    for name in ("loops.json", "metrics.json"):  # the copies point into .unit: write real files
        target = folder / name
        text = target.read_text()
        target.unlink()
        target.write_text(text)
    loops = json.loads((folder / "loops.json").read_text())
    frames = json.loads((folder / "frames.json").read_text())["frame_indices"]
    rejected = dict(loops["candidates"][0], source_frame=frames[-1], target_frame=frames[0], accepted=False)
    rejected |= {"failed_check": "overlap", "reason": "rejected: overlap 0.21 < 0.5"}
    loops["candidates"].append(rejected)
    (folder / "loops.json").write_text(json.dumps(loops))
    metrics = json.loads((folder / "metrics.json").read_text())
    metrics["run"]["flagged_frames"] = [frames[3]]
    (folder / "metrics.json").write_text(json.dumps(metrics))

    picture = tmp_path / "view.png"
    shown = CliRunner().invoke(
        cli, ["view", str(folder), "--rejected", "--screenshot", str(picture), "--size", SIZE]
    )
    assert shown.exit_code == 0, shown.output
    assert "1 rejected candidate(s)" in shown.output and "1 flagged frame(s)" in shown.output
    image = np.asarray(Image.open(picture).convert("RGB"))
    data = result.read_result(folder)
    assert data.map_points is not None and data.ground_truth is not None and data.odometry is not None
    camera = overview_camera(result.framed_points(data), WIDTH, HEIGHT)
    assert np.allclose(camera.view_matrix(), camera_used().view_matrix(), atol=1e-4)
    paths = [result.ESTIMATE, result.GROUND_TRUTH, result.ODOMETRY]
    for trajectory in (data.poses, data.ground_truth, data.odometry):
        assert share_near(image, camera, trajectory[:, :3, 3], TRACK) >= 0.8
    assert min(count(image, colour) for colour in paths) > 0, "each trajectory shows somewhere"
    size = result.scale_of(result.framed_points(data))
    for loop, colour in ((data.loops[0], result.LOOP), (data.loops[-1], result.REJECTED["overlap"])):
        (arc,) = result.loop_arcs(data, [loop], size)
        assert near(image, camera.project(arc[len(arc) // 2])[0], [colour], reach=4), loop
    assert near(image, camera.project(data.position_of(frames[3]))[0], [result.FLAGGED], reach=4)
    greys = np.abs(image.astype(int)[..., 0] - image[..., 2]) <= 2
    assert (greys & (image[..., 0] < 235)).sum() > 1000, "the map's points, grey by height"

    without = CliRunner().invoke(
        cli, ["view", str(folder), "--no-map", "--screenshot", str(picture), "--size", SIZE]
    )
    assert without.exit_code == 0, without.output
    plain = np.asarray(Image.open(picture).convert("RGB"))
    assert count(plain, result.REJECTED["overlap"]) == 0, "rejected candidates only with --rejected"


def test_run_visualize_draws_scan_local_map_and_trajectory(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    picture = tmp_path / "live.png"
    ran = CliRunner().invoke(
        cli,
        [
            "run",
            "--data-root",
            str(small_synthetic_root),
            "--seq",
            "00",
            "--method",
            "icp",
            "--results-dir",
            str(tmp_path),
            "--visualize",
            "--screenshot",
            str(picture),
            "--size",
            SIZE,
        ],
    )
    assert ran.exit_code == 0, ran.output
    image = np.asarray(Image.open(picture).convert("RGB"))
    (folder,) = [p for p in tmp_path.iterdir() if p.name.startswith("20")]
    data = result.read_result(folder, with_map=False)
    assert count(image, live.SCAN) > 500
    greys = np.abs(image.astype(int)[..., 0] - image[..., 2]) <= 2
    assert (greys & (image[..., 0] < 235)).sum() > 200, "the local map"
    assert share_near(image, camera_used(), data.poses[:, :3, 3], TRACK) >= 0.8
    assert count(image, result.NETWORK) == 0, "icp has no network to ask"


def test_the_live_view_marks_network_and_flagged_frames(tmp_path: Path) -> None:
    """The per-frame hook on its own: a straight 20 m drive, the network asked on frame 2 and frame 5
    flagged; the finished run's records replace what the hook saw (frame 6 flagged too)."""
    picture = tmp_path / "marks.png"
    view = live.LiveView(picture, width=WIDTH, height=HEIGHT)
    rng = np.random.default_rng(0)
    scan = np.column_stack([rng.uniform(-15, 15, (3000, 2)), rng.uniform(-1.7, 2, 3000), np.zeros(3000)])
    infos = [{}, {"global": "not needed"}, {"global": "first pair"}, {}, {}, {"flagged": True}, {}, {}]
    poses = []
    for k, info in enumerate(infos):
        pose = np.eye(4)
        pose[0, 3] = 2.5 * k
        poses.append(pose)
        view(k, pose, scan, info)
    assert view.asked == [2] and view.flagged == [5]
    view.mark(range(8), [*infos[:6], {"flagged": True, "reason": "x"}, {}])
    assert view.flagged == [5, 6]
    assert view.finish() == picture
    image = np.asarray(Image.open(picture).convert("RGB"))
    camera = camera_used()
    assert near(image, camera.project(poses[2][:3, 3])[0], [live.NETWORK], reach=5)
    for frame in (5, 6):
        assert near(image, camera.project(poses[frame][:3, 3])[0], [live.FLAGGED], reach=5)


def test_a_missing_extra_is_one_line_naming_it(
    mapped: tuple[Path, Path], small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "polyscope", None)
    for args in (
        ["view", str(mapped[0])],
        [
            "run",
            "--data-root",
            str(small_synthetic_root),
            "--method",
            "icp",
            "--results-dir",
            str(tmp_path),
            "--visualize",
        ],
    ):
        failed = CliRunner().invoke(cli, args)
        assert failed.exit_code == 2, failed.output
        (line,) = failed.output.strip().splitlines()
        assert "pip install 'vcr-odom[viz]'" in line
    assert not any(p.name.startswith("20") for p in tmp_path.iterdir()), "checked before any work"


def test_view_errors_name_what_was_expected(
    mapped: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    empty = CliRunner().invoke(cli, ["view", str(tmp_path), "--screenshot", str(tmp_path / "x.png")])
    assert empty.exit_code == 1 and "holds no trajectory_kitti.txt" in empty.output, empty.output
    jpeg = CliRunner().invoke(cli, ["view", str(mapped[0]), "--screenshot", str(tmp_path / "x.jpg")])
    assert jpeg.exit_code == 2 and "expected a .png" in jpeg.output, jpeg.output
    size = CliRunner().invoke(cli, ["view", str(mapped[0]), "--size", "big"])
    assert size.exit_code == 2 and "WIDTHxHEIGHT" in size.output, size.output
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if sys.platform.startswith("linux"):
        windowless = CliRunner().invoke(cli, ["view", str(mapped[0])])
        assert windowless.exit_code == 2 and "--screenshot FILE.png" in windowless.output, windowless.output
    alone = CliRunner().invoke(
        cli, ["run", "--data-root", str(tmp_path), "--screenshot", str(tmp_path / "x.png")]
    )
    assert alone.exit_code == 2 and "--screenshot goes with --visualize" in alone.output, alone.output
