"""Keep freed memory for reuse (glibc ``mallopt``) so that VCR-Net on the CPU does not page-fault
through every large temporary.

Why: the network's N x N tensors (distance bias, attention, affinity) are 4-25 MB each at N = 1024.
With glibc's defaults the heap top is returned to the system once more than 64 MB lie free there, so
each network call maps those pages again and the kernel zeroes them: at N = 1024 the self-attention
took 29 ms instead of 19 ms on two cores (``benchmarks/pipeline_speed.py`` shows it per stage). Keeping
up to :data:`TRIM_THRESHOLD_BYTES` free costs that much resident memory at most, and no time.

Process-wide, set once, only on glibc; ``VCR_ODOM_MALLOC_TUNING=0`` leaves the allocator alone (for a
host program that tunes malloc itself).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024
"""Allocations below this come from the heap (glibc's largest allowed value), not from fresh mmaps."""

TRIM_THRESHOLD_BYTES = 256 * 1024 * 1024
"""Free memory at the heap top kept for reuse instead of being returned to the system."""

OPT_OUT_VARIABLE = "VCR_ODOM_MALLOC_TUNING"

_M_TRIM_THRESHOLD = -1  # glibc malloc.h
_M_MMAP_THRESHOLD = -3

_applied: bool | None = None


def retain_freed_memory() -> bool:
    """Apply the tuning once per process; True where it is in effect (glibc, not opted out)."""
    global _applied
    if _applied is None:
        _applied = _apply()
    return _applied


def _apply() -> bool:
    if os.environ.get(OPT_OUT_VARIABLE, "1").strip() == "0":
        return False
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (macOS, musl without mallopt)
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    )
