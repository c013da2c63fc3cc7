"""The stream SNN: its frame step is the window's trajectory, the release reset, the decision,
the raster, training."""

import math

import numpy as np
import pytest
import torch

from tactilesnn.core.spikes import spike_raster
from tactilesnn.models import StreamSNNConfig, build_model
from tactilesnn.models.stream_snn import decide, frame_raster


def _model(**kw):
    return build_model(StreamSNNConfig(hidden=16, **kw), 10, 20, 3, 100.0, seed=0)


def _spikes(n=6, seed=0):
    g = torch.Generator().manual_seed(seed)
    t = torch.rand(n, 10, 20, generator=g) * 100.0
    keep = torch.rand(n, 10, 20, generator=g) < 0.3
    return torch.sort(torch.where(keep, t, torch.full_like(t, math.inf)), -1).values


def test_the_raster_bins_as_spike_raster():
    s = _spikes()
    s[0, 0, 0] = 100.0  # exactly at the window end: the last step
    np.testing.assert_array_equal(
        frame_raster(s, 5.0, 20).numpy(), spike_raster(s, 5.0, 20).numpy()
    )


def test_the_step_follows_the_window_trajectory():
    m = _model(quiet_ms=0.0)  # no release reset: the window form has none
    with torch.no_grad():
        for p in m.parameters():  # weights that make the hidden layer fire
            p.normal_(0.0, 0.8)
    s = _spikes()
    want = m.trajectory(s)
    got, _, _ = m.stream(m.raster(s))
    torch.testing.assert_close(got, want, atol=1e-4, rtol=1e-4)
    step = m.frame_module()
    raster = m.raster(s)
    state = [torch.zeros(6, 16), torch.zeros(6, 3), torch.zeros(6, 1)]
    with torch.no_grad():
        for t in range(raster.shape[0]):
            scores, _, *state = step(raster[t], *state)
    torch.testing.assert_close(scores, want[-1], atol=1e-4, rtol=1e-4)
    assert m.dt_ms == pytest.approx(5.0)  # the window over its 20 slots


def test_silence_returns_the_state_to_rest():
    m = _model(quiet_ms=20.0)  # 4 frames
    with torch.no_grad():
        m.out.bias.fill_(1.0)
    raster = torch.zeros(10, 1, 10)
    raster[0, 0, 0] = 1.0
    out, _, st = m.stream(raster)
    # frames 1..3 silent: the readout still integrates; the 4th silent frame resets it first
    assert out[3].abs().sum() > 0
    assert float(st.quiet[0, 0]) == 9.0
    np.testing.assert_allclose(out[4].numpy(), m.out.bias.detach().numpy()[None], atol=1e-6)


def test_the_decision_waits_for_the_margin():
    scores = torch.tensor([[3.0, 1.0, 0.0], [1.2, 1.0, 0.0]])
    assert decide(scores, torch.tensor(1.0)).tolist() == [0, -1]
    assert decide(scores, torch.tensor(0.1)).tolist() == [0, 0]


def test_training_lowers_the_loss_and_calibrates_a_margin():
    torch.manual_seed(0)
    m = _model()
    s = torch.cat([_spikes(16, 1), _spikes(16, 2) * 0.4])
    y = torch.cat([torch.zeros(16), torch.ones(16)]).long()
    opt = torch.optim.Adam(m.parameters(), lr=0.01)
    first = float(m.loss(s, y))
    for _ in range(60):
        opt.zero_grad()
        m.loss(s, y).backward()
        opt.step()
    assert float(m.loss(s, y)) < 0.5 * first
    m.calibrate_decision(s)
    assert 0 < float(m.decision_margin) < m.NEVER


def test_bad_settings_are_refused():
    for kw, msg in (({"burn_in": 1.0}, "burn_in"), ({"dt_ms": -1.0}, "dt_ms"),
                    ({"quiet_ms": math.inf}, "quiet_ms")):  # fmt: skip
        with pytest.raises(ValueError, match=msg):
            StreamSNNConfig(**kw)
