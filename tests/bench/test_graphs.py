"""``tactilesnn bench graphs``: its rows, ratios and agreement check (the exporters themselves
are checked in tests/export/test_exporters.py; here both are the quick TorchScript one)."""

import json

import pytest

from tactilesnn.bench import graphs
from tactilesnn.export import onnx as export_onnx


@pytest.fixture
def one_exporter(monkeypatch):
    build = export_onnx.build_graph
    monkeypatch.setattr(
        export_onnx, "build_graph", lambda pipe, exporter: build(pipe, "torchscript")
    )


def test_quick_bench_writes_rows_with_ratios_and_full_agreement(tmp_path, one_exporter, capsys):
    from tactilesnn.cli import main

    assert main(["bench", "graphs", "--quick", "--repeats", "1", "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "graphs.json").read_text())
    (row,) = res["rows"]
    for exporter in graphs.EXPORTERS:
        r = row[exporter]
        assert r["agreement"] == 1.0 and r["nodes"] > 0 and r["ms_per_window"] > 0
    # the Scan form is batched by its own (larger) bytes per window, the Loop by the eager one
    assert row["torch.export"]["bytes_per_window"] > row["torchscript"]["bytes_per_window"]
    assert row["scan_speedup_over_loop"] == pytest.approx(
        row["torchscript"]["ms_per_window"] / row["torch.export"]["ms_per_window"]
    )
    printed = capsys.readouterr().out
    assert "x the Loop's" in printed and graphs.markdown(res) in printed
    assert main(["bench", "graphs", "--from-json", str(tmp_path / "graphs.json")]) == 0
    assert graphs.markdown(res) in capsys.readouterr().out


def test_a_graph_that_disagrees_with_torch_fails_the_bench(tmp_path, one_exporter, monkeypatch):
    from tactilesnn.cli import main

    predict = graphs._pipeline

    def wrong(*a, **kw):
        pipe = predict(*a, **kw)
        true = pipe.predict
        pipe.predict = lambda X: (true(X) + 1) % 3  # torch's answer no longer the graph's
        return pipe

    monkeypatch.setattr(graphs, "_pipeline", wrong)
    assert main(["bench", "graphs", "--quick", "--repeats", "1", "--out", str(tmp_path)]) == 1


def test_bad_counts_are_refused(tmp_path, capsys):
    from tactilesnn.cli import main

    assert main(["bench", "graphs", "--quick", "--windows", "0", "--out", str(tmp_path)]) != 0
    assert "--windows must be an integer >= 1, got 0" in capsys.readouterr().err
    assert not (tmp_path / "graphs.json").exists()
