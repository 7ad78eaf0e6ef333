"""The loop closure's pose-graph parts against independent references: the odometry's propagated
uncertainty against a Monte Carlo of the same chain, pairwise consistency, the variance component the
loops measure, the chi-square gate of the candidates, the settings file and the map command's use of it."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from vcr_odom.cli.main import cli
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import invert, make_transform, rotation_from_euler_zyx, twist
from vcr_odom.loops.candidates import Chain, find_candidates
from vcr_odom.loops.graph import LoopEdge, consistent_loops, odometry_scale, optimise, select_loops
from vcr_odom.loops.nodes import Node
from vcr_odom.loops.settings import LoopSettings

EXACT = np.diag([1e8] * 3 + [1e8] * 3)
"""A loop measured so well that its own uncertainty is nothing against the odometry's."""


def _random_covariance(rng: np.random.Generator, sigma_rad: float, sigma_m: float) -> np.ndarray:
    """A full (correlated, anisotropic) 6x6 covariance, rotation then translation, of about the sigmas."""
    scales = np.array([sigma_rad] * 3 + [sigma_m] * 3) * rng.uniform(0.5, 1.5, 6)
    mixing = np.eye(6) + 0.4 * rng.normal(size=(6, 6))
    root = mixing * scales[:, None]
    return root @ root.T


def _path(rng: np.random.Generator, count: int) -> np.ndarray:
    """Node poses of a winding, climbing drive that starts far from the world's origin (lever arms)."""
    poses = [make_transform(rotation_from_euler_zyx(0.5, 0.05, -0.03), [120.0, -40.0, 8.0])]
    for _ in range(count - 1):
        yaw, pitch, roll = rng.normal(0, 0.2), rng.normal(0, 0.03), rng.normal(0, 0.03)
        step = make_transform(rotation_from_euler_zyx(yaw, pitch, roll), [rng.uniform(2.0, 4.0), 0.0, 0.0])
        poses.append(poses[-1] @ step)
    return np.stack(poses)


def _perturbation(errors: np.ndarray) -> np.ndarray:
    """Per sample, the transform of a small error (rotation vector, translation): ``N x 4 x 4``."""
    out = np.tile(np.eye(4), (len(errors), 1, 1))
    out[:, :3, :3] = Rotation.from_rotvec(errors[:, :3]).as_matrix()
    out[:, :3, 3] = errors[:, 3:]
    return out


def _sampled_chains(poses: np.ndarray, covariances: list[np.ndarray], samples: int, rng) -> np.ndarray:
    """``samples`` x nodes x 4 x 4: each edge's motion with an error drawn from its covariance applied
    on its first node's side (``T_k_k+1 <- exp(xi) T_k_k+1``, xi in node k's frame), composed from the
    first node (held where it is)."""
    chains = np.empty((samples, len(poses), 4, 4))
    chains[:, 0] = poses[0]
    for k, cov in enumerate(covariances):
        motion = invert(poses[k]) @ poses[k + 1]
        errors = rng.multivariate_normal(np.zeros(6), cov, size=samples)
        chains[:, k + 1] = chains[:, k] @ _perturbation(errors) @ motion
    return chains


