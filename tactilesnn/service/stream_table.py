"""The service's table of open streams: typed entries, a cap, and expiry of idle ones.

Each stream carries the model's state across its chunks (:class:`~.runtime.StreamState`), a lock
that feeds its chunks one at a time in arrival order, and when it was last used. The table's own
lock guards only the table (never held during inference), so a large chunk on one stream does
not hold up the others.
"""

from __future__ import annotations

import asyncio
import time
from collections import OrderedDict
from dataclasses import dataclass, field

from .runtime import StreamState


class TooManyStreams(Exception):
    """The table is full of streams that are still in use."""


@dataclass
class Stream:
    """One open stream."""

    state: StreamState = field(default_factory=StreamState)
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    last_used: float = field(default_factory=time.monotonic)


class StreamTable:
    """At most ``max_streams`` streams; one idle for ``ttl_s`` seconds is dropped (so abandoned
    ids never lock new streams out)."""

    def __init__(self, max_streams: int, ttl_s: float) -> None:
        self.max_streams, self.ttl_s = int(max_streams), float(ttl_s)
        self._streams: OrderedDict[str, Stream] = OrderedDict()  # least recently used first
        self._lock = asyncio.Lock()

    def __len__(self) -> int:
        return len(self._streams)

    async def open(self, sid: str) -> Stream:
        """The stream ``sid``, created if new (:class:`TooManyStreams` if the table is full)."""
        async with self._lock:
            now = time.monotonic()
            self._expire(now)
            stream = self._streams.get(sid)
            if stream is None:
                if len(self._streams) >= self.max_streams:
                    raise TooManyStreams(
                        f"too many open streams ({self.max_streams}); DELETE unused ones or wait "
                        f"{self.ttl_s:g} s for idle ones to expire"
                    )
                stream = self._streams[sid] = Stream()
            stream.last_used = now
            self._streams.move_to_end(sid)
            return stream

    async def close(self, sid: str) -> bool:
        """Drop ``sid``; False if it was not open."""
        async with self._lock:
            return self._streams.pop(sid, None) is not None

    def _expire(self, now: float) -> None:
        while self._streams:
            sid, stream = next(iter(self._streams.items()))
            if now - stream.last_used <= self.ttl_s:
                break
            self._streams.pop(sid)
