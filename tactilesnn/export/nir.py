"""NIR export of the SNN (https://neuroir.org): Affine -> LIF -> Affine -> LI (or LIF) graph.

Mapping (time constants in seconds, from the configured ``dt_ms`` and ``tau_ms``): our layers are
``u_t = beta u_{t-1} + i_t`` with ``beta = exp(-dt / tau)`` and ``i_t = W x_t + b`` in units of the
threshold. NIR's LIF is ``tau dv/dt = (v_leak - v) + R I``; integrated exactly for an input held
over the step (zero-order hold) that is ``v_t = beta v_{t-1} + (1 - beta) R I_t``, so
``R = 1 / (1 - beta)`` (dimensionless), ``v_leak = 0``, ``v_threshold = theta``. The graph's
input is the spike raster (counts per ``dt`` step, :func:`tactilesnn.core.spikes.spike_raster`);
``metadata["dt_s"]`` gives the step. What NIR has no primitive for, said plainly:

* **reset by subtraction** (our default): NIR's LIF resets *to* ``v_reset``. The graph carries
  ``v_reset = 0`` and ``metadata["reset"] = "subtract"``; a consumer that honours the metadata
  reproduces our spikes exactly, a plain reset-to-zero consumer approximates them (both are
  measured by :func:`compare`);
* **max / mean readout** over time: not a NIR node; the graph outputs the LI membrane per step and
  ``metadata["readout"]`` says how to reduce it (``count`` readouts output LIF spikes to sum);
* **recurrent hidden layer**: exported as an ``Affine`` self-loop edge (``W_rec``, zero bias) on
  the hidden LIF, as snnTorch's RNN import expects;
* **the exact tempotron and the encoders**: refused (continuous-time ``V_max`` of a
  double-exponential kernel, and FFT/latency or exact-crossing converters, are not NIR graphs;
  export those with ONNX).

:func:`simulate` runs a NIR graph with ``nirtorch`` (its graph wiring and state handling) and
modules written from NIR's equations (not :mod:`tactilesnn.models.functional`); nirtorch 2.6's
own ``Affine`` mapping drops the bias (see :func:`_affine`), so ours replaces it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from ..core.files import replace_atomically
from ..models.functional import reduce_readout
from ..models.snn_nir import require_nir


def write_nir(model: Any, path: Path, overwrite: bool = False) -> Path:
    """Write ``model`` as a NIR file (HDF5) atomically; refuses models NIR cannot express."""
    nir = require_nir()
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass --overwrite to replace it")
    graph = model.to_nir()
    path.parent.mkdir(parents=True, exist_ok=True)
    replace_atomically(path, lambda tmp: nir.write(str(tmp), graph))
    return path


# ---------------------------------------------------------------------------------- consumer
class _NIRLI(nn.Module):
    """NIR ``LI`` stepped exactly over ``dt_s`` for a held input; outputs the membrane."""

    def __init__(self, node: Any, dt_s: float) -> None:
        super().__init__()
        self.decay = torch.from_numpy(np.exp(-dt_s / np.asarray(node.tau, np.float64))).float()
        self.gain = (1.0 - self.decay) * torch.from_numpy(np.asarray(node.r, np.float32))
        self.v_leak = torch.from_numpy(np.asarray(node.v_leak, np.float32))

    def integrate(self, x: Tensor, state: Tensor | None) -> Tensor:
        v = torch.zeros_like(x) if state is None else state
        return self.v_leak + self.decay * (v - self.v_leak) + self.gain * x

    def forward(self, x: Tensor, state: Tensor | None = None) -> tuple[Tensor, Tensor]:
        v = self.integrate(x, state)
        return v, v


class _NIRLIF(_NIRLI):
    """NIR ``LIF``: :class:`_NIRLI` plus a threshold, reset to ``v_reset`` or by subtracting
    the threshold."""

    def __init__(self, node: Any, dt_s: float, subtract: bool) -> None:
        super().__init__(node, dt_s)
        self.thr = torch.from_numpy(np.asarray(node.v_threshold, np.float32))
        self.v_reset = torch.from_numpy(np.asarray(node.v_reset, np.float32))
        self.subtract = subtract

    def forward(self, x: Tensor, state: Tensor | None = None) -> tuple[Tensor, Tensor]:
        v = self.integrate(x, state)
        s = (v >= self.thr).to(x.dtype)
        v = v - s * self.thr if self.subtract else torch.where(s > 0, self.v_reset, v)
        return s, v


def _affine(node: Any) -> nn.Linear:
    """NIR ``Affine`` (``W x + b``). nirtorch 2.6's default mapping assigns the bias to
    ``weight.bias`` and so leaves the layer's random initial bias in place."""
    w = torch.from_numpy(np.asarray(node.weight, np.float32))
    lin = nn.Linear(w.shape[1], w.shape[0])
    with torch.no_grad():
        lin.weight.copy_(w)
        lin.bias.copy_(torch.from_numpy(np.asarray(node.bias, np.float32)))
    return lin


def simulate(graph: Any, raster: Tensor, honour_reset: bool = True) -> Tensor:
    """Run a NIR graph on ``raster [T, B, inputs]`` with nirtorch; output per step ``[T, B, out]``.

    ``honour_reset=False`` ignores ``metadata["reset"]`` (plain NIR: reset to ``v_reset``).
    """
    import nirtorch

    nir = require_nir()
    dt_s = float(graph.metadata["dt_s"])
    subtract = honour_reset and graph.metadata.get("reset") == "subtract"
    if "rec" in graph.nodes:
        raise NotImplementedError("the reference consumer runs feed-forward NIR graphs only")
    node_map = {
        nir.LIF: lambda n: _NIRLIF(n, dt_s, subtract),
        nir.LI: lambda n: _NIRLI(n, dt_s),
        nir.Affine: _affine,
    }
    module = nirtorch.nir_to_torch(graph, node_map)
    state = None
    out = []
    with torch.no_grad():
        for t in range(raster.shape[0]):
            y, state = module(raster[t], state)
            out.append(y)
    return torch.stack(out)


def compare(model: Any, spikes: Tensor, path: Path | None = None) -> dict[str, float]:
    """Our scores vs the NIR graph (written and read back if ``path``) on ``spikes [N, A, k]``.

    Reports the largest score difference and the prediction agreement, honouring the
    subtract-reset metadata and with plain NIR reset-to-zero semantics.
    """
    nir = require_nir()
    graph = nir.read(str(path)) if path is not None else model.to_nir()
    if "rec" in graph.nodes:
        return {"simulated": 0.0}
    with torch.no_grad():
        ref = model.scores(spikes)
    raster = model.raster(spikes)
    res = {"simulated": 1.0}
    for name, honour in (("subtract_reset", True), ("nir_reset_to_zero", False)):
        out = simulate(graph, raster, honour_reset=honour)
        got = reduce_readout(out, str(graph.metadata["readout"]))
        res[f"{name}_max_score_diff"] = float((got - ref).abs().max()) if len(ref) else 0.0
        res[f"{name}_prediction_agreement"] = (
            float((got.argmax(1) == ref.argmax(1)).float().mean()) if len(ref) else 1.0
        )
    return res
