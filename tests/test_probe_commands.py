"""Issue 61's probe of synth, map, train/pretrain, compare and cache: each case drives the real command
(click's CliRunner in-process, or the console script in a subprocess where a real signal is sent) and
checks the exit code, one line naming the input, that nothing already written is lost and, for a
subprocess, that it has exited."""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result
from conftest import SMALL_SYNTHETIC_FRAMES

from vcr_odom.cli.main import cli

FRAMES = SMALL_SYNTHETIC_FRAMES


def invoke(*args: object) -> Result:
    return CliRunner().invoke(cli, [os.fsdecode(a) if isinstance(a, Path) else str(a) for a in args])


def assert_fails(result: Result, code: int, *named: object) -> str:
    """Exit ``code``, one error line and no traceback, naming every one of ``named``; the line."""
    assert result.exit_code == code, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if "Error" in line]
    assert len(errors) == 1, result.output
    for name in named:
        assert str(name) in result.output, (name, result.output)
    return errors[0]


def contents(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` with its bytes: what must survive a refused command."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


# -- 1. synth writes only where nothing is, or over what it made ------------------------------------


@pytest.fixture
def real_download(small_synthetic_root: Path, tmp_path: Path) -> Path:
    """A KITTI download as a user has it: scans, calib.txt and poses/00.txt, none made by synth."""
    root = tmp_path / "kitti"
    source = small_synthetic_root / "sequences" / "00"
    shutil.copytree(source / "velodyne", root / "sequences" / "00" / "velodyne")
    shutil.copy(source / "calib.txt", root / "sequences" / "00" / "calib.txt")
    (root / "poses").mkdir()
    shutil.copy(small_synthetic_root / "poses" / "00.txt", root / "poses" / "00.txt")
    return root


def test_synth_refuses_a_real_download_and_leaves_it_whole(real_download: Path) -> None:
    before = contents(real_download)
    result = invoke("synth", "--out", real_download, "--frames", "2")
    line = assert_fails(result, 2, "--out", real_download / "sequences" / "00", "--force")
    assert "synth.json" in line and "Wrote" not in result.output
    assert contents(real_download) == before


def test_synth_refuses_ground_truth_poses_without_their_scans(real_download: Path) -> None:
    shutil.rmtree(real_download / "sequences")
    before = contents(real_download)
    result = invoke("synth", "--out", real_download, "--frames", "2")
    assert_fails(result, 2, real_download / "poses" / "00.txt")
    assert contents(real_download) == before


def test_synth_replaces_what_it_made_and_anything_with_force(real_download: Path, tmp_path: Path) -> None:
    out = tmp_path / "synthetic"
    assert invoke("synth", "--out", out, "--frames", "3").exit_code == 0
    assert (out / "sequences" / "00" / "synth.json").is_file()
    again = invoke("synth", "--out", out, "--frames", "2", "--seed", "1")
    assert again.exit_code == 0, again.output
    assert len(list((out / "sequences" / "00" / "velodyne").iterdir())) == 2

    (tmp_path / "empty" / "sequences" / "00").mkdir(parents=True)  # an empty folder is free too
    assert invoke("synth", "--out", tmp_path / "empty", "--frames", "2").exit_code == 0

    forced = invoke("synth", "--out", real_download, "--frames", "2", "--force")
    assert forced.exit_code == 0, forced.output
    assert len(list((real_download / "sequences" / "00" / "velodyne").iterdir())) == 2


# -- 17. compare --help -------------------------------------------------------------------------------


def test_compare_help_names_the_default_baselines_not_source_code() -> None:
    from vcr_odom.evaluation.compare import DEFAULT_BASELINES

    result = invoke("compare", "--help")
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    assert "join(DEFAULT_BASELINES)" not in text and "{" not in text
    assert f"Default: {', '.join(DEFAULT_BASELINES)}." in text


# -- 19. a file that is not a frame cache ------------------------------------------------------------


def test_a_text_file_as_cache_is_not_a_frame_cache_and_no_pickle_advice(tmp_path: Path) -> None:
    notes = tmp_path / "notes.txt"
    notes.write_text("frames 0-40 of drive 21\n")
    result = invoke("train", "--cache", notes, "--device", "cpu", "--out", tmp_path / "run")
    line = assert_fails(result, 1, notes, "not a frame cache made by `vcr-odom cache`")
    assert "pickle" not in line.lower()
    assert not (tmp_path / "run").exists()


# -- 10. train --resume from a broken checkpoint -------------------------------------------------------

TRAIN = ("--num-points", "64", "--protocol", "same-scan", "--batch-size", "4", "--device", "cpu")
"""A training run of seconds: 64 points, same-scan pairs of the 8 cached frames."""


@pytest.fixture(scope="module")
def trained(small_synthetic_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A frame cache and a run folder after one epoch (its last.pt good to resume)."""
    work = tmp_path_factory.mktemp("trained")
    cache = work / "cache.npz"
    built = invoke(
        "cache", "--data-root", small_synthetic_root, "--seq", "00", "--num-points", "64", "--out", cache
    )
    assert built.exit_code == 0, built.output
    run = work / "run"
    first = invoke("train", "--cache", cache, *TRAIN, "--epochs", "1", "--out", run)
    assert first.exit_code == 0, first.output
    return cache, run


def _first_float(tensors: dict) -> str:
    return next(name for name, tensor in tensors.items() if tensor.is_floating_point())


def _nan_in_model(state: dict) -> dict:
    state["model"][_first_float(state["model"])].view(-1)[0] = float("nan")
    return state


def _model_tensor_dropped(state: dict) -> dict:
    del state["model"][_first_float(state["model"])]
    return state


def _optimiser_groups_emptied(state: dict) -> dict:
    state["optimiser"]["param_groups"] = []
    return state


@pytest.mark.parametrize(
    ("breakage", "said"),
    [
        (lambda state: {"version": 1}, "it has no 'task'"),
        (_model_tensor_dropped, "missing"),
        (_optimiser_groups_emptied, "parameter group"),
        (_nan_in_model, "NaN"),
    ],
    ids=["version-only", "tensor-missing", "groups-emptied", "nan"],
)
def test_train_resume_from_a_broken_checkpoint_is_one_line_naming_it(
    trained: tuple[Path, Path], tmp_path: Path, breakage: object, said: str
) -> None:
    import torch

    cache, good = trained
    run = tmp_path / "run"
    shutil.copytree(good, run)
    state = torch.load(run / "last.pt", weights_only=False)
    torch.save(breakage(state), run / "last.pt")  # type: ignore[operator]
    before = contents(run)
    result = invoke("train", "--cache", cache, *TRAIN, "--epochs", "2", "--out", run, "--resume")
    assert_fails(result, 1, run / "last.pt", said)
    assert contents(run) == before  # nothing trained, nothing overwritten


# -- 11. train / pretrain --out where nothing can be written ----------------------------------------


@pytest.mark.parametrize("command", ["train", "pretrain", "cache"])
def test_training_refuses_an_out_it_cannot_write_before_any_work(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, command: str
) -> None:
    """A read-only mount, as os.access reports it (the tests may run as root, for whom a chmod is no
    bar): refused in one line naming --out, before the frames are pre-processed."""
    import vcr_odom.training.commands

    mount = tmp_path / "mount"
    mount.mkdir()
    real_access = os.access

    def read_only(path: object, mode: int, *args: object, **kwargs: object) -> bool:
        inside = Path(os.fspath(path)).absolute().is_relative_to(mount)  # type: ignore[arg-type]
        return False if inside and mode & os.W_OK else real_access(path, mode, *args, **kwargs)  # type: ignore[arg-type]

    def no_work(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("the frames were pre-processed before --out was checked")

    monkeypatch.setattr(os, "access", read_only)
    monkeypatch.setattr(vcr_odom.training.commands, "sequence_caches", no_work)
    out = mount / ("cache.npz" if command == "cache" else "run")
    options = ("--num-points", "64") if command == "cache" else TRAIN
    result = invoke(command, "--data-root", small_synthetic_root, "--seq", "00", *options, "--out", out)
    assert_fails(result, 2, "--out", out, "not writable")
    assert list(mount.iterdir()) == []


# -- 5. map on degenerate frames: the same map every run, the frames named ------------------------


DEGENERATE_FRAMES = 6


def degenerate_folder(root: Path, where: Path, copies: int) -> tuple[Path, Path]:
    """``root``'s first frames as a plain folder, frame 3 one point (``copies`` times); their poses."""
    where.mkdir()
    for index in range(DEGENERATE_FRAMES):
        shutil.copy(root / "sequences" / "00" / "velodyne" / f"{index:06d}.bin", where / f"{index:06d}.bin")
    scan = np.fromfile(where / "000003.bin", dtype=np.float32).reshape(-1, 4)
    np.repeat(scan[:1], copies, axis=0).tofile(where / "000003.bin")
    poses = where.parent / "poses.txt"
    lines = (root / "poses" / "00.txt").read_text().splitlines()[:DEGENERATE_FRAMES]
    poses.write_text("\n".join(lines) + "\n")
    return where, poses


def mapped(folder: Path, poses: Path, root: Path, results: Path) -> tuple[Result, Path]:
    result = invoke(
        "map", "--folder", folder, "--poses", poses, "--calib", root / "sequences" / "00" / "calib.txt",
        "--results-dir", results,
    )  # fmt: skip
    return result, (results / "latest").resolve()


@pytest.mark.parametrize("copies", [1, 5000], ids=["one-point", "5000-copies"])
def test_map_places_a_frame_of_one_point_by_its_motion_model_every_run_and_names_it(
    small_synthetic_root: Path, tmp_path: Path, copies: int
) -> None:
    folder, poses = degenerate_folder(small_synthetic_root, tmp_path / "scans", copies)
    runs = [
        mapped(folder, poses, small_synthetic_root, tmp_path / f"results{k}")
        for k in range(2 if copies == 1 else 1)
    ]
    odometries = []
    for result, saved in runs:
        assert result.exit_code == 0, result.output
        text = " ".join(result.output.split())
        assert "frame(s) flagged" in text and "[3," in text, result.output  # as run prints them
        metrics = json.loads((saved / "metrics.json").read_text())["run"]
        assert metrics["flagged_reasons"]["3"] == "too few points"
        odometry = np.loadtxt(saved / "odometry_kitti.txt").reshape(-1, 3, 4)
        poses = np.tile(np.eye(4), (len(odometry), 1, 1))
        poses[:, :3] = odometry
        # Not registered: placed by the motion model (the motion from frame 1 to 2, again).
        np.testing.assert_allclose(poses[3], poses[2] @ np.linalg.inv(poses[1]) @ poses[2], atol=1e-6)
        odometries.append(poses)
    for poses in odometries[1:]:
        np.testing.assert_array_equal(poses, odometries[0])


# -- 13. map --method kiss-icp takes the loop network's options ----------------------------------


def test_map_with_kiss_icp_passes_the_vcr_options_to_its_loop_network(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import vcr_odom.map_command
    from vcr_odom.model.weights import default_weights_path

    asked: list[tuple[object, ...]] = []
    real = vcr_odom.map_command.loop_network

    def recorded(weights: object, device: object, points: object, odometry: object = None) -> object:
        asked.append((weights, device, points))
        return real(weights, device, points, odometry)  # type: ignore[arg-type]

    monkeypatch.setattr(vcr_odom.map_command, "loop_network", recorded)
    weights = default_weights_path("default")
    result = invoke(
        "map", "--data-root", small_synthetic_root, "--frames", "0:4", "--method", "kiss-icp",
        "--device", "cpu", "--weights", weights, "--vcr-points", "256", "--results-dir", tmp_path / "r",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert asked == [(weights, "cpu", 256)]

    refused = invoke(
        "map", "--data-root", small_synthetic_root, "--method", "kiss-icp", "--vcr-passes", "2",
        "--results-dir", tmp_path / "r2",
    )  # fmt: skip
    assert_fails(refused, 2, "--vcr-passes")
    assert not (tmp_path / "r2").exists()


# -- 3. map on a full disk keeps the small files ------------------------------------------------------


def test_map_on_a_full_disk_keeps_the_small_files_and_names_the_map(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import open3d as o3d

    def full_disk(filename: str, *_args: object, **_kwargs: object) -> bool:
        Path(filename).write_bytes(b"ply\n")  # a disk fills up part-way
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), filename)

    monkeypatch.setattr(o3d.io, "write_point_cloud", full_disk)
    results = tmp_path / "results"
    result = invoke(
        "map", "--data-root", small_synthetic_root, "--frames", "0:5", "--method", "icp",
        "--results-dir", results,
    )  # fmt: skip
    (folder,) = [p for p in results.iterdir() if p.name.startswith("20")]
    line = assert_fails(result, 1, folder, "map.ply", os.strerror(errno.ENOSPC))
    assert "loops.json" in line  # what was kept is said
    for name in (
        "trajectory_kitti.txt",
        "odometry_kitti.txt",
        "odometry_tum.txt",
        "loops.json",
        "metrics.json",
    ):
        assert (folder / name).is_file() and (folder / name).stat().st_size > 0, name
    assert not (folder / "map.ply").exists()
    assert len(np.loadtxt(folder / "odometry_kitti.txt")) == 5
    json.loads((folder / "loops.json").read_text())
    marker = json.loads((folder / "result.json").read_text())
    assert marker["status"] == "partial" and "map.ply" in marker["reason"]
    assert [p for p in folder.rglob("*") if ".tmp" in p.name] == []


# -- 14. map stopped after its odometry names the folder it kept -----------------------------------

STOP_IN_LOOP_PHASE = """
import pathlib, sys, time
from vcr_odom.loops import pipeline
flag = pathlib.Path(sys.argv.pop(1))
def close_loops(*args, **kwargs):
    flag.touch()  # the odometry is done: the signal lands here
    time.sleep(120)
pipeline.close_loops = close_loops
from vcr_odom.cli.main import main
main()
"""


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_map_stopped_after_its_odometry_names_the_partial_folder(
    small_synthetic_root: Path, tmp_path: Path, signum: int
) -> None:
    flag, results = tmp_path / "odometry-done", tmp_path / "results"
    args = [
        "map",
        "--data-root",
        small_synthetic_root,
        "--frames",
        "0:5",
        "--method",
        "icp",
        "--results-dir",
        results,
    ]
    process = subprocess.Popen(
        [sys.executable, "-c", STOP_IN_LOOP_PHASE, flag, *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1", "COLUMNS": "300"},
    )
    try:
        deadline = time.monotonic() + 120
        while not flag.exists():
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, "the odometry never finished"
            time.sleep(0.05)
        process.send_signal(signum)
        out, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 128 + signum, (out, err)
    (folder,) = [p for p in results.iterdir() if p.name.startswith("20")]
    said = " ".join(err.split())
    label = "Ctrl-C" if signum == signal.SIGINT else "SIGTERM"
    assert f"Interrupted ({label})" in said and str(folder) in said and "5 frames" in said, err
    assert "Traceback" not in out + err
    marker = json.loads((folder / "result.json").read_text())
    assert marker["status"] == "partial" and marker["frames_done"] == 5
    assert len(np.loadtxt(folder / "trajectory_kitti.txt")) == 5


# -- 15. compare stopped in a +loops row prints the rows that finished -----------------------------


def test_compare_stopped_in_a_loops_row_prints_the_finished_row(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from vcr_odom.loops import pipeline

    def stopped(*_args: object, **_kwargs: object) -> None:
        raise KeyboardInterrupt  # Ctrl-C after the +loops row's odometry

    monkeypatch.setattr(pipeline, "close_loops", stopped)
    results = tmp_path / "results"
    result = invoke(
        "compare", "--data-root", small_synthetic_root, "--frames", "0:5", "-b", "kiss-icp",
        "-b", "kiss-icp+loops", "--results-dir", results,
    )  # fmt: skip
    assert result.exit_code == 130, result.output
    (folder,) = [p for p in results.iterdir() if p.name.startswith("20")]
    text = " ".join(result.output.split())
    assert "odometry: frames 0..4" in text and "│ kiss-icp " in result.output, result.output
    assert "Interrupted (Ctrl-C)" in text and str(folder) in text
    assert "Traceback" not in result.output
    assert json.loads((folder / "result.json").read_text())["status"] == "partial"
    assert (folder / "kiss-icp" / "trajectory_kitti.txt").is_file()
