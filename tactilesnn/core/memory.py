"""The process's memory between stages (standard library only: the service uses it too)."""

from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.cache
def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")  # (a subprocess on some systems: looked up once)
    try:
        return ctypes.CDLL(name) if name else None
    except OSError:
        return None


def release_memory() -> bool:
    """Hand the heap's free blocks back to the system (glibc's ``malloc_trim``): between the
    stages of a run, so that what one stage freed does not stay in the process's resident size
    while the next allocates elsewhere (:func:`~tactilesnn.core.perf.tune_allocator` keeps
    freed blocks for speed within a stage). Returns True if applied."""
    libc = _libc()
    try:
        return bool(libc.malloc_trim(0)) if libc is not None else False
    except AttributeError:  # not glibc
        return False
