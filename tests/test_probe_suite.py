"""``vcr-odom benchmark`` under a black-box probe (issue 61): a lost worker fails its own cell only, no
worker outlives a killed suite or starts a cell after it, SIGHUP stops it without tracebacks, a cell is
rerun when what it ran differs from the suite (its settings' digest) or its metrics.json is lost, the
suite file is checked whole before the first cell, an unreachable Ray cluster fails in seconds, and a
second run into one folder is refused.

The process cases run the real console script in a subprocess, through a wrapper that pauses after
every frame (in the workers too: a spawned worker imports the wrapper as ``__mp_main__``), so a signal
lands while cells run, found by polling the suite's folder, never after a guessed delay. The others
drive the command through click's CliRunner.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from click.testing import CliRunner, Result
from paced_cli import paced_cli_source

from vcr_odom.synth import generate_sequence

FRAMES = 8
PAUSE_AFTER_FRAME = 0.4
"""Seconds each frame is held in the wrapper: a cell of 8 frames lasts over 3 s, where signals land."""

WRAPPER = paced_cli_source(PAUSE_AFTER_FRAME)


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("probe-suite-data")
    generate_sequence(root, seq="00", frames=FRAMES, seed=21)
    return root


def suite_text(data: Path, methods: str = '["icp10"]', top: str = "", names: tuple[str, ...] = ("a",)) -> str:
    datasets = "".join(f'[[dataset]]\nname = "{n}"\ndata_root = "{data}"\nseq = "00"\n' for n in names)
    return f"methods = {methods}\n{top}{datasets}"


def write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def invoke(*args: str | Path) -> Result:
    from vcr_odom.cli.main import cli

    return CliRunner().invoke(cli, ["benchmark", *map(str, args)])


def rows(out: Path) -> list[dict]:
    return json.loads((out / "summary.json").read_text())["rows"]


def attempt_folders(out: Path) -> set[Path]:
    return {p for p in (out / "cells").glob("*/*/*_run_*") if p.is_dir()}


def running(out: Path, process: subprocess.Popen[str]) -> bool:
    """Two workers, each with a cell past its first frame (a cell stopped before would keep nothing)."""
    return len(workers_of(process.pid)) == 2 and sum(frames_done(p) > 0 for p in attempt_folders(out)) >= 2


def frames_done(attempt: Path) -> int:
    try:
        return int(json.loads((attempt / "result.json").read_text())["frames_done"])
    except (OSError, ValueError, KeyError, TypeError):
        return 0


# -- the processes: a lost worker, a killed suite, a hang-up -----------------------------------------


@pytest.fixture
def wrapper(tmp_path: Path) -> Path:
    return write(tmp_path / "paused_vcr_odom.py", WRAPPER)


def start(wrapper: Path, *args: str | Path, new_session: bool = False) -> subprocess.Popen[str]:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "COLUMNS": "200"}
    return subprocess.Popen(
        [sys.executable, str(wrapper), "benchmark", *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=new_session,
    )


def wait_for(process: subprocess.Popen[str], ready: Callable[[], bool], seconds: float = 180) -> None:
    deadline = time.monotonic() + seconds
    while not ready():
        assert process.poll() is None, f"exited {process.returncode} first:\n{process.communicate()}"
        assert time.monotonic() < deadline, "the suite never got there"
        time.sleep(0.02)


def children(pid: int) -> dict[int, str]:
    """The live child processes of ``pid`` with their command lines (from /proc)."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        if int(fields[1]) == pid and fields[0] != "Z":
            found[int(entry.name)] = command
    return found


def workers_of(pid: int) -> list[int]:
    return [child for child, command in children(pid).items() if "resource_tracker" not in command]


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return state[state.rindex(")") + 2] != "Z"


def wait_gone(pids: list[int], seconds: float = 60) -> list[int]:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and any(alive(pid) for pid in pids):
        time.sleep(0.1)
    return [pid for pid in pids if alive(pid)]


