"""Issue 23, reading input data: each bad input found by the probe is refused with one line that names it
(the file, the entry, the option or the variable) and says what was expected, before any work, and the
real and synthetic data that are fine are still read as before."""

from __future__ import annotations

import gc
import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result

from vcr_odom.cli.main import cli
from vcr_odom.data import FolderSequence, KittiSequence, open_sequence, read_bin_scan
from vcr_odom.data.bin_scans import likely_columns
from vcr_odom.data.kitti import DATA_ROOT_ENV, is_staging, list_sequences, staging_name
from vcr_odom.data.scans import natural_sort_key
from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import DataError, DataWarning
from vcr_odom.synth import SynthSequence, generate_sequence

EXIT_ERROR, EXIT_USAGE = 1, 2


def invoke(*args: object, env: dict[str, str] | None = None) -> Result:
    return CliRunner().invoke(cli, [str(a) for a in args], env=env)


def assert_refused(result: Result, code: int, *named: object) -> None:
    """Exit ``code``, one line and no traceback, naming every one of ``named``."""
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    for name in named:
        assert str(name) in result.output, (name, result.output)


def nothing_written(results: Path) -> bool:
    return not results.exists() or not any(results.iterdir())


def quiet(factory, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        return factory(*args, **kwargs)


@pytest.fixture
def scan(small_synthetic_root: Path) -> np.ndarray:
    """A synthetic HDL-64 scan, cut to a point count that divides by 4 (so 3 and 5 floats a point are
    whole 16-byte records too: the case the size check cannot see)."""
    points = np.fromfile(small_synthetic_root / "sequences/00/velodyne/000002.bin", dtype=np.float32)
    points = points.reshape(-1, 4)
    return points[: len(points) // 4 * 4]


def scan_folder(folder: Path, frames: list[np.ndarray], names: list[str] | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for index, points in enumerate(frames):
        points.tofile(folder / (names[index] if names else f"{index:06d}.bin"))
    return folder


def with_ring(points: np.ndarray) -> np.ndarray:
    """x, y, z, intensity, ring: what many exporters write."""
    ring = (np.arange(len(points)) % 64).astype(np.float32)
    return np.column_stack([points, ring]).astype(np.float32)


# -- 1. a .bin whose layout the size does not reveal -----------------------------------------------


@pytest.mark.parametrize("shuffled", [False, True], ids=["scan-order", "shuffled"])
@pytest.mark.parametrize(("layout", "columns"), [("xyzir", 5), ("xyz", 3)])
def test_a_bin_of_another_layout_is_refused_naming_the_file_and_the_layout(
    tmp_path, scan, layout, columns, shuffled
):
    points = scan[np.random.default_rng(0).permutation(len(scan))] if shuffled else scan
    records = with_ring(points) if layout == "xyzir" else np.ascontiguousarray(points[:, :3])
    assert records.nbytes % 16 == 0  # whole 4-float records: the size check passes
    folder = scan_folder(tmp_path / "scans", [records] * 3)
    with pytest.raises(DataError) as error:
        FolderSequence(folder)
    message = str(error.value)
    assert "000000.bin" in message and "--bin-columns 4" in message and f"--bin-columns {columns}" in message
    np.testing.assert_array_equal(  # the option it names reads the file right
        quiet(FolderSequence, folder, bin_columns=columns).frame(1)[:, : min(columns, 4)],
        points[:, : min(columns, 4)],
    )
    results = tmp_path / "results"
    result = invoke("run", "--folder", folder, "--method", "icp", "--results-dir", results)
    assert_refused(result, EXIT_ERROR, "000000.bin", f"--bin-columns {columns}")
    assert nothing_written(results)


def test_a_later_scan_of_another_layout_is_refused_when_read(tmp_path, scan):
    folder = scan_folder(tmp_path / "scans", [scan, with_ring(scan), scan])
    sequence = quiet(FolderSequence, folder)  # the first and last scans are read when opening
    np.testing.assert_array_equal(sequence.frame(0), scan)
    with pytest.raises(DataError, match=r"000001\.bin: not 4 float32 values.*--bin-columns 5"):
        sequence.frame(1)
    with_ring(scan).tofile(folder / "000003.bin")  # the last scan is read when opening too
    with pytest.raises(DataError, match=r"000003\.bin: not 4 float32 values.*--bin-columns 5"):
        FolderSequence(folder)


def test_a_kitti_sequence_of_another_layout_is_refused_too(tmp_path, scan):
    scan_folder(tmp_path / "sequences/00/velodyne", [with_ring(scan)] * 2)
    with pytest.raises(DataError, match=r"velodyne/000000\.bin: .*--bin-columns 5"):
        KittiSequence(tmp_path, "00")
    assert len(quiet(KittiSequence, tmp_path, "00", bin_columns=5)) == 2


def test_every_real_kitti_scan_is_read_as_before(kitti_sample_root):
    sequence = KittiSequence(kitti_sample_root, "00")
    for path in sequence.files:
        values = np.fromfile(path, dtype=np.float32)
        assert likely_columns(values, 4) is None, path
        with warnings.catch_warnings():
            warnings.simplefilter("error", DataWarning)
            np.testing.assert_array_equal(read_bin_scan(path), values.reshape(-1, 4))


@pytest.mark.parametrize(
    "options",
    [
        {"sensor": "hdl64"},
        {"sensor": "vlp16", "motion": "handheld"},
        {"sensor": "avia"},
        {"sensor": "mid360"},
    ],
    ids=lambda options: "-".join(options.values()),
)
def test_synthetic_scans_of_every_sensor_are_read_as_before(tmp_path, options):
    sequence = SynthSequence(frames=2, seed=5, **options)
    points = np.ascontiguousarray(sequence.frame(1), dtype=np.float32)
    points.tofile(tmp_path / "0.bin")
    assert likely_columns(points.ravel(), 4) is None
    np.testing.assert_array_equal(read_bin_scan(tmp_path / "0.bin"), points)
    np.column_stack([points, np.zeros(len(points), np.float32)]).tofile(tmp_path / "5.bin")
    assert likely_columns(np.fromfile(tmp_path / "5.bin", dtype=np.float32), 4) in (None, 5)


# -- 2. not a scan at all ---------------------------------------------------------------------------


def test_a_bin_of_random_bytes_is_refused_naming_it(tmp_path, scan):
    noise = np.random.default_rng(1).bytes(scan.nbytes)
    folder = scan_folder(tmp_path / "scans", [scan, scan, scan])
    (folder / "000001.bin").write_bytes(noise)
    sequence = quiet(FolderSequence, folder)
    with pytest.raises(DataError, match=r"000001\.bin: not a LiDAR scan.*expected headerless float32"):
        sequence.frame(1)
    (folder / "000000.bin").write_bytes(noise)
    results = tmp_path / "results"
    result = invoke("run", "--folder", folder, "--method", "icp", "--results-dir", results)
    assert_refused(result, EXIT_ERROR, "000000.bin", "not a LiDAR scan")
    assert nothing_written(results)


def test_a_bin_of_random_bytes_mid_run_keeps_the_frames_before_it_marked_partial(
    tmp_path, small_synthetic_root
):
    velodyne = sorted((small_synthetic_root / "sequences/00/velodyne").glob("*.bin"))
    assert len(velodyne) == 8
    folder = tmp_path / "scans"
    folder.mkdir()
    for path in velodyne:
        shutil.copy(path, folder / path.name)
    broken = folder / "000004.bin"  # frame 4 of 8: neither the first nor the last, read only when reached
    broken.write_bytes(np.random.default_rng(1).bytes(broken.stat().st_size))
    results = tmp_path / "results"
    result = invoke("run", "--folder", folder, "--method", "icp", "--results-dir", results)
    assert_refused(result, EXIT_ERROR, "frame 4", broken, "not a LiDAR scan")
    (run,) = [path for path in results.iterdir() if not path.is_symlink() and not path.name.startswith(".")]
    assert (results / "latest").resolve() == run.resolve()
    marker = json.loads((run / "result.json").read_text())
    assert marker["status"] == "partial" and marker["frames_done"] == 4 and marker["frames_selected"] == 8
    assert "000004.bin" in marker["reason"]
    kitti = np.loadtxt(run / "trajectory_kitti.txt", ndmin=2)
    assert kitti.shape == (4, 12) and np.isfinite(kitti).all()
    assert len((run / "trajectory_tum.txt").read_text().splitlines()) == 4
    assert json.loads((run / "frames.json").read_text())["frame_indices"] == [0, 1, 2, 3]


# -- 3. and 5. entries named like scans that are not scan files -------------------------------------


def break_entry(folder: Path, kind: str) -> Path:
    entry = folder / "000003.bin"
    entry.unlink()
    if kind == "broken-link":
        entry.symlink_to(folder / "gone" / "000003.bin")
    elif kind == "link-loop":
        entry.symlink_to(entry)
    else:
        entry.mkdir()
    return entry


@pytest.mark.parametrize(
    ("kind", "said"),
    [
        ("broken-link", "broken symbolic link"),
        ("link-loop", "symbolic link loop"),
        ("folder", "a folder, not a scan file"),
    ],
)
def test_an_entry_named_like_a_scan_that_is_not_one_is_refused_never_skipped(tmp_path, scan, kind, said):
    folder = scan_folder(tmp_path / "scans", [scan[::20]] * 6)
    entry = break_entry(folder, kind)
    with pytest.raises(DataError) as error:
        FolderSequence(folder)
    assert str(entry) in str(error.value) and said in str(error.value)
    results = tmp_path / "results"
    result = invoke("run", "--folder", folder, "--method", "icp", "--results-dir", results)
    assert_refused(result, EXIT_ERROR, entry, said)  # skipped, it would run 5 frames and exit 0
    assert nothing_written(results)
    scan_folder(tmp_path / "kitti/sequences/00/velodyne", [scan[::20]] * 6)
    entry = break_entry(tmp_path / "kitti/sequences/00/velodyne", kind)
    with pytest.raises(DataError, match=said):
        KittiSequence(tmp_path / "kitti", "00")


def test_a_broken_scan_with_poses_names_the_scan_not_the_counts(tmp_path, scan, small_synthetic_root):
    folder = scan_folder(tmp_path / "scans", [scan[::20]] * 8)
    poses = small_synthetic_root / "poses" / "00.txt"  # 8 lines
    entry = break_entry(folder, "broken-link")
    results = tmp_path / "results"
    result = invoke("run", "--folder", folder, "--poses", poses, "--method", "icp", "--results-dir", results)
    assert_refused(result, EXIT_ERROR, entry, "broken symbolic link")
    assert "poses but" not in result.output and nothing_written(results)
    entry.unlink()
    (folder / "000003.bin.bak").write_bytes(scan[::20].tobytes())  # a scan saved under another name
    with pytest.raises(
        DataError, match=r"8 poses but 7 scan files.*not counted as scans there: 000003\.bin\.bak"
    ):
        quiet(FolderSequence, folder, poses=poses)


# -- 4. frame order of timestamp names --------------------------------------------------------------


def test_scans_named_by_decimal_timestamps_are_read_in_time_order(tmp_path, scan):
    stamps = ["1700000000.05", "1700000000.1", "1700000000.15", "1700000000.2", "1700000000.4"]
    shuffled = [stamps[i] for i in (4, 0, 3, 1, 2)]
    frames = [scan[::20] + np.float32(i) for i in range(len(stamps))]
    scan_folder(tmp_path / "scans", frames, [f"{name}.bin" for name in shuffled])
    sequence = quiet(FolderSequence, tmp_path / "scans")
    assert [path.stem for path in sequence.files] == stamps
    order = sorted(stamps, key=float)
    for index, stem in enumerate(order):
        np.testing.assert_array_equal(sequence.frame(index), frames[shuffled.index(stem)])


def test_the_rule_for_mixed_names_numbers_by_value_and_ties_refused(tmp_path, scan):
    names = ["1700000001.bin", "1700000000.5.bin", "1700000000.bin", "scan_10.bin", "scan_9.5.bin"]
    ordered = sorted(names, key=natural_sort_key)
    assert ordered == [
        "1700000000.bin",
        "1700000000.5.bin",
        "1700000001.bin",
        "scan_9.5.bin",
        "scan_10.bin",
    ]
    scan_folder(tmp_path / "scans", [scan[::20]] * 2, ["5.bin", "05.bin"])
    with pytest.raises(DataError, match=r"05\.bin and \S*/5\.bin: two scans with the same number"):
        FolderSequence(tmp_path / "scans")


# -- 6. where the data root came from ---------------------------------------------------------------


def test_a_bad_data_root_from_the_environment_names_the_variable(tmp_path):
    results = tmp_path / "results"
    missing = tmp_path / "no-such-root"
    result = invoke("run", "--method", "icp", "--results-dir", results, env={DATA_ROOT_ENV: str(missing)})
    assert_refused(result, EXIT_USAGE, f"${DATA_ROOT_ENV}", missing)
    assert "--data-root" not in result.output and nothing_written(results)
    result = invoke("run", "--data-root", missing, "--method", "icp", "--results-dir", results, env={})
    assert_refused(result, EXIT_USAGE, "--data-root", missing)
    assert DATA_ROOT_ENV not in result.output


def test_a_bad_data_root_from_the_environment_names_the_variable_to_cache(tmp_path):
    out, missing = tmp_path / "s00.npz", tmp_path / "no-such-root"
    result = invoke("cache", "--seq", "00", "--out", out, env={DATA_ROOT_ENV: str(missing)})
    assert_refused(result, EXIT_USAGE, f"${DATA_ROOT_ENV}", missing)
    assert "--data-root" not in result.output and not out.exists()
    result = invoke("cache", "--data-root", missing, "--seq", "00", "--out", out, env={})
    assert_refused(result, EXIT_USAGE, "--data-root", missing)
    assert DATA_ROOT_ENV not in result.output and not out.exists()


# -- 7. and 8. recordings ---------------------------------------------------------------------------


def test_an_empty_bag_says_it_holds_no_point_clouds_naming_file_and_topic(tmp_path):
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    bag = tmp_path / "empty"
    with Writer(bag, version=9) as writer:
        writer.add_connection(
            "/points", "sensor_msgs/msg/PointCloud2", typestore=get_typestore(Stores.ROS2_HUMBLE)
        )
    results = tmp_path / "results"
    result = invoke(
        "run", "--dataloader", "rosbag", "--data", bag, "--method", "icp", "--results-dir", results
    )
    assert_refused(result, EXIT_ERROR, bag, "/points", "no point clouds")
    assert "frame(s) of 0" not in result.output and nothing_written(results)


def test_an_empty_sequence_is_named_not_blamed_on_frames(tmp_path):
    class Empty:
        name, sequence_path = "rosbag/empty", tmp_path / "empty.bag"

        def __len__(self) -> int:
            return 0

    with pytest.raises(DataError, match=r"empty\.bag: no frames to read"):
        FrameSelection().indices(Empty())  # type: ignore[arg-type]


def test_a_broken_bag_prints_no_traceback_when_collected(tmp_path, monkeypatch):
    pytest.importorskip("rosbags")
    from vcr_odom.data import KissLoaderSequence

    raised: list[object] = []
    monkeypatch.setattr(sys, "unraisablehook", raised.append)
    for name, content in (("zero.bag", b""), ("junk.bag", b"#ROSBAG V2.0\nnot a bag at all")):
        (tmp_path / name).write_bytes(content)
        with pytest.raises(DataError, match=name):
            KissLoaderSequence("rosbag", tmp_path / name)
        gc.collect()
    assert raised == []


@pytest.mark.parametrize("content", [b"", np.random.default_rng(2).bytes(4096)], ids=["empty", "junk"])
def test_run_on_a_broken_bag_exits_1_naming_it_with_no_traceback(tmp_path, content):
    """The console script itself: "Exception ignored" is printed while Python collects or exits."""
    pytest.importorskip("rosbags")
    bag = tmp_path / "drive.bag"
    bag.write_bytes(content)
    results = tmp_path / "results"
    script = Path(sys.executable).with_name("vcr-odom")
    command = [str(script)] if script.is_file() else [sys.executable, "-m", "vcr_odom.cli.main"]
    done = subprocess.run(
        [*command, "run", "--dataloader", "rosbag", "--data", str(bag), "--method", "icp",
         "--results-dir", str(results)],
        capture_output=True, text=True, timeout=120, env={**os.environ, "OMP_NUM_THREADS": "1"},
    )  # fmt: skip
    output = done.stdout + done.stderr
    assert done.returncode == EXIT_ERROR, output
    assert f"could not open {bag}" in output
    assert "Traceback" not in output and "Exception ignored" not in output, output
    assert nothing_written(results) and bag.read_bytes() == content


# -- 9. what a killed synth leaves behind -----------------------------------------------------------


@pytest.fixture
def killed_synth_root(tmp_path, monkeypatch) -> Path:
    """A root with sequence 00, and the staging folder of a synth of 01 killed at its third frame."""
    import vcr_odom.synth.kitti_layout as layout

    root = tmp_path / "root"
    generate_sequence(root, seq="00", frames=3, seed=1)

    def killed(done: int) -> None:
        if done == 3:
            raise SystemExit(137)

    monkeypatch.setattr(layout.shutil, "rmtree", lambda *args, **kwargs: None)  # a kill cleans nothing
    with pytest.raises(SystemExit):
        generate_sequence(root, seq="01", frames=5, seed=1, progress=killed)
    monkeypatch.undo()
    return root


def test_a_killed_synths_staging_folder_is_never_a_sequence(killed_synth_root, tmp_path):
    root = killed_synth_root
    (staging,) = [p for p in (root / "sequences").iterdir() if p.name.startswith(".")]
    assert is_staging(staging) and staging.name.endswith(".writing")
    assert list_sequences(root) == ["00"]
    results = tmp_path / "results"
    result = invoke("run", "--data-root", root, "--seq", "01", "--method", "icp", "--results-dir", results)
    assert_refused(result, EXIT_ERROR, "sequences found: 00")
    assert ".writing" not in result.output and nothing_written(results)
    for attempt in (
        lambda: KittiSequence(root, staging.name),
        lambda: open_sequence(folder=staging),
        lambda: FolderSequence(staging / "velodyne"),
    ):
        with pytest.raises(DataError, match="synth was writing"):
            quiet(attempt)


def test_synth_names_its_staging_folders_as_the_readers_know_them():
    for suffix in (".writing", ".old"):
        assert is_staging(Path("sequences") / staging_name("00", suffix) / "velodyne" / "000000.bin")
    assert not is_staging(Path("sequences/00")) and not is_staging(Path("/data/.cache.old/sequences/00"))


# -- 10. calibration ---------------------------------------------------------------------------------


@pytest.mark.parametrize("bad", ["nan", "inf"])
def test_a_non_finite_tr_is_refused_when_opening_naming_file_and_line(tmp_path, small_synthetic_root, bad):
    root = tmp_path / "root"
    shutil.copytree(small_synthetic_root, root)
    calib = root / "sequences/00/calib.txt"
    lines = calib.read_text().splitlines()
    number = next(i for i, line in enumerate(lines, start=1) if line.startswith("Tr:"))
    values = lines[number - 1].split()
    values[4] = bad  # the x translation
    lines[number - 1] = " ".join(values)
    calib.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=rf"calib\.txt:{number}: 'Tr' holds a NaN or infinite value"):
        KittiSequence(root, "00")
    results = tmp_path / "results"
    result = invoke("run", "--data-root", root, "--method", "icp", "--results-dir", results)
    assert_refused(result, EXIT_ERROR, f"calib.txt:{number}", "12 finite numbers")
    assert nothing_written(results)
    before = sorted(os.listdir(root / "sequences/00/velodyne"))
    result = invoke(
        "run", "--folder", root / "sequences/00/velodyne", "--poses", root / "poses/00.txt",
        "--calib", calib, "--method", "icp", "--results-dir", results,
    )  # fmt: skip
    assert_refused(result, EXIT_ERROR, f"calib.txt:{number}")
    assert nothing_written(results) and sorted(os.listdir(root / "sequences/00/velodyne")) == before
