"""Latency code: stronger -> earlier, floor, normalisation, degenerate inputs."""

import numpy as np
import pytest
import torch

from tactilesnn.encoders.latency import LatencyCode, to_dense


def scalogram(amps):
    """[1, 1, bands, 4 frames] with constant amplitude per band."""
    a = torch.tensor(amps, dtype=torch.float64)
    return a[None, None, :, None].expand(1, 1, len(amps), 4).clone()


def test_log_mapping_closed_form():
    code = LatencyCode(duration_ms=500, mapping="log", dynamic_range_db=30)
    t = code(scalogram([1.0, 0.1, 10 ** (-25 / 20), 1e-3]))[0]
    # 0 dB -> 0 ms, -20 dB -> 333.3 ms, -25 dB -> 416.7 ms, -60 dB -> silent
    np.testing.assert_allclose(t[:3].numpy(), [0.0, 500 * 20 / 30, 500 * 25 / 30], rtol=1e-5)
    assert torch.isinf(t[3])


def test_linear_mapping_and_floor():
    code = LatencyCode(duration_ms=100, mapping="linear", floor=0.2)
    t = code(scalogram([2.0, 1.0, 0.5, 0.1]))[0]
    np.testing.assert_allclose(t[:3].numpy(), [0.0, 50.0, 75.0], rtol=1e-6)
    assert torch.isinf(t[3])


def test_stronger_is_earlier_and_gain_invariant():
    code = LatencyCode()
    amps = [0.3, 0.9, 0.05, 0.6]
    t1 = code(scalogram(amps))[0]
    t2 = code(scalogram([1e5 * a for a in amps]))[0]  # 5 decades louder: same spectral shape
    torch.testing.assert_close(t1, t2)
    order = np.argsort(-np.array(amps))
    assert np.all(np.diff(t1.numpy()[order]) > 0)


def test_zero_and_tiny_inputs_stay_finite():
    code = LatencyCode(stats=("mean", "std"))
    zeros = torch.zeros(2, 3, 5, 10)
    t = code(zeros)
    assert t.shape == (2, 30) and torch.isinf(t).all()  # no division by zero, no spikes
    tiny = torch.rand(2, 3, 5, 10) * 1e-6
    assert torch.isfinite(code(tiny)).any()


def test_std_stat_sees_bursts_only():
    code = LatencyCode(stats=("mean", "std"))
    steady = torch.ones(1, 1, 2, 8)
    bursty = steady.clone()
    bursty[..., ::4] = 4.0
    assert torch.isinf(code(steady)[0, 2:]).all(), "no fluctuation -> the std neurons are silent"
    assert torch.isfinite(code(bursty)[0, 2:]).all()


def test_to_dense_roundtrip():
    # one binning convention (tactilesnn.core.spikes): a 20 ms window at 1 ms is 20 steps, step j holds
    # [j, j + 1) ms and a spike at exactly the window end falls into the last step
    t = torch.tensor([[0.0, 12.0, float("inf"), 20.0]])
    d = to_dense(t, duration_ms=20, dt_ms=1.0)
    assert d.shape == (1, 4, 20)
    assert d[0, 0, 0] == 1 and d[0, 1, 12] == 1 and d[0, 2].sum() == 0 and d[0, 3, 19] == 1
    assert d.sum() == 3


def test_rejects_bad_arguments():
    with pytest.raises(ValueError, match="mapping"):
        LatencyCode(mapping="cubic")
    with pytest.raises(ValueError, match="statistic"):
        LatencyCode(stats=("median",))
    with pytest.raises(ValueError, match="scalogram"):
        LatencyCode()(torch.zeros(3, 4))
