"""The VCR registrar: batched inference gives the same trajectory as one pair at a time."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from vcr_odom.errors import ConfigError
from vcr_odom.model.config import VcrConfig
from vcr_odom.model.network import VCRNet
from vcr_odom.model.weights import save_weights
from vcr_odom.odometry import IcpPolish, Odometry, build_odometry, run_odometry
from vcr_odom.registration.vcr import VcrRegistrar
from vcr_odom.synth import SynthSequence

SMALL = VcrConfig(
    num_points=128, k=8, point_dim=16, graph_dim=16, spatial_dim=16, feature_dim=32, ff_dim=32, top_j=4
)


@pytest.fixture(scope="module")
def weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    return save_weights(tmp_path_factory.mktemp("w") / "small.safetensors", VCRNet(SMALL), SMALL)


@pytest.fixture(scope="module")
def synth() -> SynthSequence:
    return SynthSequence(frames=6, seed=2)


@pytest.mark.parametrize("refine", ["none", "icp"])
def test_batched_odometry_equals_one_pair_at_a_time(weights: Path, synth: SynthSequence, refine: str) -> None:
    """Batch 4 over 6 frames: one chunk that starts the sequence, one that continues it. (ICP runs from
    the network's estimate only: an untrained network's estimate and the last motion can tie on
    fitness, and which start wins a tie is not what this test is about.)"""

    def odometry(batch_size: int) -> Odometry:
        registrar = VcrRegistrar(weights, "cpu", batch_size=batch_size)
        return Odometry(registrar, IcpPolish(second_start=False) if refine == "icp" else None)

    single = run_odometry(synth, odometry(1), range(6))
    method = odometry(4)
    assert method.batch_size == 4
    batched = run_odometry(synth, method, range(6))
    np.testing.assert_allclose(batched.poses, single.poses, atol=1e-4)
    assert batched.frame_indices == single.frame_indices == list(range(6))
    assert len(batched.per_frame_info) == 6
    assert [bool(i.get("flagged")) for i in batched.per_frame_info] == [
        bool(i.get("flagged")) for i in single.per_frame_info
    ]


def test_an_n_point_cloud_is_used_as_it_is(weights: Path) -> None:
    registrar = VcrRegistrar(weights, "cpu")
    cloud = np.random.default_rng(0).uniform(-20, 20, size=(SMALL.num_points, 4)).astype(np.float32)
    prepared = registrar.prepare(cloud)
    np.testing.assert_array_equal(prepared.points[0].numpy(), cloud[:, :3])


def test_pre_processed_clouds_register_where_open3d_is_not_installed(weights: Path) -> None:
    """A GPU image may hold torch alone: clouds pre-processed elsewhere (benchmarks/device_agreement.py)
    must register there, and only pre-processing may need open3d."""
    script = f"""
