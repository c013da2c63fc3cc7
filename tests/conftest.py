"""Suite-wide settings. Under CI (``CI=1``, set by ``.ci/run``) hypothesis draws the same
examples on every run, so a landing is judged on a fixed set; elsewhere each run explores new
ones (that is how the lying-header case of ``test_fuzz_hostile.py`` was found).

The CLI fits torch's threads to the CPUs other processes leave (``core/perf.py``); tests that
compare two in-process runs bit for bit need one count throughout, so the suite fixes it. Under
pytest-xdist (``make test`` runs a worker per CPU, up to 4, idle workers steal queued tests) each worker
gets its share of the CPUs and starts on its share of the slow tests.

Graphs are exported with the TorchScript-based exporter here (``TACTILESNN_ONNX_EXPORTER``): the
suite exports ~170 component graphs, which the supported ``torch.export``-based exporter (the
product's default) writes 5-15x slower; ``tests/export/test_exporters.py`` exports every
traced component and the stream graph with it and checks the same parity."""

import os

import torch
from hypothesis import settings

from tactilesnn.core.perf import limit_blas

_workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
if _workers > 1:  # pytest-xdist (make test): the CPUs shared among the workers, not oversubscribed
    _threads = max(1, (os.cpu_count() or 1) // _workers)
    torch.set_num_threads(_threads)
    os.environ.setdefault("OMP_NUM_THREADS", str(_threads))
    # numpy's OpenBLAS read the thread count when it was imported (before this file): its pool
    # of a thread per CPU spins in every worker at once unless limited here too
    limit_blas(_threads)
os.environ.setdefault("TACTILESNN_THREADS", str(torch.get_num_threads()))
os.environ.setdefault("TACTILESNN_ONNX_EXPORTER", "torchscript")
settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


def pytest_collection_modifyitems(config, items):
    """The slow tests first on every worker. pytest-xdist's worksteal scheduler hands worker
    ``i`` a contiguous share of the collection (``len(pending) // workers left``) and idle
    workers steal from the end of the longest queue; sorting every slow test to the front put
    them all in worker 0's share (one worker ran 10 minutes of slow tests in a row while the
    other stole the quick ones and waited). Each share now starts with its round-robin part of
    the slow tests, then quick ones; the order is the same in every worker (they collect it)."""
    slow = [i for i in items if i.get_closest_marker("slow") is not None]
    quick = [i for i in items if i.get_closest_marker("slow") is None]
    workers = max(1, _workers)
    sizes, left = [], len(items)
    for w in range(workers):  # the scheduler's shares, in its order
        sizes.append(left // (workers - w))
        left -= sizes[-1]
    ordered = []
    for w, size in enumerate(sizes):
        mine = slow[w::workers]
        take = max(0, size - len(mine))
        ordered += mine + quick[:take]
        quick = quick[take:]
    items[:] = ordered + quick
