"""Process-level performance settings, applied explicitly by the CLI and benchmarks.

Large tensors freed by one time step of a simulation and allocated again by the next are, with
glibc's defaults, returned to the OS and page-faulted back in (~1.7 us per 4 KB page here): for the
SNN benchmark workload that doubled the forward time. :func:`tune_allocator` raises glibc's mmap and
trim thresholds so such buffers are reused from the heap instead. It also caps glibc's malloc arenas
at one per core: each arena reserves address space (64 MB heaps) and keeps its own freed blocks, so
with the defaults (8 per core) the 1,000 x 13,000-sample `train --data` run peaked at 1.9-2.0 GB of
address space, at the edge of the 2 GiB limit it is tested under; with the cap, 1.6 GB. It changes
only how freed memory is kept, never results; it is a no-op off glibc.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_M_ARENA_MAX = -8
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
    ok = (
        bool(mallopt(_M_MMAP_THRESHOLD, threshold_bytes))
        and bool(mallopt(_M_TRIM_THRESHOLD, threshold_bytes))
        and bool(mallopt(_M_ARENA_MAX, max(2, os.cpu_count() or 2)))
    )
    _done = ok
    return ok
