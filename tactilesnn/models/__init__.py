"""Models: spike times -> class scores (see :mod:`tactilesnn.models.base`).

Registered components (``MODELS``): importing a component module registers it; the lines below
are the registry's list of shipped models.
"""

from .base import MODELS, SpikeModel, build_model, register_model
from .conv_snn import ConvSNNConfig, ConvSNNModel
from .forest_readout import ForestConfig, ForestReadout
from .li_readout import LIReadout, ReadoutConfig
from .snn import SNNClassifier, SNNConfig, SNNModel
from .stream_snn import StreamSNNConfig, StreamSNNModel
from .tempotron import Tempotron, TempotronClassifier, TempotronConfig

__all__ = [
    "MODELS",
    "ConvSNNConfig",
    "ConvSNNModel",
    "ForestConfig",
    "ForestReadout",
    "LIReadout",
    "ReadoutConfig",
    "SNNClassifier",
    "SNNConfig",
    "SNNModel",
    "SpikeModel",
    "StreamSNNConfig",
    "StreamSNNModel",
    "Tempotron",
    "TempotronClassifier",
    "TempotronConfig",
    "build_model",
    "register_model",
]
