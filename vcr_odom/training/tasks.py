"""What differs between training and pre-training: the module trained and the loss of one batch.

``loss`` returns the differentiable loss and detached per-batch means to log; keys ``rot_sq_deg`` and
``trans_sq_m`` (mean squared pose errors) become ``rot_rmse_deg`` / ``trans_rmse_m`` once averaged.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.nn.parallel import DistributedDataParallel

from vcr_odom.model.config import VcrConfig
from vcr_odom.model.losses import (
    correspondence_loss,
    matching_loss,
    transformation_loss,
    triplet_pretraining_loss,
)
from vcr_odom.model.network import VCRNet
from vcr_odom.training.config import TrainConfig


class ScaledEncoder(nn.Module):
    """The encoder alone as a module, so DDP can wrap exactly the parameters pre-training trains."""

    def __init__(self, net: VCRNet) -> None:
        super().__init__()
        self.encoder = net.encoder
        self.scale = net.config.coordinate_scale

    def forward(self, points: Tensor) -> Tensor:
        return self.encoder(points / self.scale)


class Task:
    """What differs between training and pre-training: the trained module and the per-batch loss."""

    name = ""

    def trainable(self, net: VCRNet) -> nn.Module:
        raise NotImplementedError

    def loss(
        self, module: nn.Module, batch: dict[str, Tensor], config: TrainConfig
    ) -> tuple[Tensor, dict[str, Tensor]]:
        raise NotImplementedError


class Registration(Task):
    """Loss_cor (or, with ``objective="matching"``, the matching loss plus a share of Loss_cor) trained;
    Loss_trans and the pose errors only monitored."""

    name = "train"

    def trainable(self, net: VCRNet) -> nn.Module:
        return net

    def loss(
        self, module: nn.Module, batch: dict[str, Tensor], config: TrainConfig
    ) -> tuple[Tensor, dict[str, Tensor]]:
        net_config: VcrConfig = unwrap(module).config
        out = module(batch["source"], batch["target"])
        r_gt, t_gt = batch["transform"][:, :3, :3], batch["transform"][:, :3, 3]
        gamma = config.gamma if config.gamma is not None else net_config.gamma
        cor = correspondence_loss(
            out.key_points.float(),
            out.virtual_points.float(),
            r_gt,
            t_gt,
            gamma,
            source_points=batch["source"],
            match_radius=net_config.match_radius,
        )
        rotation, translation = out.rotation.float().detach(), out.translation.float().detach()
        rot_err, trans_err = pose_errors(rotation, translation, r_gt, t_gt)
        loss = cor.loss
        metrics = {
            "trans_loss": transformation_loss(rotation, translation, r_gt, t_gt),
            "true_fraction": cor.true_fraction,
            "rot_sq_deg": rot_err.pow(2).mean(),
            "trans_sq_m": trans_err.pow(2).mean(),
        }
        if config.objective == "matching":
            # Validation runs in eval mode, whose pointer is sharpened: the cross-entropy is taken at
            # the learned temperature in both, so that the two figures compare.
            sharpening = 1.0 if module.training else net_config.inference_sharpening
            match = matching_loss(
                batch["source"],
                batch["target"],
                out.affinity / sharpening,
                out.source_weights,
                out.target_weights,
                out.key_indices,
                out.key_points,
                out.virtual_points,
                r_gt,
                t_gt,
                radius=config.counterpart_radius,
                overlap_weight=config.overlap_weight,
                pose_weight=config.pose_weight,
            )
            loss = match.loss + config.correspondence_weight * cor.loss
            metrics.update(
                correspondence=cor.loss.detach(),
                matching=match.matching,
                overlap=match.overlap,
                head_pose=match.pose,
                inlier_ratio=match.inlier_ratio,
                overlap_fraction=match.overlap_fraction,
            )
        metrics["loss"] = loss.detach()
        return loss, metrics


class Pretraining(Task):
    """Algorithm 1: the target is the source moved by the pair's transform, row for row, so the
    positive of every anchor is known exactly (whatever the dataset's own target cloud is)."""

    name = "pretrain"

    def trainable(self, net: VCRNet) -> nn.Module:
        return ScaledEncoder(net)

    def loss(
        self, module: nn.Module, batch: dict[str, Tensor], config: TrainConfig
    ) -> tuple[Tensor, dict[str, Tensor]]:
        source, transform = batch["source"], batch["transform"]
        target = source @ transform[:, :3, :3].transpose(1, 2) + transform[:, :3, 3].unsqueeze(1)
        features = module(torch.cat([source, target])).float()
        f_source, f_target = features.chunk(2)
        result = triplet_pretraining_loss(
            f_source,
            f_target,
            source,
            num_anchors=config.triplet_anchors,
            num_negatives=config.triplet_negatives,
            margin=config.triplet_margin,
            norm_weight=config.triplet_norm_weight,
        )
        return result.loss, {
            "loss": result.loss.detach(),
            "triplet": result.triplet,
            "regulariser": result.regulariser,
        }


def pose_errors(
    rotation: Tensor, translation: Tensor, rotation_gt: Tensor, translation_gt: Tensor
) -> tuple[Tensor, Tensor]:
    """Per-pair rotation error (degrees, angle of R_gtᵀ R) and translation error (metres).

    The angle is taken with atan2 of the skew part and the trace in float64: arccos of the trace alone
    cannot resolve angles below ~0.03° in float32, and the targets are 0.1°.
    """
    relative = rotation_gt.double().transpose(1, 2) @ rotation.double()
    cos = (relative.diagonal(dim1=1, dim2=2).sum(-1) - 1.0) / 2.0
    skew = relative - relative.transpose(1, 2)
    sin = torch.stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]], dim=-1).norm(dim=-1) / 2.0
    angle = torch.rad2deg(torch.atan2(sin, cos)).to(rotation.dtype)
    return angle, (translation - translation_gt).norm(dim=-1)


def unwrap(module: nn.Module) -> nn.Module:
    return module.module if isinstance(module, DistributedDataParallel) else module
