"""Revised LPD-Net on relative geometry only: features that do not change when the cloud is shifted or
turned about z (the paper, §IV-A and Algorithm 1, asks for rotation- and shift-invariant features).

Why: the first layer of :class:`~vcr_odom.model.encoder.LpdEncoder` is a pointwise MLP on absolute xyz,
so a point's feature says where it lies in the sensor frame (the model card gives how much a shift
changes it). Between two sensor positions such a feature favours matching a point to whatever
lies at the same sensor-frame place: an estimate shrunk towards zero motion, the more so the larger
the motion. Here every input is a function of differences between points, and of the z axis only
through heights and the tilt of local shapes, so the invariance holds to float rounding (tested).

Layout (channels-last ``(B, N, C)``), the same stages as LpdEncoder:

- Cartesian kNN graph on xyz (k neighbours, self excluded); each edge i->j is described by
  ``(‖d_xy‖, d_z, ‖d‖)`` of ``d = x_j - x_i`` (invariant to translations and rotations about z);
- local shape of each neighbourhood: the square roots of its covariance eigenvalues and the |z|
  components of its normal and principal direction (linearity, planarity, verticality);
- "pointwise" stage: a linear layer on each edge's geometry with the centre's shape, max-pooled over
  the k neighbours, then a pointwise layer (a learned local descriptor, a PointNet on the
  neighbourhood; the second layer after the pooling costs k times less than on every edge);
- two EdgeConv layers on the feature-space kNN graph of those features, max-pooled;
- one EdgeConv on the Cartesian graph whose edges also see their geometry;
- dense concatenation of every stage and a final linear layer to ``feature_dim``.

Deviation: the paper's LPD-Net starts from xyz and handcrafted local features; we keep only the
rotation-about-z and shift invariant part of that input, since gravity (z) is known on a vehicle but
heading and position are what registration must find.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from vcr_odom.model.encoder import EdgeConv, gather_neighbours, knn_indices, neighbour_max

EDGE_UNIT = 0.1
"""Edge lengths are given to the network in units of ``EDGE_UNIT`` network units (3 m at the default
``coordinate_scale`` of 30 m), the scale of neighbourhoods of 512-1024 sampled points."""

SHAPE_DIM = 5
EDGE_DIM = 3


def edge_geometry(xyz: Tensor, index: Tensor) -> Tensor:
    """``(B, N, k, 3)``: horizontal length, height difference and length of each edge i->j."""
    offset = gather_neighbours(xyz, index) - xyz.unsqueeze(2)
    horizontal = offset[..., :2].norm(dim=-1)
    return torch.stack([horizontal, offset[..., 2], offset.norm(dim=-1)], dim=-1) / EDGE_UNIT


def local_shape(xyz: Tensor, index: Tensor) -> Tensor:
    """``(B, N, 5)``: sqrt of the neighbourhood's covariance eigenvalues s1 >= s2 >= s3, the |z| of its
    normal (smallest eigenvector) times its planarity (s2 - s3) / s1, and the |z| of its principal
    direction times its linearity (s1 - s2) / s1.

    Eigenvectors have no sign (hence |z|), and where two eigenvalues tie their vectors are arbitrary:
    the planarity / linearity factor goes to zero exactly there, so the feature stays continuous and
    a cloud moved by float rounding keeps it (a bare |z| jumped on round, bushy neighbourhoods).
    Computed without autograd (points carry no gradient)."""
    with torch.no_grad(), torch.autocast(device_type=xyz.device.type, enabled=False):
        neighbours = gather_neighbours(xyz.float(), index)  # (B, N, k, 3)
        centred = neighbours - neighbours.mean(dim=2, keepdim=True)
        covariance = centred.transpose(-1, -2) @ centred / index.shape[-1]
        work = torch.float32 if xyz.device.type == "mps" else torch.float64
        values, vectors = symmetric_eigen(covariance.to(work))  # ascending
        spread = values.clamp_min(0.0).sqrt().flip(-1)  # s1 >= s2 >= s3
        largest = spread[..., 0:1].clamp_min(1e-9)
        planarity = (spread[..., 1:2] - spread[..., 2:3]) / largest
        linearity = (spread[..., 0:1] - spread[..., 1:2]) / largest
        tilt = vectors[..., 2, :].abs()  # z component of each eigenvector, ascending eigenvalues
        shape = torch.cat([spread / EDGE_UNIT, tilt[..., 0:1] * planarity, tilt[..., 2:3] * linearity], -1)
    return shape.to(xyz.dtype)


def symmetric_eigen(matrices: Tensor) -> tuple[Tensor, Tensor]:
    """``torch.linalg.eigh`` on the matrices' device, or on the CPU where the device's solver fails.

    cusolver's batched solver once failed on an H200 (``CUSOLVER_STATUS_INTERNAL_ERROR``, torch 2.11 +
    CUDA 13, one frame's 1,024 covariances) that it solved in every later process on the same frames:
    a crash of the whole run for what a CPU solves in milliseconds. The shipped weights were trained on
    a CPU's answers, so the fallback changes no feature beyond float rounding."""
    try:
        return torch.linalg.eigh(matrices)
    except RuntimeError:
        if matrices.device.type == "cpu":
            raise
        values, vectors = torch.linalg.eigh(matrices.to("cpu", torch.float64))
        return values.to(matrices.device, matrices.dtype), vectors.to(matrices.device, matrices.dtype)


