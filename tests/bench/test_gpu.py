"""bench gpu runs anywhere with --device cpu: the CPU against itself agrees exactly."""

from __future__ import annotations

import pytest

from tactilesnn.bench import BENCHMARKS, benchmark


@pytest.mark.slow
def test_bench_gpu_on_the_cpu_agrees_with_itself():
    assert "gpu" in BENCHMARKS
    rows = benchmark("gpu").run("cpu", windows=8, encoders=("gwt", "delta"))
    assert [r["encoder"] for r in rows] == ["gwt", "delta"]
    assert all(r["ok"] and r["max_time_diff_ms"] == 0.0 and r["same_silence"] == 1.0 for r in rows)
