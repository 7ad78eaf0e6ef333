"""Issue 23's probe of outputs, option bounds and weights: a full disk, a map written among the scans,
a folder name that is not UTF-8, an option that would allocate tens of gigabytes, weights that are
zero or absurd. Each fails in one line naming the file or option (exit 1 for a file, 2 for an option)
and leaves what was already written whole."""

from __future__ import annotations

import errno
import json
import os
import shutil
from collections import namedtuple
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
import pytest
from click.testing import CliRunner, Result
from conftest import SMALL_SYNTHETIC_FRAMES

import vcr_odom.io
from vcr_odom.cli.main import cli
from vcr_odom.errors import DataError
from vcr_odom.mapping import VoxelMap

FRAMES = SMALL_SYNTHETIC_FRAMES
NO_SPACE = os.strerror(errno.ENOSPC)


def invoke(*args: object) -> Result:
    return CliRunner().invoke(cli, [os.fsdecode(a) if isinstance(a, Path) else str(a) for a in args])


def assert_fails(result: Result, code: int, *named: object) -> None:
    """Exit ``code``, one line, no traceback, and the message names every one of ``named``."""
    assert result.exit_code == code, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.output
    error = [line for line in result.output.splitlines() if "Error" in line]
    assert len(error) == 1, result.output
    for name in named:
        assert str(name) in result.output, (name, result.output)


def hidden_litter(root: Path) -> list[Path]:
    """Temporary files and staging folders left anywhere under ``root``."""
    patterns = ("*.tmp", "*.tmp.ply", "*.tmp.pcd", "*.writing", "*.creating", "*.old")
    return sorted(path for pattern in patterns for path in root.rglob(pattern))


def marker(folder: Path) -> dict[str, Any]:
    return json.loads((folder / "result.json").read_text())


def result_folders(results: Path) -> list[Path]:
    return sorted(p for p in results.iterdir() if p.name.startswith("20") and p.is_dir())


