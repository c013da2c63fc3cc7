"""Live view of the streams a service classifies: server-sent events + a page (numpy only).

Every window the stream endpoint classifies becomes one event on ``GET /v1/live`` (``text/
event-stream``): the window's input (each channel decimated to at most ``MAX_POINTS`` points, sent
relative to ``signal_scale``), a
display spectrogram (log magnitude of a Hann-windowed short-time FFT of the channels' sum,
``[bands, frames]``, computed here, not by the model's encoder), the spike raster the exported
encoder produced (``[afferent, time ms]`` pairs, at most ``MAX_SPIKES``), and the class scores.
``GET /`` serves ``live.html`` and ``GET /live.js`` its script: plain JavaScript drawing those on
canvases, no build step; every string of an event is inserted as text.

A slow page never holds up classification: each subscriber has a bounded queue and the oldest
event is dropped when it is full.
"""

from __future__ import annotations

import asyncio
import json
from importlib import resources

import numpy as np

MAX_POINTS = 256
MAX_SPIKES = 4000
MAX_CHANNELS = 12
QUEUE_EVENTS = 32


def page_html() -> str:
    return resources.files(__package__).joinpath("live.html").read_text(encoding="utf-8")


def page_script_js() -> str:
    """The page's script, a file of its own so the page's policy can forbid inline script."""
    return resources.files(__package__).joinpath("live.js").read_text(encoding="utf-8")


def spectrogram(x: np.ndarray, fs_hz: float, frame: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """``x [channels, samples]`` -> ``(log10 magnitude [bands, frames], band centres Hz)`` of the
    channels' sum, Hann frames of ``frame`` samples every ``frame / 4`` (for display)."""
    s = np.asarray(x, np.float64).sum(0)
    frame = int(min(frame, s.size))
    hop = max(1, frame // 4)
    starts = np.arange(0, s.size - frame + 1, hop)
    frames = np.stack([s[i : i + frame] for i in starts]) * np.hanning(frame)
    mag = np.abs(np.fft.rfft(frames - frames.mean(1, keepdims=True), axis=1)).T  # [bands, frames]
    return np.log10(mag + 1e-6 * mag.max() + 1e-30), np.fft.rfftfreq(frame, 1.0 / fs_hz)


def window_event(
    stream: str,
    result: dict,
    window: np.ndarray,
    spikes: np.ndarray | None,
    fs_hz: float,
    class_names: list[str],
    hop: int,
    channels: list[str] | None = None,
) -> dict:
    """The live event of one classified window (see the module docstring); ``channels``: the
    window's channel names (the legend of the input plot: the first ``MAX_CHANNELS`` drawn)."""
    n = window.shape[1]
    step = max(1, int(np.ceil(n / MAX_POINTS)))
    signal = np.asarray(window[:MAX_CHANNELS, ::step], np.float64)
    scale = float(np.abs(signal).max()) or 1.0  # sent relative to it: 4 digits at any level
    spec, freqs = spectrogram(window, fs_hz)
    raster: list[list[float]] = []
    n_aff = 0
    if spikes is not None:
        n_aff = int(spikes.shape[0])
        a, k = np.nonzero(np.isfinite(spikes))
        raster = [[int(i), round(float(t), 3)] for i, t in zip(a, spikes[a, k], strict=True)]
        raster = raster[:MAX_SPIKES]
    duration_ms = 1000.0 * n / fs_hz
    return {
        "stream": stream,
        "window_index": result["window_index"],
        "t_s": result["window_index"] * hop / fs_hz,
        "class": result["class"],
        "scores": [round(float(v), 5) for v in result["scores"]],
        "class_names": class_names,
        "channels": list(channels or [])[:MAX_CHANNELS],
        "n_channels": int(window.shape[0]),
        "signal": np.round(signal / scale, 4).tolist(),
        "signal_scale": scale,
        "signal_dt_ms": 1000.0 * step / fs_hz,
        "spectrogram": np.round(spec, 3).tolist(),
        "freqs_hz": [round(float(f), 2) for f in freqs],
        "raster": raster,
        "n_afferents": n_aff,
        "duration_ms": duration_ms,
    }


class LiveHub:
    """Fan-out of live events to the open pages (each a bounded queue)."""

    def __init__(self) -> None:
        self.queues: set[asyncio.Queue] = set()
        self.published = 0
        self.closed = False

    def close(self) -> None:
        """End every open page's event stream (the server is stopping: a page's connection
        would otherwise hold the shutdown until its grace period ends). Call on the loop."""
        self.closed = True
        for q in self.queues:
            if q.full():
                q.get_nowait()
            q.put_nowait(None)  # the end-of-stream mark

    @property
    def active(self) -> bool:
        return bool(self.queues)

    def subscribe(self) -> asyncio.Queue:
        q: asyncio.Queue = asyncio.Queue(maxsize=QUEUE_EVENTS)
        self.queues.add(q)
        return q

    def unsubscribe(self, q: asyncio.Queue) -> None:
        self.queues.discard(q)

    def publish(self, event: dict) -> None:
        text = json.dumps(event, separators=(",", ":"))
        self.published += 1
        for q in self.queues:
            if q.full():  # a slow page loses its oldest update, never blocks the stream
                q.get_nowait()
            q.put_nowait(text)
