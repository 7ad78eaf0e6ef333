"""``vcr-odom benchmark``: the suite file's errors, a cell equal to a standalone run, the same rows on
a process pool and on Ray, failure isolation, the averages, and resuming after SIGKILL and SIGTERM."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import ConfigError
from vcr_odom.io import read_kitti_poses
from vcr_odom.odometry.run import RunSettings, run_sequence
from vcr_odom.suite.cells import attempts, cell_folder, cells_of, read_row
from vcr_odom.suite.executors import STOP_WAIT_SECONDS
from vcr_odom.suite.spec import load_suite
from vcr_odom.suite.suite import run_suite
from vcr_odom.suite.summary import averages
from vcr_odom.synth import generate_sequence

ENTRY = "from vcr_odom.cli.main import main; main()"


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("suite-data")
    generate_sequence(root, seq="00", frames=10, seed=11)
    generate_sequence(root, seq="01", frames=8, seed=12)
    return root


def write_suite(path: Path, data: Path, methods: str = '["icp10", "kiss-icp"]', extra: str = "") -> Path:
    path.write_text(
        f"methods = {methods}\nstrides = [1, 2]\n"
        f'[[dataset]]\nname = "a"\ndata_root = "{data}"\nseq = "00"\n'
        f'[[dataset]]\nname = "b"\ndata_root = "{data}"\nseq = "01"\n{extra}'
    )
    return path


def figures(rows: list[dict]) -> list[dict]:
    """A row without what depends on where and when it ran (speed, folder name)."""
    return [{k: v for k, v in row.items() if k not in ("fps", "folder")} for row in rows]


# -- the suite file --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('methods = ["kiss-icp", "nope"]\n[[dataset]]\nname = "a"\nfolder = "x"\n', "unknown method 'nope'"),
        ('methods = ["icp"]\n[[dataset]]\nname = "a"\n', "give exactly one of data_root, folder, dataloader"),
        ('methods = ["icp"]\n[[dataset]]\nname = "a b"\nfolder = "x"\n', "name: letters, digits"),
        ('methods = ["icp"]\nstrides = [0]\n[[dataset]]\nname = "a"\nfolder = "x"\n', "strides: positive"),
        (
            'methods = ["icp"]\n[[dataset]]\nname = "a"\nfolder = "x"\n[[dataset]]\nname = "a"\nfolder = "y"\n',
            "a twice",
        ),
        ('methods = ["icp"]\n[[dataset]]\nname = "a"\nfolder = "x"\nspeed = 3\n', "unknown key 'speed'"),
        ("methods = [icp\n", "not valid TOML"),
        (
            'methods = ["icp"]\n[[dataset]]\nname = "a"\nfolder = "x"\nstride = 2\n',
            "the suite's strides apply",
        ),
    ],
)
def test_a_bad_suite_file_is_named_with_its_mistake(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "suite.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as error:
        load_suite(path)
    assert str(path) in str(error.value)


def test_relative_paths_are_taken_from_the_suite_files_folder(tmp_path: Path) -> None:
    (tmp_path / "sub").mkdir()
    path = tmp_path / "sub" / "suite.toml"
    path.write_text('methods = ["vcr"]\n[[dataset]]\nname = "a"\ndata_root = "../kitti"\nseq = "03"\n')
    suite = load_suite(path)
    assert suite.methods == ["vcr+kiss-icp"]  # spelled as run names it
    assert suite.dataset[0].data_root == tmp_path / "sub" / ".." / "kitti"


# -- cells, rows, failures ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def serial(data: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The suite with a broken dataset (a scan folder with no scans: found when its cells run, unlike a
    path that does not exist, refused before any) and sequence 01 again as a scan folder, one cell
    after the other."""
    base = tmp_path_factory.mktemp("suite-serial")
    (base / "gone").mkdir()
    extra = (
        f'[[dataset]]\nname = "gone"\nfolder = "{base}/gone"\n'
        f'[[dataset]]\nname = "scans"\nfolder = "{data}/sequences/01/velodyne"\n'
        f'poses = "{data}/poses/01.txt"\ntimes = "{data}/sequences/01/times.txt"\n'
        f'calib = "{data}/sequences/01/calib.txt"\n'
    )
    suite = write_suite(base / "suite.toml", data, extra=extra)
    outcome = run_suite(suite, base / "out", jobs=1)
    assert not outcome.interrupted and len(outcome.ran) == 16
    return suite, base / "out"


