"""What the odometry said about its own frames, and what the loop phase makes of it.

Two records of the odometry's per-frame info, by frame index: the frames whose motion it replaced as
implausible (``flagged``), which bend a submap placed across them
(:data:`~vcr_odom.loops.verify.MAX_SUBMAP_FLAGGED`), and how well each frame's prior fitted the frame
before it (``prior_fit``, the default method's kiss-icp result scored frame to frame), which tells the
pose graph where the odometry was weakly held. A walk's odometry errs where a frame fits its
predecessor poorly: a narrow field of view sweeping round a corner into walls its local map does not
hold yet. On the courtyard walks (handheld Avia) the lowest fit among a node edge's frames ranks with
that edge's error (Spearman -0.3 to -0.57 on 881, 894, 897, 898, 899, 921), and a loop's correction
belongs there rather than spread evenly over the lap. A field of view all round sees the corner
before it turns: there the fit does not tell where the error was made, and loosening the edges it
names let the loops bend good odometry (car loops 801 and 806: maps 0.055 -> 0.079 m and 0.033 ->
0.043 m), so only narrow fields are weighed by it (:data:`~vcr_odom.loops.nodes.NARROW_FIELD_COVERAGE`,
the nodes' median). Methods that record no fit leave every edge as the drift model weighs it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.loops.nodes import Node, mostly_narrow

FIT_POWER = 4.0
MAX_FIT_FACTOR = 10.0
"""An edge's sigmas (translation and heading) grow by ``(median fit / lowest fit) ** FIT_POWER``, from 1
to at most this. On the tuning walks (881, 884, 891, 894, 898, 899) power 4 lowered every map's ATE
(881 0.534 -> 0.414 m, 898 1.516 -> 1.135 m); 8 lowered four of them further and raised 891 and 899;
caps of 10 and 30 gave the same maps."""


@dataclass(frozen=True)
class OdometryDoubts:
    """``flagged_frames``: where the odometry replaced a motion as implausible; ``fits``: each frame's
    prior fit (frame index -> fit in [0, 1]); empty where the method records none."""

    flagged_frames: tuple[int, ...] = ()
    fits: Mapping[int, float] = field(default_factory=dict)

    @classmethod
    def of_run(
        cls, frame_indices: Sequence[int], per_frame_info: Sequence[Mapping[str, Any]]
    ) -> OdometryDoubts:
        """From an odometry run's frames and per-frame info (``OdometryRun``)."""
        pairs = list(zip(frame_indices, per_frame_info, strict=False))
        flagged = tuple(index for index, info in pairs if info.get("flagged"))
        fits = {
            index: float(info["prior_fit"])
            for index, info in pairs
            if isinstance(info.get("prior_fit"), (int, float)) and math.isfinite(info["prior_fit"])
        }
        return cls(flagged, fits)


def fit_sigma_factors(nodes: Sequence[Node], fits: Mapping[int, float]) -> NDArray[np.float64]:
    """Per edge of the node chain (one fewer than the nodes), the factor on its sigmas from the lowest
    fit among the frames after the edge's first node up to its second: 1 where that is the run's
    median fit or better, where no frame of the edge has a fit, and on every edge of a sensor that
    sees all round."""
    factors = np.ones(max(len(nodes) - 1, 0), dtype=np.float64)
    if not fits or not mostly_narrow(nodes):
        return factors
    frames = np.array(sorted(fits), dtype=np.int64)
    values = np.array([fits[int(frame)] for frame in frames], dtype=np.float64)
    typical = float(np.median(values))
    for k, (earlier, later) in enumerate(pairwise(nodes)):
        start = np.searchsorted(frames, earlier.frame_index, side="right")
        stop = np.searchsorted(frames, later.frame_index, side="right")
        if stop > start:
            lowest = float(values[start:stop].min())
            ratio = typical / lowest if lowest > 0 else math.inf
            factors[k] = min(max(ratio**FIT_POWER, 1.0), MAX_FIT_FACTOR)
    return factors
