"""Odometry: registration methods chained into trajectories, optionally polished, run over sequences."""

from vcr_odom.odometry.chain import Odometry, PreparedFrame, Step
from vcr_odom.odometry.factory import (
    DEFAULT_GLOBAL_POLISH,
    GLOBAL_METHODS,
    build_odometry,
    canonical_spec,
    default_polish,
    parse_method_spec,
)
from vcr_odom.odometry.frame_loop import OdometryRun, run_odometry
from vcr_odom.odometry.limits import InitialGuess, MotionLimits
from vcr_odom.odometry.polish import POLISHES, IcpPolish, KissIcpPolish, Polish, PolishResult

__all__ = [
    "DEFAULT_GLOBAL_POLISH",
    "GLOBAL_METHODS",
    "POLISHES",
    "IcpPolish",
    "InitialGuess",
    "KissIcpPolish",
    "MotionLimits",
    "Odometry",
    "OdometryRun",
    "Polish",
    "PolishResult",
    "PreparedFrame",
    "Step",
    "build_odometry",
    "canonical_spec",
    "default_polish",
    "parse_method_spec",
    "run_odometry",
]
