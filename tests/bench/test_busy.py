"""bench busy: alone / beside rounds, the ratio, and no neighbour left running."""

import os
import sys

import pytest

from tactilesnn.bench import busy


def _running(pids):
    alive = []
    for pid in pids:
        try:
            os.kill(pid, 0)
            alive.append(pid)
        except ProcessLookupError:
            pass
    return alive


@pytest.mark.slow
def test_rounds_ratio_and_neighbours_stopped(tmp_path, monkeypatch):
    started = []
    real_popen = busy.subprocess.Popen

    def popen(*a, **kw):
        p = real_popen(*a, **kw)
        if a and a[0] == busy.NEIGHBOUR:  # (subprocess.run also opens the timed job)
            started.append(p.pid)
        return p

    monkeypatch.setattr(busy.subprocess, "Popen", popen)
    job = [sys.executable, "-c", "sum(range(10**6))"]
    res = busy.run(tmp_path, neighbours=2, rounds=2, command=job)
    assert len(res["alone_s"]) == len(res["beside_s"]) == 2 and len(started) == 4
    assert res["ratio"] == pytest.approx(res["beside_median_s"] / res["alone_median_s"])
    assert res["fair_share_ratio"] == (2 + res["cpus"]) / res["cpus"]
    assert (tmp_path / "busy.json").is_file()
    assert not _running(started)  # every neighbour killed


@pytest.mark.slow
def test_a_failing_job_is_reported_and_neighbours_still_stopped(monkeypatch):
    started = []
    real_popen = busy.subprocess.Popen

    def popen(*a, **kw):
        started.append(real_popen(*a, **kw))
        return started[-1]

    monkeypatch.setattr(busy.subprocess, "Popen", popen)
    with pytest.raises(RuntimeError, match="failed"):
        busy.beside([sys.executable, "-c", "raise SystemExit(3)"], 1)
    assert not _running([p.pid for p in started])


def test_the_default_command_trains_the_default_pipeline(tmp_path):
    cmd = busy.train_command(tmp_path / "r", epochs=1)
    assert cmd[3:] == [
        "train",
        "--out",
        str(tmp_path / "r"),
        "--quiet",
        "--no-export",
        "--epochs",
        "1",
    ]


@pytest.mark.slow
def test_side_by_side_times_each_job_and_stops_the_rest_on_failure():
    quick = [sys.executable, "-c", "import time; time.sleep(0.2)"]
    slow = [sys.executable, "-c", "import time; time.sleep(0.6)"]
    t = busy.side_by_side([quick, slow])
    assert 0.15 < t[0] < t[1]  # each job's own end, started together
    hang = [sys.executable, "-c", "import time; time.sleep(60)"]
    fail = [sys.executable, "-c", "import sys; sys.exit(3)"]
    started = []
    real_popen = busy.subprocess.Popen

    def popen(*a, **kw):
        p = real_popen(*a, **kw)
        started.append(p.pid)
        return p

    busy.subprocess.Popen = popen
    try:
        with pytest.raises(RuntimeError, match="failed \\(3\\)"):
            busy.side_by_side([hang, fail])
    finally:
        busy.subprocess.Popen = real_popen
    assert not _running(started)  # the hanging job was stopped
