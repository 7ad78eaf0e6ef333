"""VCR-Net (paper Fig. 3): revised LPD-Net -> self-attention -> cross-attention -> virtual corresponding
points -> SVD, returning T_target_source (it maps source points into the target frame).

``forward`` = :meth:`VCRNet.encode` on each cloud + :meth:`VCRNet.register_features`, so odometry can
encode every frame once and reuse its features for the pair before and the pair after it.

Deviation: coordinates are divided by ``coordinate_scale`` before the encoder (the paper gives no input
normalisation); all outputs are in the caller's units (metres).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, get_args

import torch
from torch import Tensor, nn

from vcr_odom.errors import ConfigError
from vcr_odom.model.attention import CrossAttention, SelfAttention
from vcr_odom.model.config import VcrConfig
from vcr_odom.model.correspondence import (
    VirtualCorrespondences,
    feature_affinity,
    gated_virtual_points,
    robust_procrustes,
    to_homogeneous,
    virtual_correspondences,
    weighted_procrustes,
)
from vcr_odom.model.encoder import LpdEncoder
from vcr_odom.model.invariant_encoder import InvariantEncoder

PoseHead = Literal["paper", "consensus", "full"]
POSE_HEADS: tuple[str, ...] = get_args(PoseHead)


@dataclass
class VcrOutput:
    """One batch of registrations; B pairs, K key points, J candidates, N points, C channels."""

    rotation: Tensor  # (B, 3, 3) R of T_target_source
    translation: Tensor  # (B, 3)
    transform: Tensor  # (B, 4, 4) T_target_source
    key_points: Tensor  # (B, K, 3) source xyz
    virtual_points: Tensor  # (B, K, 3) their virtual correspondences in the target
    key_indices: Tensor  # (B, K) rows of the source
    key_weights: Tensor  # (B, K) self-attention weight of each key point (SVD weight if weighted_svd)
    candidate_indices: Tensor  # (B, K, J) rows of the target
    pointer_weights: Tensor  # (B, K, J) soft-pointer weights
    source_weights: Tensor  # (B, N) per-point self-attention weights
    target_weights: Tensor  # (B, M)
    source_features: Tensor  # (B, N, C) encoder features, reusable for the next pair
    target_features: Tensor  # (B, M, C)
    temperature: Tensor  # () the soft-pointer temperature used
    affinity: Tensor  # (B, N, M) feature affinity of every source point to every target point


@dataclass
class Matches:
    """What the network gives the pose head (:meth:`VCRNet.match_features`)."""

    correspondences: VirtualCorrespondences
    key_weights: Tensor  # (B, K) self-attention weight of each key point
    source_weights: Tensor  # (B, N)
    target_weights: Tensor  # (B, M)
    affinity: Tensor  # (B, N, M)
    temperature: Tensor  # ()


class VCRNet(nn.Module):
    """The whole network; inputs are ``(B, N, 3)`` float tensors in metres on any device."""

    def __init__(self, config: VcrConfig | None = None) -> None:
        super().__init__()
        self.config = config or VcrConfig()
        c = self.config
        encoder = InvariantEncoder if c.encoder == "invariant" else LpdEncoder
        self.encoder = encoder(c.k, c.point_dim, c.graph_dim, c.spatial_dim, c.feature_dim)
        self.self_attention = SelfAttention(c.feature_dim, c.heads, distance_bias=c.distance_bias)
        self.cross_attention = CrossAttention(c.feature_dim, c.heads, c.ff_dim)
        self.log_temperature = nn.Parameter(torch.tensor(math.log(c.temperature)))

    @property
    def temperature(self) -> Tensor:
        return self.log_temperature.exp()

    def encode(self, points: Tensor) -> Tensor:
        """Revised LPD-Net features ``(B, N, feature_dim)`` of one batch of clouds ``(B, N, 3)``."""
        _check_points(points, self.config.k)
        return self.encoder(points / self.config.coordinate_scale)

    def attend(self, points: Tensor, features: Tensor) -> tuple[Tensor, Tensor]:
        """Self-attention of encoded clouds: the attended features and each point's weight. It depends
        on one cloud alone, so odometry computes it once per frame, for both pairs the frame is in."""
        return self.self_attention(features, points)

    def register_features(
        self,
        source_points: Tensor,
        source_features: Tensor,
        target_points: Tensor,
        target_features: Tensor,
        *,
        source_attended: tuple[Tensor, Tensor] | None = None,
        target_attended: tuple[Tensor, Tensor] | None = None,
    ) -> VcrOutput:
        """Attention, virtual correspondences and the pose head on already-encoded clouds.
        ``*_attended``: the cloud's :meth:`attend` output where it was computed before (it is then not
        recomputed)."""
        matches = self.match_features(
            source_points,
            source_features,
            target_points,
            target_features,
            source_attended=source_attended,
            target_attended=target_attended,
        )
        vcp = matches.correspondences
        rotation, translation = self.pose_head(vcp, matches.key_weights, target_points)
        return VcrOutput(
            rotation=rotation,
            translation=translation,
            transform=to_homogeneous(rotation, translation),
            key_points=vcp.key_points,
            virtual_points=vcp.virtual_points,
            key_indices=vcp.key_indices,
            key_weights=matches.key_weights,
            candidate_indices=vcp.candidate_indices,
            pointer_weights=vcp.pointer_weights,
            source_weights=matches.source_weights,
            target_weights=matches.target_weights,
            source_features=source_features,
            target_features=target_features,
            temperature=matches.temperature,
            affinity=matches.affinity,
        )

    def match_features(
        self,
        source_points: Tensor,
        source_features: Tensor,
        target_points: Tensor,
        target_features: Tensor,
        *,
        source_attended: tuple[Tensor, Tensor] | None = None,
        target_attended: tuple[Tensor, Tensor] | None = None,
    ) -> Matches:
        """Everything before the pose head: attention, affinity, key points and virtual points."""
        psi_source, w_source = source_attended or self.attend(source_points, source_features)
        psi_target, w_target = target_attended or self.attend(target_points, target_features)
        phi_source, phi_target = self.cross_attention(psi_source, psi_target)
        temperature = self.temperature
        if not self.training:
            temperature = temperature / self.config.inference_sharpening
        affinity = feature_affinity(phi_source, phi_target, temperature)
        vcp = virtual_correspondences(
            source_points,
            target_points,
            affinity,
            self.config.key_points(source_points.shape[1]),
            self.config.top_j,
            source_weights=w_source,
        )
        key_weights = torch.gather(w_source, 1, vcp.key_indices)
        return Matches(vcp, key_weights, w_source, w_target, affinity, temperature)

    def pose_head(
        self,
        matches: VirtualCorrespondences,
        key_weights: Tensor,
        target_points: Tensor,
        head: PoseHead = "full",
    ) -> tuple[Tensor, Tensor]:
        """R, t from the key points and their virtual points, by one of :data:`POSE_HEADS`:

        - ``paper``: the paper's SVD (weighted by the key points' self-attention weights where
          ``weighted_svd``), nothing else;
        - ``consensus``: the consensus start and the robust re-weighting (:func:`robust_procrustes`);
        - ``full``: that, then the gated re-pointing rounds (inference only), as ``forward`` runs.

        Why three: the consensus and the re-pointing are RANSAC and ICP in all but name, and can
        register two scans from poor correspondences; the paper's head cannot, so it shows what the
        features themselves are worth (``benchmarks/ablation.py``)."""
        c = self.config
        weights = key_weights if c.weighted_svd else None
        if head == "paper":
            return weighted_procrustes(matches.key_points, matches.virtual_points, weights)
        if head not in POSE_HEADS:
            raise ConfigError(f"pose head must be one of {', '.join(POSE_HEADS)}; got {head!r}")
        rotation, translation = robust_procrustes(
            matches.key_points,
            matches.virtual_points,
            weights,
            iterations=c.robust_iterations,
            scale=c.robust_scale,
            hypotheses=c.consensus_hypotheses,
            threshold=c.consensus_threshold,
            seeds=c.consensus_seeds,
            group=c.consensus_group,
            kernel=c.robust_kernel,
        )
        if head == "full" and not self.training and c.gated_rounds:
            rotation, translation = self._gated_rounds(
                matches.key_points, matches.key_rows, target_points, rotation, translation, key_weights
            )
        return rotation, translation

    def _gated_rounds(
        self,
        key_points: Tensor,
        key_rows: Tensor,
        target_points: Tensor,
        rotation: Tensor,
        translation: Tensor,
        key_weights: Tensor,
    ) -> tuple[Tensor, Tensor]:
        """``gated_rounds`` re-pointings (:func:`gated_virtual_points`), each followed by the robust
        re-weighting from the motion so far."""
        c = self.config
        for _ in range(c.gated_rounds):
            virtual, reached = gated_virtual_points(
                key_points, key_rows, target_points, rotation, translation, c.gate_radius
            )
            weights = reached.to(key_points.dtype) * (key_weights if c.weighted_svd else 1.0)
            rotation, translation = robust_procrustes(
                key_points,
                virtual,
                weights,
                iterations=c.robust_iterations,
                scale=c.robust_scale,
                kernel=c.robust_kernel,
            )
        return rotation, translation

    def forward(self, source: Tensor, target: Tensor) -> VcrOutput:
        """T_target_source for each pair of the batch: ``source``, ``target`` ``(B, N, 3)`` metres."""
        if source.shape[0] != target.shape[0]:
            raise ConfigError(f"source and target batch sizes differ: {source.shape[0]} vs {target.shape[0]}")
        return self.register_features(source, self.encode(source), target, self.encode(target))


def _check_points(points: Tensor, k: int) -> None:
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ConfigError(f"points must be a (B, N, 3) tensor; got shape {tuple(points.shape)}")
    if points.shape[1] < max(k + 1, 3):
        raise ConfigError(f"clouds need at least k + 1 = {k + 1} points; got {points.shape[1]}")
