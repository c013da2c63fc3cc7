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
