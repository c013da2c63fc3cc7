"""NIR export of the SNN: read back with nir.read, simulated by nirtorch, same scores as ours."""

import numpy as np
import pytest

nir = pytest.importorskip("nir")

from tactilesnn.app.run import load_run  # noqa: E402
from tactilesnn.cli import main  # noqa: E402
from tactilesnn.config import PipelineConfig  # noqa: E402
from tactilesnn.datasets_synth import HookLoopTask  # noqa: E402
from tactilesnn.export import export_pipeline  # noqa: E402
from tactilesnn.export.nir import compare, simulate  # noqa: E402
from tactilesnn.models.snn_nir import snn_to_nir  # noqa: E402
from tactilesnn.service.runtime import PipelineSession  # noqa: E402
from tests.helpers import run_task  # noqa: E402

SMALL = {"seed": 0, "n_planar": 10, "n_concave": 5, "n_convex": 5, "n_test": 4}


@pytest.mark.slow
@pytest.mark.parametrize("readout", ["max", "count"])
def test_nir_export_reproduces_scores_on_the_test_split(tmp_path, capsys, readout):
    cfg = PipelineConfig.from_flat(
        encoder="lif", model="snn", epochs=3, snn_hidden=16, snn_readout=readout, snn_dt_ms=2.0
    )
    run, _ = run_task("hook_loop", SMALL, cfg, tmp_path / "r", progress=False)
    out = tmp_path / "m.nir"
    assert main(["export", str(run), "--format", "nir", "--out", str(out), "--quiet"]) == 0
    assert "predictions agree 100.00 %" in capsys.readouterr().out
    g = nir.read(str(out))
    assert float(g.metadata["dt_s"]) == pytest.approx(0.002)
    assert np.allclose(g.nodes["lif1"].tau, 0.05)  # seconds, from tau_ms = 50
    beta = np.exp(-2.0 / 50.0)
    assert np.allclose(g.nodes["lif1"].r, 1 / (1 - beta))
    pipe, _ = load_run(run)
    test = HookLoopTask(**SMALL).build()[1]
    rep = compare(pipe.model, pipe.encode(test.X), out)
    assert rep["subtract_reset_prediction_agreement"] == 1.0
    assert rep["subtract_reset_max_score_diff"] <= 1e-4


def test_subtract_reset_is_not_plain_nir_reset(tmp_path):
    """A strong input overshoots the threshold: only a consumer honouring the metadata matches."""
    import torch

    from tactilesnn.models import SNNConfig, build_model

    m = build_model(SNNConfig(hidden=4, dt_ms=1.0, readout="count"), 3, 1, 2, 20.0)
    with torch.no_grad():
        m.net.hidden.fc.weight.fill_(0.7)
        m.net.hidden.fc.bias.zero_()
        m.net.out.fc.weight.fill_(0.6)
        m.net.out.fc.bias.zero_()
    raster = torch.zeros(20, 1, 3)
    raster[::2] = 1.0  # 2.1 threshold units every other step
    ref = m.net(raster)[0]
    g = snn_to_nir(m)
    exact = simulate(g, raster, honour_reset=True).sum(0)
    plain = simulate(g, raster, honour_reset=False).sum(0)
    assert torch.equal(exact, ref)
    assert not torch.equal(plain, ref)


@pytest.mark.slow
def test_tempotron_is_refused_and_recurrent_snn_exports(tmp_path, capsys):
    run, _ = run_task("hook_loop", SMALL, PipelineConfig.from_flat(epochs=1), tmp_path / "t",
                       progress=False)  # fmt: skip
    rc = main(["export", str(run), "--format", "nir", "--out", str(tmp_path / "t.nir")])
    assert rc == 2 and "no NIR equivalent" in capsys.readouterr().err
    cfg = PipelineConfig.from_flat(model="snn", epochs=2, snn_hidden=8, snn_recurrent=True)
    run, m = run_task("hook_loop", SMALL, cfg, tmp_path / "rec", progress=False, export=True)
    assert m["onnx"]["max_score_diff"] <= 1e-4  # recurrent layers export to ONNX (state as I/O)
    pipe, _ = load_run(run)
    assert [n for n, _ in pipe.model.state_names] == ["h_state", "o_state", "hs_state"]
    sess = PipelineSession(str(run / "model.onnx"))
    assert set(sess.state_units) == {"h_state", "o_state", "hs_state"}
    g = pipe.model.to_nir()
    assert ("lif1", "rec") in g.edges and ("rec", "lif1") in g.edges
    with pytest.raises(FileExistsError):
        export_pipeline(pipe, run / "model.onnx", np.zeros((1, 2, 100), np.float32))


@pytest.mark.slow
def test_missing_nir_extra_is_a_one_line_error(tmp_path, monkeypatch, capsys):
    import sys

    cfg = PipelineConfig.from_flat(model="snn", epochs=1, snn_hidden=8)
    run, _ = run_task("hook_loop", SMALL, cfg, tmp_path / "r", progress=False)
    monkeypatch.setitem(sys.modules, "nir", None)  # as if the extra were not installed
    rc = main(["export", str(run), "--format", "nir", "--out", str(tmp_path / "m.nir")])
    err = capsys.readouterr().err
    assert rc == 2 and "pip install 'tactilesnn[nir]'" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