pytestmark_linux = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc (Linux)")


@pytestmark_linux
def test_a_worker_killed_fails_its_own_cell_and_the_others_complete(
    data: Path, tmp_path: Path, wrapper: Path
) -> None:
    """Item 2: one worker SIGKILLed under a cell: that cell fails with the reason, a new worker takes the
    queued cells, the other running cell finishes; every cell ran, exit 1 for the one failure."""
    suite = write(tmp_path / "suite.toml", suite_text(data, top="strides = [1, 2]\n", names=("a", "b", "c")))
    out = tmp_path / "out"
    process = start(wrapper, suite, "--out", out, "--jobs", "2")
    wait_for(process, lambda: running(out, process))
    victim = workers_of(process.pid)[0]
    os.kill(victim, signal.SIGKILL)
    stdout, stderr = process.communicate(timeout=300)
    assert process.returncode == 1, stderr
    statuses = [r["status"] for r in rows(out)]
    assert sorted(statuses) == ["complete"] * 5 + ["failed"], rows(out)
    (failed,) = [r for r in rows(out) if r["status"] == "failed"]
    assert "its process was lost (killed by SIGKILL" in failed["reason"]
    assert "6 cells run" in stdout
    assert "Traceback" not in stderr
    assert not children(process.pid)


@pytestmark_linux
def test_a_suite_killed_takes_its_workers_with_it_and_they_start_no_cell(
    data: Path, tmp_path: Path, wrapper: Path
) -> None:
    """Item 4: ``kill -9`` of the suite: its workers stop (keeping their cells' partial results) instead
    of running on as orphans, and none starts a queued cell; the resource tracker goes too."""
    suite = write(tmp_path / "suite.toml", suite_text(data, top="strides = [1, 2]\n", names=("a", "b", "c")))
    out = tmp_path / "out"
    process = start(wrapper, suite, "--out", out, "--jobs", "2")
    wait_for(process, lambda: running(out, process))
    descendants = list(children(process.pid))
    process.kill()
    process.communicate(timeout=60)
    started = attempt_folders(out)
    assert wait_gone(descendants, seconds=60) == [], "processes of the killed suite still run"
    assert attempt_folders(out) == started, "a worker started a cell after its suite was killed"
    markers = [json.loads((p / "result.json").read_text()) for p in started]
    assert {m["status"] for m in markers} <= {"partial", "complete"}


@pytestmark_linux
@pytest.mark.parametrize("to", ["suite", "group"])
def test_a_hang_up_stops_a_pool_suite_quietly_keeping_what_was_done(
    data: Path, tmp_path: Path, wrapper: Path, to: str
) -> None:
    """Item 12: SIGHUP to the suite (``kill -HUP``) or to its whole process group (a terminal closed):
    exit 129, the running cells kept as partial, no traceback, no resource-tracker message, nothing
    left running."""
    suite = write(tmp_path / "suite.toml", suite_text(data, top="strides = [1, 2]\n", names=("a", "b", "c")))
    out = tmp_path / "out"
    process = start(wrapper, suite, "--out", out, "--jobs", "2", new_session=True)
    wait_for(process, lambda: running(out, process))
    descendants = list(children(process.pid))
    if to == "suite":
        process.send_signal(signal.SIGHUP)
    else:
        os.killpg(process.pid, signal.SIGHUP)
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 129, stderr
    for noise in ("Traceback", "resource_tracker", "KeyError"):
        assert noise not in stderr, stderr
    assert "Rerun the same command" in stderr
    assert "partial" in {r["status"] for r in rows(out)}
    assert wait_gone(descendants, seconds=10) == []


# -- what a cell is: its settings' digest, a metrics.json that parses ------------------------------------


