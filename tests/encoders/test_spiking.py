"""LIF converter against the closed-form solution; delta / sigma-delta reconstruction; utilities."""

import math

import numpy as np
import pytest

from tactilesnn.encoders.spiking import (
    contact_onset,
    lif_convert,
    spike_rate,
)

FS = 1000.0  # 1 ms samples


def isi_closed_form(v_inf, theta, tau, t_ref=0.0, v_reset=0.0):
    return t_ref + tau * math.log((v_inf - v_reset) / (v_inf - theta))


@pytest.mark.parametrize("current", [1.5, 3.0, 10.0])
@pytest.mark.parametrize("t_ref", [0.0, 2.5])
def test_constant_current_matches_analytic_isi(current, t_ref):
    x = np.full((1, 1, 500), current)
    ev = lif_convert(x, FS, tau_ms=10.0, threshold=1.0, refractory_ms=t_ref)
    t = ev.times(0, 0)
    first = 10.0 * math.log(current / (current - 1.0))
    assert t[0] == pytest.approx(first, abs=1e-9), "first spike is interpolated inside a sample"
    np.testing.assert_allclose(np.diff(t), isi_closed_form(current, 1.0, 10.0, t_ref), atol=1e-9)


def test_subthreshold_never_fires_and_step_onset():
    assert len(lif_convert(np.full((1, 1, 1000), 0.99), FS, tau_ms=5.0)) == 0
    x = np.zeros((1, 1, 300))
    x[..., 100:] = 2.0
    t = lif_convert(x, FS, tau_ms=5.0).times(0, 0)
    assert t[0] == pytest.approx(100 + 5.0 * math.log(2.0), abs=1e-9)


def test_reset_by_subtraction_keeps_the_overshoot():
    # with a huge drive several spikes fall in one sample; subtraction keeps rate ~ drive / theta
    x = np.full((1, 1, 50), 1000.0)
    n_sub = len(lif_convert(x, FS, tau_ms=1000.0, threshold=1.0, reset="subtract"))
    n_rest = len(lif_convert(x, FS, tau_ms=1000.0, threshold=1.0, reset="rest"))
    assert n_sub >= n_rest > 0
    assert n_sub == pytest.approx(50 * 1000.0 / 1000.0, rel=0.05)  # ~ drive * dt / (tau * theta)


def test_batches_and_channels_are_independent():
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 3, (2, 3, 200))
    ev = lif_convert(x, FS)
    for b in range(2):
        for c in range(3):
            single = lif_convert(x[b : b + 1, c : c + 1], FS).times(0, 0)
            np.testing.assert_allclose(ev.times(b, c), single)
    dense = ev.to_dense(1.0)
    assert dense.shape == (2, 3, 200) and dense.sum() == len(ev)


def test_the_delta_encoder_reconstructs_within_half_a_step():
    """The registered send-on-delta encoder (the one delta code): the first level plus the
    ON minus OFF counts is the signal within half a level step."""
    from tactilesnn.encoders import DeltaConfig, build_encoder

    t = np.arange(2000) / FS
    x = (np.sin(2 * np.pi * 3 * t) + 0.3 * np.sin(2 * np.pi * 17 * t))[None, None]
    enc = build_encoder(DeltaConfig(threshold=20.0, max_spikes=256), FS, 2000, 1).fit(x)
    step = float(enc.delta[0])
    times = enc.encode(x)[0].numpy()  # [2, k] ms
    assert np.isfinite(times).sum(-1).max() < 256  # no spike dropped
    grid = np.arange(2000) * 1000.0 / FS
    ups = np.searchsorted(np.sort(times[0][np.isfinite(times[0])]), grid, side="right")
    downs = np.searchsorted(np.sort(times[1][np.isfinite(times[1])]), grid, side="right")
    recon = np.round(x[0, 0, 0] / step) * step + step * (ups - downs)
    assert np.abs(recon - x[0, 0]).max() <= 0.5 * step * (1 + 1e-4)


