"""Process-level performance settings, applied explicitly by the CLI and benchmarks.

Large tensors freed by one time step of a simulation and allocated again by the next are, with
glibc's defaults, returned to the OS and page-faulted back in (~1.7 us per 4 KB page here): for the
SNN benchmark workload that doubled the forward time. :func:`tune_allocator` raises glibc's mmap and
trim thresholds so such buffers are reused from the heap instead. It changes only how freed memory
is kept, never results; it is a no-op off glibc.
"""

from __future__ import annotations

import ctypes
import ctypes.util

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_done = False


def tune_allocator(threshold_bytes: int = 1 << 30) -> bool:
    """Keep freed blocks up to ``threshold_bytes`` in the heap. Returns True if applied."""
    global _done
    if _done:
        return True
    name = ctypes.util.find_library("c")
    if not name:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    ok = bool(mallopt(_M_MMAP_THRESHOLD, threshold_bytes)) and bool(
        mallopt(_M_TRIM_THRESHOLD, threshold_bytes)
    )
    _done = ok
    return ok
