"""Demo source for the live page: a synthetic task's scans streamed to a running service.

``demo_stream(url, task)`` renders samples of a registered task (a task with continuous scans,
such as ``hook_loop``, gives each scan's readout stream; a trial task, its trials one after the
other), keeps the channels the served model expects (by name) and POSTs them in chunks of
``chunk_ms`` to ``/v1/stream/<stream>``, paced at ``speed`` x real time (0 = as fast as the service
answers).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator

import numpy as np

from ..service.client import Client

log = logging.getLogger("tactilesnn")


def task_stream(task, start: int = 0) -> Iterator[tuple[np.ndarray, str]]:
    """Endless ``([channels, samples] float32, description)`` pieces of ``task``."""
    from ..datasets_synth.tasks.base import ScanTask

    i = start
    while True:
        if isinstance(task, ScanTask):  # tasks with continuous scans: the readout stream itself
            x, _, info = task.scan(i % task.n_scans)
            yield np.asarray(x, np.float32), f"scan {i}: {' / '.join(info['order'])}"
        else:
            X, y = task.render(i % task.n_samples)
            yield (
                np.concatenate(list(X), axis=1).astype(np.float32),
                f"sample {i}: " + ", ".join(task.class_names[k] for k in y),
            )
        i += 1


def demo_stream(
    url: str,
    task_name: str = "hook_loop",
    stream: str = "demo",
    seconds: float = 0.0,
    speed: float = 1.0,
    chunk_ms: float = 100.0,
    seed: int = 0,
) -> int:
    """Stream ``task_name`` to the service at ``url`` for ``seconds`` of signal (0 = until
    interrupted); returns the number of windows the service classified."""
    from ..datasets_synth import get_task

    if speed < 0 or chunk_ms <= 0 or seconds < 0:
        raise ValueError("speed >= 0, chunk_ms > 0 and seconds >= 0 are required")
    client = Client(url)
    info = client.model()
    task = get_task(task_name, seed=seed)
    if abs(task.fs_hz - info["fs_hz"]) > 1e-6 * info["fs_hz"]:
        raise ValueError(f"task {task_name} samples at {task.fs_hz} Hz, the model at "
                         f"{info['fs_hz']} Hz")  # fmt: skip
    names = list(task.channel_names)
    missing = [c for c in info["channels"] if c not in names]
    if missing:
        raise ValueError(f"the model expects channels {missing} that task {task_name} lacks")
    idx = [names.index(c) for c in info["channels"]]
    step = max(1, round(chunk_ms * task.fs_hz / 1000.0))
    sent, windows, t0 = 0, 0, time.monotonic()
    limit = round(seconds * task.fs_hz) if seconds else None
    try:
        for x, what in task_stream(task):
            log.info("demo-stream %s -> %s: %s", task_name, stream, what)
            for s in range(0, x.shape[1], step):
                windows += len(client.stream(stream, x[idx, s : s + step]))
                sent += min(step, x.shape[1] - s)
                if speed > 0:  # pace: sample `sent` is due at sent / fs / speed seconds
                    time.sleep(max(0.0, sent / task.fs_hz / speed - (time.monotonic() - t0)))
                if limit is not None and sent >= limit:
                    return windows
    finally:
        try:
            client.close_stream(stream)
        except Exception:  # the service may be gone; nothing to clean up then
            pass
    return windows