def test_a_cell_equals_a_standalone_run_of_the_same_data_method_and_stride(
    serial: tuple[Path, Path], data: Path, tmp_path: Path
) -> None:
    _, out = serial
    row = next(
        r
        for r in json.loads((out / "summary.json").read_text())["rows"]
        if r["method"] == "kiss-icp" and r["dataset"] == "b" and r["stride"] == 2
    )
    standalone = run_sequence(
        RunSettings(
            selection=FrameSelection(data_root=data, seq="01", stride=2),
            method="kiss-icp",
            results_dir=tmp_path,
        )
    )
    mine = read_kitti_poses(out / row["folder"] / "trajectory_kitti.txt")
    theirs = read_kitti_poses(standalone.folder / "trajectory_kitti.txt")
    np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-6)
    metrics = json.loads((standalone.folder / "metrics.json").read_text())
    assert row["ate_m"] == pytest.approx(metrics["ate_rpe"]["ate_se3_trans_rmse_m"], abs=1e-6)
    assert row["t_rel_pct"] == pytest.approx(metrics["drift"]["t_rel_percent"], abs=1e-6)
    assert row["frames"] == 4 and row["status"] == "complete"


def test_a_failing_dataset_fails_alone_with_its_reason(serial: tuple[Path, Path]) -> None:
    _, out = serial
    rows = json.loads((out / "summary.json").read_text())["rows"]
    assert len(rows) == 16
    assert {r["status"] for r in rows if r["dataset"] != "gone"} == {"complete"}
    same_frames = {(r["method"], r["stride"]): r["ate_m"] for r in rows if r["dataset"] == "b"}
    as_folder = {(r["method"], r["stride"]): r["ate_m"] for r in rows if r["dataset"] == "scans"}
    assert as_folder == same_frames  # sequence 01 read as a KITTI root and as a scan folder
    gone = [r for r in rows if r["dataset"] == "gone"]
    assert {r["status"] for r in gone} == {"failed"}
    assert all("gone" in r["reason"] and "no scans" in r["reason"] for r in gone)
    markdown = (out / "summary.md").read_text()
    assert "## gone" in markdown and "failed: no scans" in markdown
    assert (out / "plots" / "a.png").is_file() and (out / "plots" / "t_rel.png").is_file()


def test_a_rerun_skips_complete_cells_and_retries_failed_ones(
    serial: tuple[Path, Path], tmp_path: Path
) -> None:
    suite_file, out = serial
    before = {
        c.key: [p.name for p, _ in attempts(cell_folder(out, c))] for c in cells_of(load_suite(suite_file))
    }
    outcome = run_suite(suite_file, out, jobs=1)
    assert sorted(outcome.ran) == sorted(k for k in before if k.startswith("gone/"))
    after = {
        c.key: [p.name for p, _ in attempts(cell_folder(out, c))] for c in cells_of(load_suite(suite_file))
    }
    assert after == before  # no complete cell ran again; the failed ones left no folder


def test_the_averages_are_the_mean_over_datasets_and_the_pooled_segments() -> None:
    label = "KITTI devkit drift over segments of 100-800 m"

    def row(dataset: str, t: float | None, r: float, segments: int, status: str = "complete") -> dict:
        return {
            "dataset": dataset,
            "method": "m",
            "stride": 1,
            "status": status,
            "t_rel_pct": t,
            "r_rel_deg_per_100m": r,
            "drift_segments": segments,
            "drift_label": label,
        }

    (result,) = averages([row("a", 1.0, 0.5, 10), row("b", 4.0, 1.0, 30), row("c", 9.0, 9.0, 5, "partial")])
    assert result["datasets"] == 2 and result["of"] == 3
    assert result["mean_t_rel_pct"] == pytest.approx(2.5)
    assert result["pooled_t_rel_pct"] == pytest.approx((1.0 * 10 + 4.0 * 30) / 40)
    assert result["pooled_r_rel_deg_per_100m"] == pytest.approx((0.5 * 10 + 1.0 * 30) / 40)
    assert result["kitti_segments"]


def test_a_folder_of_another_suite_with_the_same_dataset_name_is_refused(
    serial: tuple[Path, Path], data: Path, tmp_path: Path
) -> None:
    _, out = serial
    other = tmp_path / "other.toml"
    other.write_text(f'methods = ["icp10"]\n[[dataset]]\nname = "a"\ndata_root = "{data}"\nseq = "01"\n')
    with pytest.raises(ConfigError, match="dataset 'a' was read from other data"):
        run_suite(other, out)


