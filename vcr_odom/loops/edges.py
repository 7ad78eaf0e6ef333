"""The pose graph's edge: what a loop and an up prior have in common."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vcr_odom.geometry import Transform


@dataclass(frozen=True)
class GraphEdge:
    """A constraint ``T_target_source`` between nodes ``source`` and ``target``, with its information
    (6x6, rotation first as open3d orders it) over ``dof`` dimensions."""

    source: int
    target: int
    transform: Transform
    information: NDArray[np.float64]
    dof: int = 6