class FullDisk:
    """``open`` for :mod:`vcr_odom.io` whose writes raise ENOSPC once a file named ``name`` (or any
    file, after ``after`` successful ones) is written: the file is created first, as a real full disk
    does, so that what the writer leaves behind is tested too."""

    def __init__(self, name: str | None = None, after: int | None = None) -> None:
        self.name, self.after, self.opened = name, after, 0

    def __call__(self, file: Any, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        handle = open(file, mode, *args, **kwargs)  # noqa: SIM115 - handed back to the caller
        if "x" not in mode and "w" not in mode:
            return handle
        self.opened += 1
        full = (self.name is not None and self.name in Path(file).name) or (
            self.after is not None and self.opened > self.after
        )
        return _FailingWrites(handle) if full else handle


class _FailingWrites:
    def __init__(self, handle: Any) -> None:
        self.handle = handle

    def __enter__(self) -> _FailingWrites:
        return self

    def __exit__(self, *exc: object) -> None:
        self.handle.close()

    def write(self, data: bytes) -> int:
        self.handle.write(data[: len(data) // 2])
        raise OSError(errno.ENOSPC, NO_SPACE)


# -- 1. --save-map: open3d's write result and the written size are checked ----------------------------


@pytest.fixture
def small_map() -> VoxelMap:
    voxel_map = VoxelMap(voxel_size=0.5)
    cloud = np.random.default_rng(0).uniform(-20, 20, (5000, 4)).astype(np.float32)
    voxel_map.add(cloud, np.eye(4))
    return voxel_map


def _truncating_writer(*, succeed: bool):
    """An open3d writer that writes the file, cuts it in half (a disk that filled up), and returns
    ``succeed``: open3d returns True in that case, printing its errors only on stderr."""
    real = o3d.io.write_point_cloud

    def write(filename: str, cloud: Any, **kwargs: Any) -> bool:
        assert real(filename, cloud, **kwargs)
        size = os.path.getsize(filename)
        with open(filename, "rb+") as handle:
            handle.truncate(size // 2)
        return succeed

    return write


@pytest.mark.parametrize("suffix", [".ply", ".pcd"])
@pytest.mark.parametrize("reported", [True, False])
def test_a_map_cut_short_is_an_error_and_the_old_map_stays(
    tmp_path: Path, small_map: VoxelMap, monkeypatch: pytest.MonkeyPatch, suffix: str, reported: bool
) -> None:
    target = tmp_path / f"map{suffix}"
    small_map.save(target)
    before = target.read_bytes()
    monkeypatch.setattr(o3d.io, "write_point_cloud", _truncating_writer(succeed=reported))
    with pytest.raises(DataError, match="map") as caught:
        small_map.save(target)
    assert str(target) in str(caught.value)
    assert target.read_bytes() == before  # the previous map, whole
    assert [p.name for p in tmp_path.iterdir()] == [target.name]  # no temporary file left


def test_a_whole_map_passes_the_size_check(tmp_path: Path, small_map: VoxelMap) -> None:
    for suffix in (".ply", ".pcd"):
        saved = small_map.save(tmp_path / f"map{suffix}")
        assert len(o3d.io.read_point_cloud(str(saved)).points) == len(small_map)


def test_a_map_larger_than_the_free_space_is_refused_before_writing(
    tmp_path: Path, small_map: VoxelMap, monkeypatch: pytest.MonkeyPatch
) -> None:
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(vcr_odom.io.shutil, "disk_usage", lambda _path: usage(10**9, 10**9, 1000))
    target = tmp_path / "map.ply"
    with pytest.raises(DataError, match="not enough free space") as caught:
        small_map.save(target)
    assert str(target) in str(caught.value)
    assert list(tmp_path.iterdir()) == []


def test_run_save_map_on_a_full_disk_fails_and_keeps_the_run(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(o3d.io, "write_point_cloud", _truncating_writer(succeed=True))
    results, target = tmp_path / "results", tmp_path / "maps" / "map.ply"
    result = invoke(
        "run", "--data-root", small_synthetic_root, "--method", "icp", "--results-dir", results,
        "--save-map", target,
    )  # fmt: skip
    assert_fails(result, 1, target, "cut short")
    assert "written to" not in result.output
    assert not target.exists() and hidden_litter(tmp_path) == []
    (folder,) = result_folders(results)
    assert marker(folder)["status"] == "complete"
    assert len(np.loadtxt(folder / "trajectory_kitti.txt")) == FRAMES


# -- 2. no space left while writing results and sequences ---------------------------------------------


def test_run_out_of_space_for_its_scores_keeps_the_trajectory(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(vcr_odom.io, "open", FullDisk("metrics.json"), raising=False)
    results = tmp_path / "results"
    result = invoke("run", "--data-root", small_synthetic_root, "--method", "icp", "--results-dir", results)
    assert_fails(result, 1, "metrics.json", NO_SPACE)
    (folder,) = result_folders(results)
    assert f"{folder / 'metrics.json'}: could not write" in result.output, (
        "the file named in its result folder"
    )
    assert ".unit-" not in result.output, "not in the hidden staging folder it was written in"
    assert marker(folder)["status"] == "partial" and NO_SPACE in marker(folder)["reason"]
    assert len(np.loadtxt(folder / "trajectory_kitti.txt")) == FRAMES
    assert hidden_litter(results) == []
    assert len(list(folder.glob(".unit-*"))) == 1  # the published unit only, no staging left


def test_run_out_of_space_for_its_plot_is_one_line(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import matplotlib.figure

    def full(self: Any, filename: Any, **kwargs: Any) -> None:
        Path(filename).write_bytes(b"\x89PNG")
        raise OSError(errno.ENOSPC, NO_SPACE)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", full)
    results = tmp_path / "results"
    result = invoke("run", "--data-root", small_synthetic_root, "--method", "icp", "--results-dir", results)
    assert_fails(result, 1, "trajectory.png", NO_SPACE)
    (folder,) = result_folders(results)
    assert len(np.loadtxt(folder / "trajectory_kitti.txt")) == FRAMES
    assert hidden_litter(results) == []


def test_run_out_of_space_before_its_first_frame_leaves_nothing(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(vcr_odom.io, "open", FullDisk(after=0), raising=False)
    results = tmp_path / "results"
    result = invoke("run", "--data-root", small_synthetic_root, "--method", "icp", "--results-dir", results)
    assert_fails(result, 1, results, NO_SPACE)
    assert list(results.iterdir()) == []  # no staging folder, no empty result folder


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_synth_out_of_space_keeps_the_previous_sequence(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "out"
    assert invoke("synth", "--out", out, "--frames", 2, "--seed", 1).exit_code == 0
    before = _tree(out)
    monkeypatch.setattr(vcr_odom.io, "open", FullDisk(after=2), raising=False)
    result = invoke("synth", "--out", out, "--frames", 4, "--seed", 2)
    assert_fails(result, 1, out / "sequences" / "00", NO_SPACE, "already there is kept")
    assert _tree(out) == before
    assert hidden_litter(tmp_path) == []


def test_synth_out_of_space_for_the_poses_keeps_the_previous_sequence(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "out"
    assert invoke("synth", "--out", out, "--frames", 2, "--seed", 1).exit_code == 0
    before = _tree(out)
    monkeypatch.setattr(vcr_odom.io, "open", FullDisk("00.txt"), raising=False)
    assert_fails(invoke("synth", "--out", out, "--frames", 3, "--seed", 2), 1, "sequences", NO_SPACE)
    assert _tree(out) == before
    assert hidden_litter(tmp_path) == []


def test_synth_checks_the_free_space_after_its_first_frame(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(vcr_odom.io.shutil, "disk_usage", lambda _path: usage(10**9, 10**9, 3_000_000))
    out = tmp_path / "out"
    result = invoke("synth", "--out", out, "--frames", 50)
    assert_fails(result, 1, out / "sequences" / "00", "not enough free space", "50 frames")
    assert not list(out.rglob("*.bin")) and hidden_litter(tmp_path) == []


# -- 3. --save-map inside the scan folder --------------------------------------------------------------


def _scan_folder(root: Path, small_synthetic_root: Path, name: str | bytes, frames: int = 4) -> Path:
    folder = Path(os.fsdecode(os.path.join(os.fsencode(root), os.fsencode(name))))
    folder.mkdir()
    velodyne = small_synthetic_root / "sequences" / "00" / "velodyne"
    for scan in sorted(velodyne.glob("*.bin"))[:frames]:
        shutil.copy(scan, folder / scan.name)
    return folder


@pytest.mark.parametrize("inside", ["map.ply", "maps/map.ply"])
def test_save_map_inside_the_scan_folder_is_refused(
    small_synthetic_root: Path, tmp_path: Path, inside: str
) -> None:
    scans = _scan_folder(tmp_path, small_synthetic_root, "scans")
    results, target = tmp_path / "results", scans / inside
    result = invoke(
        "run", "--folder", scans, "--method", "icp", "--results-dir", results, "--save-map", target
    )
    assert_fails(result, 2, "--save-map", target, scans, "scan folder")
    assert not results.exists() and not target.exists()


def test_save_map_inside_a_kitti_scan_folder_is_refused(small_synthetic_root: Path, tmp_path: Path) -> None:
    velodyne = small_synthetic_root / "sequences" / "00" / "velodyne"
    result = invoke(
        "run", "--data-root", small_synthetic_root, "--method", "icp", "--results-dir", tmp_path,
        "--save-map", velodyne / "map.pcd",
    )  # fmt: skip
    assert_fails(result, 2, "--save-map", velodyne)
    assert not (velodyne / "map.pcd").exists()


def test_save_map_beside_the_scan_folder_is_fine(small_synthetic_root: Path, tmp_path: Path) -> None:
    scans = _scan_folder(tmp_path, small_synthetic_root, "scans")
    target = tmp_path / "scans-map.ply"
    result = invoke(
        "run", "--folder", scans, "--method", "icp", "--results-dir", tmp_path / "r", "--save-map", target
    )
    assert result.exit_code == 0, result.output
    assert target.is_file()


# -- 4. a folder name that is not UTF-8 ---------------------------------------------------------------


def test_a_folder_named_with_non_utf8_bytes_runs_to_a_complete_result(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    try:
        scans = _scan_folder(tmp_path, small_synthetic_root, b"scans\xff")
    except (OSError, UnicodeError):
        pytest.skip("this file system refuses names that are not UTF-8")
    results = tmp_path / "results"
    result = invoke("run", "--folder", scans, "--method", "icp", "--results-dir", results)
    assert result.exit_code == 0, result.output
    (folder,) = result_folders(results)
    assert marker(folder)["status"] == "complete"
    assert (folder / "metrics.json").is_file() and (folder / "trajectory.png").stat().st_size > 0


def test_plot_text_is_printable_for_any_path(tmp_path: Path) -> None:
    from vcr_odom.plots import plot_trajectories, printable

    assert printable("folder/scans\udcff: icp") == "folder/scans\ufffd: icp"
    assert printable("été \ud800") == "été \ufffd"
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 0, 3] = [0.0, 1.0, 2.0]
    path = plot_trajectories(tmp_path / "t.png", {"icp \udcfe": poses}, poses, title="scans\udcff")
    assert path.stat().st_size > 0


# -- 5. options that allocate are bounded --------------------------------------------------------------


def test_vcr_points_beyond_the_bound_is_a_usage_error_before_any_work(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    from vcr_odom.model.weights import MAX_NETWORK_POINTS

    results = tmp_path / "results"
    result = invoke(
        "run", "--data-root", small_synthetic_root, "--vcr-points", 200_000, "--results-dir", results
    )
    assert_fails(result, 2, "--vcr-points", "200000", str(MAX_NETWORK_POINTS))
    assert not results.exists()


@pytest.mark.parametrize(
    ("args", "option"),
    [
        (["compare", "--protocol", "pairs", "--pair-points", "200000"], "--pair-points"),
        (["train", "--num-points", "200000"], "--num-points"),
        (["cache", "--num-points", "200000", "--out", "c.npz"], "--num-points"),
        (["train", "--batch-size", "100000"], "--batch-size"),
        (["cache", "--copies", "100000", "--out", "c.npz"], "--copies"),
        (["synth", "--frames", "1000000000", "--out", "synth"], "--frames"),
    ],
)
def test_every_option_that_allocates_is_bounded(args: list[str], option: str, tmp_path: Path) -> None:
    result = CliRunner().invoke(cli, args, catch_exceptions=False)
    assert_fails(result, 2, option, "<=")
    assert list(tmp_path.iterdir()) == []


def test_the_registrar_refuses_a_point_count_beyond_the_bound_before_allocating() -> None:
    from vcr_odom.errors import ConfigError
    from vcr_odom.model.weights import MAX_NETWORK_POINTS
    from vcr_odom.registration.vcr import VcrRegistrar

    with pytest.raises(ConfigError, match=rf"--vcr-points.*to {MAX_NETWORK_POINTS}.*got 200000"):
        VcrRegistrar(device="cpu", num_points=200_000)
    registrar = VcrRegistrar(device="cpu")
    with pytest.raises(ConfigError, match="--vcr-points"):
        registrar.use_inference_settings(num_points=MAX_NETWORK_POINTS + 1)
    assert registrar.config.num_points != MAX_NETWORK_POINTS + 1


def test_library_settings_that_allocate_are_bounded() -> None:
    from vcr_odom.errors import ConfigError
    from vcr_odom.synth import SynthConfig
    from vcr_odom.training import FrameSource, TrainConfig

    for make, field in (
        (lambda: SynthConfig(frames=10**9), "frames"),
        (lambda: TrainConfig(batch_size=10**6), "batch_size"),
        (lambda: FrameSource(copies=10**6), "copies"),
    ):
        with pytest.raises(ConfigError, match=field):
            make()


# -- 6. weights no training produces are refused where the file is read -------------------------------


def _shipped_scaled(tmp_path: Path, name: str, change: Any) -> Path:
    """The shipped weights with every floating tensor passed through ``change``."""
    import torch

    from vcr_odom.model.network import VCRNet
    from vcr_odom.model.weights import default_weights_path, load_weights, save_weights

    model, config, _ = load_weights(default_weights_path())
    state = {k: change(k, v) if v.is_floating_point() else v for k, v in model.state_dict().items()}
    changed = VCRNet(config)
    changed.load_state_dict(state)
    with torch.no_grad():
        return save_weights(tmp_path / name, changed, config)


def test_shipped_weights_still_load() -> None:
    from vcr_odom.model.weights import WEIGHTS_DIR, load_weights

    shipped = sorted(WEIGHTS_DIR.rglob("*.safetensors"))
    assert shipped
    for path in shipped:
        model, _, _ = load_weights(path)
        assert model is not None


@pytest.mark.parametrize(
    ("name", "change", "expected"),
    [
        ("zero.safetensors", lambda _k, v: v * 0, "every weight matrix is zero"),
        ("huge.safetensors", lambda _k, v: v * 1e30, "corrupt or scaled"),
        ("large.safetensors", lambda _k, v: v * 1e3, "pose solve fails"),
        (
            "blank.safetensors",
            lambda k, v: v if k == "log_temperature" or v.ndim < 2 else v * 0 + 1e-3,
            "coincide",
        ),
    ],
)
def test_weights_no_training_produces_are_refused_at_load(
    tmp_path: Path, name: str, change: Any, expected: str
) -> None:
    from vcr_odom.model.weights import load_weights

    path = _shipped_scaled(tmp_path, name, change)
    with pytest.raises(DataError, match=expected) as caught:
        load_weights(path)
    assert str(path) in str(caught.value)


@pytest.mark.parametrize(
    ("name", "change", "expected"),
    [
        ("zero.safetensors", lambda _k, v: v * 0, "zero"),
        ("huge.safetensors", lambda _k, v: v * 1e30, "corrupt or scaled"),  # finite, but no training's
    ],
    ids=["zero", "huge"],
)
def test_run_with_weights_no_training_produces_fails_in_one_line_before_any_folder(
    small_synthetic_root: Path, tmp_path: Path, name: str, change: Any, expected: str
) -> None:
    path = _shipped_scaled(tmp_path, name, change)
    results = tmp_path / "results"
    result = invoke(
        "run", "--data-root", small_synthetic_root, "--method", "vcr", "--weights", path, "--device", "cpu",
        "--results-dir", results,
    )  # fmt: skip
    assert_fails(result, 1, path, expected)
    assert not results.exists()


@pytest.mark.filterwarnings("ignore:no plausible ground plane")
def test_a_pose_solve_that_fails_names_the_weights(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Weights that pass every load-time check but still break the SVD: DataError naming the file."""
    import torch

    from vcr_odom.model.network import VCRNet
    from vcr_odom.registration.vcr import VcrRegistrar

    registrar = VcrRegistrar(device="cpu")

    def broken(*_args: Any, **_kwargs: Any) -> None:
        raise torch.linalg.LinAlgError("linalg.svd: The algorithm failed to converge")

    monkeypatch.setattr(VCRNet, "register_features", broken)
    scan = np.random.default_rng(0).uniform(-20, 20, (4000, 4)).astype(np.float32)
    with pytest.raises(DataError, match="pose solve failed") as caught:
        registrar.register(registrar.prepare(scan), registrar.prepare(scan))
    assert str(registrar.weights_path) in str(caught.value)
