"""The eager first-spike-times path (one searchsorted) is the traceable one's, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tactilesnn.core.spikes import _first_spike_times_sorted, first_spike_times


def _traced(counts, dt, k, t0):
    # the traceable branch, as the exported graphs run it
    class G(torch.nn.Module):
        def forward(self, x):
            return first_spike_times(x, dt, k, t0)

    return torch.jit.trace(G(), (counts,))(counts)


@pytest.mark.parametrize("k", [1, 3, 16])
@pytest.mark.parametrize("t0", [0.0, 0.5])
def test_the_sorted_path_equals_the_traceable_one(k, t0):
    rng = np.random.default_rng(k)
    counts = torch.from_numpy(rng.poisson(0.3, (5, 7, 40)).astype(np.float32))
    counts[0, 0] = 0.0  # a silent afferent: every slot +inf
    counts[1, 1, -1] = 50.0  # many spikes in the last sample
    fast = _first_spike_times_sorted(counts, 0.25, k, t0)
    ref = _traced(counts, 0.25, k, t0)
    torch.testing.assert_close(fast, ref, rtol=0, atol=0)
    assert torch.isinf(fast[0, 0]).all()
    torch.testing.assert_close(first_spike_times(counts, 0.25, k, t0), ref, rtol=0, atol=0)
