"""The continuous frame code (``frames``): against a float64 reference built from SciPy's
filter, frame steps equal to windows, recordings coded with their past, errors."""

import numpy as np
import pytest
import torch

from tactilesnn.encoders import FrameCodeConfig, build_encoder
from tactilesnn.encoders.causal_gabor import reference_frames
from tactilesnn.encoders.frame_code import spike_times

FS, W, C = 2000.0, 400, 3


def _encoder(**kw):
    enc = build_encoder(FrameCodeConfig(f_lo_hz=5.0, f_hi_hz=400.0, n_bands=4, **kw), FS, W, C)
    rng = np.random.default_rng(0)
    X = (rng.standard_normal((16, C, W)) * np.array([0.1, 1.0, 30.0])[None, :, None]).astype(
        np.float32
    )
    return enc.fit(X), X


def _reference_spikes(enc, x: np.ndarray) -> np.ndarray:
    """float64: SciPy's per-pole filters (the bank's reference), then the converters as written
    in the module docstring, frame by frame. ``x [C, S]`` -> ``[frames, afferents]``."""
    env = np.abs(reference_frames(x, FS, enc.freqs_hz, hop=enc.hop))  # [C, bands, frames]
    f = env.shape[-1]
    d = (
        x[:, : f * enc.hop].reshape(x.shape[0], f, enc.hop).mean(-1)
        - enc.rest.double().numpy()[:, None]
    )
    sustained = np.stack([np.maximum(d, 0), np.maximum(-d, 0)], 1).reshape(-1, f)  # (ON, OFF)
    rows = np.concatenate([env.reshape(-1, f), sustained])
    level = enc.level.double().numpy()
    thr = np.geomspace(enc.config.lo, enc.config.hi, enc.config.neurons)
    beta = np.exp(-1.0 / enc.config.tau_frames)
    u = np.zeros((rows.shape[0], thr.size))
    out = []
    for f in range(rows.shape[1]):
        u = beta * u + (1 - beta) * rows[:, f, None] / (level[:, None] * thr[None, :])
        s = u >= 1.0
        u = u - s
        out.append(s.reshape(-1))
    return np.asarray(out, np.float64)


def test_spikes_match_the_float64_reference():
    enc, X = _encoder()
    got = enc.encode(X[:4])
    for i in range(4):
        want = _reference_spikes(enc, X[i].astype(np.float64))  # [frames, A]
        mine = np.isfinite(got[i].numpy()).sum(-1)  # spikes per afferent
        # float32 vs float64: a converter may cross its threshold one frame apart, rarely
        assert np.abs(mine - want.sum(0)).sum() <= max(2, 0.01 * want.sum())
    assert got.shape == (4, enc.n_afferents, enc.frames)


def test_times_are_ascending_frame_centres():
    enc, X = _encoder()
    t = enc.encode(X[:2]).numpy()
    fin = np.isfinite(t)
    assert fin.any()
    assert np.all(np.diff(np.where(fin, t, 1e9), axis=-1) >= 0)  # ascending, inf last
    k = t[fin] / enc.frame_ms - 0.5
    np.testing.assert_allclose(k, np.round(k), atol=1e-4)
    assert enc.frame_ms == pytest.approx(5.0)


def test_a_held_level_keeps_firing_where_bands_fall_silent():
    enc, _ = _encoder()
    x = np.zeros((1, C, W), np.float32) + enc.rest.numpy()[None, :, None]
    x[..., W // 4 :] += 5.0 * enc.level.numpy()[-2 * C :: 2][None, :, None]  # a step, then held
    t = enc.encode(x)[0].numpy()
    ms = 1000 * W / FS
    bands = C * 4 * enc.config.neurons
    # the two upper bands of each channel (the 5 Hz band's own response lasts ~ its period)
    upper = (np.arange(bands) // enc.config.neurons) % 4 >= 2
    after_step = (np.isfinite(t) & (t > 0.25 * ms) & (t < 0.5 * ms))[:bands][upper].sum()
    held = np.isfinite(t) & (t > 0.75 * ms)  # the last quarter: the level held, no change
    assert held[bands:].any()  # the sustained rows keep firing
    assert after_step > 0 and held[:bands][upper].sum() == 0  # while the fast bands fall silent


def test_louder_bands_fire_more():
    enc, X = _encoder()
    x = X[:1].copy()
    quiet = np.isfinite(enc.encode(x).numpy()).sum()
    loud = np.isfinite(enc.encode(4 * x).numpy()).sum()
    assert loud > quiet


def test_frame_steps_equal_the_window_code():
    enc, X = _encoder()
    step = enc.frame_module()
    state = [torch.from_numpy(v) for v in enc.initial_frame_state(X[:2]).values()]
    x = torch.from_numpy(X[:2])
    out = []
    with torch.no_grad():
        for i in range(enc.frames):
            s, *state = step(x[:, :, i * enc.hop : (i + 1) * enc.hop], *state)
            out.append(s)
    got = spike_times(torch.stack(out), enc.frame_ms)
    want = enc.encode(X[:2])
    flips = (torch.isfinite(got) != torch.isfinite(want)).sum().item()
    assert flips <= 2  # a threshold crossing on a float32 rounding boundary, at most


def test_recordings_are_coded_with_their_past():
    enc, X = _encoder()
    rec = np.concatenate(list(X[:3]), axis=1)
    got = enc.encode_recording(rec, [0, W, 2 * W])
    alone = enc.encode(X[:3])
    assert torch.equal(torch.isfinite(got[0]), torch.isfinite(alone[0]))  # no past: the same
    frames = enc.frame_spikes(rec)
    assert frames.shape == (3 * enc.frames, enc.n_afferents)
    assert torch.equal(torch.isfinite(got[2]).sum(-1).float(), frames[2 * enc.frames :].sum(0))
    with pytest.raises(ValueError, match="whole hops"):
        enc.encode_recording(rec, [3])


def test_bad_settings_and_silent_data_are_refused():
    with pytest.raises(ValueError, match="frame"):
        build_encoder(FrameCodeConfig(frame_ms=1000.0), FS, W, C)
    with pytest.raises(ValueError, match="hi"):
        FrameCodeConfig(lo=2.0, hi=1.0)
    enc = build_encoder(FrameCodeConfig(), FS, W, C)
    with pytest.raises(ValueError, match="zero"):
        enc.fit(np.zeros((4, C, W), np.float32))
    with pytest.raises(RuntimeError, match="not fitted"):
        enc.encode(np.zeros((1, C, W), np.float32))


def test_a_channel_stuck_near_a_large_value_is_not_coded_from_its_rounding():
    rng = np.random.default_rng(1)
    X = rng.standard_normal((16, C, W)).astype(np.float32)
    X[:, 1] = 65535.0  # a 16-bit reading stuck at its maximum, dipping by one count now and then
    X[:, 1, ::97] -= 1.0
    enc = build_encoder(FrameCodeConfig(f_lo_hz=5.0, f_hi_hz=400.0, n_bands=4), FS, W, C).fit(X)
    stuck = enc.level.view(-1)[4:8]  # channel 1's band rows
    assert float(stuck.min()) >= 256 * np.finfo(np.float32).eps * 65535.0 * 0.999
    with torch.no_grad():
        graph = enc.onnx_module().eval()(torch.from_numpy(X))
    assert (torch.isfinite(graph) != torch.isfinite(enc.encode(X))).sum() <= 2
