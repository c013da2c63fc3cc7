"""Transform -> code (``bands``): the composition is exactly its parts, codes where the energy
is, and is saved, reloaded and exported like any encoder."""

import numpy as np
import pytest
import torch

from tactilesnn.app.run import load_run
from tactilesnn.config import PipelineConfig
from tactilesnn.encoders import ENCODERS, BandCodeConfig, build_encoder
from tactilesnn.encoders.gwt import GaborScalogram
from tactilesnn.export import export_pipeline
from tactilesnn.service.runtime import PipelineSession
from tests.helpers import run_task


def _noise(n=12, c=2, w=400, seed=0):
    return np.random.default_rng(seed).normal(size=(n, c, w)).astype(np.float32)


@pytest.mark.slow
@pytest.mark.parametrize("transform", ["gwt", "cgwt", "stft"])
@pytest.mark.parametrize("code", ["lif", "delta"])
def test_the_composition_is_the_code_of_the_transforms_envelopes(transform, code):
    X = _noise()
    enc = build_encoder(BandCodeConfig(transform=transform, code=code, n_bands=6, frames=50),
                        400.0, 400, 2)  # fmt: skip
    enc.fit(X)
    env = enc.filter_bank(torch.from_numpy(X))[..., : enc.frames].reshape(12, 12, enc.frames)
    # the code alone, built for 12 envelope rows at the frame rate and fitted on the envelopes
    alone = build_encoder(ENCODERS.config_class(code)(), 400.0 / enc.hop, enc.frames, 12)
    alone.fit(env.numpy())
    assert torch.equal(enc.encode(X), alone.encode(env.numpy()))
    assert enc.n_afferents == alone.n_afferents and enc.max_spikes == alone.max_spikes


def test_gabor_envelopes_match_the_scalogram_and_a_tone_drives_its_own_band():
    fs, w = 1000.0, 1000
    enc = build_encoder(BandCodeConfig(f_lo_hz=5.0, f_hi_hz=200.0, n_bands=8, frames=100), fs, w, 1)
    x = np.sin(2 * np.pi * enc.freqs_hz[5] * np.arange(w) / fs)[None, None].astype(np.float32)
    ref = GaborScalogram(fs, enc.freqs_hz, hop=10)(torch.from_numpy(x).double())[0, 0]
    env = enc.envelopes(torch.from_numpy(x))[0]
    np.testing.assert_allclose(env.numpy(), ref.numpy(), rtol=1e-4, atol=1e-5)
    enc.fit(np.concatenate([x, 0.1 * _noise(8, 1, w)]))
    counts = torch.isfinite(enc.encode(x)[0]).sum(-1).reshape(8, -1).sum(-1)  # spikes per band
    # each row is calibrated to its own training level (noise for the other rows), so leakage
    # into weak bands spikes too; the tone's band spikes most
    assert int(counts.argmax()) == 5


@pytest.mark.parametrize(
    "settings, match",
    [
        ({"transform": "wavelet"}, "transform"),
        ({"code": "gwt"}, "code"),  # a latency code of its own, not a code of analog channels
        ({"code": "events"}, "code"),
        ({"frames": 1}, "frames"),
        ({"f_lo_hz": 50.0, "f_hi_hz": 10.0}, "f_lo_hz"),
    ],
)
def test_bad_settings_are_refused_by_name(settings, match):
    with pytest.raises(ValueError, match=match):
        BandCodeConfig(**settings)


def test_frames_follow_short_windows_and_bands_above_nyquist_are_refused():
    enc = build_encoder(BandCodeConfig(frames=500), 100.0, 200, 1)
    assert (enc.hop, enc.frames) == (1, 200)  # at most one frame per sample
    with pytest.raises(ValueError, match=r"0\.45"):
        build_encoder(BandCodeConfig(f_lo_hz=60.0, f_hi_hz=90.0), 100.0, 200, 1)


@pytest.mark.slow
@pytest.mark.parametrize("transform, code", [("gwt", "lif"), ("stft", "delta"), ("cgwt", "delta")])
def test_saved_reloaded_and_exported(tmp_path, transform, code):
    """Scripted (LIF) and traced (delta) code graphs after the envelope MatMuls."""
    params = {"seed": 0, "n_planar": 8, "n_concave": 4, "n_convex": 4, "n_test": 3}
    cfg = PipelineConfig.from_flat(encoder="bands", bands_transform=transform, bands_code=code,
                                   n_bands=6, bands_frames=40, model="readout", epochs=2)  # fmt: skip
    run, _ = run_task("hook_loop", params, cfg, tmp_path / "r", progress=False)
    pipe, _ = load_run(run)
    assert pipe.config.encoder == cfg.encoder
    from tactilesnn.datasets_synth import HookLoopTask

    X = HookLoopTask(**params).build()[1].X
    spikes = pipe.encode(X)
    export_pipeline(pipe, tmp_path / "m.onnx", X[:4])
    sess = PipelineSession(str(tmp_path / "m.onnx"))
    got = sess.run(sess.validate(X))
    ref = pipe.scores(spikes).numpy()
    assert np.array_equal(got.argmax(1), ref.argmax(1)) and np.abs(got - ref).max() <= 1e-3
