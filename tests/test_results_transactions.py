"""Result folders are transactions: the trajectory files, frames.json and the result marker always
agree, whether a run finished, was interrupted, failed part-way, or was killed at any moment."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import SMALL_SYNTHETIC_FRAMES

from vcr_odom.cli.main import cli
from vcr_odom.data import KittiSequence
from vcr_odom.errors import DataError
from vcr_odom.odometry import build_odometry
from vcr_odom.odometry.run import run_and_save
from vcr_odom.results import (
    MARKER,
    create_result_folder,
    point_latest_at,
    read_marker,
    result_unit,
    write_marker,
)
from vcr_odom.synth import generate_sequence

FRAMES = SMALL_SYNTHETIC_FRAMES


@pytest.fixture
def synthetic_root(small_synthetic_root: Path) -> Path:
    return small_synthetic_root


def result_folders(results: Path) -> list[Path]:
    return sorted(
        p for p in results.iterdir() if p.is_dir() and not p.name.startswith(".") and p.name != "latest"
    )


def check_folder(folder: Path) -> dict:
    """The acceptance check: a marker saying complete or partial, and trajectory files that agree with
    it and with each other."""
    marker = read_marker(folder)
    assert marker is not None, f"{folder} has no {MARKER}"
    assert marker["status"] in ("complete", "partial")
    done = marker["frames_done"]
    kitti, tum, frames = (folder / n for n in ("trajectory_kitti.txt", "trajectory_tum.txt", "frames.json"))
    if done == 0 and not kitti.exists():
        assert not tum.exists() and not frames.exists()
        return marker
    kitti_lines = kitti.read_text().splitlines()
    tum_lines = tum.read_text().splitlines()
    indices = json.loads(frames.read_text())["frame_indices"]
    assert len(kitti_lines) == len(tum_lines) == len(indices) == done, (folder, marker)
    if marker["status"] == "complete":
        assert done == marker["frames_selected"]
        assert (folder / "metrics.json").is_file()
    visible = [path for path in folder.iterdir() if not path.name.startswith(".")]
    assert not [path.name for path in visible if path.suffix == ".tmp" or path.stat().st_size == 0]
    return marker


# -- the unit itself --------------------------------------------------------------------------------


def test_a_unit_is_published_whole_and_replaces_the_previous_one(tmp_path: Path) -> None:
    folder = create_result_folder(tmp_path, "unit", {"command": "test"}, frames_selected=3)
    assert read_marker(folder)["frames_done"] == 0 and (folder / "config.json").is_file()
    assert not (tmp_path / "latest").exists(), "latest moves only to a folder holding a trajectory"
    for count in (1, 2):
        with result_unit(folder) as unit:
            (unit / "trajectory_kitti.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * count)
            write_marker(unit, "partial", count, 3, "checkpoint")
        assert len((folder / "trajectory_kitti.txt").read_text().splitlines()) == count
        assert read_marker(folder)["frames_done"] == count
    assert len(list(folder.glob(".unit-*"))) == 1, "older units are removed once replaced"

    with pytest.raises(RuntimeError, match="boom"), result_unit(folder) as unit:
        (unit / "trajectory_kitti.txt").write_text("half")
        raise RuntimeError("boom")
    assert read_marker(folder)["frames_done"] == 2, "a unit that failed is never published"
    assert len((folder / "trajectory_kitti.txt").read_text().splitlines()) == 2

    with pytest.raises(RuntimeError, match="marker"), result_unit(folder) as unit:
        (unit / "trajectory_kitti.txt").write_text("no marker")
    assert read_marker(folder)["frames_done"] == 2

    assert point_latest_at(tmp_path, folder)
    assert (tmp_path / "latest").resolve() == folder.resolve()


def test_latest_does_not_move_to_a_folder_without_a_trajectory(tmp_path: Path) -> None:
    empty = create_result_folder(tmp_path, "empty")
    assert not point_latest_at(tmp_path, empty)
    assert not (tmp_path / "latest").exists()


# -- through the CLI --------------------------------------------------------------------------------


def run_args(root: Path, results: Path, *extra: str) -> list[str]:
    return ["run", "--data-root", str(root), "--method", "icp10", "--results-dir", str(results), *extra]


def test_a_finished_run_is_complete_and_latest_points_at_it(synthetic_root: Path, tmp_path: Path) -> None:
    result = CliRunner().invoke(cli, run_args(synthetic_root, tmp_path))
    assert result.exit_code == 0, result.output
    (folder,) = result_folders(tmp_path)
    marker = check_folder(folder)
    assert marker["status"] == "complete" and marker["frames_done"] == FRAMES
    assert (tmp_path / "latest").resolve() == folder.resolve()


@contextmanager
def ctrl_c_after(module: str, frames: int):
    """Patch the progress bar of ``module`` so that Ctrl-C comes after ``frames`` frames."""
    import importlib

    target = importlib.import_module(module)
    original = target.frame_progress

    @contextmanager
    def progress(_title: str, _total: int):
        seen = []

        def advance(*_args: object) -> None:
            seen.append(1)
            if len(seen) == frames:
                raise KeyboardInterrupt

        yield advance

    target.frame_progress = progress
    try:
        yield
    finally:
        target.frame_progress = original


def test_ctrl_c_keeps_a_partial_run_and_exits_130(synthetic_root: Path, tmp_path: Path) -> None:
    with ctrl_c_after("vcr_odom.cli.run", 3):
        result = CliRunner().invoke(cli, run_args(synthetic_root, tmp_path))
    assert result.exit_code == 130, result.output
    assert "partial" in result.output
    (folder,) = result_folders(tmp_path)
    marker = check_folder(folder)
    assert marker["status"] == "partial" and marker["frames_done"] == 3
    assert "Ctrl-C" in marker["reason"]
    assert (tmp_path / "latest").resolve() == folder.resolve()


def test_ctrl_c_in_compare_exits_130_with_a_partial_comparison(synthetic_root: Path, tmp_path: Path) -> None:
    args = ["compare", "--data-root", str(synthetic_root), "-b", "icp10", "-b", "icp", "--results-dir"]
    with ctrl_c_after("vcr_odom.cli.compare", 2):
        result = CliRunner().invoke(cli, [*args, str(tmp_path)])
    assert result.exit_code == 130, result.output
    (folder,) = result_folders(tmp_path)
    marker = read_marker(folder)
    assert marker["status"] == "partial" and "Ctrl-C" in marker["reason"]
    assert marker["methods_done"] == []
    assert check_folder(folder / "icp10")["frames_done"] == 2
    assert not (folder / "icp").exists(), "the methods after the interrupted one are not run"
    assert set(json.loads((folder / "compare.json").read_text())) == {"icp10"}


def test_an_error_part_way_names_the_frame_and_keeps_what_was_done(
    synthetic_root: Path, tmp_path: Path
) -> None:
    class BrokenAtFour(KittiSequence):
        def frame(self, index: int) -> np.ndarray:
            if index == 4:
                raise DataError("000004.bin: cannot be read")
            return super().frame(index)

    sequence = BrokenAtFour(synthetic_root, "00")
    folder = create_result_folder(tmp_path, "broken", frames_selected=FRAMES)
    odometry = build_odometry("icp10")
    with pytest.raises(DataError, match=r"^frame 4: 000004.bin"):
        run_and_save(sequence, odometry, list(range(FRAMES)), folder)
    marker = check_folder(folder)
    assert marker["status"] == "partial" and marker["frames_done"] == 4
    assert "000004.bin" in marker["reason"]


def test_a_run_that_fails_at_start_leaves_no_folder(synthetic_root: Path, tmp_path: Path) -> None:
    weights = tmp_path / "broken.safetensors"
    weights.write_bytes(b"not weights at all")
    results = tmp_path / "results"
    result = CliRunner().invoke(
        cli,
        ["run", "--data-root", str(synthetic_root), "--weights", str(weights), "--results-dir", str(results)],
    )
    assert result.exit_code == 1 and "broken.safetensors" in result.output
    assert not results.exists() or result_folders(results) == []


def test_sigkill_at_any_moment_leaves_a_complete_or_partial_result_that_agrees(tmp_path: Path) -> None:
    """Acceptance: ``vcr-odom run`` killed at seeded random moments, checkpointing every frame so that
    kills land inside the writes, leaves folders that are complete, or partial with agreeing files."""
    root = tmp_path / "data"
    generate_sequence(root, seq="00", frames=30, seed=1)
    results = tmp_path / "results"
    code = (
        "import sys; from vcr_odom.odometry import outputs; outputs.CHECKPOINT_EVERY_FRAMES = 1; "
        "from vcr_odom.cli.main import cli; cli(sys.argv[1:], prog_name='vcr-odom')"
    )
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    rng = np.random.default_rng(12)
    kills, latest_kill = 0, 1.5  # seconds after the folder appears; shortened where runs outpace it
    for _ in range(6):
        process = subprocess.Popen(
            [sys.executable, "-c", code, *run_args(root, results)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=env,
        )
        before = set(result_folders(results)) if results.exists() else set()
        deadline = time.monotonic() + 120
        while process.poll() is None and time.monotonic() < deadline:  # wait for the run to start
            if results.exists() and set(result_folders(results)) - before:
                break
            time.sleep(0.01)
        time.sleep(rng.uniform(0.0, latest_kill))
        if process.poll() is None:
            process.send_signal(signal.SIGKILL)
            kills += 1
        else:
            latest_kill /= 2
        process.wait(timeout=60)
    assert kills >= 3, "the runs finished before they could be killed: lengthen the sequence"
    folders = result_folders(results)
    assert folders, "no run got as far as its result folder"
    statuses = [check_folder(folder)["status"] for folder in folders]
    assert "partial" in statuses
    if (results / "latest").exists():
        assert (results / "latest" / "trajectory_kitti.txt").stat().st_size > 0


def test_an_interrupted_synth_over_an_existing_sequence_leaves_the_old_one(tmp_path: Path) -> None:
    generate_sequence(tmp_path, seq="00", frames=4, seed=0)
    before = {p.relative_to(tmp_path): p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}

    def stop(frames_written: int) -> None:
        if frames_written == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        generate_sequence(tmp_path, seq="00", frames=6, seed=1, progress=stop)
    after = {p.relative_to(tmp_path): p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    assert after == before, "the old sequence is untouched and no temporary folder is left"
    written = generate_sequence(tmp_path, seq="00", frames=3, seed=1)
    assert sorted(p.name for p in (written.seq_dir / "velodyne").iterdir()) == [
        f"{i:06d}.bin" for i in range(3)
    ]
    assert len(written.poses_file.read_text().splitlines()) == 3
    assert [p.name for p in (tmp_path / "sequences").iterdir()] == ["00"]