import importlib.abc, sys
class NoOpen3d(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in ("open3d", "kiss_icp"):
            raise ModuleNotFoundError(f"No module named {{name!r}}")
sys.meta_path.insert(0, NoOpen3d())
import numpy as np
from vcr_odom.registration.vcr import VcrRegistrar
registrar = VcrRegistrar({str(weights)!r}, "cpu")
cloud = np.random.default_rng(0).uniform(-20, 20, size=({SMALL.num_points}, 3)).astype(np.float32)
source, target = registrar.encode_inputs([cloud, cloud])
print(registrar.register(source, target).transform.shape)
try:
    registrar.network_input(cloud[:-1])
except ModuleNotFoundError as error:
    print(error)
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["(4, 4)", "No module named 'open3d'"]


def test_a_sparse_frame_runs_on_the_points_it_has_not_on_repeated_ones(weights: Path) -> None:
    """A frame with fewer than N points (a near-empty scan) is fed as it is: no point repeated, which
    would give the kNN graphs zero-length edges; batches that mix it with full frames give what each
    pair gives alone, and the shipped model still measures the motion from it."""
    import warnings

    registrar = VcrRegistrar(weights, "cpu")
    rng = np.random.default_rng(1)
    sparse = rng.uniform(-20, 20, size=(90, 3)).astype(np.float32)  # N = 128, k = 8
    full = rng.uniform(-20, 20, size=(400, 3)).astype(np.float32)
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*padding")  # no point made up
        warnings.filterwarnings("ignore", message=".*ground")  # random clouds have none
        frames = registrar.prepare_batch([full, sparse, full + 1.0])
    assert [f.points.shape[1] for f in frames] == [128, 90, 128]
    assert frames[1].distinct_points == 90 and not registrar.too_few_points(frames[1])
    pairs = [(frames[1], frames[0]), (frames[2], frames[1]), (frames[2], frames[0])]
    batched = registrar.register_batch(pairs)
    alone = [registrar.register(source, target) for source, target in pairs]
    for together, single in zip(batched, alone, strict=True):
        np.testing.assert_allclose(together.transform, single.transform, atol=1e-5)


def test_a_sparse_network_input_is_encoded_as_it_is(weights: Path) -> None:
    """Loop verification turns a node's network input and encodes it: a cloud under N points must not
    be pre-processed again (its two warnings reached the console once per candidate)."""
    import warnings

    from vcr_odom.errors import DataWarning

    registrar = VcrRegistrar(weights, "cpu")
    sparse = np.random.default_rng(4).uniform(-20, 20, size=(90, 3)).astype(np.float32)  # N = 128
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*ground")  # the one pre-processing: random, no ground
        network_input = registrar.network_input(sparse)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        (frame,) = registrar.encode_inputs([network_input])
    np.testing.assert_array_equal(frame.points[0].numpy(), network_input)
    assert frame.distinct_points == 90


def test_the_point_count_can_be_chosen_at_inference_and_must_exceed_k(
    weights: Path, synth: SynthSequence
) -> None:
    """``--vcr-points``: the same tensors run on another number of points (the weights' own is the
    default); fewer than the kNN graphs need is refused by name."""
    own, fewer = VcrRegistrar(weights, "cpu"), VcrRegistrar(weights, "cpu", num_points=64)
    assert own.config.num_points == SMALL.num_points and fewer.config.num_points == 64
    assert fewer.prepare(synth.frame(0)).points.shape == (1, 64, 3)
    for name, tensor in own.model.state_dict().items():
        assert torch.equal(tensor, fewer.model.state_dict()[name]), name
    result = fewer.register(fewer.prepare(synth.frame(1)), fewer.prepare(synth.frame(0)))
    assert np.isfinite(result.transform).all()
    with pytest.raises(ConfigError, match=r"--vcr-points.*k = 8.*got 8"):
        VcrRegistrar(weights, "cpu", num_points=8)
    with pytest.raises(ConfigError, match=r"not inference settings: feature_dim"):
        fewer.use_inference_settings(feature_dim=64)
    fewer.use_inference_settings(input_max_range=30.0)
    assert fewer.preprocess_config.max_range == 30.0 and fewer.model.config.input_max_range == 30.0


def test_cpu_default_batch_is_one_and_bad_batch_is_refused(weights: Path) -> None:
    assert VcrRegistrar(weights, "cpu").batch_size == 1
    with pytest.raises(ConfigError, match="batch_size"):
        VcrRegistrar(weights, "cpu", batch_size=0)


def test_collapsed_correspondences_are_reported_degenerate() -> None:
    from vcr_odom.registration.vcr import MIN_CORRESPONDENCE_SPREAD, correspondence_spread

    rng = np.random.default_rng(0)
    spread_out = torch.as_tensor(rng.uniform(-20, 20, size=(1, 50, 3)))
    on_a_line = torch.as_tensor(np.outer(rng.uniform(-20, 20, 50), [1.0, 2.0, 0.5])[None])
    ratios = correspondence_spread(torch.cat([spread_out, on_a_line])).tolist()
    assert ratios[0] > 0.3 and ratios[1] < MIN_CORRESPONDENCE_SPREAD


def test_a_degenerate_pair_falls_back_to_the_previous_motion_and_is_flagged(synth: SynthSequence) -> None:
    from scripted_registrar import ScriptedRegistrar

    from vcr_odom.registration.base import DEGENERATE, RegistrationResult

    def degenerate_third_pair(pair: int, truth: np.ndarray) -> RegistrationResult:
        if pair == 3:  # plausible, but not an estimate
            return RegistrationResult(np.eye(4), info={"status": DEGENERATE})
        return RegistrationResult(truth)

    poses = synth.gt_poses
    run = run_odometry(synth, Odometry(ScriptedRegistrar(poses, degenerate_third_pair)), range(5))
    assert run.flagged_frames == [3]
    assert run.per_frame_info[3]["reason"] == DEGENERATE
    previous_motion = np.linalg.inv(poses[1]) @ poses[2]
    np.testing.assert_allclose(run.poses[3], run.poses[2] @ previous_motion, atol=1e-9)
    assert np.all(np.isfinite(run.poses))


def test_a_second_pass_registers_the_source_moved_by_the_first(weights: Path) -> None:
    """passes=2 is pass 1, then pass 1 again on the source moved by its estimate, composed."""
    rng = np.random.default_rng(3)
    source = rng.uniform(-20, 20, size=(SMALL.num_points, 3)).astype(np.float32)
    target = (source @ _yaw(0.3).T + np.array([1.0, -0.5, 0.1])).astype(np.float32)
    one_pass = VcrRegistrar(weights, "cpu", passes=1)
    first = one_pass.register(one_pass.prepare(source), one_pass.prepare(target)).transform
    moved = (source @ first[:3, :3].T + first[:3, 3]).astype(np.float32)
    second = one_pass.register(one_pass.prepare(moved), one_pass.prepare(target)).transform
    two_pass = VcrRegistrar(weights, "cpu", passes=2)
    result = two_pass.register(two_pass.prepare(source), two_pass.prepare(target))
    np.testing.assert_allclose(result.transform, second @ first, atol=1e-4)
    assert result.info["passes"] == 2
    with pytest.raises(ConfigError, match="passes"):
        VcrRegistrar(weights, "cpu", passes=0)


def test_the_factory_decides_the_passes_and_the_polish(weights: Path, tmp_path: Path) -> None:
    """Legacy xyz weights run two passes alone, one when polished; what the caller says wins."""
    legacy = SMALL.with_changes(encoder="xyz", distance_bias=False)
    path = save_weights(tmp_path / "xyz.safetensors", VCRNet(legacy), legacy, {})

    def passes(spec: str, **options: object) -> int:
        odometry = build_odometry(spec, device="cpu", **options)
        assert isinstance(odometry, Odometry)
        return odometry.registrar.passes

    assert passes("vcr+none", weights=path) == 2
    assert passes("vcr", weights=path) == passes("vcr+icp", weights=path) == 1
    assert passes("vcr+icp", weights=path, passes=3) == 3
    assert passes("vcr+none", weights=weights) == 1  # the invariant encoder: one pass alone too
    assert build_odometry("vcr", weights=weights, device="cpu").name == "vcr+kiss-icp"


def test_legacy_xyz_weights_run_two_passes_unpolished(tmp_path: Path) -> None:
    from vcr_odom.registration.vcr import DEFAULT_PASSES

    legacy = SMALL.with_changes(encoder="xyz", distance_bias=False)
    path = save_weights(tmp_path / "xyz.safetensors", VCRNet(legacy), legacy, {})
    assert VcrRegistrar(path, "cpu").passes == DEFAULT_PASSES == 2


def test_a_second_pass_of_the_invariant_model_changes_nothing(weights: Path) -> None:
    """Its features of the moved source are the same, so a second pass finds the same correspondences."""
    from test_invariance import street_like_cloud

    source = street_like_cloud(SMALL.num_points, seed=4)
    target = (source @ _yaw(0.2).T + np.array([2.0, -0.5, 0.1])).astype(np.float32)
    one, two = VcrRegistrar(weights, "cpu", passes=1), VcrRegistrar(weights, "cpu", passes=2)
    first = one.register(one.prepare(source), one.prepare(target)).transform
    second = two.register(two.prepare(source), two.prepare(target)).transform
    np.testing.assert_allclose(second, first, atol=5e-3)


def _yaw(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("passes", [1, 2])
def test_a_frames_self_attention_is_computed_once_and_changes_nothing(
    weights: Path, synth: SynthSequence, passes: int
) -> None:
    """A prepared frame carries its self-attention (it depends on the frame alone), so a frame that is
    the source of one pair and the target of the next is attended once; registering with it gives what
    the network computes from the encoded clouds alone."""
    import dataclasses

    registrar = VcrRegistrar(weights, "cpu", passes=passes)
    frames = [registrar.prepare(synth.frame(i)) for i in range(3)]
    assert all(frame.attended is not None for frame in frames)
    calls = 0
    attend = registrar.model.attend

    def counted(*args: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        nonlocal calls
        calls += 1
        return attend(*args)

    registrar.model.attend = counted  # type: ignore[method-assign]
    cached = [registrar.register(frames[i], frames[i - 1]).transform for i in (1, 2)]
    assert calls == 2 * (passes - 1)  # only the moved source of a later pass is attended again
    bare = [dataclasses.replace(frame, attended=None) for frame in frames]
    recomputed = [registrar.register(bare[i], bare[i - 1]).transform for i in (1, 2)]
    np.testing.assert_allclose(np.stack(cached), np.stack(recomputed), atol=1e-6)
