"""The activity gate, defined once.

A window's channel whose RMS about its mean (the population standard deviation over the
window's samples, in the input's units) is at or below the channel's threshold is not encoded:
its afferents stay silent. The encoders fit the threshold as ``gate`` x the channel's median
training RMS (:func:`thresholds`); the torch path, the exported graph, the served contract
(:meth:`~tactilesnn.core.graph_contract.GraphContract.silent_channels`) and the offline sliding
encoder all decide with :func:`active_channels`, so they agree window for window.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .data import row_blocks


def channel_rms(x: Any) -> Any:
    """RMS about the mean along the last axis: float64 for a NumPy array (the served
    contract's arithmetic), the tensor's own dtype for a torch tensor (traceable)."""
    if isinstance(x, np.ndarray):
        return np.asarray(x, np.float64).std(axis=-1)
    return x.std(-1, unbiased=False)


def active_channels(x: Any, gate_rms: Any) -> Any:
    """``x [..., samples]`` -> bool ``[...]``: the channels the gate lets through (RMS above
    ``gate_rms``, broadcast along the leading axes)."""
    return channel_rms(x) > gate_rms


def thresholds(train_windows: np.ndarray, gate: float) -> np.ndarray:
    """Per channel: ``gate`` x the median RMS of ``train_windows [N, channels, samples]``
    (float64), computed a block of windows at a time."""
    rms = np.concatenate([channel_rms(block) for block in row_blocks(train_windows)])
    return gate * np.median(rms, axis=0)
