"""VCR-Net hyper-parameters: one frozen configuration, two presets, a dict round-trip for weight files.

The ``paper`` preset follows the paper's experiments section (N=1024, k=20, 512-d LPD-Net output, K=896,
J=32, attention feed-forward width 1024, 4 heads). The ``default`` preset is a narrower network, sized
to keep up with a 10 Hz LiDAR at batch 1 on 2 CPU cores (``vcr_odom.model.profile`` measures it).

Deviation: the paper does not give γ (false-match weight of Loss_cor), the temperature of the soft
pointer, nor the input scaling; the values here are ours and are recorded with the weights.

Weight files written before a field existed load with that field's :data:`LEGACY_VALUES` (the behaviour
the file was trained with), not with today's default.
"""

from __future__ import annotations

from typing import Any, Literal, Self, get_args

from pydantic import Field, model_validator

from vcr_odom.errors import ConfigError
from vcr_odom.settings import Settings

PRESETS = ("paper", "default")
Encoder = Literal["invariant", "xyz"]
RobustKernel = Literal["cauchy", "geman-mcclure"]
ROBUST_KERNELS: tuple[str, ...] = get_args(RobustKernel)
ENCODERS: tuple[str, ...] = get_args(Encoder)
"""``invariant``: features from relative geometry only (``vcr_odom.model.invariant_encoder``), unchanged
by a translation or a rotation about z of the cloud; ``xyz``: the first layer sees absolute coordinates
(``vcr_odom.model.encoder``, the weights shipped before the invariant encoder)."""

LEGACY_VALUES: dict[str, object] = {
    "encoder": "xyz",
    "input_max_range": 80.0,
    "robust_iterations": 0,
    "consensus_hypotheses": 0,
    "inference_sharpening": 1.0,
    "distance_bias": False,
    "gated_rounds": 0,
    "consensus_seeds": 0,
}
"""What a weight file that lacks a field was trained with."""

INFERENCE_FIELDS: tuple[str, ...] = (
    "num_points",
    "input_max_range",
    "robust_iterations",
    "robust_scale",
    "robust_kernel",
    "consensus_hypotheses",
    "consensus_threshold",
    "consensus_seeds",
    "consensus_group",
    "inference_sharpening",
    "gated_rounds",
    "gate_radius",
    "weighted_svd",
)
"""Fields no tensor was fitted to: a file can run with other values than it was trained with.

Why ``num_points`` is among them: every layer is shared over points (pointwise MLPs, kNN EdgeConv,
attention), so no tensor's shape or meaning depends on N; the shipped file was trained on 512-point
clouds and runs on 1024 (``weights/MODEL_CARD.md``). The crop and the point count still shape what
*training* sees, so caches are checked against the model being trained, not against an init file."""


def parse_inference_setting(name: str, value: str) -> object:
    """A command-line ``NAME``, ``VALUE`` pair as :meth:`VcrConfig.with_changes` takes it: the name must be
    one of :data:`INFERENCE_FIELDS`; integer fields are parsed here (they are strict, as a weight file
    stores plain ints) and so are true/false ones, other values are left to the field's own validation."""
    if name not in INFERENCE_FIELDS:
        raise ConfigError(f"{name!r} is not an inference-only setting; valid: {', '.join(INFERENCE_FIELDS)}")
    if VcrConfig.model_fields[name].annotation is bool:
        if value.strip().lower() not in ("true", "false"):
            raise ConfigError(f"{name}: expected true or false; got {value!r}")
        return value.strip().lower() == "true"
    if VcrConfig.model_fields[name].annotation is int:
        try:
            return int(value)
        except ValueError:
            raise ConfigError(f"{name}: expected a whole number; got {value!r}") from None
    return value


def _count(default: int, minimum: int, description: str) -> Any:
    """An integer field (no bool, no float, no numpy integer: a weight file stores plain ints)."""
    return Field(default, ge=minimum, strict=True, description=description)


def _positive(default: float, description: str) -> Any:
    """A finite float field > 0."""
    return Field(default, gt=0, allow_inf_nan=False, description=description)


