"""Revisit-pair selection on hand-built trajectories and the evaluation with registrars whose answers are
known (the gap sweep's TruthScaled, and one off by 1 m)."""

from __future__ import annotations

from collections import Counter
from itertools import combinations

import numpy as np
import pytest
from test_gap_sweep import TruthScaled, _yaw

from vcr_odom.errors import ConfigError, DataError
from vcr_odom.evaluation.revisits import (
    RevisitOptions,
    RevisitPair,
    candidate_pairs,
    heading_bin,
    markdown_table,
    pool_rows,
    run_revisits,
    select_revisits,
    share_limit,
    stratified_sample,
    true_revisits,
)
from vcr_odom.registration.base import RegistrationResult


def _poses(xy_yaw_deg: list[tuple[float, float, float]]) -> np.ndarray:
    """Level poses at (x, y) with yaw (deg) about z."""
    poses = np.tile(np.eye(4), (len(xy_yaw_deg), 1, 1))
    for k, (x, y, yaw) in enumerate(xy_yaw_deg):
        poses[k, :3, :3] = _yaw(np.radians(yaw))
        poses[k, :2, 3] = x, y
    return poses


def square_loop(side: int = 10) -> np.ndarray:
    """1 m steps around a side x side square, counter-clockwise, facing the way of travel; the last
    frame is one step short of the start, so the loop closes on frame 0."""
    steps = []
    for edge, yaw in enumerate((0.0, 90.0, 180.0, 270.0)):
        start = np.array([[0, 0], [side, 0], [side, side], [0, side]][edge], dtype=float)
        direction = np.array([np.cos(np.radians(yaw)), np.sin(np.radians(yaw))])
        steps += [(*(start + k * direction), yaw) for k in range(side)]
    return _poses(steps)


def u_turn() -> np.ndarray:
    """10 m along x, a turn on the spot in 45 deg steps, and back 1 m to the side."""
    out = [(float(x), 0.0, 0.0) for x in range(11)]
    turn = [(10.0, 0.0, yaw) for yaw in (45.0, 90.0, 135.0, 180.0)]
    back = [(float(x), 1.0, 180.0) for x in range(10, -1, -1)]
    return _poses(out + turn + back)


def _heading(poses: np.ndarray, i: int, j: int) -> float:
    """Independently of the library: |yaw_j - yaw_i| wrapped to [0, 180] deg."""
    yaw = [np.degrees(np.arctan2(p[1, 0], p[0, 0])) for p in (poses[i], poses[j])]
    return abs((yaw[1] - yaw[0] + 180.0) % 360.0 - 180.0)


def _brute_force(poses: np.ndarray, options: RevisitOptions) -> set[tuple[int, int]]:
    return {
        (i, j)
        for i, j in combinations(range(len(poses)), 2)
        if options.min_m - 1e-9 <= np.linalg.norm(poses[i, :3, 3] - poses[j, :3, 3]) <= options.max_m + 1e-9
        and _heading(poses, i, j) <= options.max_heading_deg + 1e-9
        and j - i >= options.min_frame_gap
    }


@pytest.mark.parametrize("poses", [square_loop(), u_turn()], ids=["square", "u-turn"])
def test_candidates_are_every_pair_inside_the_bounds(poses: np.ndarray) -> None:
    options = RevisitOptions()
    pairs = candidate_pairs(poses, options)
    assert {(p.target, p.source) for p in pairs} == _brute_force(poses, options)
    for p in pairs:
        assert p.target < p.source
        assert p.distance_m == pytest.approx(np.linalg.norm(poses[p.source, :3, 3] - poses[p.target, :3, 3]))
        assert 3.0 <= p.distance_m <= 6.0
        assert p.heading_deg == pytest.approx(_heading(poses, p.target, p.source))
        assert p.heading_deg <= 90.0 + 1e-9
        assert p.rotation_deg == pytest.approx(p.heading_deg, abs=1e-6)  # level poses: geodesic = yaw


def test_square_loop_finds_the_closure_across_time() -> None:
    poses = square_loop()
    pairs = candidate_pairs(poses, RevisitOptions(min_frame_gap=20))
    assert pairs, "the loop's end is 1-6 m from its start"
    assert all(p.source - p.target >= 20 for p in pairs)
    # Frame 0 faces +x, the last edge faces -y (yaw 270 = -90): a 90 deg change, kept; corners give both bins.
    assert (0, 37) in {(p.target, p.source) for p in pairs}
    assert {heading_bin(p.heading_deg, [0, 30, 60, 90]) for p in candidate_pairs(poses)} == {0, 2}


def test_u_turn_keeps_quarter_turns_and_drops_the_reversal() -> None:
    poses = u_turn()
    pairs = candidate_pairs(poses)
    headings = {round(p.heading_deg) for p in pairs}
    assert headings == {0, 45, 90}  # the way back (180 deg) and the 135 deg step never qualify
    wide = candidate_pairs(poses, RevisitOptions(max_heading_deg=180.0))
    assert {round(p.heading_deg) for p in wide} == {0, 45, 90, 135, 180}


