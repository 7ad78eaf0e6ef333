"""Shared fixtures: the team's real KITTI data (skipped cleanly when ../shared/data is absent)."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def pytest_configure() -> None:
    """Stop signals as a terminal delivers them, whoever started pytest: `nohup make test &` starts it
    with SIGINT and SIGHUP ignored, which its subprocesses inherit, and the tests of Ctrl-C and SIGHUP
    would then see a run that cannot be interrupted."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if signal.getsignal(signal.SIGHUP) is signal.SIG_IGN:
        signal.signal(signal.SIGHUP, signal.SIG_DFL)


@pytest.fixture(scope="session")
def kitti_sample_root() -> Path:
    """Root of the 60-frame real KITTI sample (KITTI odometry layout, sequence '00')."""
    root = SHARED_DATA / "kitti-sample"
    if not (root / "sequences" / "00" / "velodyne").is_dir():
        pytest.skip(f"real KITTI sample not found at {root}")
    return root


@pytest.fixture(scope="session")
def kitti_gt_poses_dir() -> Path:
    """Folder of the official KITTI ground-truth poses 00.txt..10.txt (camera frame) and calib 00-02."""
    root = SHARED_DATA / "kitti-gt-poses"
    if not (root / "poses" / "00.txt").is_file():
        pytest.skip(f"KITTI ground-truth poses not found at {root}")
    return root


SMALL_SYNTHETIC_FRAMES = 8


@pytest.fixture(scope="session")
def small_synthetic_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An 8-frame synthetic KITTI-layout sequence '00' (seed 3), shared by the CLI error and result tests."""
    from vcr_odom.synth import generate_sequence

    root = tmp_path_factory.mktemp("small-synthetic")
    generate_sequence(root, seq="00", frames=SMALL_SYNTHETIC_FRAMES, seed=3)
    return root