class VcrConfig(Settings):
    """Every architecture, inference and loss constant of VCR-Net (the model works for any N >= k + 1).

    Equality is field by field: :func:`vcr_odom.model.weights.load_weights` refuses a file whose
    stored configuration differs from the one requested in any field.
    """

    num_points: int = _count(512, 4, "N points per cloud fed by pre-processing (the paper: 1024).")
    k: int = _count(16, 1, "Neighbours of the feature-space and Cartesian kNN graphs (paper: 20).")
    point_dim: int = _count(64, 1, "Width of the pointwise MLP (3 -> p -> p).")
    graph_dim: int = _count(64, 1, "Width of the two feature-space EdgeConv layers.")
    spatial_dim: int = _count(128, 1, "Width of the Cartesian-space EdgeConv layer.")
    feature_dim: int = _count(128, 1, "LPD-Net output width (paper: 512).")
    heads: int = _count(4, 1, "Attention heads (paper: 4); must divide feature_dim.")
    ff_dim: int = _count(256, 1, "Feed-forward width of the attention blocks (the paper's 1024).")
    coordinate_scale: float = _positive(
        30.0,
        "Metres per network unit: xyz is divided by it before the first layer, so that a scan tens of "
        "metres across lands in the range the initialisation expects.",
    )
    top_k_fraction: float = Field(
        0.875,
        gt=0,
        le=1,
        description="K = round(fraction * N) key points of the source (paper: 896/1024).",
    )
    top_j: int = _count(16, 2, "Candidates per key point (paper: 32; J = 1 would have no gradient).")
    temperature: float = _positive(
        0.01,
        "Initial soft-pointer temperature (learned, stored as its log); the affinity is the negative "
        "mean squared feature difference divided by it. It starts sharp enough that unrelated points "
        "get far lower logits than feature-space neighbours, and a sharp pointer biases virtual points "
        "at the edges of a sparse scan less.",
    )
    weighted_svd: bool = Field(
        False,
        strict=True,
        description="Weight each key point by its self-attention weight in the pose head (no tensor "
        "depends on it; a file trained with the matching objective, whose weights say which points have "
        "a counterpart, runs with it).",
    )
    encoder: Encoder = Field("invariant", description="One of ENCODERS.")
    distance_bias: bool = Field(
        True,
        strict=True,
        description="Self-attention logits get a learned function of the distance between the two "
        "points (invariant to any rigid motion), so a point's feature can say where it lies relative to "
        "the rest of the scene rather than in the sensor frame.",
    )
    input_max_range: float = _positive(
        40.0,
        "The network sees points within this many metres of the sensor. Farther rings are sparse, make "
        "up few of a scan's points yet take many of farthest point sampling's N, and their pattern "
        "moves with the sensor, so they have no counterpart in a scan taken metres later.",
    )
    robust_iterations: int = _count(
        5,
        0,
        "After the paper's SVD, this many re-solves with robust weights (robust_kernel) of each key "
        "point's residual r, c halving down to robust_scale. Key points without a counterpart in the "
        "other scan get a virtual point somewhere in its cloud, and with full weight they pull the "
        "estimate towards zero motion. 0 = the paper's single unweighted SVD.",
    )
    robust_scale: float = _positive(0.125, "Final scale c of the re-weighting (metres).")
    robust_kernel: RobustKernel = Field(
        "cauchy",
        description="The re-weighting's weights: cauchy 1 / (1 + (r / c)²), or geman-mcclure, its square, "
        "whose influence falls to zero with the residual: far outliers that agree with each other (a "
        "repeated facade matched one bay off) cannot pull a right consensus start away from its inliers "
        "while c is still wider than the consensus radius.",
    )
    consensus_hypotheses: int = _count(
        256,
        0,
        "Where > 0, the re-weighting starts from the best of this many motions fitted to three "
        "correspondences each, instead of the unweighted SVD, whose start lies outside the "
        "re-weighting's basin when many virtual points are wrong (inference only: no gradient).",
    )
    consensus_threshold: float = _positive(
        1.0,
        "Support radius of a consensus hypothesis (metres); also the tolerance on pairwise distances "
        "of consensus_seeds.",
    )
    consensus_seeds: int = _count(
        32,
        0,
        "Where > 0, the consensus also tries this many motions, each fitted to a seed correspondence "
        "and the consensus_group correspondences that agree most with it on pairwise distances (a rigid "
        "motion keeps distances; inference only). Random triples rarely hit a right motion where only "
        "a few per cent of the virtual points are right, as 10 frames apart in an old-town street.",
    )
    consensus_group: int = _count(16, 3, "Correspondences per consensus_seeds motion.")
    inference_sharpening: float = _positive(
        64.0,
        "Outside training the soft pointer's temperature is divided by this, so each virtual point is "
        "(nearly) its best candidate: a blend of J candidates is drawn towards the middle of the target "
        "cloud, i.e. towards zero motion. Training keeps the learned temperature (its gradient needs "
        "the blend).",
    )
    gated_rounds: int = _count(
        3,
        0,
        "After the pose head, this many rounds of gated re-pointing (inference only): each key point's "
        "virtual point is re-chosen among the target points within gate_radius of where the estimate "
        "so far puts it, by the same feature affinity, and the motion re-solved. 0 = off.",
    )
    gate_radius: float = _positive(2.0, "Radius of the gated re-pointing (metres).")
    gamma: float = _positive(1.0, "The paper's γ: weight of the false-match term of Loss_cor.")
    match_radius: float | None = Field(
        None,
        gt=0,
        allow_inf_nan=False,
        description="None = the paper's true-match test (the GT-aligned virtual point's nearest source "
        "point is its key point); metres = true when the virtual point lies within this radius.",
    )

    @model_validator(mode="after")
    def _sizes_fit(self) -> Self:
        if self.k >= self.num_points:
            raise ValueError(f"k must be < num_points ({self.num_points}); got {self.k}")
        if self.feature_dim % self.heads:
            raise ValueError(f"heads must divide feature_dim ({self.feature_dim}); got {self.heads}")
        if self.top_j > self.num_points:
            raise ValueError(f"top_j must be <= num_points ({self.num_points}); got {self.top_j}")
        return self

    def key_points(self, n: int) -> int:
        """K for a cloud of ``n`` points: round(top_k_fraction * n), at least 3 and at most n."""
        return max(3, min(n, round(self.top_k_fraction * n)))

    @classmethod
    def preset(cls, name: str) -> VcrConfig:
        """``paper`` or ``default``."""
        if name == "paper":
            return cls(
                num_points=1024,
                k=20,
                point_dim=64,
                graph_dim=128,
                spatial_dim=256,
                feature_dim=512,
                heads=4,
                ff_dim=1024,
                top_k_fraction=0.875,
                top_j=32,
            )
        if name == "default":
            return cls()
        raise ConfigError(f"preset must be one of {', '.join(PRESETS)}; got {name!r}")

    @classmethod
    def from_dict(cls, data: Any) -> Self:
        """Inverse of :meth:`to_dict`; unknown keys raise ConfigError (a file for another model); a
        missing key of :data:`LEGACY_VALUES` takes the value older files were trained with."""
        if not isinstance(data, dict):
            raise ConfigError(f"a VcrConfig dict is needed; got {type(data).__name__}")
        return super().from_dict(LEGACY_VALUES | data)