def test_rate_and_onset():
    x = np.zeros((1, 1, 1000))
    x[..., 400:] = np.linspace(0, 1, 600) * 5 + 2.0  # contact at 400 ms: jump then ramp
    ev = lif_convert(x, FS, tau_ms=5.0)
    t, rate = spike_rate(ev, bin_ms=100.0, step_ms=10.0)
    assert rate[0, 0, t <= 400].max() == 0 and rate[0, 0, -1] > 0
    assert contact_onset(x, FS, smooth_ms=3.0)[0, 0] == pytest.approx(400, abs=3)


def test_refuses_bad_input():
    x = np.zeros((1, 2, 10))
    x[0, 1, 3] = np.nan
    with pytest.raises(ValueError, match="channel 1, sample 3"):
        lif_convert(x, FS)
    with pytest.raises(ValueError, match="reset"):
        lif_convert(np.zeros((1, 1, 5)), FS, reset="zero")
    with pytest.raises(ValueError, match="threshold"):
        lif_convert(np.zeros((1, 1, 5)), FS, threshold=-1.0)


def test_lif_population_floors_a_channel_silent_in_training():
    from tactilesnn.encoders import LIFPopulationConfig, build_encoder

    rng = np.random.default_rng(0)
    X = rng.standard_normal((20, 2, 200)).astype(np.float32)
    X[:, 1] = 0.0  # a dead taxel during training
    enc = build_encoder(LIFPopulationConfig(), 1000.0, 200, 2).fit(X)
    assert float(enc.ref[1]) == pytest.approx(1e-3 * float(enc.ref[0]), rel=1e-5)
    Xt = X.copy()
    Xt[:, 1] = 1e-5 * rng.standard_normal((20, 200))  # its noise at test time stays silent
    assert np.isinf(enc.encode(Xt).numpy()[:, 8:]).all()
    with pytest.raises(ValueError, match="every channel is zero"):
        build_encoder(LIFPopulationConfig(), 1000.0, 200, 2).fit(np.zeros_like(X))


def test_lif_convert_refuses_runaway_rates_before_work() -> None:
    """Amplitudes >= 1e5 used to run for hours (one crossing per loop step); now the rate bound
    is checked first, and inputs under it still convert exactly."""
    x = np.ones((1, 1, 1000))
    with pytest.raises(ValueError, match="max_spikes_per_sample"):
        lif_convert(x * 1e5, FS)
    with pytest.raises(ValueError, match="max_spikes_per_sample"):
        lif_convert(x * 1e30, FS)
    # a 10x drive at 1 ms samples fires ~1 spike/ms: well under the bound, same as before
    assert 900 < len(lif_convert(x * 10.0, FS)) < 1000
    # the bound counts the refractory time: 20 ms refractory keeps even 1e5 under the cap
    assert len(lif_convert(x * 1e5, FS, refractory_ms=20.0)) <= 1000 / 20 + 1


