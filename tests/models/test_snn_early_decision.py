"""The SNN's early decision: the running scores, the margin rule (against plain loops), the
margin fitted on the training windows, and old runs loading with it off."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tactilesnn.models.functional import (
    POOLED_MAX_STEPS,
    decide_by_margin,
    pooled_prefix_max,
    prefix_max,
    reduce_readout,
    running_readout,
)
from tactilesnn.models.snn import SNNConfig, SNNModel


@pytest.mark.parametrize("steps", [1, 2, 3, 7, 64, 101])
def test_prefix_max_is_the_running_maximum(steps):
    x = torch.randn(steps, 3, 4, generator=torch.Generator().manual_seed(steps))
    assert torch.equal(prefix_max(x), torch.cummax(x, 0).values)


@pytest.mark.parametrize("steps", [1, 2, 7, 100, POOLED_MAX_STEPS])
def test_the_pooled_running_maximum_is_exact(steps):
    x = torch.randn(steps, 3, 4, generator=torch.Generator().manual_seed(steps))
    x[steps // 2] = -1e30  # far below the rest: the -inf padding never wins
    assert torch.equal(pooled_prefix_max(x), torch.cummax(x, 0).values)


@pytest.mark.slow
@pytest.mark.parametrize("exporter", ["torch.export", "torchscript"])
@pytest.mark.parametrize("steps", [100, POOLED_MAX_STEPS + 1])
def test_the_exported_running_maximum_is_one_max_pool_up_to_its_step_limit(exporter, steps):
    import onnx
    import onnxruntime as ort

    from tactilesnn.core.onnx_graph import component_to_onnx

    class Running(torch.nn.Module):  # batch first, as components take it
        def forward(self, x):
            return prefix_max(x.transpose(0, 1)).transpose(0, 1)

    x = torch.randn(2, steps, 3, generator=torch.Generator().manual_seed(0))
    model = component_to_onnx(Running(), (x,), ["x"], ["run"], exporter=exporter)
    ops = [n.op_type for n in model.graph.node]
    pooled = steps <= POOLED_MAX_STEPS
    assert ("MaxPool" in ops) == pooled and (ops.count("Max") == 0) == pooled
    onnx.checker.check_model(model)
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    for batch in (1, 5):  # the batch axis stays free
        xb = torch.randn(batch, steps, 3, generator=torch.Generator().manual_seed(batch))
        (got,) = sess.run(None, {"x": xb.numpy()})
        np.testing.assert_array_equal(got, torch.cummax(xb, 1).values.numpy())


@pytest.mark.parametrize("readout", ["count", "max", "mean"])
def test_running_scores_end_at_the_window_scores(readout):
    out = torch.rand(50, 6, 3, generator=torch.Generator().manual_seed(1))
    run = running_readout(out, readout)
    torch.testing.assert_close(run[-1], reduce_readout(out, readout), rtol=1e-6, atol=1e-6)
    for t in (0, 9, 31):  # each step: the readout of the window cut after it
        want = reduce_readout(out[: t + 1], readout)
        want = want * (t + 1) / 50 if readout == "mean" else want
        torch.testing.assert_close(run[t], want, rtol=1e-6, atol=1e-6)


def _decide_loop(run: np.ndarray, margin: float, dt: float, duration: float, final):
    """Reference: walk each window's steps until the leader leads by the margin."""
    cls, t_ms = [], []
    for b in range(run.shape[1]):
        for t in range(run.shape[0]):
            s = np.sort(run[t, b])[::-1]
            if s[0] - s[1] >= margin:
                cls.append(int(np.argmax(run[t, b])))
                t_ms.append(min((t + 1) * dt, duration))
                break
        else:
            cls.append(int(final[b]))
            t_ms.append(duration)
    return np.array(cls), np.array(t_ms)


@pytest.mark.parametrize("margin", [0.0, 0.3, 1.5, 1e9])
def test_margin_rule_matches_a_plain_loop(margin):
    gen = torch.Generator().manual_seed(2)
    run = prefix_max(torch.randn(40, 32, 4, generator=gen))  # nondecreasing scores so far
    final = run[-1].argmax(1)
    cls, t_ms = decide_by_margin(run, torch.tensor(margin), 5.0, 197.0, final)
    ref_c, ref_t = _decide_loop(run.numpy(), margin, 5.0, 197.0, final.numpy())
    np.testing.assert_array_equal(cls.numpy(), ref_c)
    np.testing.assert_allclose(t_ms.numpy(), ref_t)
    assert cls.dtype == torch.int64


