"""The frame loop's producer thread and the on-doubt consultation of the global registrar."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from vcr_odom.errors import DataError
from vcr_odom.metrics import trajectory_pair_errors
from vcr_odom.odometry import IcpPolish, KissIcpPolish, Odometry, build_odometry, run_odometry
from vcr_odom.odometry.chain import SECOND_START_AGREES, DoubtRule
from vcr_odom.registration.base import RegistrationResult
from vcr_odom.synth import SynthSequence


@pytest.fixture(scope="module")
def synth() -> SynthSequence:
    return SynthSequence(frames=18, seed=0)


class IndexedOracle:
    """The true motion of any pair of the sequence's frames, whichever pairs are asked for."""

    name = "oracle"
    needs_initial_guess = False

    def __init__(self, sequence: SynthSequence, interrupt_at_pair: int | None = None) -> None:
        self.index = {sequence.frame(i).tobytes(): i for i in range(len(sequence))}
        self.poses = sequence.gt_poses
        self.calls: list[tuple[int, int]] = []
        self.interrupt_at_pair = interrupt_at_pair

    def prepare(self, points: np.ndarray) -> int:
        return self.index[np.asarray(points).tobytes()]

    def register(
        self, source: int, target: int, initial_guess: np.ndarray | None = None
    ) -> RegistrationResult:
        self.calls.append((source, target))
        if len(self.calls) == self.interrupt_at_pair:
            raise KeyboardInterrupt
        return RegistrationResult(np.linalg.inv(self.poses[target]) @ self.poses[source])


@pytest.mark.parametrize("consult", ["every-frame", "on-doubt"])
def test_a_prefetched_run_equals_the_serial_run(synth: SynthSequence, consult: str) -> None:
    """The producer only loads and prepares; chaining stays in order, so the poses are the same (to
    float rounding: two serial runs already differ at 1e-15, from kiss-icp's and open3d's threaded sums)."""
    method = build_odometry("vcr+kiss-icp", device="cpu", consult=consult)
    serial = run_odometry(synth, method, range(8), prefetch=0)
    overlapped = run_odometry(synth, method, range(8), prefetch=2)
    np.testing.assert_allclose(overlapped.poses, serial.poses, rtol=0, atol=1e-9)
    assert [i.get("global") for i in overlapped.per_frame_info] == [
        i.get("global") for i in serial.per_frame_info
    ]
    assert "waiting" in overlapped.stage_seconds and "waiting" not in serial.stage_seconds


def test_on_doubt_asks_the_registrar_on_the_first_pair_only_when_the_prior_holds(
    synth: SynthSequence,
) -> None:
    oracle = IndexedOracle(synth)
    run = run_odometry(synth, Odometry(oracle, IcpPolish(), consult="on-doubt"), range(8))
    assert oracle.calls == [(1, 0)]
    assert [i["global"] for i in run.per_frame_info[1:]] == ["first pair"] + ["not needed"] * 6
    always = IndexedOracle(synth)
    run_odometry(
        synth, Odometry(always, IcpPolish(), consult="on-doubt", doubt=DoubtRule(ratio=2.0)), range(8)
    )
    assert always.calls == [(i, i - 1) for i in range(1, 8)]  # a fit is never twice the median


@pytest.mark.parametrize("polish", [IcpPolish, KissIcpPolish])
def test_a_prior_that_a_gap_in_the_frames_breaks_is_caught_by_its_fit(
    synth: SynthSequence, polish: type
) -> None:
    """Frames 4 -> 14 after steps of one frame: the constant-velocity prior is ~7 m short. Its
    polished result fits the scan poorly, so the registrar is asked, and the pair comes out right."""
    indices = [0, 1, 2, 3, 4, 14, 15, 16]
    oracle = IndexedOracle(synth)
    run = run_odometry(synth, Odometry(oracle, polish(), consult="on-doubt"), indices)
    assert (14, 4) in oracle.calls
    assert run.per_frame_info[5]["global"] != "not needed"
    errors = trajectory_pair_errors(run.poses, np.linalg.inv(synth.gt_poses[0]) @ synth.gt_poses[indices])
    assert errors.trans_errors_m.max() < 0.3


def test_ctrl_c_in_the_consumer_keeps_what_was_done_and_stops_the_producer(synth: SynthSequence) -> None:
    oracle = IndexedOracle(synth, interrupt_at_pair=5)
    run = run_odometry(synth, Odometry(oracle), range(12), prefetch=2)
    assert run.interrupted and run.frame_indices == [0, 1, 2, 3, 4]
    assert not any(thread.name == "odometry-producer" for thread in threading.enumerate())


def test_an_error_in_the_producer_reaches_the_caller(synth: SynthSequence) -> None:
    class BrokenFrame:
        name, timestamps, gt_poses, tr_velo_to_cam = "broken", synth.timestamps, synth.gt_poses, None

        def __len__(self) -> int:
            return len(synth)

        def frame(self, index: int) -> np.ndarray:
            if index == 5:
                raise DataError("frame 5: truncated file")
            return synth.frame(index)

    with pytest.raises(DataError, match="frame 5: truncated"):
        run_odometry(BrokenFrame(), Odometry(IndexedOracle(synth)), range(8), prefetch=2)
    assert not any(thread.name == "odometry-producer" for thread in threading.enumerate())