@pytest.mark.slow
def test_lif_population_spreads_kept_spikes_over_a_long_window() -> None:
    """6 s recordings: keeping the first 8 spikes put most of them in the first 130 ms; the
    fitted prescaler keeps every m-th spike so the slots span the window, and the exported graph
    (same function) matches the float64 encoder."""
    import torch

    from tactilesnn.encoders.base import ENCODERS, build_encoder

    fs, n = 500.0, 3000
    rng = np.random.default_rng(0)
    t = np.arange(n) / fs
    X = np.sin(2 * np.pi * 5 * t)[None, None] * (1 + 0.2 * rng.standard_normal((12, 2, 1)))
    X = (X + 0.1 * rng.standard_normal((12, 2, n))).astype(np.float32)
    cfg = ENCODERS.config_class("lif")
    first = build_encoder(cfg(keep="first"), fs, n, 2).fit(X).encode(X).numpy()
    enc = build_encoder(cfg(keep="spread"), fs, n, 2).fit(X)
    spread = enc.encode(X).numpy()
    early = lambda s: (s[np.isfinite(s)] < 130).mean()  # noqa: E731
    assert early(first) > 0.5 and early(spread) < 0.1
    assert np.median(spread[np.isfinite(spread)]) > 1000  # ms: the middle of the recording
    assert (enc.every >= 1).all() and enc.every.max() > 1
    # kept spike j of a prescaled converter is spike (j + 1) * m of the unscaled one
    m = int(enc.every[0])
    full = build_encoder(cfg(keep="first", max_spikes=8 * m), fs, n, 2).fit(X).encode(X[:1]).numpy()
    np.testing.assert_allclose(spread[0, 0, :8], full[0, 0, m - 1 :: m][:8], atol=1e-4)
    graph = enc.onnx_module()
    got = graph(torch.from_numpy(X[:2])).numpy()
    fin = np.isfinite(spread[:2])
    assert np.array_equal(np.isfinite(got), fin)
    assert np.abs(got[fin] - spread[:2][fin]).max() < 1e-2


@pytest.mark.slow
def test_exported_lif_graph_counts_spikes_as_torch_does(tmp_path) -> None:
    """With the prescaler a slot holds the m-th, 2m-th ... spike: a crossing counted differently
    in float32 moved the material task's exported spikes by a whole interval (85 ms). The graph
    counts in float64 like the encoder, so onnxruntime agrees to the float32 output's rounding."""
    import onnxruntime as ort
    import torch

    from tactilesnn.core.onnx_graph import torch_to_onnx
    from tactilesnn.encoders.base import ENCODERS, build_encoder

    fs, n, c = 500.0, 1500, 8
    rng = np.random.default_rng(0)
    t = np.arange(n) / fs
    X = np.sin(2 * np.pi * 5 * t)[None, None] * (1 + 0.2 * rng.standard_normal((64, c, 1)))
    X = (X + 0.3 * rng.standard_normal((64, c, n))).astype(np.float32)
    cfg = ENCODERS.config_class("lif")(neurons=6, lo=0.05, hi=3, tau_ms=20, max_spikes=32)
    enc = build_encoder(cfg, fs, n, c).fit(X)
    assert enc.every.max() > 10  # many spikes per slot: the case that drifted
    ref = enc.encode(X).numpy()
    path = tmp_path / "lif.onnx"
    torch_to_onnx(enc.onnx_module(), (torch.from_numpy(X[:2]),), path, ["window"], ["spikes"],
                  scripted=True)  # fmt: skip
    got = ort.InferenceSession(str(path)).run(None, {"window": X})[0]
    assert got.dtype == np.float32
    fin = np.isfinite(ref)
    assert np.array_equal(np.isfinite(got), fin)
    assert np.abs(got[fin] - ref[fin]).max() <= 5e-4  # ms: float32 rounding of times <= 3 s


@pytest.mark.slow
def test_closed_form_sample_matches_the_crossing_by_crossing_converter() -> None:
    """lif_first_spikes counts every crossing of a held sample in closed form; lif_convert
    (subtractive reset) locates them one at a time: same spike times and counts, float64, from
    silent to ~20 spikes per sample, negative drive included."""
    import torch

    from tactilesnn.encoders.spiking import lif_first_spikes

    rng = np.random.default_rng(3)
    fs, tau = 1000.0, 10.0
    x = np.concatenate([rng.uniform(-2, 3, (2, 3, 400)),
                        rng.uniform(0, 200, (1, 3, 400))])  # fmt: skip
    ev = lif_convert(x, fs, tau_ms=tau, reset="subtract")
    k = 4000
    times, count = lif_first_spikes(torch.from_numpy(x), 1000.0 / fs, tau, k)
    for b in range(3):
        for c in range(3):
            ref = ev.times(b, c)
            assert count[b, c].item() == ref.size
            got, n = times[b, c].numpy(), min(k, ref.size)
            np.testing.assert_allclose(got[:n], ref[:n], rtol=0, atol=1e-9)
            assert np.isinf(got[n:]).all()
    assert count[2].min() > 400 * 5  # the fast converters fire many times per sample
    # a prescaler keeps spikes m, 2m, ... of the same train
    every = torch.full((3,), 7.0, dtype=torch.float64)
    kept, _ = lif_first_spikes(torch.from_numpy(x), 1000.0 / fs, tau, 50, every)
    np.testing.assert_allclose(kept[2, 1].numpy(), times[2, 1, 6::7][:50].numpy(), atol=1e-9)


