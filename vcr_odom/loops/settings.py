"""Every number the loop closure decides by, as one validated settings model.

Why one model: a threshold buried in a module can only be found by reading the code; here each has a
name with its unit, a description, bounds, and a place in the result's ``config.json``. A user tunes
them from a file, as kiss-icp's users do (``vcr-odom map --dump-config``, ``--config``: docs/usage.md).
"""

from __future__ import annotations

from typing import ClassVar

from pydantic import Field

from vcr_odom.settings import Settings


class LoopSettings(Settings):
    """The loop closure's settings (``map``'s options beyond ``run``'s)."""

    toml_title: ClassVar[str] = "vcr-odom map --config: the loop closure's settings (units in the names)"
    toml_listed_by: ClassVar[str] = "vcr-odom map --dump-config"

    loops: bool = Field(default=True, description="False: the odometry and its map only (a baseline).")
    # Keyframes and submaps
    node_spacing_m: float = Field(
        default=3.0, ge=0.1, description="Path between two nodes (and each odometry edge's prior sigma)."
    )
    node_angle_deg: float = Field(
        default=20.0, ge=1.0, description="A turn that makes a node too (and that prior's rotation sigma)."
    )
    narrow_field_coverage: float = Field(
        default=0.5,
        gt=0,
        le=1,
        description="A node whose cloud covers less than this share of the azimuth is a narrow field "
        "of view: turned away from the other visit, it is registered as a submap.",
    )
    submap_turn_deg: float = Field(
        default=45.0, ge=0, description="Narrow fields of view turned this much between visits use submaps."
    )
    submap_half_path_m: float = Field(default=30.0, gt=0, description="Path either side a submap spans.")
    submap_radius_m: float = Field(default=20.0, gt=0, description="A submap's crop round its node.")
    # Candidates gated by uncertainty
    revisit_radius_m: float = Field(
        default=5.0, ge=0.5, description="Two nodes this close see the same place (the sensor's overlap)."
    )
    min_loop_path_m: float = Field(default=30.0, ge=1.0, description="Path between the visits of a loop.")
    candidate_confidence: float = Field(
        default=0.99,
        gt=0,
        lt=1,
        description="A node is a candidate unless the odometry's position uncertainty between the visits "
        "(propagated along the path) makes a revisit less likely than 1 - this (a chi-square gate).",
    )
    attempt_spacing_m: float = Field(default=6.0, ge=0, description="Path between two attempts on a passage.")
    passage_attempts: int = Field(
        default=20, ge=1, description="At most about this many attempts along one revisited passage."
    )
    # Every fit's information
    information_points: float = Field(
        default=10.0,
        gt=0,
        description="Independent points behind an odometry edge's fit information (the points of a voxel "
        "cloud are correlated, and their count would make every fit overconfident): the prior on the "
        "odometry's drift until the loops measure it, so it errs loose (a walk's heading drifts "
        "coherently, where a random walk of fits would not).",
    )
    loop_information_points: float = Field(
        default=300.0,
        gt=0,
        description="The same for a loop's fit, calibrated so that right loops' errors against the truth "
        "follow their information (benchmarks/loop_calibration.py: median normalised squared error "
        "5.35, chi-square's on 6 dof).",
    )
    min_fit_rmse_m: float = Field(
        default=0.05, gt=0, description="The smallest noise a fit's information is scaled by."
    )
    # Verification as a measurement
    coarse_distance_m: float = Field(default=3.0, gt=0, description="ICP's first stage: the network's error.")
    fine_distance_m: float = Field(default=1.0, gt=0, description="ICP's second stage, the fit's scores.")
    icp_iterations: int = Field(default=30, ge=1, description="ICP iterations per stage.")
    min_cloud_points: int = Field(
        default=50, ge=3, description="Fewer voxels in a cloud: nothing to register."
    )
    min_overlap: float = Field(
        default=0.5, gt=0, le=1, description="Share of the source within the fine distance of the target."
    )
    min_overlap_narrow: float = Field(
        default=0.4,
        gt=0,
        le=1,
        description="The same where a field of view is narrow (view cones overlap in part).",
    )
    max_fit_rmse_m: float = Field(
        default=0.6,
        gt=0,
        description="Inlier RMSE on 1 m voxels (two voxelisations of a surface differ ~0.5 m).",
    )
    min_normal_share: float = Field(
        default=0.02,
        ge=0,
        lt=1 / 3,
        description="A loop fit whose correspondences' normals put less than this share along some "
        "direction (the smallest eigenvalue of their mean outer product) can slide along it: degenerate. "
        "The odometry's own threshold for a direction a scan cannot measure.",
    )
    starts_agree_m: float = Field(default=1.0, gt=0, description="Two starts that end this close: one fit.")
    starts_agree_deg: float = Field(default=5.0, gt=0, description="... and turned this little.")
    spread_start_sigmas: float = Field(
        default=2.0,
        ge=0,
        description="The odometry's start is also tried turned (about the world's up) and moved (along "
        "its least sure level direction) this many sigmas of its uncertainty either way: a fit such a "
        "start leaves for another of like overlap is one of several the odometry allows.",
    )
    ambiguity_overlap_gap: float = Field(
        default=0.15,
        ge=0,
        le=1,
        description="Two starts (the network's among them) that end in two fits whose overlaps differ "
        "less than this: the place repeats and the loop is ambiguous.",
    )
    odometry_confidence: float = Field(
        default=0.999,
        gt=0,
        lt=1,
        description="A loop whose correction of the odometry is less likely than 1 - this under the "
        "odometry's propagated uncertainty is a look-alike place (a chi-square gate on 6 dof).",
    )
    # Consistency across loops and the graph
    pairwise_confidence: float = Field(
        default=0.999,
        gt=0,
        lt=1,
        description="Two loops are consistent where the cycle they close with the odometry between them "
        "misses identity within this confidence (pairwise consistency maximisation).",
    )
    ground_up: bool = Field(
        default=True,
        description="Hold each node's tilt to the up measured in its cloud (its walls', else its ground's) "
        "where the odometry's tilt drifted from it beyond the measurement's noise.",
    )
    ground_sigma_deg: float = Field(
        default=2.0, gt=0, description="A road's slope plus the ground fit's noise."
    )
    walls_sigma_deg: float = Field(
        default=1.0,
        gt=0,
        description="A node's walls' up error, for the test whether to give the priors at all (in the "
        "graph each node's walls weigh by their own information).",
    )
    tilt_test_sigmas: float = Field(
        default=3.0,
        gt=0,
        description="Up priors are given where the odometry's tilt (90th percentile over the nodes) "
        "differs from the measured up by more than this many of the measurement's sigmas.",
    )
    # The map
    map_voxel_m: float = Field(default=0.5, ge=0.05, description="The map's voxel.")
    map_scan_spacing_m: float = Field(
        default=6.0, gt=0, description="Path between the scans the map is made of."
    )
