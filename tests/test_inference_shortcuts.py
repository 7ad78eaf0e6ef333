"""Layers that compute their inference output another way than their training output (for speed on a
CPU) must give the numbers the layer's definition gives, checked here against numpy written from it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vcr_odom.model.attention import DistanceBias
from vcr_odom.model.encoder import knn_indices
from vcr_odom.model.invariant_encoder import GeometricEdgeConv, edge_geometry


def distance_bias_by_definition(distance: np.ndarray, centres: np.ndarray, width: float, mix: np.ndarray):
    """``(B, heads, N, N)``: Σ_c mix[h, c] · exp(-((d_ij - centre_c) / width)² / 2), in float64."""
    basis = np.exp(-0.5 * ((distance[..., None] - centres) / width) ** 2)
    return np.einsum("bijc,hc->bhij", basis, mix)


@pytest.mark.parametrize("grad", [False, True], ids=["inference", "training"])
def test_distance_bias_matches_its_definition_near_and_far(grad: bool) -> None:
    torch.manual_seed(0)
    layer = DistanceBias(heads=4)
    with torch.no_grad():
        layer.mix.weight.normal_(0.0, 1.0)
    rng = np.random.default_rng(3)
    points = rng.uniform(-80, 80, (2, 300, 3)).astype(np.float32)  # rows span several row blocks
    points[0, :4] += np.float32(400.0)  # far beyond the crop: every basis function is ~0 there
    points[1, :3] = points[1, 3]  # duplicates: distance 0
    # the layer's own distances (torch's float32 cdist is off by up to ~1e-2 m between duplicates;
    # both of the layer's paths share it): what is checked is the function of distance
    distance = torch.cdist(torch.as_tensor(points), torch.as_tensor(points)).numpy().astype(np.float64)
    expected = distance_bias_by_definition(
        distance, layer.centres.numpy(), layer.width, layer.mix.weight.detach().numpy()
    )
    with torch.set_grad_enabled(grad):
        got = layer(torch.as_tensor(points))
    assert got.shape == expected.shape
    np.testing.assert_allclose(got.detach().numpy(), expected, atol=2e-5, rtol=1e-5)
    assert np.abs(expected).max() > 1.0  # the biases are not trivially small


def test_geometric_edge_conv_pools_what_its_edges_compute() -> None:
    torch.manual_seed(1)
    layer = GeometricEdgeConv(in_dim=6, out_dim=5)
    points = torch.randn(2, 40, 3)
    features = torch.randn(2, 40, 6)
    index = knn_indices(points, 7)
    geometry = edge_geometry(points, index)
    with torch.no_grad():
        got = layer.pooled_with_geometry(features, index, geometry).numpy()
    f, idx, g = features.numpy().astype(np.float64), index.numpy(), geometry.numpy().astype(np.float64)
    w = layer.linear.weight.detach().numpy().astype(np.float64)
    b = layer.linear.bias.detach().numpy().astype(np.float64)
    w_geometry = layer.geometry.weight.detach().numpy().astype(np.float64)
    expected = np.empty(got.shape)
    for batch in range(f.shape[0]):
        for i in range(f.shape[1]):
            edges = [
                np.maximum(
                    w @ np.concatenate([f[batch, j] - f[batch, i], f[batch, i]])
                    + b
                    + w_geometry @ g[batch, i, n],
                    0,
                )
                for n, j in enumerate(idx[batch, i])
            ]
            expected[batch, i] = np.max(edges, axis=0)
    np.testing.assert_allclose(got, expected, atol=1e-5, rtol=1e-5)
    assert (expected > 0).mean() > 0.3  # the ReLU leaves most outputs alive: the max is tested