class GeometricEdgeConv(EdgeConv):
    """EdgeConv whose edges also see their geometry: ReLU(W [f_j - f_i, f_i] + G g_ij + b)."""

    def __init__(self, in_dim: int, out_dim: int) -> None:
        super().__init__(in_dim, out_dim)
        self.geometry = nn.Linear(EDGE_DIM, out_dim, bias=False)

    def pooled_with_geometry(self, features: Tensor, index: Tensor, geometry: Tensor) -> Tensor:
        """``(B, N, C_out)``: the edges' output max-pooled over each point's neighbours.

        The centre's term and the ReLU are the same on all of a point's edges and monotone, so they
        are applied after the max: max_j ReLU(c_i + e_ij) = ReLU(c_i + max_j e_ij), two passes over
        N x C values instead of N x k x C (about a quarter of this layer's time on a CPU)."""
        w_neighbour = self.linear.weight[:, : self.in_dim]
        w_centre = self.linear.weight[:, self.in_dim :] - w_neighbour
        neighbour = features @ w_neighbour.T
        centre = features @ w_centre.T + self.linear.bias
        strongest = neighbour_max(gather_neighbours(neighbour, index) + self.geometry(geometry))
        return torch.relu(strongest + centre)


class InvariantEncoder(nn.Module):
    """``(B, N, 3)`` xyz (network units) -> ``(B, N, feature_dim)`` features invariant to translations
    and rotations about z of the cloud."""

    def __init__(self, k: int, point_dim: int, graph_dim: int, spatial_dim: int, feature_dim: int) -> None:
        super().__init__()
        self.k = k
        self.local_edge = nn.Linear(EDGE_DIM + SHAPE_DIM, point_dim)
        self.local_point = nn.Linear(point_dim, point_dim)
        self.graph1 = EdgeConv(point_dim, graph_dim)
        self.graph2 = nn.Linear(graph_dim, graph_dim)
        self.spatial = GeometricEdgeConv(graph_dim, spatial_dim)
        self.output = nn.Linear(point_dim + 2 * graph_dim + spatial_dim, feature_dim)
        for module in self.modules():
            if isinstance(module, nn.Linear):  # He init, zero bias (as LpdEncoder)
                nn.init.kaiming_normal_(module.weight, nonlinearity="relu")
                if module.bias is not None:
                    nn.init.zeros_(module.bias)

    def forward(self, xyz: Tensor) -> Tensor:
        k = min(self.k, xyz.shape[1] - 1)
        spatial_graph = knn_indices(xyz, k)
        geometry = edge_geometry(xyz, spatial_graph)
        shape = local_shape(xyz, spatial_graph)
        edge_input = torch.cat([geometry, shape.unsqueeze(2).expand(-1, -1, k, -1)], dim=-1)
        x0 = torch.relu(self.local_point(neighbour_max(torch.relu(self.local_edge(edge_input)))))
        feature_graph = knn_indices(x0, k)
        edges = self.graph1(x0, feature_graph)
        x1 = neighbour_max(edges)
        x2 = neighbour_max(torch.relu(self.graph2(edges)))
        x3 = self.spatial.pooled_with_geometry(x2, spatial_graph, geometry)
        return self.output(torch.cat([x0, x1, x2, x3], dim=-1))