def test_heading_wraps_across_180() -> None:
    poses = _poses([(0.0, 0.0, 170.0), (4.0, 0.0, -170.0)])
    (pair,) = candidate_pairs(poses)
    assert pair.heading_deg == pytest.approx(20.0)


def test_true_revisits_need_travel_between_the_frames() -> None:
    """The U-turn's way back passes 1 m beside the way out (180 deg): revisits once the sensor has
    travelled far enough in between; standing still (or turning on the spot) never is one."""
    poses = u_turn()
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))])
    pairs = true_revisits(poses, radius_m=1.5, min_path_m=8.0)
    assert pairs and {round(p.heading_deg) for p in pairs} <= {135, 180}
    for p in pairs:
        assert p.distance_m <= 1.5 and travelled[p.source] - travelled[p.target] >= 8.0
    assert (10, 15) not in {(p.target, p.source) for p in pairs}  # the turn on the spot: no travel
    standing = np.tile(np.eye(4), (20, 1, 1))
    assert not true_revisits(standing)
    assert len(true_revisits(standing, min_path_m=0.0)) == 20 * 19 // 2
    with pytest.raises(ConfigError, match="radius_m"):
        true_revisits(poses, radius_m=0.0)


def test_frames_restrict_the_pairs() -> None:
    pairs = candidate_pairs(square_loop(), frames=range(5, 15))
    assert pairs and all(5 <= p.target < p.source < 15 for p in pairs)
    with pytest.raises(ConfigError, match="outside"):
        candidate_pairs(square_loop(), frames=[0, 40])


def _scattered(count: int = 80, seed: int = 1) -> np.ndarray:
    """Positions in a 10 m box and yaws anywhere: candidates in every heading bin and distance."""
    rng = np.random.default_rng(seed)
    return _poses([(*rng.uniform(0, 10, 2), rng.uniform(-180, 180)) for _ in range(count)])


def test_sample_is_stratified_seeded_and_limited() -> None:
    poses = _scattered()
    candidates = candidate_pairs(poses)
    edges = [0, 30, 60, 90]
    sizes = Counter(heading_bin(p.heading_deg, edges) for p in candidates)
    assert min(sizes[k] for k in range(3)) >= 30

    options = RevisitOptions(limit=30, seed=4)
    kept, num_candidates = select_revisits(poses, options)
    assert num_candidates == len(candidates)
    assert len(kept) == 30 and len(set(kept)) == 30
    assert set(kept) <= set(candidates)
    assert Counter(heading_bin(p.heading_deg, edges) for p in kept) == {0: 10, 1: 10, 2: 10}
    assert kept == sorted(kept, key=lambda p: (p.target, p.source))
    # Spread over distance inside each bin: one pick per tenth of the bin's pairs sorted by distance.
    for k in range(3):
        pool = np.array([p.distance_m for p in candidates if heading_bin(p.heading_deg, edges) == k])
        picked = [p.distance_m for p in kept if heading_bin(p.heading_deg, edges) == k]
        assert min(picked) <= np.quantile(pool, 0.1) and max(picked) >= np.quantile(pool, 0.9)

    assert select_revisits(poses, options)[0] == kept
    assert select_revisits(poses, RevisitOptions(limit=30, seed=5))[0] != kept
    assert len(select_revisits(poses, RevisitOptions(limit=7))[0]) == 7
    everything = select_revisits(poses, RevisitOptions(limit=None))[0]
    assert len(everything) == len(candidates)


def test_limit_is_shared_by_bin_size() -> None:
    assert share_limit(30, [100, 100, 100]) == [10, 10, 10]
    assert share_limit(30, [2, 100, 100]) == [2, 14, 14]
    assert share_limit(30, [0, 5, 100]) == [0, 5, 25]
    assert share_limit(30, [3, 4, 5]) == [3, 4, 5]
    scarce = [RevisitPair(0, k + 1, 4.0, 10.0, 10.0) for k in range(2)]
    plenty = [RevisitPair(0, k + 10, 3.0 + k / 100, 45.0, 45.0) for k in range(100)]
    kept = stratified_sample(scarce + plenty, RevisitOptions(limit=10))
    assert len(kept) == 10 and set(scarce) <= set(kept)


@pytest.mark.parametrize(
    ("options", "named"),
    [
        ({"min_m": 7.0}, "--min-m 7.0 is more than --max-m 6.0"),
        ({"min_m": -1.0}, "--min-m"),
        ({"max_m": 0.0, "min_m": 0.0}, "--max-m"),
        ({"max_heading_deg": 0.0}, "--max-heading"),
        ({"max_heading_deg": 200.0}, "--max-heading"),
        ({"max_m": float("nan")}, "--max-m"),
        ({"limit": 0}, "--limit"),
        ({"min_frame_gap": 0}, "--min-frame-gap"),
        ({"seed": -1}, "--seed"),
        ({"bin_deg": -30.0}, "--heading-bin"),
        ({"min_path_m": -1.0}, "min_path_m"),
    ],
)
def test_bad_options_name_themselves(options: dict, named: str) -> None:
    with pytest.raises(ConfigError, match=named):
        RevisitOptions(**options)


