"""Interruptions and what survives them (issue 23's probe): SIGTERM and SIGHUP stop a command as Ctrl-C
does, an interrupt while starting exits quietly, a second interrupt never cuts short the writing of the
partial result, a killed comparison's markers say what finished, and a run too short to score does not
claim there is no ground truth.

Each CLI case runs the real console-script entry point (``vcr_odom.cli.main:main``) in a subprocess and
sends the signal at a moment found by polling the result folder, never after a guessed delay: the
wrapper publishes a checkpoint after every frame and pauses after it, so the signal lands there.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import tomllib
from collections.abc import Callable, Iterable
from pathlib import Path

import pytest
from paced_cli import paced_cli_source

from vcr_odom import results as results_module
from vcr_odom.results import deferred_interrupts, read_marker, result_unit, write_marker
from vcr_odom.synth import generate_sequence

REPOSITORY = Path(__file__).resolve().parents[1]
FRAMES = 12
PAUSE_AFTER_FRAME = 0.5
"""Seconds the wrapper waits after publishing each frame: where the test's signal lands."""

WRAPPER = paced_cli_source(PAUSE_AFTER_FRAME)

SLOW_IMPORT = """
import pathlib, sys, time
flag = pathlib.Path(sys.argv.pop(1))
class SlowTorch:
    def find_spec(self, name, path=None, target=None):
        if name == "torch":
            flag.touch()
            time.sleep(60)
        return None
sys.meta_path.insert(0, SlowTorch())
from vcr_odom.cli.main import main
main()
"""
"""The entry point with ``import torch`` held for a minute: the signal lands while the commands load."""


@pytest.fixture(scope="module")
def data_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("signals-data")
    generate_sequence(root, seq="00", frames=FRAMES, seed=5)
    return root


def start(code: str, *args: str | Path, ignore: int | None = None) -> subprocess.Popen[str]:
    """``python -c code args``; ``ignore``: a signal it starts with ignored, as ``nohup`` does SIGHUP."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "COLUMNS": "200"}
    return subprocess.Popen(
        [sys.executable, "-c", code, *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=None if ignore is None else lambda: signal.signal(ignore, signal.SIG_IGN),
    )


def wait_for(process: subprocess.Popen[str], ready: Callable[[], bool], seconds: float = 60) -> None:
    deadline = time.monotonic() + seconds
    while not ready():
        assert process.poll() is None, f"exited {process.returncode} first:\n{process.communicate()}"
        assert time.monotonic() < deadline, "the command never got there"
        time.sleep(0.01)


def markers(results: Path) -> list[dict]:
    """The markers of the folders in ``results``, as they are now."""
    return markers_of(results.glob("*/result.json"))


def markers_of(paths: Iterable[Path]) -> list[dict]:
    found = []
    for path in paths:
        try:
            found.append(json.loads(path.read_text()))
        except (OSError, ValueError):  # between a link and its unit: the next poll sees it
            continue
    return found


def frames_done(results: Path) -> int:
    return max((marker["frames_done"] for marker in markers(results)), default=0)


def the_folder(results: Path) -> Path:
    (folder,) = [p for p in results.iterdir() if not p.name.startswith(".") and p.name != "latest"]
    return folder


def agreeing_marker(folder: Path) -> dict:
    """The folder's marker, with trajectory files that hold the frames it says."""
    marker = read_marker(folder)
    assert marker is not None, f"{folder} has no marker"
    kitti = (folder / "trajectory_kitti.txt").read_text().splitlines()
    tum = (folder / "trajectory_tum.txt").read_text().splitlines()
    indices = json.loads((folder / "frames.json").read_text())["frame_indices"]
    assert len(kitti) == len(tum) == len(indices) == marker["frames_done"], marker
    return marker


def run_args(data_root: Path, results: Path) -> list[str | Path]:
    return ["run", "--data-root", data_root, "--method", "icp10", "--results-dir", results]


