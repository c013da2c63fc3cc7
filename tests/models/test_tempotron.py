"""Exact tempotron maximum against a float64 dense grid and hand-built spike patterns."""

import math

import numpy as np
import pytest
import torch

from tactilesnn.models.tempotron import Tempotron, psp_norm


def dense_reference(model: Tempotron, times: torch.Tensor, step_ms: float = 0.01):
    """Brute force in float64: V on a dense grid (plus the spike times themselves)."""
    m64 = Tempotron(
        model.n_inputs, model.n_classes, model.duration_ms, model.tau_ms, model.tau_s_ms
    )
    m64 = m64.double()
    with torch.no_grad():
        m64.weight.copy_(model.weight.double())
    grid = torch.arange(0, model.duration_ms + step_ms / 2, step_ms, dtype=torch.float64)
    # V has kinks at spike times (inhibitory arrivals): the grid must contain them
    spikes = times[torch.isfinite(times) & (times <= model.duration_ms)].double()
    grid = torch.unique(torch.cat([grid, spikes]))
    with torch.no_grad():
        v = m64.potential(times.double(), grid)
    v_max, idx = v.max(dim=2)
    return v_max, grid[idx]


def test_v0_normalises_peak_to_one():
    eta = 4.0
    assert psp_norm(4.0, 1.0) == pytest.approx(eta ** (eta / (eta - 1)) / (eta - 1), rel=1e-12)
    m = Tempotron(1, 1, 100.0, tau_ms=20.0, tau_s_ms=5.0)
    s = torch.linspace(0, 100, 200001, dtype=torch.float64)
    assert float(m.kernel(s).max()) == pytest.approx(1.0, abs=1e-9)


def test_single_spike_peak_closed_form():
    m = Tempotron(1, 1, 200.0, tau_ms=20.0, tau_s_ms=5.0)
    with torch.no_grad():
        m.weight.fill_(0.7)
    v, t = m(torch.tensor([[30.0]]))
    s_peak = 20 * 5 / 15 * math.log(4)
    assert float(v.detach()) == pytest.approx(0.7, rel=1e-5)
    assert float(t.detach()) == pytest.approx(30 + s_peak, abs=1e-3)


def test_hand_built_patterns():
    m = Tempotron(3, 1, 100.0, tau_ms=10.0, tau_s_ms=2.5)
    with torch.no_grad():
        m.weight.copy_(torch.tensor([[1.0, 1.0, -5.0]]))
    # two coincident excitatory spikes sum to a peak of exactly 2
    v, _ = m(torch.tensor([[10.0, 10.0, float("inf")]]))
    assert float(v.detach()) == pytest.approx(2.0, rel=1e-5)
    # far-apart spikes do not sum: the peak stays ~1
    v, _ = m(torch.tensor([[10.0, 90.0, float("inf")]]))
    assert float(v.detach()) == pytest.approx(1.0, rel=1e-3)
    # inhibition only: V never rises above rest, the maximum is V_rest = 0 at t = 0
    v, t = m(torch.tensor([[float("inf"), float("inf"), 5.0]]))
    assert float(v.detach()) == 0.0 and float(t.detach()) == 0.0
    # no spikes at all
    v, _ = m(torch.full((1, 3), float("inf")))
    assert float(v.detach()) == 0.0


@pytest.mark.parametrize("seed", range(5))
def test_matches_dense_grid_on_random_patterns(seed):
    g = torch.Generator().manual_seed(seed)
    n_in, n_cls, dur = 12, 3, 100.0
    m = Tempotron(n_in, n_cls, dur, tau_ms=15.0, tau_s_ms=3.75, seed=seed)
    with torch.no_grad():
        m.weight.copy_(torch.randn(n_cls, n_in, generator=g))
    times = torch.rand(8, n_in, 3, generator=g) * dur
    times[torch.rand(times.shape, generator=g) < 0.3] = float("inf")
    with torch.no_grad():
        v, t = m(times)
    v_ref, t_ref = dense_reference(m, times)
    np.testing.assert_allclose(v.numpy(), v_ref.numpy(), atol=1e-5)
    # t_max agrees to the grid step unless two maxima tie within the tolerance
    close = torch.isclose(t.double(), t_ref, atol=0.02)
    with torch.no_grad():
        v_at_t = m.double().potential(times.double(), t.double().flatten()).diagonal(dim1=0, dim2=2)
    assert bool(close.all()) or torch.allclose(v_at_t.T.reshape_as(v_ref), v_ref, atol=1e-5)


def test_long_window_float32_no_overflow():
    # 1e5 ms window with tau_s = 2.5 ms: a naive exp(t / tau_s) running sum overflows at ~220 ms
    dur = 1.0e5
    m = Tempotron(4, 1, dur, tau_ms=10.0, tau_s_ms=2.5)
    with torch.no_grad():
        m.weight.copy_(torch.tensor([[0.6, 0.6, 0.6, -1.0]]))
    times = torch.tensor([[99000.0, 99001.0, 99002.0, 50.0]])
    v, t = m(times)
    assert torch.isfinite(v).all() and torch.isfinite(t).all()
    ref_m = Tempotron(4, 1, 200.0, tau_ms=10.0, tau_s_ms=2.5)
    with torch.no_grad():
        ref_m.weight.copy_(m.weight)
    v_ref, t_ref = dense_reference(ref_m, times - 98900.0)
    assert float(v.detach()) == pytest.approx(float(v_ref), abs=1e-5)
    assert float(t.detach()) - 98900.0 == pytest.approx(float(t_ref), abs=0.02)


