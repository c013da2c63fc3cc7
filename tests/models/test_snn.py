"""Surrogate-gradient LIF layers: exact discretisation, resets, gradients, explicit state."""

import itertools
import math

import pytest
import torch

from tactilesnn.models.functional import lif_scan
from tactilesnn.models.snn import (
    LIFLayer,
    SNNClassifier,
    _LIFScan,
    _SpikeFn,
    surrogate_grad,
)


def test_subthreshold_membrane_matches_closed_form():
    # constant current c: u_t = c (1 - beta^(t+1)) / (1 - beta), exact for held input
    beta, c = math.exp(-1 / 20), 0.02
    cur = torch.full((200, 1, 1), c, dtype=torch.float64)
    u = torch.zeros(1, 1, dtype=torch.float64)
    out, u_end = _LIFScan.apply(cur, u, beta, 1.0, "subtract", "fast_sigmoid", 10.0)
    assert out.sum() == 0  # steady state c / (1 - beta) = 0.41 < theta
    assert float(u_end) == pytest.approx(c * (1 - beta**200) / (1 - beta), rel=1e-12)


@pytest.mark.parametrize("reset", ["subtract", "zero"])
def test_spike_times_for_a_constant_current(reset):
    beta, c = 0.9, 0.3  # steady state 3.0 > theta = 1
    cur = torch.full((100, 1, 1), c, dtype=torch.float64)
    spikes, _ = _LIFScan.apply(
        cur, torch.zeros(1, 1, dtype=torch.float64), beta, 1.0, reset, "arctan", 5.0
    )
    t = torch.nonzero(spikes[:, 0, 0]).flatten().tolist()
    # first crossing: smallest t with c (1 - beta^(t+1)) / (1 - beta) >= 1
    first = math.ceil(math.log(1 - (1 - beta) / c) / math.log(beta)) - 1
    assert t[0] == first
    if reset == "zero":  # after each reset the same trajectory repeats: period first + 1
        assert all(b - a == first + 1 for a, b in itertools.pairwise(t))
    ref, _ = lif_scan(cur, torch.zeros(1, 1, dtype=torch.float64), beta, 1.0, reset == "subtract")
    assert torch.equal(spikes, ref)


@pytest.mark.parametrize("reset", ["subtract", "zero"])
@pytest.mark.parametrize("kind", ["fast_sigmoid", "arctan"])
def test_hand_written_backward_equals_autograd(reset, kind):
    torch.manual_seed(0)
    cur = (torch.randn(60, 3, 5, dtype=torch.float64) * 0.6 + 0.3).requires_grad_()
    u0 = torch.randn(3, 5, dtype=torch.float64).requires_grad_()
    w, wu = torch.randn(60, 3, 5, dtype=torch.float64), torch.randn(3, 5, dtype=torch.float64)
    s, u = _LIFScan.apply(cur, u0, 0.9, 1.0, reset, kind, 5.0)
    ((s * w).sum() + (u * wu).sum()).backward()
    cur2 = cur.detach().clone().requires_grad_()
    uu = u02 = u0.detach().clone().requires_grad_()
    out = []
    for c in cur2.unbind(0):
        uu = 0.9 * uu + c
        sp = _SpikeFn.apply(uu - 1.0, kind, 5.0)
        uu = uu - sp.detach() if reset == "subtract" else uu * (1 - sp.detach())
        out.append(sp)
    ((torch.stack(out) * w).sum() + (uu * wu).sum()).backward()
    torch.testing.assert_close(cur.grad, cur2.grad, atol=1e-12, rtol=0)
    torch.testing.assert_close(u0.grad, u02.grad, atol=1e-12, rtol=0)


def test_surrogates_peak_at_threshold():
    x = torch.linspace(-1, 1, 201)
    for kind in ("fast_sigmoid", "arctan"):
        g = surrogate_grad(x, kind, 10.0)
        assert int(g.argmax()) == 100 and torch.all(g > 0)