# -- 1 and 5: SIGTERM and SIGHUP keep the partial result, as Ctrl-C does ------------------------------


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_sigterm_and_sighup_keep_the_partial_result_and_exit_128_plus_the_signal(
    data_root: Path, tmp_path: Path, signum: int, code: int
) -> None:
    name = signal.Signals(signum).name
    process = start(WRAPPER, *run_args(data_root, tmp_path))
    wait_for(process, lambda: frames_done(tmp_path) >= 1)
    process.send_signal(signum)
    out, err = process.communicate(timeout=60)
    assert process.returncode == code, err
    assert "Traceback" not in err
    assert f"Interrupted ({name}) after 1 frames" in " ".join(err.split())
    folder = the_folder(tmp_path)
    marker = agreeing_marker(folder)
    assert marker["status"] == "partial" and marker["frames_done"] == 1
    assert marker["reason"] == f"interrupted ({name}) after 1 of {FRAMES} frames"
    assert (tmp_path / "latest").resolve() == folder.resolve()
    # 5: one frame of a sequence with ground truth is too short to score; it is not "no ground truth"
    assert "No ground truth" not in out and "too short to score" in out
    metrics = json.loads((folder / "metrics.json").read_text())
    assert metrics["ground_truth"] == "available" and "too short to score" in metrics["not_scored"]


def test_a_run_under_nohup_goes_on_through_sighup(data_root: Path, tmp_path: Path) -> None:
    process = start(WRAPPER, *run_args(data_root, tmp_path), "--frames", "0:3", ignore=signal.SIGHUP)
    wait_for(process, lambda: frames_done(tmp_path) >= 1)
    process.send_signal(signal.SIGHUP)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 0, err
    marker = agreeing_marker(the_folder(tmp_path))
    assert marker["status"] == "complete" and marker["frames_done"] == 3


# -- 2: an interrupt while the commands load ---------------------------------------------------------


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_an_interrupt_while_starting_exits_quietly_with_its_code(
    data_root: Path, tmp_path: Path, signum: int, code: int
) -> None:
    flag = tmp_path / "importing-torch"
    results = tmp_path / "results"
    process = start(SLOW_IMPORT, flag, *run_args(data_root, results))
    wait_for(process, flag.exists)
    process.send_signal(signum)
    _, err = process.communicate(timeout=60)
    assert process.returncode == code, err
    assert "Traceback" not in err
    label = "Ctrl-C" if signum == signal.SIGINT else "SIGTERM"
    assert err.strip() == f"Interrupted ({label}) while starting; nothing was written."
    assert not results.exists()


SIGNAL_WHILE_EXITING = """
import atexit, os, signal, sys
signum = int(sys.argv.pop(1))
atexit.register(lambda: os.kill(os.getpid(), signum))
from vcr_odom.cli.main import main
main()
"""
"""The entry point sending itself a signal while Python exits, after the command finished."""


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_after_the_command_finished_changes_nothing(
    data_root: Path, tmp_path: Path, signum: int
) -> None:
    results = tmp_path / "results"
    process = start(
        SIGNAL_WHILE_EXITING,
        int(signum),
        "run",
        "--data-root",
        data_root,
        "--seq",
        "00",
        "--method",
        "icp",
        "--frames",
        "0:4",
        "--results-dir",
        results,
    )
    _, err = process.communicate(timeout=120)
    assert process.returncode == 0, err
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert read_marker(the_folder(results))["status"] == "complete"


def test_the_console_script_is_the_entry_point_that_handles_signals_first() -> None:
    project = tomllib.loads((REPOSITORY / "pyproject.toml").read_text())
    assert project["project"]["scripts"]["vcr-odom"] == "vcr_odom.cli.main:main"


# -- 3: a second interrupt waits until the partial result is written ---------------------------------


def test_repeated_ctrl_c_does_not_cut_short_the_partial_result(data_root: Path, tmp_path: Path) -> None:
    process = start(WRAPPER, *run_args(data_root, tmp_path))
    wait_for(process, lambda: frames_done(tmp_path) >= 1)
    process.send_signal(signal.SIGINT)
    sent = 1
    while process.poll() is None and sent < 200:  # every 20 ms until it is gone: through the writing
        time.sleep(0.02)
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
            sent += 1
    _, err = process.communicate(timeout=60)
    assert sent > 2, "the command was gone before a second Ctrl-C could test anything"
    assert process.returncode == 130, err
    assert "Traceback" not in err and "Fatal Python error" not in err
    assert "already stopping" in err
    folder = the_folder(tmp_path)
    marker = agreeing_marker(folder)
    assert marker["reason"] == f"interrupted (Ctrl-C) after 1 of {FRAMES} frames", "the write was cut short"
    assert (folder / "metrics.json").is_file() and (folder / "trajectory.png").stat().st_size > 0
    assert not [p.name for p in folder.iterdir() if p.name.endswith((".creating", ".link"))]


