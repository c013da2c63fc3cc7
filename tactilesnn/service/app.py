"""HTTP inference service over an exported pipeline (Starlette on uvicorn).

Endpoints:
  ``POST /v1/classify``  body JSON ``{"window": [[...]] | "windows": [[[...]]], "fs_hz": 200}`` or
                         a binary ``.npy`` (``Content-Type: application/x-npy``, header ``X-Fs-Hz``
                         optional) of ``[channels, samples]`` or ``[batch, channels, samples]``;
                         -> ``{"classes", "class_index", "scores"}``.
  ``POST /v1/stream/{id}`` JSON ``{"chunk": [[...]]}`` (``[channels, n]``) or ``.npy``: appended to
                         the stream's buffer; every completed window (hop = window / 2) is
                         classified, SNN state carried -> ``{"results": [...]}``.
  ``DELETE /v1/stream/{id}``, ``GET /v1/model`` (metadata), ``GET /healthz``.
  ``GET /`` a live page of the streams (input, spectrogram, spike raster, scores), fed by
                         ``GET /v1/live`` (server-sent events, one per classified window;
                         see :mod:`tactilesnn.service.live`).

Bad input gets a 4xx with a specific message (400 malformed, 413 too large, 415 content type,
422 wrong shape / dtype / rate / NaN, 429 too many streams). Concurrent single requests are
micro-batched: requests arriving within ``batch_window_ms`` run as one onnxruntime call. uvicorn
finishes in-flight requests on SIGTERM/SIGINT (graceful shutdown).
"""

from __future__ import annotations

import asyncio
import io
import json
import logging
import math
import time
from collections import deque
from collections.abc import Iterable
from concurrent.futures.process import BrokenProcessPool
from contextlib import asynccontextmanager
from typing import Any

import numpy as np
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.requests import ClientDisconnect, Request
from starlette.responses import HTMLResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from .live import LiveHub, page_html, page_script_js, window_event
from .runtime import InputError, PipelineSession
from .security import BrowserGuard, default_allowed_hosts
from .stream_table import StreamTable, TooManyStreams

MAX_BODY_BYTES = 8 << 20
MAX_STREAMS = 256
STREAM_TTL_S = 300.0  # a stream idle this long is dropped
BODY_TIMEOUT_S = 30.0  # a body not received within this is dropped (408)
INFLIGHT_BYTES = 64 << 20  # large bodies held at once, counted as they arrive (503 beyond)
SMALL_BODY_BYTES = 64 << 10  # the first bytes of every body are not counted (small ones pass)
PARSE_INLINE_BYTES = 64 << 10  # larger bodies are parsed off the event loop


log = logging.getLogger("tactilesnn.service")


class HTTPError(Exception):
    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status, self.message = status, message

    def __reduce__(self):  # it crosses back from the parser process
        return type(self), (self.status, self.message)


#: windows of one request run per onnxruntime call at most: a large batch is split, so another
#: client's request waits for one slice of it, not the whole
FAIR_SLICE_WINDOWS = 16