def test_a_changed_consult_reruns_the_cell_and_keeps_the_old_attempt(data: Path, tmp_path: Path) -> None:
    """Item 6: the same suite with ``consult`` changed reruns its cell (and says why); the earlier
    attempt stays on disk; the summary's row is the new attempt's; the same suite again skips it."""
    out = tmp_path / "out"
    top = 'consult = "{}"\ndevice = "cpu"\n'
    body = suite_text(data, '["vcr"]').replace('seq = "00"\n', 'seq = "00"\nframes = "0:3"\n')
    suite = tmp_path / "suite.toml"
    write(suite, top.format("on-doubt") + body)
    first = invoke(suite, "--out", out)
    assert first.exit_code == 0, first.output
    write(suite, top.format("every-frame") + body)
    second = invoke(suite, "--out", out)
    assert second.exit_code == 0, second.output
    assert "cells complete in" not in second.output
    assert "consult: 'on-doubt' -> 'every-frame'" in second.output
    folders = sorted(attempt_folders(out))
    assert len(folders) == 2
    consults = [json.loads((f / "config.json").read_text())["config"]["consult"] for f in folders]
    assert sorted(consults) == ["every-frame", "on-doubt"]
    (row,) = rows(out)
    assert json.loads((out / row["folder"] / "config.json").read_text())["config"]["consult"] == "every-frame"
    third = invoke(suite, "--out", out)
    assert third.exit_code == 0 and "1 of 1 cells complete" in third.output


def test_a_complete_cell_whose_metrics_do_not_parse_is_rerun(data: Path, tmp_path: Path) -> None:
    """Item 9: a complete attempt with a corrupt metrics.json counts for nothing: the rerun says so,
    runs the cell again and keeps the damaged attempt."""
    out = tmp_path / "out"
    suite = write(tmp_path / "suite.toml", suite_text(data))
    assert invoke(suite, "--out", out).exit_code == 0
    (damaged,) = attempt_folders(out)
    (damaged / "metrics.json").write_text('{"drift": {"t_rel_per')  # through its link, into the unit
    rerun = invoke(suite, "--out", out)
    assert rerun.exit_code == 0, rerun.output
    assert "metrics.json does not parse" in rerun.output and "cells complete in" not in rerun.output
    assert damaged in attempt_folders(out) and len(attempt_folders(out)) == 2
    (row,) = rows(out)
    assert row["status"] == "complete" and row["ate_m"] is not None
    assert row["folder"] != str(damaged.relative_to(out))


def test_a_map_cell_runs_its_loop_network_on_the_suites_device(data: Path, tmp_path: Path) -> None:
    """A ``+loops`` cell's loop network takes the suite's ``device`` (it took ``run``'s default,
    ``auto``: a GPU where there is one, whatever the suite said)."""
    out = tmp_path / "out"
    suite = write(tmp_path / "suite.toml", suite_text(data, '["icp10+loops"]', top='device = "cpu"\n'))
    result = invoke(suite, "--out", out)
    assert result.exit_code == 0, result.output
    (row,) = rows(out)
    assert json.loads((out / row["folder"] / "config.json").read_text())["config"]["device"] == "cpu"


# -- the suite file, checked whole before any cell -------------------------------------------------------


SECOND = 'name = "b"\ndata_root = "{data}"\nseq = "00"\n'
"""The second dataset of a mistaken suite (the first is fine): where a mistake found by its cells would
only have come after the first dataset's cells ran."""


