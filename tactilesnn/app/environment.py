"""What the command line asks of the process before a command runs: the package's version, the
allocator's settings and the compute threads (beside other work). Standard library and core."""

from __future__ import annotations

from ..core.perf import fit_threads, tune_allocator
from ..core.version import __version__

__all__ = ["__version__", "fit_threads", "tune_allocator"]
