"""Encoders: raw sensor windows -> spike times (see :mod:`tactilesnn.encoders.base`).

Registered components (``ENCODERS``): importing a component module registers it; the lines below
are the registry's list of shipped encoders.
"""

from .band_code import TRANSFORMS, BandCodeConfig, BandCodeEncoder
from .base import ENCODERS, SpikeEncoder, build_encoder, register_encoder
from .causal_gwt import CausalGWTConfig, CausalGWTLatencyEncoder
from .delta import DeltaConfig, DeltaEncoder
from .events import EventsConfig, EventsEncoder
from .frame_code import FrameCodeConfig, FrameCodeEncoder
from .gwt import GaborScalogram, log_bands
from .latency import LatencyCode
from .lif_population import LIFPopulationConfig, LIFPopulationEncoder
from .scalogram_latency import GWTConfig, GWTLatencyEncoder, STFTConfig, STFTLatencyEncoder
from .spiking import SpikeEvents, lif_convert
from .stft import STFTScalogram

__all__ = [
    "ENCODERS",
    "TRANSFORMS",
    "BandCodeConfig",
    "BandCodeEncoder",
    "CausalGWTConfig",
    "CausalGWTLatencyEncoder",
    "DeltaConfig",
    "DeltaEncoder",
    "EventsConfig",
    "EventsEncoder",
    "FrameCodeConfig",
    "FrameCodeEncoder",
    "GWTConfig",
    "GWTLatencyEncoder",
    "GaborScalogram",
    "LIFPopulationConfig",
    "LIFPopulationEncoder",
    "LatencyCode",
    "STFTConfig",
    "STFTLatencyEncoder",
    "STFTScalogram",
    "SpikeEncoder",
    "SpikeEvents",
    "build_encoder",
    "lif_convert",
    "log_bands",
    "register_encoder",
]