def _world_errors(sampled: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Per sample, the world-frame error of a node: ``twist(sampled @ inv(pose))``."""
    return np.stack([twist(s @ invert(pose)) for s in sampled])


def _relative_spread(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The eigenvalues of ``estimate`` whitened by ``reference`` (all 1 where they agree)."""
    values, vectors = np.linalg.eigh(reference)
    whiten = vectors / np.sqrt(values)
    return np.linalg.eigvalsh(whiten.T @ estimate @ whiten)


def test_the_chains_covariance_between_two_nodes_is_a_monte_carlo_of_the_same_chain() -> None:
    rng = np.random.default_rng(0)
    poses = _path(rng, 10)
    covariances = [_random_covariance(rng, 0.004, 0.04) for _ in range(len(poses) - 1)]
    chain = Chain(poses, [np.linalg.inv(cov) for cov in covariances])
    sampled = _sampled_chains(poses, covariances, 8000, rng)

    # node 9 against node 0 (held): every edge's error, moved to the world by its node's pose
    errors = _world_errors(sampled[:, 9], poses[9])
    reference = np.cov(errors.T)
    spread = _relative_spread(chain.world_covariance(0, 9), reference)
    assert spread.min() > 0.9 and spread.max() < 1.1, spread
    assert chain.world_covariance(9, 0) == pytest.approx(chain.world_covariance(0, 9))

    # node 8 against node 3: the error node 8 gathers after node 3, in the world frame
    after_three = np.stack(
        [
            twist(s8 @ invert(poses[8]) @ invert(s3 @ invert(poses[3])))
            for s3, s8 in zip(sampled[:, 3], sampled[:, 8], strict=True)
        ]
    )
    spread = _relative_spread(chain.world_covariance(3, 8), np.cov(after_three.T))
    assert spread.min() > 0.9 and spread.max() < 1.1, spread
    # the squared Mahalanobis distances of the samples average the dimensions (6)
    mean_chi2 = np.mean(
        np.einsum("ij,ij->i", after_three, np.linalg.solve(chain.world_covariance(3, 8), after_three.T).T)
    )
    assert mean_chi2 == pytest.approx(6.0, rel=0.05)

    # two loops' corrections share the drift of the edges both span: their difference is the rest
    def drift(first: int, second: int) -> np.ndarray:
        return np.stack(
            [
                twist(b @ invert(poses[second]) @ invert(a @ invert(poses[first])))
                for a, b in zip(sampled[:, first], sampled[:, second], strict=True)
            ]
        )

    difference = drift(1, 7) - drift(4, 9)
    spread = _relative_spread(chain.between((1, 7), (4, 9)), np.cov(difference.T))
    assert spread.min() > 0.9 and spread.max() < 1.1, spread
    disjoint = drift(0, 3) - drift(5, 8)
    spread = _relative_spread(chain.between((5, 8), (0, 3)), np.cov(disjoint.T))
    assert spread.min() > 0.9 and spread.max() < 1.1, spread


def _lap(rng: np.random.Generator, covariance: np.ndarray, factor: float = 1.0):
    """True node poses of a lap and a half of 40 m radius, and an odometry whose every edge erred by a
    draw of ``factor`` times ``covariance`` (the chain's own model of it)."""
    count = 60
    step = make_transform(
        rotation_from_euler_zyx(2 * math.pi / count, 0, 0), [2 * math.pi * 40.0 / count, 0, 0]
    )
    truth = [np.eye(4)]
    for _ in range(count + count // 2):
        truth.append(truth[-1] @ step)
    truth = np.stack(truth)
    errors = rng.multivariate_normal(np.zeros(6), factor * covariance, size=len(truth) - 1)
    odometry = [truth[0]]
    for k, error in enumerate(errors):
        odometry.append(odometry[-1] @ _perturbation(error[None])[0] @ invert(truth[k]) @ truth[k + 1])
    return truth, np.stack(odometry)


def test_consistent_loops_keep_the_loops_that_agree_and_leave_out_a_look_alike() -> None:
    rng = np.random.default_rng(1)
    covariance = np.diag([math.radians(0.05) ** 2] * 3 + [0.03**2] * 3)
    truth, odometry = _lap(rng, covariance)
    chain = Chain(odometry, [np.linalg.inv(covariance)] * (len(odometry) - 1))
    right = [LoopEdge(j, j - 60, invert(truth[j - 60]) @ truth[j], EXACT) for j in range(60, 90, 4)]
    block_away = make_transform(np.eye(3), [12.0, 0, 0])  # a look-alike place 12 m further on
    false = LoopEdge(75, 15, block_away @ invert(truth[15]) @ truth[75], EXACT)
    for position in (0, 3, len(right)):
        loops = [*right[:position], false, *right[position:]]
        kept, contested, distances = consistent_loops(loops, chain, 0.999)
        assert kept == [loop is not false for loop in loops] and contested == kept
        gate = chi2.ppf(0.999, 6)
        rights = [k for k, loop in enumerate(loops) if loop is not false]
        assert (distances[np.ix_(rights, rights)] <= gate).all()
        assert (distances[position, rights] > gate).all()
        assert np.allclose(distances, distances.T) and np.all(np.diag(distances) == 0)
    # the odometry itself, asked nothing: two loops that agree with it are consistent
    odometry_loops = [LoopEdge(j, j - 60, invert(odometry[j - 60]) @ odometry[j], EXACT) for j in (62, 70)]
    kept, _, distances = consistent_loops(odometry_loops, chain, 0.999)
    assert kept == [True, True] and distances[0, 1] < 1e-6


def test_two_equally_large_sets_that_disagree_keep_neither_and_the_loops_both_hold_stay() -> None:
    """A right loop and a look-alike alone: nothing says which is right, so neither is kept (keeping the
    first would be a coin toss); loops every largest set holds stay."""
    rng = np.random.default_rng(1)
    covariance = np.diag([math.radians(0.05) ** 2] * 3 + [0.03**2] * 3)
    truth, odometry = _lap(rng, covariance)
    chain = Chain(odometry, [np.linalg.inv(covariance)] * (len(odometry) - 1))
    right = LoopEdge(80, 20, invert(truth[20]) @ truth[80], EXACT)
    false = LoopEdge(75, 15, make_transform(np.eye(3), [12.0, 0, 0]) @ invert(truth[15]) @ truth[75], EXACT)
    for loops in ([right, false], [false, right]):
        kept, contested, _ = consistent_loops(loops, chain, 0.999)
        assert kept == [False, False] and contested == [True, True]
        verdicts = select_loops(loops, chain, LoopSettings()).verdicts
        assert all(v is not None and v[0] == "inconsistent" for v in verdicts)
    # two more right loops make the right set the largest: the look-alike alone is left out
    more = [LoopEdge(j, j - 60, invert(truth[j - 60]) @ truth[j], EXACT) for j in (70, 86)]
    kept, _, _ = consistent_loops([false, right, *more], chain, 0.999)
    assert kept == [False, True, True, True]


def test_the_graph_weighs_each_loop_along_the_axes_its_fit_measured_in_the_earlier_nodes_frame() -> None:
    """Two loops onto node 0 (a fit's information is on the target's frame) that each hold one
    direction well, with node 1 turned a quarter: the solve lands on their information-weighted mean,
    the closed form for loops that differ only in translation."""
    turned = make_transform(rotation_from_euler_zyx(math.pi / 2, 0.0, 0.0), [5.0, 0.0, 0.0])
    holds_x = np.diag([1e4] * 3 + [1e4, 1.0, 1e4])
    holds_y = np.diag([1e4] * 3 + [1.0, 1e4, 1e4])
    measured = {"x": (5.0, 0.0, 0.0), "y": (6.0, 1.0, 0.0)}
    loops = [
        LoopEdge(1, 0, make_transform(turned[:3, :3], measured[axis]), held)
        for axis, held in (("x", holds_x), ("y", holds_y))
    ]
    odometry_free = [np.eye(6) * 1e-9]
    after = optimise(np.stack([np.eye(4), turned]), odometry_free, loops)
    weights = holds_x[3:, 3:] + holds_y[3:, 3:]
    expected = np.linalg.solve(weights, holds_x[3:, 3:] @ measured["x"] + holds_y[3:, 3:] @ measured["y"])
    assert np.allclose(after[1][:3, 3], expected, atol=1e-3), (after[1][:3, 3], expected)
    assert np.allclose(after[1][:3, :3], turned[:3, :3], atol=1e-6)


@pytest.mark.parametrize("factor", [0.25, 4.0])
def test_the_odometry_scale_is_the_factor_its_errors_were_drawn_with(factor: float) -> None:
    """Loops over disjoint stretches of an odometry whose edges erred by ``factor`` times the chain's
    covariance: the median of their chi-square (6 dof) puts the factor back (about: 150 loops)."""
    rng = np.random.default_rng(2)
    covariance = np.diag([0.002**2] * 3 + [0.02**2] * 3)
    count = 150 * 6 + 1
    truth = _path(rng, count)
    errors = rng.multivariate_normal(np.zeros(6), factor * covariance, size=count - 1)
    odometry = [truth[0]]
    for k, error in enumerate(errors):
        odometry.append(odometry[-1] @ _perturbation(error[None])[0] @ invert(truth[k]) @ truth[k + 1])
    odometry = np.stack(odometry)
    chain = Chain(odometry, [np.linalg.inv(covariance)] * (count - 1))
    loops = [LoopEdge(i + 5, i, invert(truth[i]) @ truth[i + 5], EXACT) for i in range(0, count - 6, 6)]
    assert odometry_scale(loops, chain) == pytest.approx(factor, rel=0.2)
    assert odometry_scale([], chain) == 1.0


def _straight_and_back(offset_m: float) -> list[Node]:
    """Out 120 m along x, then back along x ``offset_m`` to the side, a node every 3 m."""
    out = [make_transform(np.eye(3), [3.0 * k, 0.0, 0.0]) for k in range(41)]
    back = [
        make_transform(rotation_from_euler_zyx(math.pi, 0, 0), [3.0 * k, offset_m, 0.0])
        for k in range(40, -1, -1)
    ]
    path = 0.0
    nodes = []
    for k, pose in enumerate(out + back):
        if k:
            path += float(np.linalg.norm(pose[:3, 3] - nodes[-1].pose[:3, 3]))
        nodes.append(Node(k, k, pose, path, np.zeros((0, 3), np.float32)))
    return nodes


def _translation_chain(nodes: list[Node], sigma_m: float) -> Chain:
    """Each edge uncertain by ``sigma_m`` in translation (isotropic) and by nothing in rotation: the
    position covariance between two nodes is then (edges between) x sigma^2, whatever the path."""
    info = np.diag([1e14] * 3 + [sigma_m**-2] * 3)
    return Chain(np.stack([node.pose for node in nodes]), [info] * (len(nodes) - 1))


def test_candidates_are_gated_by_the_odometrys_propagated_uncertainty() -> None:
    settings = LoopSettings()
    near = _straight_and_back(3.0)
    found = find_candidates(near, _translation_chain(near, 0.01), settings)
    assert found, "the way back, a lane from the way out, revisits it"
    for candidate in found:
        assert candidate.source > 40 >= candidate.target
        assert near[candidate.source].path_m - near[candidate.target].path_m >= settings.min_loop_path_m
        assert candidate.sigma_m == pytest.approx(
            0.01 * math.sqrt(candidate.source - candidate.target), rel=1e-3
        )
        assert candidate.distance_m == pytest.approx(
            np.linalg.norm(near[candidate.source].pose[:3, 3] - near[candidate.target].pose[:3, 3])
        )
        np.testing.assert_allclose(
            candidate.prior, invert(near[candidate.target].pose) @ near[candidate.source].pose, atol=1e-12
        )
    far = _straight_and_back(60.0)  # another street 60 m away
    assert find_candidates(far, _translation_chain(far, 0.01), settings) == [], (
        "certain: never the same place"
    )
    uncertain = find_candidates(far, _translation_chain(far, 5.0), settings)  # sigma 30-45 m there
    assert uncertain, "an odometry that uncertain may have come back to the way out"
    assert all(c.sigma_m == pytest.approx(5.0 * math.sqrt(c.source - c.target), rel=1e-3) for c in uncertain)
    assert (
        find_candidates(far, _translation_chain(far, 5.0), settings.with_changes(candidate_confidence=0.2))
        == []
    )


def test_loop_settings_round_trip_through_their_toml_file(tmp_path: Path) -> None:
    path = tmp_path / "loops.toml"
    for settings in (
        LoopSettings(),
        LoopSettings(revisit_radius_m=7.5, passage_attempts=3, ground_up=False, candidate_confidence=0.95),
    ):
        path.write_text(settings.dump_toml())
        assert LoopSettings(**LoopSettings.from_toml(path)) == settings
    text = LoopSettings().dump_toml()
    assert all(f"\n{name} = " in text for name in LoopSettings.model_fields)
    path.write_text("passage_attempts = 4\n")
    assert LoopSettings.from_toml(path) == {"passage_attempts": 4}, "only what the file sets"


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("max_heading_drift = 2.0\n", "unknown setting(s) max_heading_drift"),
        ("revisit_radius_m = -1\n", "revisit_radius_m"),
        ('ground_up = "maybe"\n', "ground_up"),
        ("passage_attempts = [\n", "not a readable TOML file"),
        (None, "no such file"),
    ],
    ids=["unknown", "out of range", "bad type", "bad toml", "missing"],
)
def test_a_bad_settings_file_is_refused_naming_it(tmp_path: Path, text: str | None, says: str) -> None:
    path = tmp_path / "loops.toml"
    if text is not None:
        path.write_text(text)
    with pytest.raises(ConfigError) as caught:
        LoopSettings.from_toml(path)
    assert str(path) in str(caught.value) and says in str(caught.value)


