"""Connections that cannot hold the service: header deadlines and eviction of half-open ones.

uvicorn's HTTP/1.1 protocol (h11) waits for a request's headers as long as the client likes, and
counts every open connection against ``limit_concurrency``: 300 clients that send half a request
line and stop held every slot (a normal client got 503 on all of ~19,700 requests for 15 s) and
were never closed. :class:`GuardedH11Protocol` adds what the server lacks:

* a **header deadline**: a connection must complete a request's headers within
  :data:`HEADER_TIMEOUT_S` of opening, or of its previous response (keep-alive), else it is
  closed (the body has its own deadline in the app, ``body_timeout_s``);
* **eviction**: beyond :data:`EVICT_ABOVE` open connections, a new connection closes the oldest
  one still waiting for its headers, else the one idle longest since its last answer (a
  keep-alive connection with nothing in flight: its client opens another when it next asks, as
  HTTP clients do when a server closes an idle connection); never one with a request in flight.
  530 clients that each keep a connection and poll every 3 s held uvicorn's cap while idle
  keep-alive connections were exempt (67 % of other requests got 503 or a reset);
* one log line per closed connection (DEBUG: an attack would flood the log otherwise), and the
  count in :data:`CLOSED`.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any

from uvicorn.protocols.http.h11_impl import H11Protocol

log = logging.getLogger("tactilesnn.service")

#: seconds a connection has to complete a request's headers (from opening or its last answer)
HEADER_TIMEOUT_S = 5.0
#: open connections uvicorn accepts before it answers 503 (``limit_concurrency``)
MAX_CONNECTIONS = 512
#: above this many open connections a new one evicts the oldest waiting for its headers
EVICT_ABOVE = MAX_CONNECTIONS - 128
#: connections closed so far, by reason (``header deadline``, ``evicted``)
CLOSED: dict[str, int] = {"header deadline": 0, "evicted": 0, "idle evicted": 0}


class GuardedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with a header deadline and eviction (module docstring)."""

    header_timeout_s = HEADER_TIMEOUT_S
    evict_above = EVICT_ABOVE

    def connection_made(self, transport: Any) -> None:  # type: ignore[override]
        self._deadline: asyncio.TimerHandle | None = None
        self._waiting_since = time.monotonic()
        self._partial = False  # bytes of a request received since the last answer
        self._served = False  # a request was answered on this connection
        super().connection_made(transport)
        self._arm()
        if len(self.connections) > self.evict_above:
            self._evict_one()

    def data_received(self, data: bytes) -> None:
        if self._deadline is not None:
            self._partial = True
        super().data_received(data)

    def handle_events(self) -> None:
        super().handle_events()
        if self.cycle is not None and not self.cycle.response_complete:
            self._disarm()  # a request's headers are complete: the app's deadlines take over

    def on_response_complete(self) -> None:
        self._served = True
        super().on_response_complete()  # (may start a pipelined request already received)
        idle = self.cycle is None or self.cycle.response_complete
        if idle and not self.transport.is_closing():
            self._arm()  # the next request's headers within the deadline again

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

    # ------------------------------------------------------------------------------- helpers
    @property
    def waiting_for_headers(self) -> bool:
        """Open, no request in flight, and either never answered or partway through the next
        request's headers (an idle keep-alive connection is not waiting)."""
        return self._deadline is not None and (self._partial or not self._served)

    def _arm(self) -> None:
        self._disarm()
        self._waiting_since, self._partial = time.monotonic(), False
        self._deadline = self.loop.call_later(self.header_timeout_s, self._expired)

    def _disarm(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _expired(self) -> None:
        self._deadline = None
        self._close("header deadline")

    def _evict_one(self) -> None:
        """Close the oldest connection waiting for headers, else the longest idle one."""
        quiet = [
            c
            for c in self.connections
            if isinstance(c, GuardedH11Protocol) and c is not self and c._deadline is not None
        ]  # fmt: skip  (armed: nothing in flight)
        if quiet:
            c = min(quiet, key=lambda c: (not c.waiting_for_headers, c._waiting_since))
            c._close("evicted" if c.waiting_for_headers else "idle evicted")

    def _close(self, reason: str) -> None:
        CLOSED[reason] = CLOSED.get(reason, 0) + 1
        log.debug("closed a connection from %s: %s (no request in flight)", _peer(self.client),
                  reason)  # fmt: skip
        self._disarm()
        self.transport.close()


def _peer(client: Any) -> str:
    return f"{client[0]}:{client[1]}" if client else "an unknown peer"


def server_config(app: Any, host: str, port: int, **kwargs: Any) -> Any:
    """The :class:`uvicorn.Config` every server of the service runs with (``serve``, ``bench
    serve``, the tests): the guarded protocol, uvicorn's connection cap, keep-alive 5 s;
    ``kwargs`` override (log level, access log)."""
    import uvicorn

    settings = {"http": GuardedH11Protocol, "limit_concurrency": MAX_CONNECTIONS,
                "timeout_keep_alive": 5, "timeout_graceful_shutdown": 10, "log_level": "info",
                **kwargs}  # fmt: skip
    return uvicorn.Config(app, host=host, port=port, **settings)
