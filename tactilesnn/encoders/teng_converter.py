"""Seed 000's analog-to-spike converter for the TENG sensor's gate potential (SPEC 2.2).

The sensor model (:mod:`tactilesnn.datasets_synth.sensors.teng`) delivers ``V_T`` in volts; this
converter is the encoding stage after it, built on the package's one LIF converter
(:func:`~.spiking.lif_convert`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .spiking import lif_convert


@dataclass(frozen=True)
class TENGConverter:
    """Seed 000's LIF analog-to-spike converter (transistor + leaky integrate-and-fire).

    ``v_on_V``: transistor turn-on; the drain current ``g (V_T - v_on)`` (``gain`` = R g, V/V)
    drives ``tau_mem dV/dt = -(V - V_rest) + R I``; a spike (2 V, 1.2 ms on the scope) at
    ``threshold_V``, then reset to rest.
    """

    v_on_V: float = 0.15
    gain: float = 5.0
    tau_mem_ms: float = 20.0
    threshold_V: float = 1.0
    refractory_ms: float = 1.2

    def convert(self, v_t: np.ndarray, fs_hz: float):
        """``V_T [..., channels, samples]`` (V) -> :class:`~tactilesnn.encoders.SpikeEvents`."""
        drive = np.maximum(np.asarray(v_t, dtype=np.float64) - self.v_on_V, 0.0)
        if drive.ndim == 2:
            drive = drive[None]
        return lif_convert(
            drive, fs_hz, tau_ms=self.tau_mem_ms, threshold=self.threshold_V, gain=self.gain,
            reset="rest", refractory_ms=self.refractory_ms,
        )  # fmt: skip