class ThreadCountingOracle(IndexedOracle):
    """Records torch's CPU thread count wherever the registrar works: prepare (the producer thread
    when the loop prepares ahead) and register (the consumer)."""

    def __init__(self, sequence: SynthSequence) -> None:
        super().__init__(sequence)
        self.threads: dict[str, set[int]] = {"prepare": set(), "register": set()}

    def prepare(self, points: np.ndarray) -> int:
        self.threads["prepare"].add(torch.get_num_threads())
        return super().prepare(points)

    def register(
        self, source: int, target: int, initial_guess: np.ndarray | None = None
    ) -> RegistrationResult:
        self.threads["register"].add(torch.get_num_threads())
        return super().register(source, target, initial_guess)


@pytest.mark.parametrize(
    ("consult", "prefetch", "shared"),
    [("every-frame", 2, True), ("every-frame", 0, False), ("on-doubt", 2, False)],
)
def test_the_two_threads_share_the_cores_only_where_both_run_the_registrar(
    synth: SynthSequence, consult: str, prefetch: int, shared: bool
) -> None:
    """With the network on every pair and the frames prepared ahead, the encoder (producer) and the
    pose head (consumer) run at once: each gets half of torch's threads, and the count is restored."""
    before = torch.get_num_threads()
    torch.set_num_threads(4)
    try:
        oracle = ThreadCountingOracle(synth)
        doubt = DoubtRule(ratio=2.0)  # on-doubt asks on every pair: both calls are seen
        run_odometry(
            synth, Odometry(oracle, IcpPolish(), consult=consult, doubt=doubt), range(5), prefetch=prefetch
        )
        expected = {2} if shared else {4}
        assert oracle.threads == {"prepare": expected, "register": expected}
        assert torch.get_num_threads() == 4
    finally:
        torch.set_num_threads(before)


def test_an_assumed_frame_rate_only_flags_motions_it_calls_implausible() -> None:
    """2 Hz keyframes ~9 m apart read as 10 Hz (no times file): 90 m/s "exceeds" the limits. With the
    rate assumed, the estimates are kept and flagged with a hint; the trajectory is the one the true
    times give, where nothing is flagged."""
    drive = SynthSequence(frames=8, seed=3, frame_period=0.5, speed=18.0)

    class AssumedRate:
        name, gt_poses, tr_velo_to_cam, timestamps_assumed = "assumed", drive.gt_poses, None, True
        timestamps = np.arange(len(drive)) * 0.1

        def __len__(self) -> int:
            return len(drive)

        def frame(self, index: int) -> np.ndarray:
            return drive.frame(index)

    method = build_odometry("vcr+icp", device="cpu", consult="every-frame")
    true_rate = run_odometry(drive, method, range(8))
    assumed = run_odometry(AssumedRate(), method, range(8))
    assert true_rate.flagged_frames == []
    np.testing.assert_allclose(assumed.poses, true_rate.poses, atol=1e-6)
    assert assumed.flagged_frames and all(
        "--times" in assumed.per_frame_info[i]["reason"] for i in assumed.flagged_frames
    )


@pytest.mark.parametrize("polish", [IcpPolish, KissIcpPolish])
def test_a_prior_far_from_its_polished_result_is_doubted_by_default(
    synth: SynthSequence, polish: type
) -> None:
    """Frames 4 -> 6 after steps of one frame: the constant-velocity prior is a frame (~1 m) short and
    the polish finds the way, so its fit gives no doubt; the correction it needed does, when asked to,
    unless (the default) the polish from standing still, a second start, ends in the same result."""
    indices = [0, 1, 2, 3, 4, 6, 7, 8]
    fit_only = DoubtRule(correction_m=0.0, correction_deg=0.0)
    trusting = run_odometry(
        synth, Odometry(IndexedOracle(synth), polish(), consult="on-doubt", doubt=fit_only), indices
    )
    assert trusting.per_frame_info[5]["global"] == "not needed"
    oracle = IndexedOracle(synth)
    one_start = DoubtRule(second_start=False)
    doubting = run_odometry(synth, Odometry(oracle, polish(), consult="on-doubt", doubt=one_start), indices)
    assert doubting.per_frame_info[5]["global"].startswith("far from the prior")
    assert (6, 4) in oracle.calls
    assert doubting.per_frame_info[7]["global"] == "not needed"  # steps of one frame again
    oracle = IndexedOracle(synth)
    confirmed = run_odometry(synth, Odometry(oracle, polish(), consult="on-doubt"), indices)  # the default
    assert confirmed.per_frame_info[5]["global"] == f"not needed: {SECOND_START_AGREES}"
    assert (6, 4) not in oracle.calls
    np.testing.assert_allclose(confirmed.poses, doubting.poses, atol=0.02)


def test_where_the_prior_is_mostly_in_doubt_every_pair_is_asked_until_it_holds_again(
    synth: SynthSequence,
) -> None:
    """Steps of two and one frames in turn: the constant-velocity prior is a frame off on every pair,
    so the checks doubt them all. When steps of one frame come back, the first pair the prior gets right
    is still asked (most of the window was in doubt); the asking ends as the window fills with pairs
    the prior got right, and never if that rule is off."""
    indices = [0, 2, 3, 5, 6, 8, 9, 10, 11, 12, 13, 14]
    reasons = {}
    for share in (0.5, 1.0):
        run = run_odometry(
            synth,
            Odometry(
                IndexedOracle(synth),
                IcpPolish(),
                consult="on-doubt",
                doubt=DoubtRule(window=4, share=share, second_start=False),
            ),
            indices,
        )
        reasons[share] = [info["global"] for info in run.per_frame_info[1:]]
    assert all(r.startswith("far from the prior") for r in reasons[0.5][1:6])
    assert reasons[0.5][6] == "most recent pairs in doubt (3 of 4)"
    assert reasons[0.5][7:] == ["not needed"] * 4
    assert reasons[1.0][6:] == ["not needed"] * 5
