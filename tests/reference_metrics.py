"""Independent references the metric tests compare against (not part of the library)."""

from __future__ import annotations

import math

from vcr_odom.metrics import DriftResult

KISS_ICP_PI = 3.14
"""kiss-icp's C++ port converts radians to degrees with 180 / 3.14 (not pi)."""


def kiss_icp_equivalent(drift: DriftResult) -> tuple[float, float]:
    """Our drift in the units ``kiss_icp.metrics.sequence_error`` returns: (%, "deg/m" with pi = 3.14).

    kiss-icp's port averages rad/m and multiplies by 180 / 3.14 without the factor 100, so its second
    number is deg/m, slightly high. Only meaningful with the default 100..800 m lengths, the only
    ones kiss-icp evaluates.
    """
    r_rad_per_m = math.radians(drift.r_rel_deg_per_100m) / 100.0
    return drift.t_rel_percent, r_rad_per_m * 180.0 / KISS_ICP_PI
