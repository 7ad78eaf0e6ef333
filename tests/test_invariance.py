"""What the invariant encoder promises: features unchanged by moving the cloud, and an estimate that
moves with the target (the property whose absence shrank every motion towards zero)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from vcr_odom.geometry import invert, make_transform, rotation_from_euler_zyx
from vcr_odom.model import VCRNet
from vcr_odom.model.config import VcrConfig
from vcr_odom.model.invariant_encoder import symmetric_eigen
from vcr_odom.model.weights import default_weights_path, load_weights

MOTIONS = [
    ((5.0, 0.0, 0.0), 0.0),
    ((14.0, -14.0, 0.7), 0.0),
    ((0.0, 0.0, 0.0), 30.0),
    ((-12.0, 9.0, -0.4), -75.0),
]


def street_like_cloud(n: int, seed: int) -> np.ndarray:
    """Walls, poles and car-sized boxes around the origin: structure without exact distance ties."""
    rng = np.random.default_rng(seed)
    wall = np.column_stack([rng.uniform(-30, 30, n // 2), np.full(n // 2, 8.0), rng.uniform(-1.5, 6, n // 2)])
    wall[:, 1] += rng.normal(0, 0.05, n // 2)
    poles = np.concatenate(
        [
            np.column_stack([np.full(n // 8, x), np.full(n // 8, y), rng.uniform(-1.5, 5, n // 8)])
            for x, y in [(-12.0, -6.0), (3.0, -7.0), (15.0, -5.5), (25.0, 4.0)]
        ]
    )
    poles[:, :2] += rng.normal(0, 0.08, (len(poles), 2))
    rest = n - len(wall) - len(poles)
    boxes = rng.uniform([-20, -6, -1.5], [20, 5, 0.0], (rest, 3))
    return np.concatenate([wall, poles, boxes]).astype(np.float32)


def moved(points: np.ndarray, shift: tuple[float, float, float], yaw_deg: float) -> np.ndarray:
    motion = make_transform(rotation_from_euler_zyx(math.radians(yaw_deg), 0.0, 0.0), shift)
    return (points.astype(np.float64) @ motion[:3, :3].T + motion[:3, 3]).astype(np.float32)


@pytest.mark.parametrize(("shift", "yaw_deg"), MOTIONS)
def test_invariant_encoder_features_do_not_change_when_the_cloud_moves(shift, yaw_deg) -> None:
    torch.manual_seed(0)
    net = VCRNet(VcrConfig(num_points=256)).eval()
    cloud = street_like_cloud(256, seed=1)
    with torch.no_grad():
        base = net.encode(torch.as_tensor(cloud)[None])
        after = net.encode(torch.as_tensor(moved(cloud, shift, yaw_deg))[None])
    assert base.abs().max() > 0.1  # the features are not trivially zero
    torch.testing.assert_close(after, base, rtol=1e-4, atol=1e-4)


def test_xyz_encoder_features_do_change_when_the_cloud_moves() -> None:
    """The legacy encoder (absolute xyz) as the counter-example the invariance test must tell apart."""
    torch.manual_seed(0)
    net = VCRNet(VcrConfig(num_points=256, encoder="xyz", distance_bias=False)).eval()
    cloud = street_like_cloud(256, seed=1)
    with torch.no_grad():
        base = net.encode(torch.as_tensor(cloud)[None])
        after = net.encode(torch.as_tensor(moved(cloud, (5.0, 0.0, 0.0), 0.0))[None])
    assert float((after - base).norm() / base.norm()) > 0.02


def test_attention_with_distance_bias_is_invariant_too() -> None:
    torch.manual_seed(0)
    net = VCRNet(VcrConfig(num_points=256)).eval()
    with torch.no_grad():  # a non-zero distance bias, so that the test sees it
        net.self_attention.distance_bias.mix.weight.normal_(0.0, 1.0)
    cloud = street_like_cloud(256, seed=2)
    other = moved(cloud, (14.0, -14.0, 0.7), 40.0)
    with torch.no_grad():
        features = net.encode(torch.as_tensor(cloud)[None])
        psi, weight = net.self_attention(features, torch.as_tensor(cloud)[None])
        psi_moved, weight_moved = net.self_attention(features, torch.as_tensor(other)[None])
    torch.testing.assert_close(psi_moved, psi, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(weight_moved, weight, rtol=1e-4, atol=1e-4)


def test_legacy_weight_files_keep_their_encoder_and_pipeline(tmp_path) -> None:
    """A file written before the invariant encoder has no ``encoder`` field: it must load as what it was."""
    config = VcrConfig.from_dict(
        {
            k: v
            for k, v in VcrConfig().to_dict().items()
            if k not in ("encoder", "distance_bias", "input_max_range", "robust_iterations")
        }
    )
    assert (config.encoder, config.distance_bias, config.input_max_range, config.robust_iterations) == (
        "xyz",
        False,
        80.0,
        0,
    )


# ------------------------------------------------------------------------- shipped weights, real use


@pytest.fixture(scope="module")
def shipped_pair():
    """The shipped registrar and two frames of an unseen synthetic drive 5 frames (~5 m) apart."""
    from vcr_odom.registration.vcr import VcrRegistrar
    from vcr_odom.synth import SynthSequence

    torch.set_num_threads(1)
    registrar = VcrRegistrar(device="cpu", passes=1)
    sequence = SynthSequence(frames=6, seed=101)
    source = registrar.network_input(sequence.frame(5))
    target = registrar.network_input(sequence.frame(0))
    truth = invert(sequence.gt_poses[0]) @ sequence.gt_poses[5]
    return registrar, source, target, truth


@pytest.mark.parametrize(("shift", "yaw_deg"), MOTIONS)
def test_shipped_estimate_moves_with_the_target(shipped_pair, shift, yaw_deg) -> None:
    """Moving the target cloud by M must turn the estimate T into M @ T (within a few cm / 0.05°)."""
    registrar, source, target, _ = shipped_pair
    estimate = registrar.register(registrar.prepare(source), registrar.prepare(target)).transform
    motion = make_transform(rotation_from_euler_zyx(math.radians(yaw_deg), 0.0, 0.0), shift)
    moved_target = registrar.prepare(moved(target, shift, yaw_deg))
    after = registrar.register(registrar.prepare(source), moved_target).transform
    expected = motion @ estimate
    assert np.linalg.norm(after[:3, 3] - expected[:3, 3]) < 0.03
    cos = (np.trace(expected[:3, :3].T @ after[:3, :3]) - 1.0) / 2.0
    assert math.degrees(math.acos(min(1.0, cos))) < 0.05


def test_shipped_weights_measure_a_5_m_motion(shipped_pair) -> None:
    """Not shrunk towards zero: the estimated length within 5 % of the truth, error < 0.5 m / 1°."""
    registrar, source, target, truth = shipped_pair
    estimate = registrar.register(registrar.prepare(source), registrar.prepare(target)).transform
    length = np.linalg.norm(truth[:3, 3])
    assert length > 3.0
    assert abs(np.linalg.norm(estimate[:3, 3]) / length - 1.0) < 0.05
    assert np.linalg.norm(estimate[:3, 3] - truth[:3, 3]) < 0.5


@pytest.mark.filterwarnings("ignore::vcr_odom.errors.DataWarning")
def test_shipped_weights_measure_10_m_from_sparse_frames_on_the_points_they_have() -> None:
    """Two scans of an unseen drive ~10 m apart, cut to 300 points each (a near-empty scan; the file
    runs on 1024): the network runs on those 300 and measures the motion (0.04 m / 0.35° measured).
    Repeating points up to 1024, as inference once did, put this estimate 14.5 m off (and turned it
    by 178° with the file before the old-town fine-tune)."""
    from vcr_odom.preprocess import preprocess
    from vcr_odom.registration.vcr import VcrRegistrar
    from vcr_odom.synth import SynthSequence

    torch.set_num_threads(1)
    registrar = VcrRegistrar(device="cpu", passes=1)
    sequence = SynthSequence(frames=11, seed=101)
    sparse = registrar.preprocess_config.with_changes(n_points=300)
    source = registrar.prepare(preprocess(sequence.frame(10), sparse))
    target = registrar.prepare(preprocess(sequence.frame(0), sparse))
    assert source.points.shape[1] == target.points.shape[1] == 300
    estimate = registrar.register(source, target).transform
    truth = invert(sequence.gt_poses[0]) @ sequence.gt_poses[10]
    assert np.linalg.norm(truth[:3, 3]) > 8.0
    assert np.linalg.norm(estimate[:3, 3] - truth[:3, 3]) < 0.3
    cos = (np.trace(truth[:3, :3].T @ estimate[:3, :3]) - 1.0) / 2.0
    assert math.degrees(math.acos(min(1.0, cos))) < 1.0


def test_shipped_weights_do_not_turn_round_on_an_old_town_street_that_looks_alike_both_ways() -> None:
    """An OS1-128 old-town pair ~10 m apart (tuning drive 401, frames 4 and 14), where about 5 % of the
    virtual points are right: the pose head's 256 random triples settle on a motion turned by 180°
    (7.8 m off); the compatible seeds find the true one (0.26 m / 1.2° measured)."""
    from vcr_odom.registration.vcr import VcrRegistrar
    from vcr_odom.synth import SynthSequence

    torch.set_num_threads(1)
    sequence = SynthSequence(frames=15, seed=401, sensor="os128", speed=10.0, scene="oldtown")
    registrar = VcrRegistrar(device="cpu", passes=1)
    source, target = registrar.prepare(sequence.frame(14)), registrar.prepare(sequence.frame(4))
    truth = invert(sequence.gt_poses[4]) @ sequence.gt_poses[14]

    def errors() -> tuple[float, float]:
        estimate = registrar.register(source, target).transform
        cos = (np.trace(truth[:3, :3].T @ estimate[:3, :3]) - 1.0) / 2.0
        return float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3])), math.degrees(
            math.acos(max(-1.0, min(1.0, cos)))
        )

    shipped_m, shipped_deg = errors()
    registrar.use_inference_settings(consensus_seeds=0, gated_rounds=2)  # the head before the seeds
    _, before_deg = errors()
    assert np.linalg.norm(truth[:3, 3]) > 9.0
    assert shipped_m < 0.5 and shipped_deg < 2.0
    assert before_deg > 90.0


@pytest.mark.filterwarnings("ignore:.*no timestamps:vcr_odom.errors.DataWarning")
def test_shipped_weights_measure_10_m_motions_on_unseen_real_scans(kitti_sample_root) -> None:
    """Issue 9's hardest item, on the KITTI sample's test block (frames 40-59, never trained or tuned
    on): VCR alone, one pass, every pair 10 frames (~10 m) apart. Measured 100 % success, length ratio
    0.987, 0.27° / 0.14 m RMSE (0.980, 0.26° / 0.24 m before the gated re-pointing, the old-town
    fine-tune and the compatible seeds); with 512 input points that earlier file got 40 % and 0.763."""
    from vcr_odom.data import open_sequence
    from vcr_odom.evaluation.gap_sweep import run_gap_sweep
    from vcr_odom.registration.vcr import VcrRegistrar

    torch.set_num_threads(1)
    sequence = open_sequence("00", data_root=kitti_sample_root)
    (row,) = run_gap_sweep(sequence, range(40, 60), [VcrRegistrar(device="cpu", passes=1)], [10]).rows
    assert row.num_pairs == 10
    assert row.errors.success_rate >= 0.9
    assert 0.95 <= row.length_ratio <= 1.05
    assert row.errors.rot_rmse_deg <= 0.6 and row.errors.trans_rmse_m <= 0.6


def test_the_legacy_xyz_file_loads_as_it_was_and_fails_the_equivariance_property(shipped_pair) -> None:
    """The weights shipped before the invariant encoder (kept for the model card's before figures):
    still loadable, run as trained (xyz encoder, 80 m input, two passes), and their estimate does not
    follow a moved target, which is what the property tests above catch."""
    from vcr_odom.registration.vcr import VcrRegistrar

    path = default_weights_path("default").parent / "legacy" / "vcr-default-xyz.safetensors"
    legacy = VcrRegistrar(path, device="cpu")
    assert (legacy.config.encoder, legacy.config.input_max_range, legacy.passes) == ("xyz", 80.0, 2)
    legacy.passes = 1
    _, source, target, _ = shipped_pair
    estimate = legacy.register(legacy.prepare(source), legacy.prepare(target)).transform
    shift = np.array([5.0, 0.0, 0.0])
    after = legacy.register(
        legacy.prepare(source), legacy.prepare(target + shift.astype(np.float32))
    ).transform
    assert np.linalg.norm(after[:3, 3] - (estimate[:3, 3] + shift)) > 0.5


def test_shipped_default_is_the_invariant_model() -> None:
    _, config, _ = load_weights(default_weights_path("default"))
    assert config.encoder == "invariant"


def _covariances(seed: int = 0) -> torch.Tensor:
    points = torch.as_tensor(np.random.default_rng(seed).normal(size=(2, 64, 20, 3)))
    centred = points - points.mean(dim=2, keepdim=True)
    return centred.transpose(-1, -2) @ centred / 20


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_a_failing_cuda_eigen_solver_falls_back_to_the_cpu(monkeypatch: pytest.MonkeyPatch) -> None:
    solve = torch.linalg.eigh

    def failing_on_cuda(matrices: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if matrices.is_cuda:
            raise RuntimeError("cusolver error: CUSOLVER_STATUS_INTERNAL_ERROR")
        return solve(matrices)

    covariances = _covariances()
    expected_values, expected_vectors = solve(covariances)
    monkeypatch.setattr(torch.linalg, "eigh", failing_on_cuda)
    values, vectors = symmetric_eigen(covariances.cuda())
    assert values.is_cuda and vectors.is_cuda
    torch.testing.assert_close(values.cpu(), expected_values)
    torch.testing.assert_close(vectors.abs().cpu(), expected_vectors.abs())
