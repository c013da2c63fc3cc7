"""Device selection: one resolver, clear refusals, and the CPU path unchanged by ``device``."""

import numpy as np
import pytest
import torch

from tactilesnn.config import PipelineConfig, TrainConfig
from tactilesnn.core.device import resolve_device
from tactilesnn.models import build_model
from tactilesnn.trainer import Trainer


def test_auto_is_cuda_when_torch_sees_a_gpu_else_the_cpu():
    want = "cuda" if torch.cuda.is_available() else "cpu"
    assert resolve_device("auto").type == want and resolve_device("cpu") == torch.device("cpu")


@pytest.mark.parametrize("bad", ["gpu", "cuda:x", "cpu:0", "", "CUDA", "mps"])
def test_unknown_devices_are_refused_by_name(bad):
    with pytest.raises(ValueError, match="device must be"):
        resolve_device(bad)
    with pytest.raises(ValueError, match="device must be"):
        TrainConfig(device=bad)


@pytest.mark.skipif(torch.cuda.is_available(), reason="a machine with a GPU")
def test_a_cuda_device_this_machine_lacks_is_a_clear_error():
    with pytest.raises(ValueError, match="no CUDA GPU"):
        resolve_device("cuda")
    cfg = PipelineConfig.from_flat(model="snn", device="cuda")  # a setting; refused at training
    model = build_model(cfg.model, 4, 1, 2, 50.0, seed=0)
    spikes = torch.rand(8, 4, 1) * 50
    with pytest.raises(ValueError, match="no CUDA GPU"):
        Trainer(model, cfg.train).fit(spikes, np.arange(8) % 2)


def _train(device: str):
    cfg = PipelineConfig.from_flat(model="snn", snn_hidden=8, epochs=2, device=device)
    model = build_model(cfg.model, 6, 1, 2, 50.0, seed=0)
    gen = torch.Generator().manual_seed(0)
    spikes = torch.where(torch.rand(16, 6, 1, generator=gen) < 0.7,
                         torch.rand(16, 6, 1, generator=gen) * 50, torch.inf)  # fmt: skip
    hist = Trainer(model, cfg.train).fit(spikes, np.arange(16) % 2)
    return hist, {k: v.clone() for k, v in model.state_dict().items()}


def test_cpu_and_auto_train_alike_here_and_the_model_ends_on_the_cpu():
    hist_cpu, w_cpu = _train("cpu")
    hist_auto, w_auto = _train("auto")
    assert all(v.device.type == "cpu" for v in w_auto.values())  # export, checkpoints: CPU
    if not torch.cuda.is_available():
        assert hist_cpu == hist_auto and all(torch.equal(w_cpu[k], w_auto[k]) for k in w_cpu)


# --------------------------------------------------------------------------- encoding on a device
ENCODERS_ON_A_DEVICE = ("gwt", "stft", "cgwt", "delta", "lif", "bands", "events")


def _calibrated(encoder: str):
    from tactilesnn.pipeline import SpikePipeline

    cfg = PipelineConfig.from_flat(encoder=encoder, model="readout", channels=("all",))
    pipe = SpikePipeline(cfg, 200.0, 100, ("a", "b"), ("x", "y"))
    rng = np.random.default_rng(0)
    X = (rng.poisson(0.3, (16, 2, 100)) if encoder == "events"
         else rng.standard_normal((16, 2, 100))).astype(np.float32)  # fmt: skip
    pipe.calibrate(X)
    return pipe, X


@pytest.mark.slow
@pytest.mark.parametrize("encoder", [e for e in ENCODERS_ON_A_DEVICE if e != "events"])
def test_every_encoder_computes_on_the_device_its_input_is_on(encoder):
    """On torch's ``meta`` device (shapes, no values) any tensor an encoder made on the CPU
    instead of its input's device fails the op that meets it, as it would on a GPU. (``events``
    reads its prescaler's value when it builds its graph: a GPU synchronises, ``meta`` has no
    values; it is in the GPU test below.)"""
    pipe, X = _calibrated(encoder)
    enc = pipe.encoder
    want = enc.encode_batch(torch.from_numpy(X[:4]))
    enc.to("meta")
    got = enc.encode_batch(torch.from_numpy(X[:4]).to("meta"))
    assert got.device.type == "meta" and got.shape == want.shape and got.dtype == want.dtype


def test_encoding_on_a_device_moves_the_encoder_there_and_back_even_on_failure(monkeypatch):
    pipe, X = _calibrated("cgwt")
    enc = pipe.encoder
    want = pipe.encode(X)
    assert torch.equal(pipe.encode(X, device="cpu"), want)  # the CPU path: unchanged
    moves, seen = [], []
    monkeypatch.setattr(type(enc), "to", lambda self, dev: moves.append(str(dev)) or self)

    def fails(x):
        seen.append(x.device.type)
        raise RuntimeError("out of device memory")

    monkeypatch.setattr(enc, "encode_batch", fails)
    with pytest.raises(RuntimeError, match="out of device memory"):
        pipe.encode(X, device="meta")
    assert seen == ["meta"] and moves == ["meta", "cpu"]  # the batch went there; back after


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("encoder", ENCODERS_ON_A_DEVICE)
def test_encoding_on_the_gpu_matches_the_cpu(encoder):
    pipe, X = _calibrated(encoder)
    cpu = pipe.encode(X).numpy()
    gpu = pipe.encode(X, device="cuda").numpy()
    assert (np.isfinite(cpu) == np.isfinite(gpu)).mean() > 0.999  # a cutoff may flip
    both = np.isfinite(cpu) & np.isfinite(gpu)
    assert np.abs(cpu[both] - gpu[both]).max() < 0.05  # ms: float32 rounding on a GPU
