"""bench pareto's frame rows: the one-frame step graph, its gather form, many streams per call
and the floor of any call (each also through bound buffers), each timed and printed with its
latency and real-time factor."""

import pytest

from tactilesnn.bench.pareto import (
    _F,
    _FB,
    _FBOUND,
    _FG,
    _FLOOR,
    _FLOORB,
    FRAME_STREAMS,
    format_rt,
    realtime_rows,
)


@pytest.mark.slow
def test_the_frame_rows_run_and_say_one_frame(tmp_path):
    forms = [_F, _FG, _FB, _FLOOR, _FBOUND, _FLOORB]
    rows = tuple((10, None, False, (16, 5.0), f) for f in forms)
    rt = realtime_rows(rows, 3, tmp_path, window=400, rounds=1)
    assert [r["form"] for r in rt] == forms
    for r in rt:
        line = format_rt(r)
        assert "latency one frame" in line or r["form"] in (_FLOOR, _FLOORB)
        assert "x real time" in line and r["realtime_factor"] > 0
        assert r["step_samples"] == 10  # one 5 ms frame at 2 kHz per call
    assert rt[2]["streams"] == FRAME_STREAMS and rt[0]["streams"] == 1
    assert rt[0]["nodes"] > 1