def test_the_eager_loop_is_the_scan_step_bit_for_bit() -> None:
    """lif_first_spikes_sparse (the eager encoder) updates the kept spike times only of the
    converters that fire in a sample; the exported graphs run first_spikes_step on every
    converter: the same times and counts, bit for bit (float32, gains per channel, prescalers,
    slots filled and not)."""
    import torch

    from tactilesnn.encoders.spiking import first_spikes_step, lif_first_spikes_sparse

    gen = torch.Generator().manual_seed(0)
    drive = torch.rand(5, 3, 300, generator=gen) * 4.0 - 1.0  # silent to several per sample
    gain = torch.tensor([0.3, 1.0, 2.5])
    every = torch.tensor([1.0, 2.0, 5.0] * 3)
    k, dt, tau = 6, 0.5, 4.0
    times, count = lif_first_spikes_sparse(drive, dt, tau, k, every, gain)
    v, c = torch.zeros(5, 9), torch.zeros(5, 9)
    t = torch.full((5, 9, k), math.inf)
    wanted = (torch.arange(k, dtype=torch.float32).view(1, 1, -1) + 1.0) * every.view(1, 9, 1)
    for i in range(drive.shape[-1]):
        v, c, t = first_spikes_step(v, c, t, drive[:, :, i], i * dt, gain, wanted, dt, tau)
    assert torch.equal(times, t) and torch.equal(count, c)
    assert torch.isfinite(times).any() and torch.isinf(times).any() and count.max() > 3 * k


def test_the_scan_operator_is_the_eager_loop_bit_for_bit() -> None:
    """lif_first_spikes_op (the exported graph's form: the drive's constants for every sample
    at once, only the potential in the scan, the kept slots read from each sample's count and
    first time afterwards) gives the eager encoder's times and counts bit for bit: float64 (the
    graph's), a rate that is not a power of two, gains per channel, prescalers, slots filled and
    not, converters silent and firing several times a sample."""
    import torch

    from tactilesnn.encoders.spiking import lif_first_spikes_op, lif_first_spikes_sparse

    gen = torch.Generator().manual_seed(1)
    drive = (torch.rand(4, 3, 120, generator=gen) * 30.0 - 1.0).double()
    drive[0, 0] = 0.0  # a silent channel
    gain = torch.tensor([0.05, 0.4, 3.0], dtype=torch.float64)
    every = torch.tensor([1.0, 3.0, 40.0] * 3, dtype=torch.float64)
    k, dt, tau = 5, 1000.0 / 93.97, 7.0
    want_t, want_n = lif_first_spikes_sparse(drive, dt, tau, k, every, gain)
    got_t, got_n = lif_first_spikes_op(drive, dt, tau, k, every, gain)
    assert torch.equal(got_t, want_t) and torch.equal(got_n, want_n)
    # the form for windows too long for the samples' values: the slots updated in the loop
    loop_t, loop_n = lif_first_spikes_op(drive, dt, tau, k, every, gain, slots_in_loop=True)
    assert torch.equal(loop_t, want_t) and torch.equal(loop_n, want_n)
    assert torch.isfinite(got_t).any() and torch.isinf(got_t).any()
    assert (got_n == 0).any() and got_n.max() > drive.shape[-1]  # silent and several a sample
