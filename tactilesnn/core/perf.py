"""Process-level performance settings, applied explicitly by the CLI and benchmarks: the allocator
(below) and the compute threads (:func:`fit_threads`).

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
#: :func:`fit_threads` chose the thread count itself (no user setting): :func:`refit_threads`
#: may change it as other processes come and go
_governed = False
_last_refit = 0.0
#: seconds between two looks at the machine's load while governed
REFIT_EVERY_S = 1.0
#: every compute-thread count :func:`fit_threads` / :func:`refit_threads` set in this process
_counts_set: set[int] = set()


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


def other_runnable(
    samples: int = 5, gap_s: float = 0.02, path: str = "/proc/loadavg"
) -> int | None:
    """Processes runnable now besides this one (median of ``samples`` reads of the kernel's
    running count, ``/proc/loadavg`` field 4), or None where the kernel does not say."""
    import statistics
    import time

    counts = []
    for i in range(samples):
        try:
            with open(path) as f:
                counts.append(int(f.read().split()[3].split("/")[0]))
        except (OSError, ValueError, IndexError):
            return None
        if i + 1 < samples:
            time.sleep(gap_s)
    return max(0, int(statistics.median(counts)) - 1)  # the reader itself is running


def usable_cpus() -> int:
    """CPUs this process may run on (affinity mask; the count where the platform has none)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def fit_threads(cpus: int | None = None, others: int | None = None) -> int | None:
    """Size torch's intra-op threads to the CPUs left by processes already running: ``cpus``
    (default: this process's affinity) minus ``others`` (default: :func:`other_runnable`), at
    least 1. Threads that wait at every parallel barrier for a sibling the scheduler gave away
    cost more than they bring: the default training beside two CPU-bound processes on 2 CPUs took
    40.6 s with 2 threads and 26.7 s with 1 (alone: 14.6 and 17.8 s; ``tactilesnn bench busy``).
    A thread count the user set (``OMP_NUM_THREADS``, ``TACTILESNN_THREADS``) is left alone; set
    one for bit-identical reruns (float sums split over threads round differently).
    Returns the count set, or None if unchanged."""
    global _governed
    if "OMP_NUM_THREADS" in os.environ:
        return None
    import torch

    wanted = os.environ.get("TACTILESNN_THREADS")
    _governed = wanted is None
    if wanted is not None:
        n = int(wanted)
    else:
        if cpus is None:
            cpus = usable_cpus()
        others = other_runnable() if others is None else others
        if others is None:
            return None
        n = max(1, min(cpus, cpus - others))
    # BLAS too when torch already has n: its pool was sized at numpy's import, not by torch
    limit_blas(n)
    _counts_set.add(n)
    if n == torch.get_num_threads():
        return None
    torch.set_num_threads(n)
    return n


def compute_threads() -> dict:
    """What a run's ``metrics.json`` records of its compute threads: the counts used (the
    current one and any :func:`fit_threads` / :func:`refit_threads` set) and whether they
    followed the machine's load. A seeded result is bit-identical only at the same counts
    (float sums split over threads round differently; ST-MNIST's csnn: 95.51 % quiet, 95.30 %
    beside a busy process): set ``TACTILESNN_THREADS`` to one of them to rerun it."""
    import torch

    return {"counts": sorted(_counts_set | {torch.get_num_threads()}),
            "fitted_to_load": _governed}  # fmt: skip


def limit_blas(n: int) -> None:
    """NumPy's and SciPy's BLAS pools (OpenBLAS spins its threads at every call) to ``n``
    threads too, as torch's: beside a busy process, a FabricSlide run's evaluation after the
    readout's solve took 38 s with BLAS at 2 threads on the 1 CPU left, 4 s alone."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # (scikit-learn's dependency: present wherever the baselines run)
        return
    threadpool_limits(limits=n, user_api="blas")


def refit_threads(cpus: int | None = None, others: int | None = None) -> int | None:
    """Fit the thread count again (at most every :data:`REFIT_EVERY_S`) where :func:`fit_threads`
    chose it: long work calls this between its steps (the trainer after every epoch). Two
    trainings started together each saw the other not yet running and kept 2 threads on 2 CPUs:
    149 s each against 15 s alone, until they looked again. A no-op where the user set the
    threads or :func:`fit_threads` was not called (a library user's process is left alone).
    Returns the count set, or None if unchanged."""
    global _last_refit
    import time

    if not _governed:
        return None
    now = time.monotonic()
    if now - _last_refit < REFIT_EVERY_S:
        return None
    _last_refit = now
    if others is None:
        # a few short reads after a pause: this process's own threads have gone to sleep
        # (bounded spin) and are not counted as others
        time.sleep(0.003)
        others = other_runnable(samples=3, gap_s=0.003)
        if others is None:
            return None
    return fit_threads(cpus, others)
