"""tactilesnn: tactile sensor models, spike encoders and spiking classifiers.

Data flows one way: scene -> sensor -> raw stream -> encoder -> spikes -> model -> prediction.
The names below are imported on first use, so ``tactilesnn.service`` (onnxruntime + numpy only)
never pulls in torch.
"""

from __future__ import annotations

import importlib
from typing import Any

from .core.version import __version__

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
