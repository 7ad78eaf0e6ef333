"""VCR-Net in plain PyTorch: configuration, network, losses and a size/speed profile.

Public API::

    VcrConfig, VcrConfig.preset("paper" | "default")
    VCRNet(config)(source, target) -> VcrOutput   # T_target_source, (B, N, 3) inputs in metres
    VCRNet.encode(points), VCRNet.register_features(src_pts, src_feat, tgt_pts, tgt_feat)
    weighted_procrustes(source, target, weights=None) -> (R, t); to_homogeneous(R, t)
    correspondence_loss, transformation_loss, triplet_pretraining_loss, farthest_point_sampling
    parameter_count, flops_per_pair, describe  (vcr_odom.model.profile)
"""

from vcr_odom.model.config import PRESETS, VcrConfig
from vcr_odom.model.correspondence import (
    VirtualCorrespondences,
    feature_affinity,
    to_homogeneous,
    virtual_correspondences,
    weighted_procrustes,
)
from vcr_odom.model.losses import (
    CorrespondenceLoss,
    TripletLoss,
    correspondence_loss,
    farthest_point_sampling,
    transformation_loss,
    triplet_pretraining_loss,
)
from vcr_odom.model.network import VCRNet, VcrOutput

__all__ = [
    "PRESETS",
    "CorrespondenceLoss",
    "TripletLoss",
    "VCRNet",
    "VcrConfig",
    "VcrOutput",
    "VirtualCorrespondences",
    "correspondence_loss",
    "farthest_point_sampling",
    "feature_affinity",
    "to_homogeneous",
    "transformation_loss",
    "triplet_pretraining_loss",
    "virtual_correspondences",
    "weighted_procrustes",
]
