"""The run's plan and stage lines: the estimate arithmetic and what the log says."""

import logging

import pytest

from tactilesnn.core.stages import StagePlan, bar_disabled, seconds


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_the_plan_sums_estimates_and_revises_what_is_left(caplog) -> None:
    clock = Clock()
    plan = StagePlan({"encoder selection": 10.0, "fit": 30.0, "export": 20.0}, time_fn=clock)
    assert plan.total() == 60.0 and plan.left() == 60.0
    assert plan.plan_line() == (
        "plan: encoder selection ~10 s; fit ~30 s; export ~20 s; total ~1 min 0 s"
    )
    with caplog.at_level(logging.INFO, logger="tactilesnn"), plan.stage("encoder selection"):
        clock.t = 12.0
    assert plan.taken == {"encoder selection": 12.0}
    plan.estimate("fit", 40.0)  # what the selection measured
    plan.estimate("encoder selection", 99.0)  # a stage done keeps what it took
    assert plan.left() == 60.0 and plan.total() == 72.0
    lines = [r.getMessage() for r in caplog.records]
    assert lines[0] == "[1/3] encoder selection (~10 s) ..."
    assert lines[1].startswith(
        "[1/3] encoder selection done in 12 s (elapsed 12 s, ~50 s left; peak memory"
    )
    assert "\r" not in "".join(lines)  # lines, not a redrawn bar


def test_an_unknown_estimate_is_shown_as_unknown() -> None:
    plan = StagePlan({"fit": None, "export": 5.0}, time_fn=Clock())
    assert plan.left() is None and plan.total() is None
    assert plan.plan_line() == "plan: fit ~?; export ~5 s; total ~?"


@pytest.mark.parametrize(
    "s, text", [(0.42, "0.4 s"), (42.0, "42 s"), (61.0, "1 min 1 s"), (None, "?"), (-3, "0.0 s")]
)
def test_seconds_for_a_person(s, text) -> None:
    assert seconds(s) == text


def test_bars_only_when_asked_and_on_a_terminal() -> None:
    assert bar_disabled(False) is True
    assert bar_disabled(True) is None  # tqdm decides: shown on a terminal, not in a piped log


def test_peak_memory_is_the_process_own_not_its_parents():
    """A run started by a large process (a benchmark, a notebook) logs its own peak: the rusage
    keeps the starting process's pages across the exec (a 0.9 GB run logged 3.8 GB)."""
    import subprocess
    import sys

    import numpy as np

    from tactilesnn.core.stages import peak_rss_bytes

    held = np.ones(400 << 20, np.uint8)  # 400 MiB resident here, in the parent
    code = "from tactilesnn.core.stages import peak_rss_bytes; print(peak_rss_bytes())"
    child = int(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                               check=True).stdout)  # fmt: skip
    assert peak_rss_bytes() >= held.nbytes  # this process's own peak counts what it holds
    assert child > 1 << 20 and child < 200 << 20, child  # tens of MB: its own, not the parent's
    assert peak_rss_bytes(999_999_999) == 0  # no such process: not known
