"""tactilesnn: tactile sensor models, spike encoders and spiking classifiers.

Data flows one way: scene -> sensor -> raw stream -> encoder -> spikes -> model -> prediction.
The names below are imported on first use, so ``tactilesnn.service`` (onnxruntime + numpy only)
never pulls in torch.
"""

from __future__ import annotations

import importlib
import os
from typing import Any

from .core.version import __version__

# OpenMP threads (torch's CPU kernels) spin 300,000 iterations before they sleep; beside other
# CPU-bound processes that spinning takes the time slices the work needs. 10,000 costs nothing
# on a quiet machine (default training 14.2 s either way) and halves the time beside two busy
# neighbours on 2 cores (47 -> 28 s; iCub Braille 54 -> 26 s). Read when torch is first
# imported, so it is set here, before; a value you set yourself wins.
os.environ.setdefault("GOMP_SPINCOUNT", "10000")

_LAZY = {
    "PipelineConfig": "tactilesnn.config",
    "TrainConfig": "tactilesnn.config",
    "SpikePipeline": "tactilesnn.pipeline",
    "SpikeClassifier": "tactilesnn.estimator",
    "WindowDataset": "tactilesnn.core.data",
    "Trainer": "tactilesnn.trainer",
    "RunSpec": "tactilesnn.app.run",
    "TaskSource": "tactilesnn.app.run",
    "FileSource": "tactilesnn.app.run",
    "train_run": "tactilesnn.app.run",
    "load_run": "tactilesnn.app.run",
    "load_data_file": "tactilesnn.recordings",
    "export_pipeline": "tactilesnn.export",
    "ENCODERS": "tactilesnn.encoders",
    "MODELS": "tactilesnn.models",
    "TASKS": "tactilesnn.datasets_synth",
    "get_task": "tactilesnn.datasets_synth",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'tactilesnn' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})
