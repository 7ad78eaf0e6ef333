"""Revised LPD-Net encoder (paper §IV-A, Fig. 4): per-point features from a feature-space kNN graph,
then a Cartesian-space kNN graph, with dense (DenseNet-style) skip connections.

Layout, channels-last ``(B, N, C)``: pointwise MLP 3->p->p; feature-space graph on those p-d features
(k neighbours, self excluded) with two EdgeConv layers (the second applied to the per-edge output of the
first), each max-pooled over neighbours; a Cartesian-space graph on xyz aggregating the second layer's
features with one more EdgeConv; concatenation of every stage; a final pointwise layer to feature_dim.

Deviation: the paper names the graphs but gives no edge function; we use DGCNN's EdgeConv edge
``(f_j - f_i, f_i)``. The last layer is linear (no ReLU), so features may take either sign, and the
pointwise features are part of the dense concatenation.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


def knn_indices(points: Tensor, k: int) -> Tensor:
    """Indices ``(B, N, k)`` of each point's k nearest neighbours in ``points`` ``(B, N, C)``, self excluded.

    Squared distances from one batched matmul (an N x N matrix per sample, fine for N <= a few
    thousand); the diagonal is set to +inf instead of dropping the first hit, so duplicate points
    do not make the result depend on point order.
    """
    points = points.detach()  # indices only: no autograd graph for the N x N matrix
    sq = points.pow(2).sum(-1)
    dist = sq.unsqueeze(-1) + sq.unsqueeze(-2) - 2.0 * points @ points.transpose(-1, -2)
    dist.diagonal(dim1=-2, dim2=-1).fill_(float("inf"))
    return dist.topk(k, dim=-1, largest=False).indices


def gather_neighbours(features: Tensor, index: Tensor) -> Tensor:
    """``features`` ``(B, N, C)`` at ``index`` ``(B, M, k)`` -> ``(B, M, k, C)``."""
    batch = torch.arange(features.shape[0], device=features.device).view(-1, 1, 1)
    return features[batch, index]


def neighbour_max(edges: Tensor) -> Tensor:
    """Max over the neighbour axis of ``(B, N, k, C)`` -> ``(B, N, C)``.

    Why two ways: ``amax``'s backward builds a mask of every maximum over the whole edge tensor (a
    sixth of a training step on a CPU), ``max``'s scatters the gradient to the one index it kept; but
    ``max`` forward is slower, as it also finds that index. So the index is only asked for where a
    gradient will flow. The values are the same either way."""
    if torch.is_grad_enabled() and edges.requires_grad:
        return edges.max(dim=2).values
    return edges.amax(dim=2)


class EdgeConv(nn.Module):
    """EdgeConv (DGCNN): ReLU(W [f_j - f_i, f_i] + b) for each edge i->j.

    The linear map of the concatenation is split as ``W1 f_j + (W2 - W1) f_i + b`` and applied per
    point before gathering, k times cheaper than on the edge tensor and mathematically identical.
    """

    def __init__(self, in_dim: int, out_dim: int) -> None:
        super().__init__()
        self.linear = nn.Linear(2 * in_dim, out_dim)
        self.in_dim = in_dim

    def forward(self, features: Tensor, index: Tensor) -> Tensor:
        """``(B, N, C_in)``, ``(B, N, k)`` -> per-edge output ``(B, N, k, C_out)``."""
        w_neighbour = self.linear.weight[:, : self.in_dim]
        w_centre = self.linear.weight[:, self.in_dim :] - w_neighbour
        neighbour = features @ w_neighbour.T
        centre = features @ w_centre.T + self.linear.bias
        return torch.relu(gather_neighbours(neighbour, index) + centre.unsqueeze(2))


class LpdEncoder(nn.Module):
    """Revised LPD-Net: ``(B, N, 3)`` xyz (network units) -> ``(B, N, feature_dim)`` features."""

    def __init__(self, k: int, point_dim: int, graph_dim: int, spatial_dim: int, feature_dim: int) -> None:
        super().__init__()
        self.k = k
        self.pointwise = nn.Sequential(
            nn.Linear(3, point_dim), nn.ReLU(), nn.Linear(point_dim, point_dim), nn.ReLU()
        )
        self.graph1 = EdgeConv(point_dim, graph_dim)
        self.graph2 = nn.Linear(graph_dim, graph_dim)
        self.spatial = EdgeConv(graph_dim, spatial_dim)
        self.output = nn.Linear(point_dim + 2 * graph_dim + spatial_dim, feature_dim)
        for module in self.modules():
            if isinstance(module, nn.Linear):  # He init, zero bias: keeps the per-point variation of
                nn.init.kaiming_normal_(module.weight, nonlinearity="relu")  # the input instead of
                nn.init.zeros_(module.bias)  # drowning it in biases (every point alike at start)

    def forward(self, xyz: Tensor) -> Tensor:
        k = min(self.k, xyz.shape[1] - 1)
        x0 = self.pointwise(xyz)
        feature_graph = knn_indices(x0, k)
        edges = self.graph1(x0, feature_graph)
        x1 = neighbour_max(edges)
        x2 = neighbour_max(torch.relu(self.graph2(edges)))  # second layer on the per-edge tensor
        spatial_graph = knn_indices(xyz, k)
        x3 = neighbour_max(self.spatial(x2, spatial_graph))
        return self.output(torch.cat([x0, x1, x2, x3], dim=-1))
