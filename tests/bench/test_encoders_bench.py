"""`bench encoders`' GWT rows on a tiny workload: every form of ours is timed and judged
against its own float64 transform."""

from __future__ import annotations

from tactilesnn.bench.encoders import Workload, bench_gwt


def test_gwt_rows_cover_each_edge_treatment_with_float32_errors():
    w = Workload("tiny", 2, 1, 200.0, 2.0, 2.0, 90.0, 8)
    rows = {r["impl"]: r for r in bench_gwt(w, repeats=1, hop=10, threads_list=[1])}
    for name in ("tactilesnn-gwt f32", "tactilesnn-gwt f32 hop=10", "tactilesnn-gwt f32 periodic"):
        assert rows[name]["ms"] > 0
        assert rows[name]["max_err_rel_peak"] < 1e-5  # float32 rounding of the same transform


def test_fft_rows_time_every_installed_backend_at_float32_error():
    from tactilesnn.bench.encoders import bench_fft, fft_summary
    from tactilesnn.core.fft_backend import available

    w = Workload("tiny", 2, 1, 200.0, 2.0, 2.0, 90.0, 8)
    rows = [r for r in bench_fft(w, repeats=1, threads_list=[1]) if "error" not in r]
    ours = {r["impl"]: r for r in rows if r["impl"].startswith("tactilesnn")}
    assert len(ours) == 2 * len(available())  # both edge treatments per backend
    assert all(r["max_err_rel_peak"] < 1e-5 for r in ours.values())
    summary = fft_summary(rows)
    assert "| tiny | 1 | periodic |" in summary and "| tiny | 1 | reflect |" in summary