class MicroBatcher:
    """Runs the windows of concurrent requests in shared session calls, fairly.

    Requests arriving within ``window_ms`` of each other run as one call (micro-batching). Each
    request is cut into slices of at most :data:`FAIR_SLICE_WINDOWS` windows, queued per client
    (a connection); a call takes slices from the clients in turn (round robin) up to
    ``max_batch`` windows. A client posting 8 MB batches back to back thus gets its share of the
    calls, and a one-window request waits for at most one call, not for the whole batch ahead
    of it (measured in ``tactilesnn bench serve``)."""

    def __init__(self, session: PipelineSession, window_ms: float = 2.0, max_batch: int = 64,
                 slice_windows: int = FAIR_SLICE_WINDOWS) -> None:  # fmt: skip
        self.session, self.window_s, self.max_batch = session, window_ms / 1000.0, max_batch
        self.slice = max(1, int(slice_windows))
        self.pending: dict[object, deque] = {}  # client -> slices (windows, future)
        self.arrived: asyncio.Event | None = None
        self.task: asyncio.Task | None = None
        self.calls = 0
        self.windows = 0

    async def start(self) -> None:
        self.arrived = asyncio.Event()
        self.task = asyncio.create_task(self._loop())

    async def stop(self) -> None:
        if self.task:
            self.task.cancel()

    async def submit(self, x: np.ndarray, client: object = None) -> np.ndarray:
        """Scores ``[N, classes]`` of the windows ``x [N, ...]`` of ``client``'s request."""
        loop = asyncio.get_running_loop()
        futures = []
        queue = self.pending.setdefault(client, deque())
        for i in range(0, len(x), self.slice):
            fut = loop.create_future()
            queue.append((x[i : i + self.slice], fut))
            futures.append(fut)
        self.arrived.set()
        try:
            parts = [await f for f in futures]
        finally:  # a request whose client left: its slices not yet run are dropped
            for f in futures:
                f.cancel()
        return np.concatenate(parts)

    def _take(self) -> list[tuple[np.ndarray, asyncio.Future]]:
        """Slices for one call: one from each client in turn, up to ``max_batch`` windows."""
        items, size = [], 0
        while size < self.max_batch:
            took = False
            for client in list(self.pending):
                queue = self.pending[client]
                while queue and queue[0][1].done():  # cancelled: its request is gone
                    queue.popleft()
                if not queue:
                    del self.pending[client]
                    continue
                if items and size + len(queue[0][0]) > self.max_batch:
                    continue
                x, fut = queue.popleft()
                items.append((x, fut))
                size += len(x)
                took = True
                # the client goes to the back of the turn order
                self.pending[client] = self.pending.pop(client)
            if not took:
                break
        return items

    async def _loop(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            await self.arrived.wait()
            queued = sum(len(x) for q in self.pending.values() for x, _ in q)
            if queued < self.max_batch:  # the requests of the next few ms join the call
                await asyncio.sleep(self.window_s)
            items = self._take()
            if not any(self.pending.values()):
                self.arrived.clear()
            if not items:
                continue
            batch = np.concatenate([x for x, _ in items])
            try:
                scores = await loop.run_in_executor(None, self.session.run, batch)
            except Exception as e:  # the model failed: fail every request of the call
                for _, fut in items:
                    if not fut.done():
                        fut.set_exception(e)
                continue
            self.calls += 1
            self.windows += len(batch)
            start = 0
            for x, fut in items:
                if not fut.done():
                    fut.set_result(scores[start : start + len(x)])
                start += len(x)


NPY_TYPES = frozenset({"application/x-npy", "application/octet-stream"})
MAX_STREAM_ID = 128


def _media_type(ctype: str) -> str:
    """``application/json; charset=utf-8`` -> ``application/json``."""
    return ctype.split(";", 1)[0].strip().lower()


def _check_stream_id(sid: str) -> str:
    if len(sid) > MAX_STREAM_ID:
        raise HTTPError(422, f"stream id longer than {MAX_STREAM_ID} characters")
    if not sid.isprintable():
        raise HTTPError(422, "stream id contains control characters")
    return sid


def _check_media_type(ctype: str) -> str:
    media = _media_type(ctype)
    if media != "application/json" and media not in NPY_TYPES:
        shown = repr(ctype[:100]) if ctype else "none"
        raise HTTPError(
            415,
            f"unsupported content type {shown}; send Content-Type: application/json or "
            "application/x-npy",
        )
    return media


def _parse(body: bytes, ctype: str, key: str) -> tuple[object, float | None]:
    """Body -> (array-like, fs_hz or None). Only content types a browser cannot send across
    sites without a CORS preflight are accepted (see :mod:`tactilesnn.service.security`)."""
    media = _check_media_type(ctype)
    if media in NPY_TYPES:
        try:
            arr = np.load(io.BytesIO(body), allow_pickle=False)
        except Exception as e:
            raise HTTPError(400, f"body is not a valid .npy array: {e}") from e
        return arr, None
    try:
        doc = json.loads(body)
    except RecursionError as e:
        raise HTTPError(400, "JSON nested too deeply") from e
    except ValueError as e:  # malformed, bad UTF-8, an integer of more than 4,300 digits
        raise HTTPError(400, f"malformed JSON: {str(e)[:200]}") from e
    if not isinstance(doc, dict):
        raise HTTPError(400, "JSON body must be an object")
    keys = [k for k in (key, key + "s") if k in doc]
    if not keys:
        raise HTTPError(422, f"JSON body needs a {key!r} (or {key + 's'!r}) field")
    if len(keys) > 1:  # which one the client meant is not ours to guess
        raise HTTPError(422, f"JSON body has both {key!r} and {key + 's'!r}; send one")
    return doc[keys[0]], _rate(doc.get("fs_hz"))


def _parse_to_array(body: bytes, ctype: str, key: str) -> tuple[object, float | None]:
    """:func:`_parse` in the parser process, the nested lists turned into an array there (the
    array crosses back to the service in one piece; a ragged or non-numeric value crosses as it
    is and is refused by the session's checks)."""
    data, fs = _parse(body, ctype, key)
    if isinstance(data, list):
        try:
            arr = np.asarray(data)
        except (ValueError, TypeError, OverflowError):
            return data, fs
        if arr.dtype.kind in "fiu":
            return arr, fs
    return data, fs


def _rate(fs: object) -> float | None:
    """A request's ``fs_hz``: None, or a positive finite float (422 otherwise)."""
    if fs is None:
        return None
    if isinstance(fs, bool) or not isinstance(fs, int | float):
        raise HTTPError(422, "fs_hz must be a finite number")
    try:
        value = float(fs)  # a JSON integer of 400 digits overflows here
    except OverflowError:
        value = math.inf
    if not math.isfinite(value) or value <= 0:
        raise HTTPError(422, "fs_hz must be a finite number > 0")
    return value


class ByteBudget:
    """Bytes of request bodies the service holds at once, counted as they arrive: a body
    that would take the total past ``limit`` is refused (503) and dropped. The first
    ``free_bytes`` of each body are not counted (small requests always pass; the connection cap
    bounds them), so stalled large uploads cannot starve small ones."""

    def __init__(self, limit: int, free_bytes: int) -> None:
        self.limit, self.free_bytes, self.held = int(limit), int(free_bytes), 0

    def take(self, n: int) -> None:
        if self.held + n > self.limit:
            raise HTTPError(503, f"the service holds {self.held} bytes of uploads (budget "
                            f"{self.limit}); retry shortly")  # fmt: skip
        self.held += n

    def give(self, n: int) -> None:
        self.held -= n


class Service:
    """The endpoints over one exported pipeline (see the module docstring)."""

    def __init__(self, model_path: str, threads: int, max_body_bytes: int, batch_window_ms: float,
                 max_streams: int, stream_ttl_s: float, body_timeout_s: float,
                 inflight_bytes: int) -> None:  # fmt: skip
        self.session = PipelineSession(model_path, threads=threads, expose_spikes=True)
        self.batcher = MicroBatcher(self.session, batch_window_ms)
        self.hub = LiveHub()
        self.streams = StreamTable(max_streams, stream_ttl_s)
        self.max_body_bytes, self.body_timeout_s = int(max_body_bytes), float(body_timeout_s)
        self.uploads = ByteBudget(inflight_bytes, free_bytes=SMALL_BODY_BYTES)
        self._parser = None

    async def body(self, request: Request, key: str) -> tuple[object, float | None]:
        """The request's array-like and its ``fs_hz``: size checked on ``Content-Length``
        first, read within ``body_timeout_s`` and the upload budget, parsed off the event loop
        when large (an 8 MB JSON body takes ~0.5 s to parse)."""
        limit = self.max_body_bytes
        declared = request.headers.get("content-length")
        if declared is not None and declared.isdigit() and int(declared) > limit:
            raise HTTPError(413, f"request body of {declared} bytes exceeds the {limit}-byte limit")
        ctype = request.headers.get("content-type", "")
        _check_media_type(ctype)  # 415 before reading anything
        counted = [0]  # bytes of this body counted against the upload budget
        try:
            body = await asyncio.wait_for(self._read(request, limit, counted), self.body_timeout_s)
        except asyncio.TimeoutError as e:
            raise HTTPError(
                408, f"request body not received within {self.body_timeout_s:g} s"
            ) from e
        except ClientDisconnect:  # one line, not the framework's traceback
            log.info("%s %s: the client hung up after %d body bytes", request.method,
                     request.url.path, counted[0] + min(self.uploads.free_bytes, limit))  # fmt: skip
            raise HTTPError(400, "the client hung up before its body was complete") from None
        finally:
            self.uploads.give(counted[0])
        if len(body) < PARSE_INLINE_BYTES or _media_type(ctype) in NPY_TYPES:
            # (a .npy body is its header and a copy of its bytes: sending it to the parser
            # process and back would cost more than reading it here)
            return _parse(body, ctype, key)
        loop = asyncio.get_running_loop()
        try:
            return await loop.run_in_executor(self.parser_pool(), _parse_to_array, body, ctype, key)
        except BrokenProcessPool as e:  # the body crashed the parser: a new one for the next
            self.close()
            raise HTTPError(400, "the body could not be parsed") from e

    def parser_pool(self):
        """One worker process for large bodies: parsing 8 MB of JSON holds the GIL for ~0.5 s,
        which in a thread would still stall every other request (measured: other clients' p99
        268 ms beside one such client); in a process it does not."""
        if self._parser is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            self._parser = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
        return self._parser

    def close(self) -> None:
        """Stop the parser process (a new one starts on the next large body)."""
        if self._parser is not None:
            self._parser.shutdown(wait=False, cancel_futures=True)
            self._parser = None

    async def _read(self, request: Request, limit: int, counted: list[int]) -> bytes:
        """The body, at most ``limit`` bytes (413), its size beyond the budget's free bytes
        counted in ``counted[0]`` as it arrives (503 when the budget is spent)."""
        body = bytearray()
        async for chunk in request.stream():
            body += chunk
            if len(body) > limit:
                raise HTTPError(413, f"request body exceeds the {limit}-byte limit")
            extra = len(body) - self.uploads.free_bytes - counted[0]
            if extra > 0:
                self.uploads.take(extra)
                counted[0] += extra
        if not body:
            raise HTTPError(400, "empty request body")
        return bytes(body)

    async def classify(self, request: Request) -> JSONResponse:
        session = self.session
        data, fs = await self.body(request, "window")
        if fs is None and request.headers.get("x-fs-hz"):
            try:
                fs = _rate(float(request.headers["x-fs-hz"]))
            except ValueError as e:
                raise HTTPError(422, "X-Fs-Hz must be a number") from e
        if isinstance(data, np.ndarray) and data.nbytes > PARSE_INLINE_BYTES:
            # a large batch checked off the event loop (NaN scan, range, copy: ~10 ms at 8 MB)
            x = await asyncio.get_running_loop().run_in_executor(None, session.validate, data, fs)
        else:
            x = session.validate(data, fs)
        scores = await self.batcher.submit(x, client=request.client)
        idx = scores.argmax(1)
        return JSONResponse({"classes": [session.class_names[i] for i in idx],
                             "class_index": idx.tolist(), "scores": scores.tolist()})  # fmt: skip

    async def stream(self, request: Request) -> JSONResponse:
        session = self.session
        sid = _check_stream_id(request.path_params["sid"])
        if request.method == "DELETE":
            existed = await self.streams.close(sid)
            return JSONResponse({"deleted": existed}, status_code=200 if existed else 404)
        data, fs = await self.body(request, "chunk")
        if fs is not None and abs(fs - session.fs_hz) > 1e-6 * session.fs_hz:
            raise HTTPError(
                422, f"sampling rate {fs} Hz does not match the model's {session.fs_hz}"
            )
        try:
            stream = await self.streams.open(sid)
        except TooManyStreams as e:
            raise HTTPError(429, str(e)) from e
        async with stream.lock:  # one chunk at a time per stream, in arrival order
            live = self.hub.active
            results = await asyncio.get_running_loop().run_in_executor(
                None, lambda: session.feed_stream(stream.state, data, detail=live)
            )
            stream.last_used = time.monotonic()
        # the page shows a window every half window of signal: a stream graph stepping a frame
        # per call classifies ~100 windows in that time, which no one could watch
        every = max(1, (session.window // 2) // session.window_step)
        for r in results if live else ():
            window, spikes = r.pop("window"), r.pop("spikes")
            if r["window_index"] % every == 0:
                self.hub.publish(window_event(sid, r, window, spikes, session.fs_hz,
                                              session.class_names, session.window_step,
                                              session.channels))  # fmt: skip
        return JSONResponse({"stream": sid, "results": results})

    async def page(self, request: Request) -> HTMLResponse:
        return HTMLResponse(page_html())

    async def page_script(self, request: Request) -> Response:
        return Response(page_script_js(), media_type="text/javascript; charset=utf-8")

    async def live(self, request: Request) -> StreamingResponse:
        queue = self.hub.subscribe()

        async def events():
            try:
                yield ": connected\n\n"
                while not self.hub.closed:
                    try:
                        text = await asyncio.wait_for(queue.get(), timeout=15.0)
                    except asyncio.TimeoutError:
                        yield ": keep-alive\n\n"  # proxies close silent connections
                        continue
                    if text is None:  # the server is stopping
                        return
                    yield f"data: {text}\n\n"
            finally:
                self.hub.unsubscribe(queue)

        headers = {"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
        return StreamingResponse(events(), media_type="text/event-stream", headers=headers)

    async def model(self, request: Request) -> JSONResponse:
        return JSONResponse(self.session.info())

    async def health(self, request: Request) -> JSONResponse:
        return JSONResponse({"status": "ok", "batches": self.batcher.calls,
                             "windows": self.batcher.windows, "open_streams": len(self.streams),
                             "live_pages": len(self.hub.queues), "live_events": self.hub.published,
                             "upload_bytes_held": self.uploads.held})  # fmt: skip

    def routes(self) -> list[Route]:
        return [
            Route("/v1/classify", self.classify, methods=["POST"]),
            Route("/v1/stream/{sid}", self.stream, methods=["POST", "DELETE"]),
            Route("/v1/model", self.model, methods=["GET"]),
            Route("/healthz", self.health, methods=["GET"]),
            Route("/", self.page, methods=["GET"]),
            Route("/live.js", self.page_script, methods=["GET"]),
            Route("/v1/live", self.live, methods=["GET"]),
        ]


async def _on_error(request: Request, exc: Exception) -> JSONResponse:
    if isinstance(exc, HTTPError):
        return JSONResponse({"error": exc.message}, status_code=exc.status)
    if isinstance(exc, InputError):
        return JSONResponse({"error": str(exc)}, status_code=422)
    return JSONResponse({"error": f"internal error: {type(exc).__name__}"}, status_code=500)


def create_app(
    model_path: str,
    threads: int = 0,
    max_body_bytes: int = MAX_BODY_BYTES,
    batch_window_ms: float = 2.0,
    max_streams: int = MAX_STREAMS,
    stream_ttl_s: float = STREAM_TTL_S,
    allowed_hosts: Iterable[str] | None = None,
    body_timeout_s: float = BODY_TIMEOUT_S,
    inflight_bytes: int = INFLIGHT_BYTES,
) -> Starlette:
    """The HTTP app (:class:`Service`'s endpoints behind the browser guard). ``allowed_hosts``:
    the names a request's ``Host`` may carry (default: the loopback names; see
    :mod:`tactilesnn.service.security`)."""
    hosts = default_allowed_hosts("127.0.0.1") if allowed_hosts is None else set(allowed_hosts)
    service = Service(model_path, threads, max_body_bytes, batch_window_ms, max_streams,
                      stream_ttl_s, body_timeout_s, inflight_bytes)  # fmt: skip

    @asynccontextmanager
    async def lifespan(app):
        await service.batcher.start()
        yield
        await service.batcher.stop()
        service.close()

    app = Starlette(
        routes=service.routes(),
        exception_handlers={HTTPError: _on_error, InputError: _on_error, Exception: _on_error},
        lifespan=lifespan,
        middleware=[Middleware(BrowserGuard, allowed_hosts=hosts)],
    )
    app.state.service = service
    app.state.session = service.session
    app.state.batcher = service.batcher
    app.state.hub = service.hub
    return app


def serve(
    model_path: str,
    host: str = "127.0.0.1",
    port: int = 8000,
    threads: int = 0,
    stream_ttl_s: float = STREAM_TTL_S,
    allowed_hosts: Iterable[str] = (),
) -> None:
    """Run the app on ``host:port``; browsers may reach it under the names
    :func:`~tactilesnn.service.security.default_allowed_hosts` gives for ``host`` plus
    ``allowed_hosts``."""
    from .connections import server_config

    hosts = default_allowed_hosts(host) | set(allowed_hosts)
    app = create_app(model_path, threads=threads, stream_ttl_s=stream_ttl_s, allowed_hosts=hosts)
    stopping_server(server_config(app, host, port), app.state.hub).run()


def stopping_server(config: Any, hub: LiveHub) -> Any:
    """A :class:`uvicorn.Server` for ``config`` that, asked to stop (SIGTERM / SIGINT), also
    ends the live pages' event streams: they never end by themselves, so uvicorn's graceful
    shutdown would wait out its whole timeout for them and then log an error."""
    import uvicorn

    class StoppingServer(uvicorn.Server):
        def handle_exit(self, sig: int, frame: Any) -> None:
            try:
                asyncio.get_running_loop().call_soon_threadsafe(hub.close)
            except RuntimeError:  # not on the loop's thread
                hub.close()
            super().handle_exit(sig, frame)

    return StoppingServer(config)