def test_map_dumps_a_config_it_accepts_and_its_options_win_over_the_file(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    runner = CliRunner()
    dumped = runner.invoke(cli, ["map", "--dump-config"])
    assert dumped.exit_code == 0, dumped.output
    assert LoopSettings(**_parse(dumped.output)) == LoopSettings()
    config = tmp_path / "loops.toml"
    config.write_text(dumped.output)
    again = runner.invoke(cli, ["map", "--config", str(config), "--dump-config"])
    assert again.exit_code == 0 and again.output == dumped.output, again.output

    config.write_text("passage_attempts = 3\ncandidate_confidence = 0.95\nrevisit_radius_m = 7.5\n")
    chosen = runner.invoke(cli, ["map", "--config", str(config), "--passage-attempts", "9", "--dump-config"])
    assert chosen.exit_code == 0, chosen.output
    chosen_here = {"passage_attempts": 9, "candidate_confidence": 0.95, "revisit_radius_m": 7.5}
    assert _parse(chosen.output).items() >= chosen_here.items()

    args = ["map", "--data-root", str(small_synthetic_root), "--seq", "00", "--frames", "0:3"]
    result = runner.invoke(
        cli,
        [*args, "--results-dir", str(tmp_path / "out"), "--config", str(config), "--passage-attempts", "9"],
    )
    assert result.exit_code == 0, result.output
    (folder,) = [p for p in (tmp_path / "out").iterdir() if p.is_dir() and p.name.startswith("20")]
    saved = json.loads((folder / "config.json").read_text())["config"]
    assert saved.items() >= chosen_here.items()
    assert set(LoopSettings.model_fields) <= set(saved), "every loop setting is in config.json"

    config.write_text("max_heading_drift = 2\n")
    refused = runner.invoke(cli, [*args, "--results-dir", str(tmp_path / "no"), "--config", str(config)])
    assert refused.exit_code == 2 and str(config) in refused.output and "max_heading_drift" in refused.output
    assert not (tmp_path / "no").exists() or not any((tmp_path / "no").iterdir())


def _parse(text: str) -> dict:
    import tomllib

    return tomllib.loads(text)


def test_a_submap_loop_weighs_its_fit_and_the_odometrys_placement_of_its_submap() -> None:
    """Two loops from node 1 onto node 0 that hold translation alike, one of them fitted on a submap
    whose members the odometry placed with a known uncertainty: the solve lands on their weighted
    mean, the submap loop's covariance its fit's plus the placement's mean over the members (node 1
    itself, placed exactly, and node 2, half a metre either way): closed form, as above."""
    turned = make_transform(rotation_from_euler_zyx(math.pi / 2, 0.0, 0.0), [5.0, 0.0, 0.0])
    poses = np.stack([np.eye(4), turned, turned @ make_transform(np.eye(3), [3.0, 0.0, 0.0])])
    held_rotation = 1e10
    free = np.eye(6) * 1e-9
    placed = np.diag([held_rotation] * 3 + [0.5**-2] * 3)
    chain = Chain(poses, [free, placed])
    fit = np.diag([held_rotation] * 3 + [4.0] * 3)  # half a metre, every way
    measured = {"plain": (5.0, 0.0, 0.0), "submap": (6.0, 1.0, 0.0)}
    submap = LoopEdge(
        1, 0, make_transform(turned[:3, :3], measured["submap"]), fit, chain.submap_placement(1, (1, 2))
    )
    plain = LoopEdge(1, 0, make_transform(turned[:3, :3], measured["plain"]), fit)
    loops = [chain.weighted(loop, scale=1.0) for loop in (plain, submap)]
    assert loops[0] is plain and loops[1].placement is None
    after = optimise(poses, [free, placed], loops)
    weight_plain = np.eye(3) * 4.0
    weight_submap = np.linalg.inv(np.eye(3) / 4.0 + np.eye(3) * 0.5**2 / 2)
    expected = np.linalg.solve(
        weight_plain + weight_submap, weight_plain @ measured["plain"] + weight_submap @ measured["submap"]
    )
    assert np.allclose(after[1][:3, 3], expected, atol=1e-3), (after[1][:3, 3], expected)
    scaled = chain.weighted(submap, scale=4.0)  # the odometry measured four times looser: the same factor
    covariance = np.linalg.inv(scaled.information)[3:, 3:]
    assert np.allclose(covariance, np.eye(3) / 4.0 + np.eye(3) * 4.0 * 0.5**2 / 2, atol=1e-6)
