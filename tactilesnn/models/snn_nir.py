"""The SNN component as a NIR graph (https://neuroir.org); the mapping is described in
:mod:`tactilesnn.export.nir`, which writes, reads back and simulates it."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from torch import Tensor


def require_nir():
    try:
        import nir
    except ImportError as e:  # optional dependency
        raise ImportError(
            "NIR export needs the 'nir' package: pip install 'tactilesnn[nir]'"
        ) from e
    return nir


def snn_to_nir(model: Any):
    """The SNN component (:class:`~tactilesnn.models.snn.SNNModel`) as a ``nir.NIRGraph``."""
    nir = require_nir()
    net, cfg = model.net, model.config
    dt_s, tau_s = cfg.dt_ms / 1000.0, cfg.tau_ms / 1000.0
    beta = math.exp(-cfg.dt_ms / cfg.tau_ms)
    r = 1.0 / (1.0 - beta)

    def arr(t: Tensor) -> np.ndarray:
        return t.detach().cpu().numpy().astype(np.float32)

    def full(n: int, v: float) -> np.ndarray:
        return np.full(n, v, dtype=np.float32)

    n_in, n_h, n_c = net.hidden.fc.in_features, net.hidden.fc.out_features, model.n_classes
    nodes: dict[str, Any] = {
        "input": nir.Input(input_type={"input": np.array([n_in])}),
        "fc1": nir.Affine(weight=arr(net.hidden.fc.weight), bias=arr(net.hidden.fc.bias)),
        "lif1": nir.LIF(
            tau=full(n_h, tau_s),
            r=full(n_h, r),
            v_leak=full(n_h, 0.0),
            v_threshold=full(n_h, net.hidden.theta),
            v_reset=full(n_h, 0.0),
        ),
        "fc2": nir.Affine(weight=arr(net.out.fc.weight), bias=arr(net.out.fc.bias)),
        "output": nir.Output(output_type={"output": np.array([n_c])}),
    }
    if cfg.readout == "count":
        nodes["readout"] = nir.LIF(tau=full(n_c, tau_s), r=full(n_c, r), v_leak=full(n_c, 0.0),
                               v_threshold=full(n_c, net.out.theta), v_reset=full(n_c, 0.0))  # fmt: skip
    else:
        nodes["readout"] = nir.LI(tau=full(n_c, tau_s), r=full(n_c, r), v_leak=full(n_c, 0.0))
    edges = [
        ("input", "fc1"),
        ("fc1", "lif1"),
        ("lif1", "fc2"),
        ("fc2", "readout"),
        ("readout", "output"),
    ]
    if net.hidden.rec is not None:
        nodes["rec"] = nir.Affine(weight=arr(net.hidden.rec.weight), bias=np.zeros(n_h, np.float32))
        edges += [("lif1", "rec"), ("rec", "lif1")]
    meta = {
        "producer": "tactilesnn",
        "dt_s": dt_s,
        "reset": "subtract",
        "readout": cfg.readout,
        "input": "spike counts per dt step (raster of the encoder's spike times)",
        "steps": int(model.steps),
    }
    return nir.NIRGraph(nodes=nodes, edges=edges, metadata=meta)
