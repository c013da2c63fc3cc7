"""onnxruntime calls over a batch axis in bounded slices (numpy only; no torch)."""

from __future__ import annotations

import numpy as np

from .memory import release_memory


def run_batched(
    sess,
    outputs: list[str],
    feeds: dict[str, np.ndarray],
    batch: int,
    desc: str | None = None,
    trim: bool = False,
) -> list:
    """``sess.run`` over the leading axis in slices of ``batch`` (bounded memory), concatenated;
    with ``desc`` a progress bar of that name (over two slices or more); ``trim``: the heap's
    free blocks handed back after each slice (a long verification: without it the process kept
    every slice's intermediates resident, FabricSlide's export 1.08 -> 1.40 GB)."""
    n = len(next(iter(feeds.values())))
    if n <= batch:  # one slice: no views to pass, no copies to join (16 us of a 0.27 ms call)
        return sess.run(outputs, feeds)
    starts = range(0, n, batch)
    if desc is not None and len(starts) > 1:
        from tqdm.auto import tqdm  # not needed by the service itself

        starts = tqdm(starts, desc=desc, unit="batch", disable=None)
    parts = []
    for i in starts:
        parts.append(sess.run(outputs, {k: v[i : i + batch] for k, v in feeds.items()}))
        if trim:
            release_memory()
    return [np.concatenate([p[j] for p in parts]) for j in range(len(outputs))]


#: onnxruntime's CPU kernels of these operators, with a ``reduction`` other than ``none``, lose
#: updates that share an output element when the node runs on more than one intra-op thread
#: (microsoft/onnxruntime#18048 and #23396; measured with 1.32: 20,000 rows added into 426 on
#: 2 threads, off by up to 5.1 against float64, every run different; on 1 thread 8e-6). A SNN's
#: window graph adds each spike's weight column into its step with one such ``ScatterND``.
#: ``ScatterElements`` is not one: its CPU kernel runs sequentially whatever the threads
#: (microsoft/onnxruntime#28584), and 3.2 million int64 and float64 additions into 135,168
#: elements came out exact on 1, 2 and 4 threads, 20 runs each (1.32); the LIF code's graph
#: counts its slots with one (``spiking.slots_from_samples``) and keeps its threads.
REDUCING_SCATTERS = ("ScatterND",)


def reducing_scatter(model) -> bool:
    """Whether the ONNX ``model`` (a ``ModelProto``) holds a :data:`REDUCING_SCATTERS` node with
    a reduction, in its graph or any subgraph."""
    from onnx import AttributeProto

    def walk(graph) -> bool:
        for node in graph.node:
            for a in node.attribute:
                if a.type == AttributeProto.GRAPH and walk(a.g):
                    return True
                if a.type == AttributeProto.GRAPHS and any(walk(g) for g in a.graphs):
                    return True
            if node.op_type in REDUCING_SCATTERS and any(
                a.name == "reduction" and a.s not in (b"", b"none") for a in node.attribute
            ):
                return True
        return False

    return walk(model.graph)


def session_threads(model, threads: int = 0) -> int:
    """The intra-op threads to run ``model`` on (0 = onnxruntime's default, every core): one
    when it holds a reducing scatter (:data:`REDUCING_SCATTERS`: more would race), or when the
    ``onnx`` package is missing and the graph cannot be read; else ``threads``."""
    if model is None:
        return 1
    return 1 if reducing_scatter(model) else int(threads)
