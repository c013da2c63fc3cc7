"""A run's stages as plain log lines: the plan with an estimate before work starts, then one line
when each stage starts and one when it ends, with the elapsed time and an estimate of what is
left. Lines, not a redrawn bar, so a piped log reads like the terminal (no carriage returns).

Estimates are in seconds and may be revised as stages finish (:meth:`StagePlan.estimate`); a
stage without one is shown without a figure.
"""

from __future__ import annotations

import logging
import resource
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from .memory import release_memory

log = logging.getLogger("tactilesnn")


def peak_rss_bytes(pid: int | None = None) -> int:
    """Peak resident memory so far (bytes) of this process, or of ``pid`` (0 where that is not
    known). Read from ``/proc/PID/status``'s ``VmHWM``, which starts afresh when a process
    executes its program; the rusage's ``ru_maxrss`` (the fallback for this process, where
    there is no /proc) keeps the pages of the process it was started from: ``train --data`` on
    a 16-channel CSV folder, started by the fit benchmark, logged a peak of 3.80 GB for its own
    0.90 GB."""
    try:
        status = Path(f"/proc/{'self' if pid is None else int(pid)}/status").read_text()
        for line in status.splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    if pid is not None:
        return 0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak) * (1 if sys.platform == "darwin" else 1024)


def seconds(s: float | None) -> str:
    """``s`` for a person: ``"42 s"``, ``"3 min 5 s"`` (``"?"`` when unknown)."""
    if s is None:
        return "?"
    s = max(0.0, float(s))
    if s < 60:
        return f"{s:.0f} s" if s >= 1 else f"{s:.1f} s"
    m, r = divmod(round(s), 60)
    return f"{m} min {r} s"


class StagePlan:
    """Named stages with estimated seconds (``None``: not known yet), in order.

    ``time_fn`` is the clock (tests pass their own)."""

    def __init__(self, stages: dict[str, float | None], time_fn=time.perf_counter) -> None:
        self.order = list(stages)
        self.estimates: dict[str, float | None] = dict(stages)
        self.taken: dict[str, float] = {}
        self._now = time_fn
        self.t0 = time_fn()

    def estimate(self, name: str, s: float | None) -> None:
        """Revise the estimate of a stage not yet done."""
        if name not in self.taken:
            self.estimates[name] = s

    def left(self) -> float | None:
        """Estimated seconds of the stages not done (None if any is unknown)."""
        rest = [self.estimates[n] for n in self.order if n not in self.taken]
        return None if any(v is None for v in rest) else float(sum(rest))  # type: ignore[arg-type]

    def total(self) -> float | None:
        left = self.left()
        return None if left is None else sum(self.taken.values()) + left

    def plan_line(self) -> str:
        parts = [f"{n} ~{seconds(self.estimates[n])}" for n in self.order]
        return f"plan: {'; '.join(parts)}; total ~{seconds(self.total())}"

    def elapsed(self) -> float:
        return self._now() - self.t0

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Log the stage's start and end (with the elapsed time and what is left)."""
        k = self.order.index(name) + 1
        n = len(self.order)
        log.info("[%d/%d] %s (~%s) ...", k, n, name, seconds(self.estimates[name]))
        t = self._now()
        yield
        self.taken[name] = self._now() - t
        release_memory()  # what this stage freed is not the next one's resident memory
        left = self.left()
        log.info("[%d/%d] %s done in %s (elapsed %s%s; peak memory %.2f GB)", k, n, name,
                 seconds(self.taken[name]), seconds(self.elapsed()),
                 "" if k == n else f", ~{seconds(left)} left", peak_rss_bytes() / 1e9)  # fmt: skip


def bar_disabled(progress: bool) -> bool | None:
    """tqdm's ``disable`` for a bar shown only when ``progress`` is asked for and the output is
    a terminal (``None``: tqdm's own test), so a piped log gets the stage lines, not hundreds of
    carriage-return redraws."""
    return None if progress else True