def test_deferred_interrupts_hold_ctrl_c_until_the_block_is_done() -> None:
    finished = False
    with pytest.raises(KeyboardInterrupt), deferred_interrupts():
        signal.raise_signal(signal.SIGINT)
        finished = True
    assert finished
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_ctrl_c_just_after_a_unit_is_swapped_in_leaves_that_unit_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The unit's staging folder is the published unit once ``.unit`` points at it: an interrupt then
    must neither stop the publication half-way nor delete the unit as a failed staging folder."""
    with result_unit(tmp_path) as unit:
        (unit / "trajectory_kitti.txt").write_text("old\n")
        write_marker(unit, "partial", 1, 2)
    replace = os.replace

    def replace_then_ctrl_c(source: str | Path, target: str | Path) -> None:
        replace(source, target)
        if Path(target).name == ".unit":
            signal.raise_signal(signal.SIGINT)

    monkeypatch.setattr(results_module.os, "replace", replace_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt), result_unit(tmp_path) as unit:
        (unit / "trajectory_kitti.txt").write_text("new\n")
        write_marker(unit, "complete", 2, 2)
    assert (tmp_path / "trajectory_kitti.txt").read_text() == "new\n"
    assert read_marker(tmp_path)["status"] == "complete"
    assert len(list(tmp_path.glob(".unit-*"))) == 1, "the previous unit is cleared, the new one kept"


# -- 4: a comparison stopped part-way says what finished ----------------------------------------------


def test_a_stopped_comparison_marks_each_method_and_what_finished(data_root: Path, tmp_path: Path) -> None:
    args = ["compare", "--data-root", data_root, "--frames", "0:2", "-b", "icp10", "-b", "icp"]
    process = start(WRAPPER, *args, "--results-dir", tmp_path)
    unmarked: set[str] = set()
    checkpoints: list[dict] = []

    def second_method_going() -> bool:
        """Also, at every moment, what a SIGKILL would leave: no method folder without its marker, and a
        comparison marker that counts the finished method."""
        for method in tmp_path.glob("*/*/"):
            if not method.name.startswith(".") and not (method / "result.json").exists():
                unmarked.add(method.name)
        checkpoints.extend(m for m in markers(tmp_path) if m.get("methods_done"))
        return any(m["frames_done"] >= 1 for m in markers_of(tmp_path.glob("*/icp/result.json")))

    wait_for(process, second_method_going)
    process.send_signal(signal.SIGTERM)
    out, err = process.communicate(timeout=60)
    assert process.returncode == 143, err
    assert not unmarked, f"method folders seen without a marker: {unmarked}"
    assert checkpoints, "no comparison marker said that icp10 finished while icp ran"
    assert {(m["status"], m["frames_done"], tuple(m["methods_done"])) for m in checkpoints} == {
        ("partial", 2, ("icp10",))
    }
    folder = the_folder(tmp_path)
    marker = read_marker(folder)
    assert marker["status"] == "partial" and marker["reason"].startswith("interrupted (SIGTERM)")
    assert marker["methods_done"] == ["icp10"] and marker["frames_done"] == 2
    assert agreeing_marker(folder / "icp10")["status"] == "complete"
    second = agreeing_marker(folder / "icp")
    assert second["status"] == "partial" and second["reason"] == "interrupted (SIGTERM) after 1 of 2 frames"
    assert "partial result is kept in" in out + err and folder.name in out + err, (
        "the line names what was kept"
    )


def test_an_interrupt_while_a_result_folder_is_made_leaves_none_and_says_so(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    rename = results_module._rename_to_free_name

    def rename_then_interrupt(staging: Path, folder: Path) -> Path:
        made = rename(staging, folder)
        signal.raise_signal(signal.SIGINT)  # held until the folder is whole, then acts
        return made

    monkeypatch.setattr(results_module, "_rename_to_free_name", rename_then_interrupt)
    with pytest.raises(KeyboardInterrupt) as stopped:
        results_module.create_result_folder(tmp_path, "run_x", {}, frames_selected=3)
    assert list(tmp_path.iterdir()) == [], "no folder left that says 'started' forever"
    assert stopped.value.kept_note == "no result folder was kept"
