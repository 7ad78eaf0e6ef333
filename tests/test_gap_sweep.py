"""The gap sweep's figures against independently computed numbers, with a registrar whose answers are known."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from vcr_odom.errors import ConfigError
from vcr_odom.evaluation.gap_sweep import gap_pairs, markdown_table, run_gap_sweep
from vcr_odom.registration.base import RegistrationResult
from vcr_odom.synth import SynthSequence

FRAMES = 12


class TruthScaled:
    """Prepares a frame to its index (found by its point count) and answers the true motion with the
    translation scaled by ``scale`` and, from ``wrong_from`` frames apart on, a 5 deg yaw added.
    Counts prepares per frame, so a test can check that each frame is prepared once."""

    needs_initial_guess = False

    def __init__(
        self, name: str, poses: np.ndarray, sizes: dict[int, int], scale: float, wrong_from: int
    ) -> None:
        self.name = name
        self.poses = poses
        self.index_of = {size: index for index, size in sizes.items()}
        self.scale = scale
        self.wrong_from = wrong_from
        self.prepared: Counter[int] = Counter()

    def prepare(self, points: np.ndarray) -> int:
        index = self.index_of[len(points)]
        self.prepared[index] += 1
        return index

    def register(
        self, source: int, target: int, initial_guess: np.ndarray | None = None
    ) -> RegistrationResult:
        assert initial_guess is None
        estimate = np.linalg.inv(self.poses[target]) @ self.poses[source]
        estimate[:3, 3] *= self.scale
        if source - target >= self.wrong_from:
            estimate[:3, :3] = estimate[:3, :3] @ _yaw(np.radians(5.0))
        return RegistrationResult(estimate)


def _yaw(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def sequence() -> SynthSequence:
    return SynthSequence(frames=FRAMES, seed=3)


@pytest.fixture(scope="module")
def sizes(sequence: SynthSequence) -> dict[int, int]:
    sizes = {k: len(sequence.frame(k)) for k in range(FRAMES)}
    assert len(set(sizes.values())) == FRAMES, "frames must be told apart by their point counts"
    return sizes


def _true_translations(poses: np.ndarray, frames: list[int], gap: int) -> np.ndarray:
    """Independently of the library: |t| of inv(P_i) P_(i+gap) for consecutive selected frames."""
    return np.array(
        [
            np.linalg.norm((np.linalg.inv(poses[i]) @ poses[i + gap])[:3, 3])
            for i in frames
            if i + gap in frames
        ]
    )


def test_figures_match_independent_numbers(sequence: SynthSequence, sizes: dict[int, int]) -> None:
    poses = sequence.gt_poses
    half = TruthScaled("half", poses, sizes, scale=0.5, wrong_from=5)
    exact = TruthScaled("exact", poses, sizes, scale=1.0, wrong_from=99)
    frames = list(range(2, FRAMES))
    sweep = run_gap_sweep(sequence, frames, [half, exact], gaps=(1, 2, 5))
    rows = {(row.method, row.gap): row for row in sweep.rows}
    assert list(rows) == [(name, gap) for name in ("half", "exact") for gap in (1, 2, 5)]

    for gap in (1, 2, 5):
        true = _true_translations(poses, frames, gap)
        row = rows[("half", gap)]
        assert row.num_pairs == len(true) == len(frames) - gap
        assert row.true_length_mean_m == pytest.approx(true.mean())
        assert row.length_ratio == pytest.approx(0.5)
        assert row.length_ratio_median == pytest.approx(0.5)
        assert row.ratio_pairs == int((true > 0.2).sum())
        # Translation error of each pair is 0.5 |t|; RMSE and MAE follow.
        assert row.errors.trans_rmse_m == pytest.approx(np.sqrt(np.mean((0.5 * true) ** 2)))
        assert row.errors.trans_mae_m == pytest.approx(np.mean(0.5 * true))
        expected_success = np.mean(0.5 * true < 0.5) if gap < 5 else 0.0  # 5 deg yaw fails from gap 5
        assert row.errors.success_rate == pytest.approx(expected_success)
        assert row.ms_per_pair == pytest.approx(row.prepare_ms_per_pair + row.register_ms_per_pair)

    # The translation threshold bites at gap 2 (0.5 x ~1.3 m), the 5 deg yaw at gap 5.
    assert [rows[("half", gap)].errors.success_rate for gap in (1, 2, 5)] == [1.0, 0.0, 0.0]
    assert rows[("half", 5)].errors.rot_rmse_deg == pytest.approx(5.0)
    assert rows[("half", 1)].errors.rot_rmse_deg == pytest.approx(0.0, abs=1e-6)
    for gap in (1, 2, 5):
        assert rows[("exact", gap)].length_ratio == pytest.approx(1.0)
        assert rows[("exact", gap)].errors.success_rate == 1.0
        assert rows[("exact", gap)].errors.trans_rmse_m == pytest.approx(0.0, abs=1e-9)

    table = markdown_table(sweep)
    assert table.count("\n") == 1 + len(sweep.rows)
    assert "| half | 5 | 5 |" in table
    assert sweep.to_dict()["rows"][0]["length_ratio"] == pytest.approx(0.5)


def test_each_frame_prepared_once_per_method(sequence: SynthSequence, sizes: dict[int, int]) -> None:
    methods = [TruthScaled(name, sequence.gt_poses, sizes, 1.0, 99) for name in ("a", "b")]
    run_gap_sweep(sequence, range(FRAMES), methods, gaps=(1, 2, 5, 10))
    for method in methods:
        assert method.prepared == Counter(range(FRAMES))


def test_gap_pairs_stay_inside_the_selection() -> None:
    assert gap_pairs([4, 5, 6, 8], 2) == [(4, 6), (6, 8)]
    assert gap_pairs(range(3), 3) == []


def test_too_large_gap_names_the_option(sequence: SynthSequence, sizes: dict[int, int]) -> None:
    method = TruthScaled("m", sequence.gt_poses, sizes, 1.0, 99)
    with pytest.raises(ConfigError, match="--gap 12"):
        run_gap_sweep(sequence, range(FRAMES), [method], gaps=(1, 12))
    with pytest.raises(ConfigError, match="--gap"):
        run_gap_sweep(sequence, range(FRAMES), [method], gaps=(0,))
    assert method.prepared == Counter()  # checked before any frame is read
