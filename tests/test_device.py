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