# -- where cells run -----------------------------------------------------------------------------------


def test_a_process_pool_and_ray_give_the_rows_of_a_serial_run(
    serial: tuple[Path, Path], data: Path, tmp_path: Path
) -> None:
    pytest.importorskip("ray")
    suite = write_suite(tmp_path / "suite.toml", data)
    serial_rows = [
        r for r in json.loads((serial[1] / "summary.json").read_text())["rows"] if r["dataset"] in ("a", "b")
    ]
    pool = run_suite(suite, tmp_path / "pool", jobs=2)
    ray = run_suite(suite, tmp_path / "ray", jobs=1, ray="local")  # one slot: a cell must fit in it
    assert figures(pool.rows) == figures(serial_rows)
    assert figures(ray.rows) == figures(pool.rows)


# -- stopped suites ------------------------------------------------------------------------------------


def start(*args: str | Path) -> subprocess.Popen[str]:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "COLUMNS": "200"}
    return subprocess.Popen(
        [sys.executable, "-c", ENTRY, "benchmark", *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def wait_for(process: subprocess.Popen[str], ready: Callable[[], bool], seconds: float = 120) -> None:
    deadline = time.monotonic() + seconds
    while not ready():
        assert process.poll() is None, f"exited {process.returncode} first:\n{process.communicate()}"
        assert time.monotonic() < deadline, "the suite never got there"
        time.sleep(0.02)


def complete_cells(out: Path) -> list[str]:
    try:
        rows = json.loads((out / "summary.json").read_text())["rows"]
    except (OSError, ValueError, KeyError):
        return []
    return [f"{r['dataset']}/{r['method']}/{r['stride']}" for r in rows if r["status"] == "complete"]


def test_sigkill_mid_suite_then_a_rerun_completes_it_and_runs_no_complete_cell_twice(
    data: Path, tmp_path: Path
) -> None:
    suite_file = write_suite(tmp_path / "suite.toml", data)
    out = tmp_path / "out"
    process = start(suite_file, "--out", out)
    wait_for(process, lambda: len(complete_cells(out)) >= 2)
    process.kill()
    process.wait()
    done_before = {
        c.key: [p.name for p, _ in attempts(cell_folder(out, c))]
        for c in cells_of(load_suite(suite_file))
        if read_row(c, out)["status"] == "complete"
    }
    assert 2 <= len(done_before) < 8
    rerun = subprocess.run(
        [sys.executable, "-c", ENTRY, "benchmark", str(suite_file), "--out", str(out)],
        capture_output=True,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
        check=False,
    )
    assert rerun.returncode == 0, rerun.stderr
    assert f"{len(done_before)} of 8 cells complete" in rerun.stdout
    rows = json.loads((out / "summary.json").read_text())["rows"]
    assert len(rows) == 8 and {r["status"] for r in rows} == {"complete"}
    for key, names in done_before.items():
        cell = next(c for c in cells_of(load_suite(suite_file)) if c.key == key)
        assert [p.name for p, _ in attempts(cell_folder(out, cell))] == names


def test_sigterm_stops_a_pool_suite_keeping_what_is_complete_and_a_rerun_finishes_it(
    data: Path, tmp_path: Path
) -> None:
    suite_file = write_suite(tmp_path / "suite.toml", data)
    out = tmp_path / "out"
    process = start(suite_file, "--out", out, "--jobs", "2")
    wait_for(process, lambda: any((out / "cells").glob("*/*/*_run_*")))
    process.send_signal(signal.SIGTERM)
    try:  # the executor waits up to STOP_WAIT_SECONDS for a busy worker before it kills it
        _, stderr = process.communicate(timeout=STOP_WAIT_SECONDS + 60)
    except subprocess.TimeoutExpired:
        process.kill()
        pytest.fail(f"the suite did not stop on SIGTERM:\n{process.communicate()[1]}")
    assert process.returncode == 143, stderr
    assert "Rerun the same command" in stderr
    rows = json.loads((out / "summary.json").read_text())["rows"]
    assert {r["status"] for r in rows} <= {"complete", "partial", "pending"}
    assert any(r["status"] != "complete" for r in rows)
    rerun = subprocess.run(
        [sys.executable, "-c", ENTRY, "benchmark", str(suite_file), "--out", str(out), "--jobs", "2"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert rerun.returncode == 0, rerun.stderr
    assert {r["status"] for r in json.loads((out / "summary.json").read_text())["rows"]} == {"complete"}


def test_a_pool_process_killed_under_a_cell_fails_its_cells_and_a_rerun_finishes_them(
    data: Path, tmp_path: Path
) -> None:
    """A worker lost mid-cell (the OOM killer, a node gone) fails what it held, with the reason; the
    suite goes on to its summary, and the rerun completes those cells."""
    import multiprocessing
    import threading

    suite = write_suite(tmp_path / "suite.toml", data)
    out = tmp_path / "out"

    def kill_a_worker() -> None:
        deadline = time.monotonic() + 120
        while not any((out / "cells").glob("*/*/*_run_*")) and time.monotonic() < deadline:
            time.sleep(0.01)
        for child in multiprocessing.active_children():
            os.kill(child.pid, signal.SIGKILL)

    killer = threading.Thread(target=kill_a_worker)
    killer.start()
    outcome = run_suite(suite, out, jobs=2)
    killer.join()
    assert not outcome.interrupted
    lost = [r for r in outcome.rows if r["status"] == "failed"]
    assert lost and all("process was lost" in r["reason"] for r in lost)
    rerun = run_suite(suite, out, jobs=2)
    assert {r["status"] for r in rerun.rows} == {"complete"}
    assert sorted(rerun.ran) == sorted(
        f"{r['dataset']}/{r['method'].replace('+', '_')}_stride{r['stride']}"
        for r in outcome.rows
        if r["status"] != "complete"
    )


def test_the_command_names_a_bad_suite_file_and_exits_2_before_any_work(tmp_path: Path) -> None:
    from click.testing import CliRunner

    from vcr_odom.cli.main import cli

    suite = tmp_path / "suite.toml"
    suite.write_text('methods = ["kiss-icp"]\n[[dataset]]\nname = "a"\n')
    result = CliRunner().invoke(cli, ["benchmark", str(suite), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert (
        str(suite) in result.output and "give exactly one of data_root, folder, dataloader" in result.output
    )
    assert not (tmp_path / "out").exists()


def test_a_recording_and_a_map_cell_take_their_place_in_a_suite(data: Path, tmp_path: Path) -> None:
    """Fleets: a dataset may be a recording (here a ROS 2 bag of sequence 01's frames, with its poses
    and calibration), and a ``+loops`` method is a ``vcr-odom map`` cell."""
    pytest.importorskip("rosbags")
    from test_data_recordings import write_ros2

    from vcr_odom.data import open_sequence

    scans = open_sequence("01", data_root=data)
    bag = write_ros2(tmp_path / "drive", [scans.frame(i) for i in range(len(scans))])
    suite = tmp_path / "suite.toml"
    suite.write_text(
        'methods = ["icp10", "icp10+loops"]\n'
        f'[[dataset]]\nname = "b"\ndata_root = "{data}"\nseq = "01"\n'
        f'[[dataset]]\nname = "bag"\ndataloader = "rosbag"\ndata = "{bag}"\n'
        f'poses = "{data}/poses/01.txt"\ncalib = "{data}/sequences/01/calib.txt"\n'
    )
    rows = {(r["dataset"], r["method"]): r for r in run_suite(suite, tmp_path / "out").rows}
    assert {r["status"] for r in rows.values()} == {"complete"}
    assert rows["bag", "icp10"]["ate_m"] == rows["b", "icp10"]["ate_m"]  # the same frames, read from a bag
    assert "_map_" in rows["b", "icp10+loops"]["folder"]
    assert (tmp_path / "out" / rows["b", "icp10+loops"]["folder"] / "loops.json").is_file()
    assert rows["b", "icp10+loops"]["ate_m"] == rows["b", "icp10"]["ate_m"]  # no revisit: unchanged


def test_results_dir_names_where_the_suite_folder_goes_as_for_run_compare_and_map(
    data: Path, tmp_path: Path
) -> None:
    from click.testing import CliRunner

    from vcr_odom.cli.main import cli

    suite = tmp_path / "mine.toml"
    suite.write_text(f'methods = ["icp10"]\n[[dataset]]\nname = "a"\ndata_root = "{data}"\nseq = "01"\n')
    result = CliRunner().invoke(cli, ["benchmark", str(suite), "--results-dir", str(tmp_path / "res")])
    assert result.exit_code == 0, result.output
    rows = json.loads((tmp_path / "res" / "benchmark_mine" / "summary.json").read_text())["rows"]
    assert [row["method"] for row in rows] == ["icp10"]