def test_learning_rule_signs_and_magnitude():
    m = Tempotron(2, 2, 100.0, tau_ms=10.0, tau_s_ms=2.5, theta=1.0)
    with torch.no_grad():
        m.weight.copy_(torch.tensor([[0.2, 0.2], [2.0, 0.0]]))
    times = torch.tensor([[10.0, 12.0]])
    _, t = m(times)
    w0 = m.weight.detach().clone()
    n_err, _ = m.rule_update(times, torch.tensor([0]), lr=0.005)
    assert int(n_err) == 2  # class 0 missed its target, class 1 fired falsely
    k = m.kernel(t[:, :, None] - times[:, None, :])[0]
    expected = w0 + 0.005 * torch.stack([k[0], -k[1]])
    torch.testing.assert_close(m.weight.detach(), expected)


@pytest.mark.slow
def test_rule_learns_a_separable_timing_task():
    # class 0: inputs 0-4 fire together early; class 1: inputs 5-9 fire together early
    g = torch.Generator().manual_seed(0)
    n = 200
    y = torch.randint(0, 2, (n,), generator=g)
    times = 60 + 30 * torch.rand(n, 10, generator=g)
    for i in range(n):
        lo = 0 if y[i] == 0 else 5
        times[i, lo : lo + 5] = 10 + 2 * torch.rand(5, generator=g)
    m = Tempotron(10, 2, 100.0, tau_ms=10.0, tau_s_ms=2.5, seed=0)
    for _ in range(30):
        for i in range(0, n, 10):
            m.rule_update(times[i : i + 10], y[i : i + 10], lr=0.01)
    assert float((m.predict(times) == y).float().mean()) == 1.0


def test_rule_update_in_budgeted_chunks_equals_one_batch(monkeypatch):
    # a mini-batch of wide inputs is taken a few samples at a time (bounded memory); the update,
    # summed over the batch, is the same as the whole batch at once
    g = torch.Generator().manual_seed(1)
    times = 100 * torch.rand(12, 40, 2, generator=g)
    times[:, ::3, 1] = math.inf
    y = torch.randint(0, 3, (12,), generator=g)
    whole, chunked = Tempotron(40, 3, 100.0, seed=2), Tempotron(40, 3, 100.0, seed=2)
    with torch.no_grad():
        chunked.weight.copy_(whole.weight)
        chunked.weight[1] = -chunked.weight[1].abs()  # one silent tempotron: the coincidence path
        whole.weight[1] = chunked.weight[1]
    whole.rule_update(times, y, lr=0.01, momentum=0.5, margin=0.2)
    events = 40 * 2 + 1
    monkeypatch.setattr(Tempotron, "BUDGET_BYTES", 5 * 4 * 6 * events * events)  # 5 per call
    calls = []
    original = Tempotron._intervals
    monkeypatch.setattr(Tempotron, "_intervals", lambda self, t, w=None: calls.append(len(t)) or
                        original(self, t, w))  # fmt: skip
    chunked.rule_update(times, y, lr=0.01, momentum=0.5, margin=0.2)
    assert max(calls) == 5 and sum(calls) >= 12
    torch.testing.assert_close(chunked.weight, whole.weight, rtol=1e-6, atol=1e-7)


def test_rejects_bad_spike_input():
    m = Tempotron(3, 2, 100.0)
    with pytest.raises(ValueError, match="spike times"):
        m(torch.zeros(4, 5))
    with pytest.raises(ValueError, match="NaN"):
        m(torch.tensor([[1.0, float("nan"), 2.0]]))
    with pytest.raises(ValueError, match="tau > tau_s"):
        Tempotron(3, 2, 100.0, tau_ms=5.0, tau_s_ms=10.0)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(3))
def test_decision_time_is_the_first_dense_grid_crossing(seed):
    g = torch.Generator().manual_seed(seed)
    m = Tempotron(10, 2, 100.0, tau_ms=15.0, tau_s_ms=3.75)
    with torch.no_grad():
        m.weight.copy_(torch.randn(2, 10, generator=g) * 0.8)
    times = torch.rand(16, 10, 2, generator=g) * 100
    t_dec = m.decision_times(times)
    grid = torch.arange(0, 100.0 + 1e-9, 0.001, dtype=torch.float64)
    with torch.no_grad():
        v = m.double().potential(times.double(), grid)
    above = v >= 1.0
    first = torch.where(
        above.any(2), grid[above.to(torch.int8).argmax(2)], torch.full(above.shape[:2], math.inf)
    )
    fin = torch.isfinite(first)
    assert torch.equal(fin, torch.isfinite(t_dec))
    np.testing.assert_allclose(t_dec[fin].numpy(), first[fin].numpy(), atol=2e-3)


def test_early_decision_agrees_when_one_class_dominates():
    m = Tempotron(4, 2, 200.0, tau_ms=20.0, tau_s_ms=5.0)
    with torch.no_grad():
        m.weight.copy_(torch.tensor([[0.8, 0.8, 0.0, 0.0], [0.0, 0.0, 0.8, 0.8]]))
    times = torch.tensor([[10.0, 11.0, 150.0, 151.0]])  # class 0 fires ~ 15 ms, class 1 later
    cls, t = m.predict_early(times)
    assert int(cls) == 0 and 10 < float(t) < 30


def test_a_silenced_tempotron_recovers():
    # all-negative weights: V never rises above rest, t_max is the window start; the rule must
    # still potentiate the missed target instead of giving a zero update forever
    m = Tempotron(3, 1, 100.0, tau_ms=10.0, tau_s_ms=2.5)
    with torch.no_grad():
        m.weight.fill_(-1.0)
    times = torch.tensor([[10.0, 20.0, 30.0]])
    w0 = m.weight.detach().clone()
    for _ in range(400):
        m.rule_update(times, torch.tensor([0]), lr=0.05)
    assert torch.all(m.weight > w0)
    assert bool(m.fired(m(times)[0]).all())
