"""Virtual corresponding points (paper §IV-D, soft-pointer method) and the SVD head (paper §IV-E).

Affinity A_ij = -mean_c (Φ1_ic - Φ2_jc)² / τ with a learned temperature τ. Top-K key points: the rows
with the largest max_j A_ij (paper), plus log w_i, the source point's self-attention weight. Top-J
candidates: the J largest A_ij of each key row. Virtual point ŷ_i = Σ_j M_ij y_j over those J.

Deviation: the paper's soft pointer takes M = Softmax(Φ1 Φ2ᵀ) over all N columns and then sums only the
J candidates (weights that do not sum to 1 pull ŷ towards the origin); we renormalise with a softmax over
the J candidates, and use one affinity (on Φ) for selection and pointer where the paper uses
θ1 φ2ᵀ for selection. The temperature is learned and the affinity is a scaled squared distance, never the
raw one, so the learned scale sets how peaked the pointer is. Key points are ranked by max affinity + log w (the paper: max affinity only), so the
self-attention weight removes hard-to-match points as §IV-B intends.
Deviation: the SVD head accepts optional per-point weights (weighted Kabsch); the paper's E(R, t) is
unweighted, which is the default. Deviation (``robust_iterations`` > 0): the paper's solve is followed
by a few iteratively reweighted ones (:func:`robust_procrustes`), which give key points without a
counterpart in the other scan little say.
Deviation (``gated_rounds`` > 0, inference only): after that, each key point's virtual point is
re-chosen among the target points near where the estimate puts it (:func:`gated_virtual_points`) and
the motion re-solved; on streets that repeat along their length the best feature match can lie metres
from the counterpart (weights/MODEL_CARD.md, "Gated re-pointing", gives the figures).
Deviation (``consensus_seeds`` > 0, inference only): the consensus start also tries motions fitted to
groups of correspondences that keep each other's pairwise distances (:func:`compatible_hypotheses`),
where random triples rarely hit a right motion (weights/MODEL_CARD.md, "Compatible seeds and a
third gated round").
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from vcr_odom.model.config import ROBUST_KERNELS
from vcr_odom.model.encoder import gather_neighbours


def feature_affinity(source: Tensor, target: Tensor, temperature: Tensor) -> Tensor:
    """``(B, N, C)``, ``(B, M, C)`` -> ``(B, N, M)``: negative mean squared difference over channels / τ."""
    channels = source.shape[-1]
    sq = (
        source.pow(2).sum(-1).unsqueeze(-1)
        + target.pow(2).sum(-1).unsqueeze(-2)
        - 2.0 * source @ target.transpose(-1, -2)
    )
    return -sq.clamp_min(0.0) / (channels * temperature)


def gather_points(points: Tensor, index: Tensor) -> Tensor:
    """``points`` ``(B, N, C)`` at ``index`` ``(B, K)`` -> ``(B, K, C)``."""
    return torch.gather(points, 1, index.unsqueeze(-1).expand(-1, -1, points.shape[-1]))


@dataclass
class VirtualCorrespondences:
    """Key points of the source and their virtual points in the target, with how they were made."""

    key_indices: Tensor  # (B, K) long, rows of the source, best match (key_scores) first
    key_points: Tensor  # (B, K, 3) source xyz
    virtual_points: Tensor  # (B, K, 3) target-frame xyz
    candidate_indices: Tensor  # (B, K, J) long, rows of the target
    pointer_weights: Tensor  # (B, K, J) softmax over the J candidates
    key_scores: Tensor  # (B, K) the ranking score of each key point
    key_rows: Tensor  # (B, K, M) the key points' affinity rows (reused by the gated re-pointing)


def virtual_correspondences(
    source_xyz: Tensor,
    target_xyz: Tensor,
    affinity: Tensor,
    num_keys: int,
    num_candidates: int,
    source_weights: Tensor | None = None,
) -> VirtualCorrespondences:
    """Top-K key points, Top-J candidates each, soft pointer over the candidates (differentiable in
    ``affinity``; indices carry no gradient, weights and virtual points do)."""
    num_candidates = min(num_candidates, target_xyz.shape[1])
    num_keys = min(num_keys, source_xyz.shape[1])
    score = affinity.amax(dim=-1)
    if source_weights is not None:
        score = score + torch.log(source_weights.clamp_min(1e-12))
    key_scores, key_indices = score.topk(num_keys, dim=-1)
    key_rows = torch.gather(affinity, 1, key_indices.unsqueeze(-1).expand(-1, -1, affinity.shape[-1]))
    logits, candidate_indices = key_rows.topk(num_candidates, dim=-1)
    pointer = torch.softmax(logits, dim=-1)
    candidates = gather_neighbours(target_xyz, candidate_indices)  # (B, K, J, 3)
    virtual = (pointer.unsqueeze(-1) * candidates).sum(dim=2)
    return VirtualCorrespondences(
        key_indices=key_indices,
        key_points=gather_points(source_xyz, key_indices),
        virtual_points=virtual,
        candidate_indices=candidate_indices,
        pointer_weights=pointer,
        key_scores=key_scores,
        key_rows=key_rows,
    )


def gated_virtual_points(
    key_points: Tensor,
    key_rows: Tensor,
    target_xyz: Tensor,
    rotation: Tensor,
    translation: Tensor,
    radius: float,
) -> tuple[Tensor, Tensor]:
    """Virtual points ``(B, K, 3)`` re-chosen as the target point of highest affinity ``key_rows``
    ``(B, K, M)`` among those within ``radius`` metres of where ``rotation``, ``translation`` put each
    key point, and a ``(B, K)`` mask of the key points that had any target point within reach
    (elsewhere the virtual point is the moved key point itself, to be given no weight).

    Why: where a street repeats along its length (facades, parked cars), the best feature match can
    lie metres from the true counterpart; the pose head's consensus gets the motion roughly right,
    and the same affinity restricted to that neighbourhood then picks the counterpart. One candidate,
    not the pose head's soft pointer over J: at inference that pointer is sharpened to nearly its
    best candidate anyway (``inference_sharpening``), and a max costs a fraction of a top-J."""
    with torch.no_grad():
        moved = key_points @ rotation.transpose(1, 2) + translation.unsqueeze(1)
        near = torch.cdist(moved.float(), target_xyz.float()) <= radius
        best, index = key_rows.masked_fill(~near, float("-inf")).max(dim=-1)
        reached = torch.isfinite(best)
        virtual = torch.where(reached.unsqueeze(-1), gather_points(target_xyz, index), moved)
    return virtual, reached


def weighted_procrustes(
    source: Tensor, target: Tensor, weights: Tensor | None = None
) -> tuple[Tensor, Tensor]:
    """Batched (weighted) Kabsch: R ``(B, 3, 3)``, t ``(B, 3)`` minimising Σ w_i ‖R x_i + t - y_i‖².

    Paper §IV-E: H = Σ (x_i - x̄)(y_i - ȳ)ᵀ = U S Vᵀ, R = V diag(1, 1, det(V Uᵀ)) Uᵀ (the determinant
    fix keeps R a rotation when the best orthogonal map is a reflection), t = ȳ - R x̄. One batched
    ``torch.linalg.svd``, no loop over samples; the 3x3 SVD runs in float64 (except on MPS) for stable
    gradients, and the result is cast back to the input dtype.
    """
    if weights is None:
        weights = torch.ones(source.shape[:2], dtype=source.dtype, device=source.device)
    weights = weights / weights.sum(dim=1, keepdim=True).clamp_min(1e-12)
    w = weights.unsqueeze(-1)
    source_mean = (w * source).sum(dim=1, keepdim=True)
    target_mean = (w * target).sum(dim=1, keepdim=True)
    covariance = (source - source_mean).transpose(1, 2) @ (w * (target - target_mean))
    work_dtype = torch.float32 if covariance.device.type == "mps" else torch.float64
    u, _, vh = torch.linalg.svd(covariance.to(work_dtype))
    v = vh.transpose(1, 2)
    sign = torch.linalg.det(v @ u.transpose(1, 2)).sign()
    sign = torch.where(sign == 0, torch.ones_like(sign), sign)
    fix = torch.ones(covariance.shape[0], 3, dtype=work_dtype, device=covariance.device)
    fix = torch.cat([fix[:, :2], sign.unsqueeze(-1)], dim=1)
    rotation = ((v * fix.unsqueeze(1)) @ u.transpose(1, 2)).to(source.dtype)
    translation = target_mean.squeeze(1) - (rotation @ source_mean.transpose(1, 2)).squeeze(-1)
    return rotation, translation


def triple_hypotheses(source: Tensor, target: Tensor, hypotheses: int) -> tuple[Tensor, Tensor]:
    """``hypotheses`` rigid motions ``(B, H, 3, 3)``, ``(B, H, 3)``, each fitted to three correspondences
    drawn from a fixed-seed generator (deterministic, and the same for a moved cloud, so the estimate
    stays equivariant)."""
    batch, count, _ = source.shape
    generator = torch.Generator().manual_seed(0)
    triples = torch.randint(count, (hypotheses, 3), generator=generator).to(source.device)
    src = source[:, triples].reshape(batch * hypotheses, 3, 3).float()
    tgt = target[:, triples].reshape(batch * hypotheses, 3, 3).float()
    rotation, translation = weighted_procrustes(src, tgt)
    return rotation.view(batch, hypotheses, 3, 3), translation.view(batch, hypotheses, 3)


def compatible_hypotheses(
    source: Tensor, target: Tensor, seeds: int, group: int, tolerance: float
) -> tuple[Tensor, Tensor]:
    """``seeds`` rigid motions ``(B, S, 3, 3)``, ``(B, S, 3)``, each fitted to one seed correspondence and
    the ``group`` correspondences that agree most with it on pairwise distances.

    Why: a rigid motion keeps distances, so two right correspondences i, j have ``| |x_i - x_j| -
    |y_i - y_j| |`` below ``tolerance``, whatever the motion; wrong ones agree only by chance. Two
    correspondences that agree and share many other agreeing ones (second-order compatibility, as in
    SC²-PCR, Chen et al. 2022) are very likely both right. Where only 4-9 % of virtual points are right
    (an old-town street 10 frames apart), a random triple is all right once in thousands of draws; a
    seed with the most second-order support and its best-agreeing group are right far more often.
    Everything here depends on distances within each cloud, so it is unchanged by moving either cloud.
    """
    batch, count, _ = source.shape
    seeds = min(seeds, count)
    group = min(group, count)
    agree = ((torch.cdist(source, source) - torch.cdist(target, target)).abs() < tolerance).float()
    agree.diagonal(dim1=1, dim2=2).zero_()
    degree = agree.sum(-1)  # (B, K) first-order support of each correspondence
    first = degree.topk(min(count, 4 * seeds), dim=-1).indices  # candidates for seeds
    rows = torch.gather(agree, 1, first.unsqueeze(-1).expand(-1, -1, count))  # (B, 4S, K)
    second = rows * (rows @ agree)  # common agreeing correspondences, for agreeing pairs only
    strength = second.sum(-1)
    pick = strength.topk(seeds, dim=-1).indices  # (B, S)
    seed_rows = torch.gather(second, 1, pick.unsqueeze(-1).expand(-1, -1, count))
    seed_index = torch.gather(first, 1, pick)
    seed_rows.scatter_(2, seed_index.unsqueeze(-1), float("inf"))  # the seed is in its own group
    members = seed_rows.topk(group, dim=-1).indices  # (B, S, G)
    flat = members.reshape(batch, seeds * group)
    src = gather_points(source, flat).reshape(batch * seeds, group, 3)
    tgt = gather_points(target, flat).reshape(batch * seeds, group, 3)
    rotation, translation = weighted_procrustes(src, tgt)
    return rotation.view(batch, seeds, 3, 3), translation.view(batch, seeds, 3)


def consensus_start(
    source: Tensor,
    target: Tensor,
    weights: Tensor | None,
    hypotheses: int,
    threshold: float,
    seeds: int = 0,
    group: int = 16,
) -> tuple[Tensor, Tensor]:
    """The rigid motion, among ``hypotheses`` fitted to three random correspondences each and ``seeds``
    fitted to compatible groups (:func:`compatible_hypotheses`), that brings the most (weighted)
    correspondences within ``threshold`` metres: a RANSAC start for the re-weighting.

    Why: where many virtual points are wrong (scans metres apart, repeated structure), the least-squares
    start of the paper's SVD lies outside the basin of the re-weighting, which then keeps it. No
    gradient flows through the choice."""
    batch = source.shape[0]
    with torch.no_grad():
        src, tgt = source.float(), target.float()
        candidates = []
        if hypotheses > 0:
            candidates.append(triple_hypotheses(src, tgt, hypotheses))
        if seeds > 0:
            candidates.append(compatible_hypotheses(src, tgt, seeds, group, threshold))
        rotation = torch.cat([r for r, _ in candidates], dim=1)
        translation = torch.cat([t for _, t in candidates], dim=1).unsqueeze(2)
        moved = src.unsqueeze(1) @ rotation.transpose(-1, -2) + translation
        residual = (moved - tgt.unsqueeze(1)).norm(dim=-1)  # (B, H, K)
        support = (1.0 - (residual / threshold) ** 2).clamp_min(0.0)
        if weights is not None:
            support = support * weights.float().unsqueeze(1)
        best = support.sum(-1).argmax(dim=1)
        pick = torch.arange(batch, device=source.device)
    return rotation[pick, best].to(source.dtype), translation[pick, best, 0].to(source.dtype)


def robust_procrustes(
    source: Tensor,
    target: Tensor,
    weights: Tensor | None = None,
    iterations: int = 0,
    scale: float = 0.5,
    hypotheses: int = 0,
    threshold: float = 1.0,
    seeds: int = 0,
    group: int = 16,
    kernel: str = "cauchy",
) -> tuple[Tensor, Tensor]:
    """:func:`weighted_procrustes` (or, with ``hypotheses`` or ``seeds``, :func:`consensus_start`), then
    ``iterations`` re-solves with Cauchy weights of each pair's residual ``r``: ``w / (1 + (r / c)²)``
    with ``c`` halving each round down to ``scale`` (metres); ``kernel="geman-mcclure"`` squares the
    robust factor (a redescending influence: see ``VcrConfig.robust_kernel``).

    Why: a key point with no counterpart in the other scan still gets a virtual point, somewhere in
    that cloud; at full weight such points pull the estimate towards the centroids' difference, which
    for two scans around their own sensors means towards zero motion. The robust weights are
    detached (iteratively reweighted least squares): the gradient flows through the last solve.
    """
    if kernel not in ROBUST_KERNELS:
        raise ValueError(f"kernel must be one of {', '.join(ROBUST_KERNELS)}; got {kernel!r}")
    power = 2 if kernel == "geman-mcclure" else 1
    if hypotheses > 0 or seeds > 0:
        rotation, translation = consensus_start(source, target, weights, hypotheses, threshold, seeds, group)
    else:
        rotation, translation = weighted_procrustes(source, target, weights)
    base = (
        torch.ones(source.shape[:2], dtype=source.dtype, device=source.device) if weights is None else weights
    )
    for round_index in range(iterations):
        c = scale * 2.0 ** (iterations - 1 - round_index)
        with torch.no_grad():
            moved = source @ rotation.transpose(1, 2) + translation.unsqueeze(1)
            residual = (moved - target).norm(dim=-1)
            robust = (1.0 / (1.0 + (residual / c) ** 2)) ** power
        rotation, translation = weighted_procrustes(source, target, base * robust)
    return rotation, translation


def to_homogeneous(rotation: Tensor, translation: Tensor) -> Tensor:
    """R ``(B, 3, 3)``, t ``(B, 3)`` -> ``(B, 4, 4)`` homogeneous transforms."""
    transform = torch.zeros(*rotation.shape[:-2], 4, 4, dtype=rotation.dtype, device=rotation.device)
    transform[..., :3, :3] = rotation
    transform[..., :3, 3] = translation
    transform[..., 3, 3] = 1.0
    return transform
