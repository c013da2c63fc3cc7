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


@pytest.mark.parametrize("model", ["readout", "snn", "tempotron", "csnn", "stream"])
def test_the_model_is_counted_before_it_is_built(model: str) -> None:
    """The size check counts every parameter and buffer the model will have, on torch's meta
    device (nothing allocated)."""
    from tactilesnn.models.base import MODELS, build_model
    from tactilesnn.pipeline import parameter_count

    args = (MODELS.config_class(model)(), 24, 8, 3, 100.0)
    built = build_model(*args, seed=1)
    assert parameter_count(*args) == sum(t.numel() for t in (*built.parameters(), *built.buffers()))


def test_counting_the_default_models_does_not_load_torchs_compiler() -> None:
    """The read-out and the tempotron (the defaults of ``train --data`` and of the tasks) draw
    their weights and make their constants without the meta device's reference kernels, whose
    first use imports torch._dynamo (~2.5 s of every ``train`` / ``evaluate``)."""
    import subprocess
    import sys

    code = (
        "import sys; from tactilesnn.models.base import MODELS; "
        "from tactilesnn.pipeline import parameter_count; "
        "n = [parameter_count(MODELS.config_class(m)(), 24, 8, 3, 100.0) "
        "for m in ('readout', 'tempotron')]; "
        "assert min(n) > 0, n; print('torch._dynamo' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