def test_bad_poses_are_refused() -> None:
    with pytest.raises(DataError, match="ground-truth poses"):
        candidate_pairs(np.zeros((3, 3, 4)))


# -------------------------------------------------------------------------------------- evaluation


class PoseSequence:
    """A sequence of the given poses whose frame k is ``100 + k`` empty points: only the registrars
    below read frames, and they recognise a frame by its point count."""

    def __init__(self, name: str, poses: np.ndarray | None) -> None:
        self.name = name
        self.poses = poses
        self.read: Counter[int] = Counter()

    def __len__(self) -> int:
        return 40 if self.poses is None else len(self.poses)

    def frame(self, index: int) -> np.ndarray:
        self.read[index] += 1
        return np.zeros((100 + index, 3))

    @property
    def gt_poses(self) -> np.ndarray | None:
        return self.poses

    def sizes(self) -> dict[int, int]:
        return {k: 100 + k for k in range(len(self))}


def oracle(sequence: PoseSequence, name: str = "oracle") -> TruthScaled:
    return TruthScaled(name, sequence.gt_poses, sequence.sizes(), scale=1.0, wrong_from=10**9)


class OneMetreOff(TruthScaled):
    """The true motion with 1 m added along the target's x axis."""

    def register(
        self, source: int, target: int, initial_guess: np.ndarray | None = None
    ) -> RegistrationResult:
        result = super().register(source, target, initial_guess)
        result.transform[0, 3] += 1.0
        return result


def test_oracle_succeeds_and_an_offset_fails() -> None:
    sequence = PoseSequence("square", square_loop())
    exact = oracle(sequence)
    off = OneMetreOff("off", sequence.gt_poses, sequence.sizes(), 1.0, 10**9)
    run = run_revisits(sequence, [exact, off], RevisitOptions(limit=20))
    assert len(run.pairs) == 20 and run.num_candidates > 20
    used = {f for p in run.pairs for f in (p.target, p.source)}
    assert sequence.read == Counter(used)  # each used frame read once, prepared once per method
    assert exact.prepared == off.prepared == Counter(used)

    good, bad = run.rows
    assert good.success_rate == 1.0 and good.errors.trans_rmse_m == pytest.approx(0.0, abs=1e-9)
    assert good.errors.rot_rmse_deg == pytest.approx(0.0, abs=1e-6)
    by_bin = good.success_by_bin()
    assert list(by_bin) == ["0-30", "30-60", "60-90"]
    assert by_bin["30-60"][0] == 0 and np.isnan(by_bin["30-60"][1])
    assert by_bin["0-30"] == (10, 1.0) and by_bin["60-90"] == (10, 1.0)
    assert bad.success_rate == 0.0 and bad.errors.trans_rmse_m == pytest.approx(1.0)
    assert bad.errors.rot_rmse_deg == pytest.approx(0.0, abs=1e-6)
    assert good.ms_per_pair > 0 and good.num_failed == 0

    table = markdown_table(run.rows)
    assert table.count("\n") == 1 + len(run.rows)
    assert "| square | off | 20 | 0 % | 0 % (10) | - (0) | 0 % (10) |" in table
    figures = run.to_dict()
    assert figures["rows"][0]["success_by_heading_deg"]["30-60"] == {"pairs": 0, "success_rate": None}


def test_pooling_weights_every_pair() -> None:
    square = PoseSequence("square", square_loop())
    turn = PoseSequence("u-turn", u_turn())
    rows = []
    for sequence in (square, turn):
        off = OneMetreOff("m", sequence.gt_poses, sequence.sizes(), 1.0, 10**9)
        rows += run_revisits(sequence, [off], RevisitOptions(limit=12)).rows
    rows[1] = run_revisits(turn, [oracle(turn, "m")], RevisitOptions(limit=12)).rows[0]
    (pooled,) = pool_rows(rows)
    assert pooled.sequence == "all" and pooled.num_pairs == rows[0].num_pairs + rows[1].num_pairs
    assert pooled.success_rate == pytest.approx(rows[1].num_pairs / pooled.num_pairs)
    assert pooled.prepare_ms_total == pytest.approx(rows[0].prepare_ms_total + rows[1].prepare_ms_total)


def test_no_truth_or_no_pair_names_the_way_out() -> None:
    with pytest.raises(ConfigError, match="ground-truth poses"):
        run_revisits(PoseSequence("blind", None), [oracle(PoseSequence("x", square_loop()))])
    sequence = PoseSequence("square", square_loop())
    with pytest.raises(ConfigError, match="--min-m/--max-m"):
        run_revisits(sequence, [oracle(sequence)], RevisitOptions(min_m=30.0, max_m=40.0))
    assert sequence.read == Counter()  # checked before any frame is read
