"""Sizes are checked before work starts: a clear error instead of an out-of-memory kill."""

import numpy as np
import pytest

from tactilesnn.config import PipelineConfig
from tactilesnn.pipeline import SpikePipeline


def test_encoding_too_many_windows_is_refused_before_work() -> None:
    pipe = SpikePipeline(
        PipelineConfig.from_flat(channels=["all"]), 1000.0, 100, ("c",), ("a", "b")
    )
    huge = np.broadcast_to(np.zeros((1, 1, 100), np.float32), (10**9, 1, 100))  # no memory
    with pytest.raises(ValueError, match="GiB"):
        pipe.encode(huge)


def test_bands_and_neurons_are_bounded_in_the_settings() -> None:
    with pytest.raises(ValueError, match="n_bands"):
        PipelineConfig.from_flat(n_bands=100_000)
    with pytest.raises(ValueError, match="neurons"):
        PipelineConfig.from_flat(encoder="lif", lif_neurons=0)
