"""benchmarks/loop_acceptance.py: two replays held to the loop design's acceptance items."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "loop_acceptance.py"


def _row(sequence: str, odometry: float, map_ate: float, passages: int, closed: int, false: int, kept: int):
    return {
        "sequence": sequence,
        "odometry_ate_m": odometry,
        "map_ate_m": map_ate,
        "revisit_passages": passages,
        "passages_closed": closed,
        "false_closures": false,
        "accepted": kept,
    }


def _judge(tmp_path: Path, before: list[dict], after: list[dict]) -> tuple[int, dict[str, dict]]:
    paths = [tmp_path / "before.json", tmp_path / "after.json"]
    for path, rows in zip(paths, (before, after), strict=True):
        path.write_text(json.dumps(rows))
    verdicts = tmp_path / "verdicts.json"
    done = subprocess.run(
        [sys.executable, str(SCRIPT), *map(str, paths), "--json", str(verdicts)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode in (0, 1), done.stderr
    return done.returncode, {
        v["item"].split(" ")[0] + v["item"].split(" ")[1]: v for v in json.loads(verdicts.read_text())
    }


BEFORE = [
    _row("a", 1.0, 0.5, 2, 2, 0, 3),  # ratio 0.5
    _row("b", 1.0, 0.6, 3, 3, 1, 4),  # ratio 0.6, one false loop already
    _row("c", 0.2, 0.2, 0, 0, 0, 0),  # no revisit, no loop: must stay as it is
    _row("d", 2.0, 1.4, 0, 0, 0, 5),  # a return along its own road: loops but no passage
]


def test_a_change_that_keeps_every_item_passes(tmp_path: Path) -> None:
    after = [
        _row("a", 1.0, 0.45, 2, 2, 0, 3),
        _row("b", 1.0, 0.62, 3, 2, 2, 4),  # one passage lost (slack 2), a false loop on a drive that had one
        _row("c", 0.2, 0.205, 0, 0, 0, 0),  # within 1 cm
        _row("d", 2.0, 1.45, 0, 0, 0, 5),  # not a drive without revisits: may change
    ]
    status, verdicts = _judge(tmp_path, BEFORE, after)
    assert status == 0
    assert all(v["holds"] for v in verdicts.values())
    assert verdicts["revisitsclosed"]["before"] == "5/5" and verdicts["revisitsclosed"]["after"] == "4/5"
    assert verdicts["revisitsclosed"]["drives"] == ["b"]


def test_each_failed_item_names_the_drives_that_fail_it(tmp_path: Path) -> None:
    after = [
        _row("a", 1.0, 1.2, 2, 0, 1, 3),  # gains a false loop, loses both passages, map worse than odometry
        _row("b", 1.0, 0.6, 3, 2, 1, 4),
        _row("c", 0.2, 0.25, 0, 0, 0, 0),  # moved 5 cm
        _row("d", 2.0, 1.4, 0, 0, 0, 5),
    ]
    status, verdicts = _judge(tmp_path, BEFORE, after)
    assert status == 1
    assert verdicts["nodrive"] == {**verdicts["nodrive"], "holds": False, "drives": ["a"]}
    assert not verdicts["revisitsclosed"]["holds"] and verdicts["revisitsclosed"]["drives"] == ["a", "b"]
    # medians of the ratios: (0.5, 0.6, 1.0, 0.7) -> 0.65; after (1.2, 0.6, 1.25, 0.7) -> 0.95
    assert not verdicts["medianmap/odometry"]["holds"]
    assert (verdicts["medianmap/odometry"]["before"], verdicts["medianmap/odometry"]["after"]) == (
        "0.65",
        "0.95",
    )
    assert verdicts["driveswithout"]["drives"] == ["c"]
    assert verdicts["nomap"]["drives"] == ["a", "c"]  # 1.2 > 1.05 + 0.01; 0.25 > 0.22


def test_a_file_that_is_not_a_replay_is_named(tmp_path: Path) -> None:
    good, bad = tmp_path / "good.json", tmp_path / "bad.json"
    good.write_text(json.dumps(BEFORE))
    bad.write_text(json.dumps({"sequence": "a"}))
    done = subprocess.run(
        [sys.executable, str(SCRIPT), str(good), str(bad)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 2
    assert str(bad) in done.stderr and "loop_replay.py" in done.stderr