@pytest.mark.parametrize("recurrent", [False, True])
def test_streaming_in_chunks_equals_one_shot(recurrent):
    torch.manual_seed(1)
    layer = LIFLayer(6, 8, tau_mem_ms=10.0, recurrent=recurrent)
    x = (torch.rand(80, 2, 6) < 0.3).float()
    with torch.no_grad():
        whole, _ = layer(x)
        a, st = layer(x[:33])
        b, _ = layer(x[33:], st)
    assert torch.equal(torch.cat([a, b]), whole)


@pytest.mark.slow
@pytest.mark.parametrize("readout", ["count", "max", "mean"])
def test_classifier_learns_a_rate_task(readout):
    torch.manual_seed(0)
    x = torch.zeros(40, 64, 4)
    y = torch.randint(0, 2, (64,))
    for i in range(64):  # class k: afferents 2k, 2k+1 fire often
        x[:, i, 2 * int(y[i]) : 2 * int(y[i]) + 2] = (torch.rand(40, 2) < 0.5).float()
    model = SNNClassifier(4, 16, 2, readout=readout, tau_mem_ms=10.0)
    opt = torch.optim.Adam(model.parameters(), lr=0.02)
    for _ in range(60):
        opt.zero_grad()
        scores, _ = model(x)
        torch.nn.functional.cross_entropy(scores, y).backward()
        opt.step()
    assert float((model(x)[0].argmax(1) == y).float().mean()) >= 0.95


def test_bad_arguments():
    with pytest.raises(ValueError, match="reset"):
        LIFLayer(2, 2, reset="none")
    with pytest.raises(ValueError, match="surrogate"):
        LIFLayer(2, 2, surrogate="relu")
    with pytest.raises(ValueError, match="readout"):
        SNNClassifier(2, 2, 2, readout="last")
    with pytest.raises(ValueError, match=r"\[T, batch, 3\]"):
        LIFLayer(3, 2)(torch.zeros(5, 4))


@pytest.mark.parametrize("reset", ["subtract", "zero"])
@pytest.mark.parametrize("kind", ["fast_sigmoid", "arctan"])
def test_fused_kernel_equals_pure_torch(monkeypatch, reset, kind):
    import tactilesnn.models._lif_kernel as lk
    from tactilesnn.models.snn import _fused

    if lk.kernel() is None:  # no compiler here: the pure-torch path must be the one in use
        assert _fused(torch.zeros(2, 2)) is None
    torch.manual_seed(2)
    cur = torch.randn(120, 4, 33) * 0.5 + 0.25
    u0 = torch.randn(4, 33) * 0.3
    w = torch.randn(120, 4, 33)

    def run():
        c, u = cur.clone().requires_grad_(), u0.clone().requires_grad_()
        s, last = _LIFScan.apply(c, u, 0.93, 1.0, reset, kind, 7.0)
        ((s * w).sum() + last.sum()).backward()
        return s.detach(), last.detach(), c.grad, u.grad

    fused = run()
    monkeypatch.setattr(lk, "_kernel", None)
    plain = run()
    assert torch.equal(fused[0], plain[0])  # same spikes
    torch.testing.assert_close(fused[1], plain[1], atol=1e-5, rtol=1e-5)  # FMA rounding only
    torch.testing.assert_close(fused[2], plain[2], atol=1e-4, rtol=1e-4)  # f32 scan order
    torch.testing.assert_close(fused[3], plain[3], atol=1e-4, rtol=1e-4)


def test_states_are_typed_and_carry_a_stream():
    from tactilesnn.models.functional import LIFState, LIState, SNNState

    torch.manual_seed(2)
    for readout, recurrent in (("max", False), ("count", True)):
        model = SNNClassifier(4, 8, 3, readout=readout, recurrent=recurrent)
        x = (torch.rand(30, 2, 4) < 0.4).float()
        with torch.no_grad():
            whole, _ = model.trajectory(x)
            a, st = model.trajectory(x[:11])
            b, st2 = model.trajectory(x[11:], st)
        assert isinstance(st, SNNState) and isinstance(st.hidden, LIFState)
        assert isinstance(st.out, LIState if readout == "max" else LIFState)
        assert (st.hidden.s is not None) == recurrent and st.hidden.u.shape == (2, 8)
        torch.testing.assert_close(torch.cat([a, b]), whole)
        assert st2.hidden._fields == ("u", "s")