@pytest.mark.parametrize(
    ("top", "second", "message"),
    [
        ("", SECOND.replace('"b"', '"sample\\n"'), r"name: letters, digits"),  # item 7
        ("strides = [true]\n", SECOND, r"strides\[0\]: expected an integer, got a boolean \(true\)"),  # 8
        ('strides = ["2"]\n', SECOND, r"strides\[0\]: expected an integer, got a string"),
        ("", SECOND + "bin_columns = true\n", r"\('b'\): bin_columns: expected an integer"),
        ("", SECOND + 'dataloder = "rosbag"\n', r"unknown key 'dataloder' \(did you mean 'dataloader'\?\)"),
        (
            "",
            'name = "b"\ndataloader = "rosbg"\ndata = "{data}"\n',
            r"not a loader \(did you mean 'rosbag'\?\)",
        ),
        ('device = "cuda:0"\n', SECOND, r"device: one of auto, cpu, cuda"),
        ("", SECOND + 'device = "cpu"\n', r"device: a key of the whole suite; write it at the top"),
        ("", SECOND + 'poses = "missing/poses.txt"\n', r"'b': poses \S*missing/poses.txt: does not exist"),
        ("", SECOND.replace("{data}", "{data}/nowhere"), r"'b': data_root \S*nowhere: does not exist"),
    ],
)
def test_a_suite_mistake_is_named_before_any_cell_runs(
    data: Path, tmp_path: Path, top: str, second: str, message: str
) -> None:
    """Items 7, 8, 18: a name ending in a newline, a bool or a string for an integer, a misspelt key,
    loader or device, a key in the wrong table, a missing path, each in the second dataset, exit 2 with
    one line naming the file and the key, before any cell ran: nothing is written."""
    first = f'[[dataset]]\nname = "a"\ndata_root = "{data}"\nseq = "00"\n'
    text = f'methods = ["icp10"]\n{top}{first}[[dataset]]\n{second.replace("{data}", str(data))}'
    suite = write(tmp_path / "suite.toml", text)
    out = tmp_path / "out"
    result = invoke(suite, "--out", out)
    assert result.exit_code == 2, result.output
    error = " ".join(result.output.split())  # rich may wrap the one line
    assert error.startswith(f"Error: {suite}"), result.output
    assert re.search(message, error), result.output
    assert not out.exists()


def test_a_suite_file_with_a_byte_order_mark_is_read_and_the_mark_named(data: Path, tmp_path: Path) -> None:
    """Item 18: a UTF-8 BOM (Windows editors write one) is read past, with a warning naming it, where
    it was "not valid TOML (Invalid statement (at line 1, column 1))"."""
    suite = tmp_path / "suite.toml"
    suite.write_bytes(b"\xef\xbb\xbf" + suite_text(data).encode())
    result = invoke(suite, "--out", tmp_path / "out")
    assert result.exit_code == 0, result.output
    assert "byte-order mark (BOM)" in result.stderr and str(suite) in result.stderr
    assert rows(tmp_path / "out")[0]["status"] == "complete"


def test_an_unreachable_ray_cluster_fails_in_seconds_naming_it(data: Path, tmp_path: Path) -> None:
    """Item 16: ``--ray 127.0.0.1:1`` (nothing listens there) exits 2 in seconds, naming the address,
    before anything is written; Ray's client retried for minutes."""
    pytest.importorskip("ray", reason="--ray needs Ray installed: pip install 'vcr-odom[ray]'")
    suite = write(tmp_path / "suite.toml", suite_text(data))
    began = time.monotonic()
    result = invoke(suite, "--out", tmp_path / "out", "--ray", "127.0.0.1:1")
    assert time.monotonic() - began < 30
    assert result.exit_code == 2, result.output
    assert "--ray 127.0.0.1:1" in result.output
    assert not (tmp_path / "out").exists()


def test_a_second_run_into_the_same_folder_is_refused(data: Path, tmp_path: Path) -> None:
    """Two runs into one ``--out`` would each run every cell not yet complete: the second is refused,
    naming the folder, while the first holds it, and the first's work is untouched."""
    from vcr_odom.suite.suite import planned

    suite = write(tmp_path / "suite.toml", suite_text(data))
    out = tmp_path / "out"
    with planned(suite, out):  # the first run, between reading the folder and its last cell
        second = invoke(suite, "--out", out)
    assert second.exit_code == 2, second.output
    assert f"--out {out}: another benchmark is writing into it (process {os.getpid()})" in second.output
    assert not (out / "cells").exists()
    assert invoke(suite, "--out", out).exit_code == 0  # the lock went with the first