def _rate_spikes(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Two classes of latency spikes: class 1 fires its half of the afferents early."""
    gen = torch.Generator().manual_seed(seed)
    y = torch.arange(n) % 2
    t = torch.rand(n, 20, 1, generator=gen) * 100.0
    early = torch.zeros(n, 20, 1, dtype=torch.bool)
    early[y == 1, :10] = True
    early[y == 0, 10:] = True
    return torch.where(early, t * 0.3, t), y


def _trained(spikes: torch.Tensor, y: torch.Tensor, **config: object) -> SNNModel:
    """A 16-unit SNN after 30 full-batch Adam steps (its margin not fitted yet)."""
    model = SNNModel(SNNConfig(hidden=16, dt_ms=2.0, **config), 20, 1, 2, 100.0, seed=0)
    opt = torch.optim.Adam(model.parameters(), lr=0.01)
    for _ in range(30):
        loss = model.loss(spikes, y)
        opt.zero_grad()
        loss.backward()
        opt.step()
    return model.eval()


def test_the_fitted_margin_agrees_on_the_training_windows():
    spikes, y = _rate_spikes(400, 0)
    model = _trained(spikes, y)
    assert float(model.early_margin) == SNNModel.NEVER  # before fitting: wait for the end
    cls, t_ms = model.early_decision(spikes)
    assert torch.equal(cls, model.scores(spikes).argmax(1)) and (t_ms == 100.0).all()

    model.calibrate_decision(spikes)
    m = float(model.early_margin)
    assert 0 < m < SNNModel.NEVER
    cls, t_ms = model.early_decision(spikes)
    full = model.scores(spikes).argmax(1)
    assert float((cls == full).float().mean()) >= model.config.early_agreement
    assert float(t_ms.mean()) < 100.0  # it decides before the window ends


@pytest.mark.slow
def test_a_stricter_agreement_decides_later_and_agrees_more():
    spikes, y = _rate_spikes(400, 3)
    times, agree = [], []
    for a in (0.9, 1.0):
        model = _trained(spikes, y, early_agreement=a)
        model.calibrate_decision(spikes)
        cls, t_ms = model.early_decision(spikes)
        agree.append(float((cls == model.scores(spikes).argmax(1)).float().mean()))
        times.append(float(t_ms.mean()))
        assert agree[-1] >= a
    assert agree[1] == 1.0 and times[0] <= times[1]
    with pytest.raises(ValueError, match="early_agreement"):
        SNNConfig(early_agreement=0.0)


def test_a_run_saved_before_the_early_decision_loads_with_it_off():
    from tactilesnn.config import PipelineConfig
    from tactilesnn.pipeline import SpikePipeline

    cfg = PipelineConfig.from_flat(model="snn", channels=("all",))
    pipe = SpikePipeline(cfg, 200.0, 100, ("a", "b"), ("x", "y"))
    X = np.random.default_rng(0).standard_normal((6, 2, 100)).astype(np.float32)
    pipe.calibrate(X)
    pipe.model.early_margin.fill_(1.0)
    old = {k: v for k, v in pipe.weights().items() if k != "model.early_margin"}
    fresh = SpikePipeline(cfg, 200.0, 100, ("a", "b"), ("x", "y"))
    fresh.load_weights(old)  # no error for the missing buffer
    assert float(fresh.model.early_margin) == SNNModel.NEVER
    spikes = fresh.encode(X)
    cls, t_ms = fresh.model.early_decision(spikes)
    assert torch.equal(cls, fresh.model.scores(spikes).argmax(1)) and (t_ms == 500.0).all()


def test_a_silent_output_layer_waits_for_the_window_end():
    """A spiking output that never fires has no leader: the margin stays NEVER."""
    model = SNNModel(SNNConfig(hidden=4, readout="count"), 20, 1, 2, 100.0, seed=0)
    with torch.no_grad():
        model.net.out.fc.weight.zero_()
        model.net.out.fc.bias.fill_(-1.0)
    spikes, _ = _rate_spikes(16, 1)
    model.calibrate_decision(spikes)
    assert float(model.early_margin) == SNNModel.NEVER
    cls, t_ms = model.early_decision(spikes)
    assert (t_ms == 100.0).all() and torch.equal(cls, model.scores(spikes).argmax(1))
