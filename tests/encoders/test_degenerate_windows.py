"""Degenerate windows through every encoder the selection may choose, in torch and onnxruntime:
a constant channel, a channel at the integer maximum, tiny-scale and denormal data, a ripple on a
large level. Silent where there is nothing to code, and the exported graph's verification (the
run's last step) passes: a run never ends with a model it cannot export."""

import numpy as np
import pytest
import torch

from tactilesnn.config import DATA_ENCODER_CANDIDATES, PipelineConfig
from tactilesnn.export import export_pipeline
from tactilesnn.pipeline import SpikePipeline

FS, WINDOW = 200.0, 200


def _windows(n=12, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(WINDOW) / FS
    x = np.zeros((n, 4, WINDOW), dtype=np.float32)
    for i in range(n):
        f = 5 + 3 * (i % 3)
        x[i, 0] = np.sin(2 * np.pi * f * t) + 0.1 * rng.standard_normal(WINDOW)
    x[:, 1] = 65535.0  # a status column stuck at the integer maximum
    x[:, 2] = x[:, 0] + 30000.0  # the same ripple on a large level
    x[:, 3] = 7.0  # a constant
    return x, np.arange(n) % 3


@pytest.mark.parametrize("encoder", DATA_ENCODER_CANDIDATES)
@pytest.mark.parametrize("scale", [1.0, 1e-40])  # (1e-40: float32 denormals)
def test_degenerate_channels_are_silent_and_export(encoder, scale, tmp_path):
    x, y = _windows()
    x = (x * np.float32(scale)).astype(np.float32)
    cfg = PipelineConfig.from_flat(channels=("all",), encoder=encoder, model="readout")
    pipe = SpikePipeline(cfg, FS, WINDOW, ("a", "b", "c", "d"), ("p", "q", "r"))
    pipe.fit(x, y)
    spikes = pipe.encoder.encode(x)[:, :, 0].reshape(len(x), 4, -1)
    assert not torch.isnan(spikes).any()
    if encoder != "lif":  # (the LIF code keeps levels: a constant is a level, not silence)
        assert torch.isinf(spikes[:, 1]).all() and torch.isinf(spikes[:, 3]).all()
        if scale == 1.0:  # the ripple on a level is coded as the ripple alone
            assert torch.equal(torch.isinf(spikes[:, 2]), torch.isinf(spikes[:, 0]))
    rep = export_pipeline(pipe, tmp_path / "m.onnx", x)  # raises if the graph differs
    assert rep["prediction_agreement"] == 1.0


def test_runs_saved_before_the_stft_level_was_taken_off_keep_their_spikes():
    from tactilesnn.app.run import saved_pipeline_config

    cfg = PipelineConfig.from_flat(channels=("all",), encoder="stft", model="readout")
    saved = cfg.to_dict()
    saved["encoder"].pop("level_off")
    assert saved_pipeline_config(saved).encoder.level_off is False
    assert PipelineConfig.from_dict(cfg.to_dict()).encoder.level_off is True
