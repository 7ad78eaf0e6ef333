"""Losses of VCR-Net (paper §IV-F) and of the encoder's self-supervised pre-training (paper Algorithm 1).

Loss_cor = (1/N_cor) Σ_true ‖x_i - ỹ_i‖ + (γ/N_mis) Σ_false ‖x_i - ỹ_i‖, where ỹ_i is the virtual point
ŷ_i taken back into the source frame by the ground truth; a correspondence is true when ỹ_i's nearest
source point is x_i (the paper's criterion), or, with ``match_radius``, when ‖x_i - ỹ_i‖ <= radius.
Loss_trans = ‖Rᵀ R_g - I‖² + ‖t - t_g‖² is for monitoring only, as the paper trains without it. The
Tikhonov term β‖e‖² is the optimiser's weight decay.

Deviation: each sum is averaged per pair of the batch and then over the batch; a pair with no true (or
no false) match contributes nothing to that term.

Addition (:func:`matching_loss`, ``TrainConfig.objective = "matching"``): Loss_cor only asks the
virtual point, a blend of J candidates, to land near the truth; it never asks the feature affinity to
rank the right target point first, so a pose head that searches for consensus among the
correspondences (RANSAC-like) does as well on random features as on trained ones. The matching loss
trains what the features must do: a cross-entropy of each point's affinity row against the target
points near its true position (both directions), a binary cross-entropy making each point's
self-attention weight the probability that it has a counterpart in the other cloud, and a pose loss
of the paper's head (virtual points + SVD weighted by those weights) on the pairs that overlap.
Deviation: Algorithm 1 says "triplet loss with L1-norm regularization" without a formula; we use the
margin triplet loss on Euclidean feature distances, max(0, d(a, p) - d(a, n) + margin), averaged over
anchors and their m negatives, plus λ · mean_i |‖f_i‖ - 1| (an L1 penalty keeping each embedding near
unit length, which fixes the scale the margin refers to).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from vcr_odom.model.correspondence import gather_points, weighted_procrustes


@dataclass
class CorrespondenceLoss:
    """Loss_cor and what it was made of (all but ``loss`` detached)."""

    loss: Tensor  # () differentiable
    true_fraction: Tensor  # () share of key points that are true matches
    mean_error: Tensor  # () mean ‖x_i - ỹ_i‖ over all key points (metres)


def correspondence_loss(
    key_points: Tensor,
    virtual_points: Tensor,
    rotation_gt: Tensor,
    translation_gt: Tensor,
    gamma: float = 1.0,
    source_points: Tensor | None = None,
    match_radius: float | None = None,
) -> CorrespondenceLoss:
    """Paper Loss_cor. ``key_points`` x_i ``(B, K, 3)`` (source), ``virtual_points`` ŷ_i ``(B, K, 3)``
    (target frame), GT T_target_source as ``rotation_gt`` ``(B, 3, 3)``, ``translation_gt`` ``(B, 3)``.

    The nearest-neighbour criterion needs the whole source cloud ``source_points`` ``(B, N, 3)``; it is
    required unless ``match_radius`` is given.
    """
    back = (virtual_points - translation_gt.unsqueeze(1)) @ rotation_gt  # Rᵀ (ŷ - t), row vectors
    error = (back - key_points).norm(dim=-1)  # (B, K)
    with torch.no_grad():
        if match_radius is not None:
            true = error <= match_radius
        else:
            if source_points is None:
                raise ValueError("source_points is needed for the nearest-neighbour true-match test")
            nearest = torch.cdist(back, source_points).amin(dim=-1)
            true = error <= nearest + 1e-6
    true_f = true.to(error.dtype)
    false_f = 1.0 - true_f
    true_term = (error * true_f).sum(1) / true_f.sum(1).clamp_min(1.0)
    false_term = (error * false_f).sum(1) / false_f.sum(1).clamp_min(1.0)
    loss = (true_term + gamma * false_term).mean()
    return CorrespondenceLoss(loss, true_f.mean().detach(), error.mean().detach())


def transformation_loss(
    rotation: Tensor, translation: Tensor, rotation_gt: Tensor, translation_gt: Tensor
) -> Tensor:
    """Paper Eq. (Loss_trans), batch mean: ‖Rᵀ R_g - I‖²_F + ‖t - t_g‖². For monitoring only."""
    eye = torch.eye(3, dtype=rotation.dtype, device=rotation.device)
    rot = (rotation.transpose(1, 2) @ rotation_gt - eye).pow(2).sum((1, 2))
    return (rot + (translation - translation_gt).pow(2).sum(-1)).mean()


def farthest_point_sampling(points: Tensor, count: int) -> Tensor:
    """Indices ``(B, count)`` of farthest point sampling on ``(B, N, 3)``, batched over B.

    Starts at the point farthest from the centroid (deterministic, independent of point order up to
    ties), then repeatedly adds the point farthest from the chosen set: ``count`` steps of O(B N).
    """
    b, n, _ = points.shape
    count = min(count, n)
    points = points.detach()
    index = torch.empty(b, count, dtype=torch.long, device=points.device)
    batch = torch.arange(b, device=points.device)
    centroid = points.mean(dim=1, keepdim=True)
    current = (points - centroid).pow(2).sum(-1).argmax(dim=1)
    nearest = torch.full((b, n), float("inf"), dtype=points.dtype, device=points.device)
    for step in range(count):
        index[:, step] = current
        chosen = points[batch, current].unsqueeze(1)
        nearest = torch.minimum(nearest, (points - chosen).pow(2).sum(-1))
        current = nearest.argmax(dim=1)
    return index


@dataclass
class TripletLoss:
    """Pre-training loss and its parts."""

    loss: Tensor  # () triplet + norm_weight * regulariser, differentiable
    triplet: Tensor  # () detached
    regulariser: Tensor  # () detached


def triplet_pretraining_loss(
    source_features: Tensor,
    target_features: Tensor,
    source_points: Tensor,
    num_anchors: int = 32,
    num_negatives: int = 8,
    margin: float = 0.5,
    norm_weight: float = 0.05,
) -> TripletLoss:
    """Paper Algorithm 1. Row i of ``target_features`` must be the correspondent of source row i (the
    target cloud is the source moved by a known transform, same point order).

    Anchors: ``num_anchors`` FPS points of the source (line 1); positive: the target feature at the same
    index (line 3); negatives: the targets of the ``num_negatives`` anchors farthest from the anchor in
    source xyz (line 5); then the triplet loss with the norm regulariser (line 8).
    """
    anchors_idx = farthest_point_sampling(source_points, num_anchors)  # (B, A)
    num_negatives = min(num_negatives, anchors_idx.shape[1] - 1)
    if num_negatives < 1:
        raise ValueError("triplet pre-training needs at least two anchors")
    anchor_xyz = gather_points(source_points, anchors_idx)
    distance = torch.cdist(anchor_xyz, anchor_xyz)  # (B, A, A)
    farthest = distance.topk(num_negatives, dim=-1).indices  # (B, A, m), positions among the anchors
    negatives_idx = torch.gather(anchors_idx.unsqueeze(1).expand(-1, anchors_idx.shape[1], -1), 2, farthest)
    anchor = gather_points(source_features, anchors_idx)  # (B, A, C)
    positive = gather_points(target_features, anchors_idx)
    b, a, m = negatives_idx.shape
    negative = gather_points(target_features, negatives_idx.reshape(b, a * m)).reshape(b, a, m, -1)
    d_pos = (anchor - positive).norm(dim=-1)  # (B, A)
    d_neg = (anchor.unsqueeze(2) - negative).norm(dim=-1)  # (B, A, m)
    triplet = torch.relu(d_pos.unsqueeze(-1) - d_neg + margin).mean()
    norms = torch.cat([source_features, target_features], dim=1).norm(dim=-1)
    regulariser = (norms - 1.0).abs().mean()
    loss = triplet + norm_weight * regulariser
    return TripletLoss(loss, triplet.detach(), regulariser.detach())


@dataclass
class MatchingLoss:
    """The matching objective and its parts (all but ``loss`` detached)."""

    loss: Tensor  # () differentiable
    matching: Tensor  # () cross-entropy of the affinity rows and columns
    overlap: Tensor  # () binary cross-entropy of the self-attention weights
    pose: Tensor  # () the paper head's pose error on the overlapping pairs
    inlier_ratio: Tensor  # () key points whose best candidate lies within ``radius`` of the truth
    overlap_fraction: Tensor  # () source points with a target point within ``radius`` of the truth


def matching_loss(
    source_points: Tensor,
    target_points: Tensor,
    affinity: Tensor,
    source_weights: Tensor,
    target_weights: Tensor,
    key_indices: Tensor,
    key_points: Tensor,
    virtual_points: Tensor,
    rotation_gt: Tensor,
    translation_gt: Tensor,
    radius: float = 2.0,
    overlap_weight: float = 1.0,
    pose_weight: float = 0.5,
    min_overlap: float = 0.3,
) -> MatchingLoss:
    """What the features must do for the registration, on one batch (B pairs; N source, M target points).

    - matching: point i's affinity row ``(B, N, M)`` is a distribution over the target points; its
      target puts mass ``exp(-d² / (2 (radius / 2)²))`` on the target points within ``radius`` metres
      of where the truth moves point i (a down-sampled scan holds no exact counterpart, so the nearest
      ones share it), and the cross-entropy is averaged over the points that have any; the same for
      the columns (target to source).
    - overlap: each point's self-attention weight (sigmoid) against whether it has a counterpart
      within ``radius``, so that a low weight marks a point the other scan does not see.
    - pose: the paper's head (:func:`~vcr_odom.model.correspondence.weighted_procrustes` of the key
      points' virtual points, weighted by their self-attention weights), ``|R - R_gt|_F + |t - t_gt|``
      per pair, averaged over the pairs whose overlap fraction is at least ``min_overlap`` (two scans
      that share few surfaces carry little information about their motion).

    The returned ``inlier_ratio`` is the network's own correspondence quality before any pose head:
    the share of key points whose highest-affinity target point lies within ``radius`` of the truth.
    """
    moved = source_points @ rotation_gt.transpose(1, 2) + translation_gt.unsqueeze(1)
    with torch.no_grad():
        distance = torch.cdist(moved.float(), target_points.float())  # (B, N, M)
        near = distance <= radius
        sigma = radius / 2.0
        closeness = torch.exp(-0.5 * (distance / sigma) ** 2) * near
        source_has = near.any(dim=2)  # (B, N)
        target_has = near.any(dim=1)  # (B, M)
    logits = affinity.float()
    row_target = closeness / closeness.sum(2, keepdim=True).clamp_min(1e-12)
    col_target = closeness / closeness.sum(1, keepdim=True).clamp_min(1e-12)
    row_ce = -(row_target * torch.log_softmax(logits, dim=2)).sum(2)  # (B, N)
    col_ce = -(col_target * torch.log_softmax(logits, dim=1)).sum(1)  # (B, M)
    matching = 0.5 * (_masked_mean(row_ce, source_has) + _masked_mean(col_ce, target_has))

    overlap = 0.5 * (
        F.binary_cross_entropy(source_weights.float().clamp(1e-6, 1 - 1e-6), source_has.float())
        + F.binary_cross_entropy(target_weights.float().clamp(1e-6, 1 - 1e-6), target_has.float())
    )

    key_weights = torch.gather(source_weights, 1, key_indices).float()
    rotation, translation = weighted_procrustes(key_points.float(), virtual_points.float(), key_weights)
    pose_error = (rotation - rotation_gt).flatten(1).norm(dim=1) + (translation - translation_gt).norm(dim=1)
    overlap_fraction = source_has.float().mean(dim=1)  # (B,)
    usable = (overlap_fraction >= min_overlap).float()
    pose = (pose_error * usable).sum() / usable.sum().clamp_min(1.0)

    with torch.no_grad():
        best = affinity.gather(1, key_indices.unsqueeze(-1).expand(-1, -1, affinity.shape[-1])).argmax(-1)
        key_distance = distance.gather(1, key_indices.unsqueeze(-1).expand(-1, -1, distance.shape[-1]))
        inlier = key_distance.gather(2, best.unsqueeze(-1)).squeeze(-1) <= radius
    loss = matching + overlap_weight * overlap + pose_weight * pose
    return MatchingLoss(
        loss,
        matching.detach(),
        overlap.detach(),
        pose.detach(),
        inlier.float().mean(),
        overlap_fraction.mean(),
    )


def _masked_mean(values: Tensor, mask: Tensor) -> Tensor:
    """Mean of ``values`` ``(B, N)`` over ``mask`` per pair, then over the pairs that have any."""
    mask_f = mask.to(values.dtype)
    count = mask_f.sum(1)
    per_pair = (values * mask_f).sum(1) / count.clamp_min(1.0)
    has = (count > 0).to(values.dtype)
    return (per_pair * has).sum() / has.sum().clamp_min(1.0)
