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
import math
import time
from collections import OrderedDict
from collections.abc import Iterable
from contextlib import asynccontextmanager

import numpy as np
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from .live import LiveHub, page_html, page_script_js, window_event
from .runtime import InputError, PipelineSession, StreamState
from .security import BrowserGuard, default_allowed_hosts

MAX_BODY_BYTES = 8 << 20
MAX_STREAMS = 256
STREAM_TTL_S = 300.0  # a stream idle this long is dropped


class HTTPError(Exception):
    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status, self.message = status, message


class MicroBatcher:
    """Collects concurrent window batches and runs them in one session call."""

    def __init__(self, session: PipelineSession, window_ms: float = 2.0, max_batch: int = 256):
        self.session, self.window_s, self.max_batch = session, window_ms / 1000.0, max_batch
        self.queue: asyncio.Queue | None = None
        self.task: asyncio.Task | None = None
        self.calls = 0
        self.windows = 0

    async def start(self) -> None:
        self.queue = asyncio.Queue()
        self.task = asyncio.create_task(self._loop())

    async def stop(self) -> None:
        if self.task:
            self.task.cancel()

    async def submit(self, x: np.ndarray) -> np.ndarray:
        fut = asyncio.get_running_loop().create_future()
        await self.queue.put((x, fut))
        return await fut

    async def _loop(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            items = [await self.queue.get()]
            deadline = time.monotonic() + self.window_s
            size = len(items[0][0])
            while size < self.max_batch:
                timeout = deadline - time.monotonic()
                if timeout <= 0:
                    break
                try:
                    item = await asyncio.wait_for(self.queue.get(), timeout)
                except asyncio.TimeoutError:
                    break
                items.append(item)
                size += len(item[0])
            batch = np.concatenate([x for x, _ in items])
            try:
                scores = await loop.run_in_executor(None, self.session.run, batch)
            except Exception as e:  # the model failed: fail every request of the batch
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


async def _read_body(request: Request, limit: int) -> bytes:
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > limit:
        raise HTTPError(413, f"request body of {declared} bytes exceeds the {limit}-byte limit")
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > limit:
            raise HTTPError(413, f"request body exceeds the {limit}-byte limit")
    if not body:
        raise HTTPError(400, "empty request body")
    return bytes(body)


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


def _parse(body: bytes, ctype: str, key: str) -> tuple[object, float | None]:
    """Body -> (array-like, fs_hz or None). Only content types a browser cannot send across
    sites without a CORS preflight are accepted (see :mod:`tactilesnn.service.security`)."""
    media = _media_type(ctype)
    if media in NPY_TYPES:
        try:
            arr = np.load(io.BytesIO(body), allow_pickle=False)
        except Exception as e:
            raise HTTPError(400, f"body is not a valid .npy array: {e}") from e
        return arr, None
    if media == "application/json":
        try:
            doc = json.loads(body)
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise HTTPError(400, f"malformed JSON: {e}") from e
        except RecursionError as e:
            raise HTTPError(400, "JSON nested too deeply") from e
        if not isinstance(doc, dict):
            raise HTTPError(400, "JSON body must be an object")
        keys = [k for k in (key, key + "s") if k in doc]
        if not keys:
            raise HTTPError(422, f"JSON body needs a {key!r} (or {key + 's'!r}) field")
        fs = doc.get("fs_hz")
        if fs is not None and (
            isinstance(fs, bool) or not isinstance(fs, int | float) or not math.isfinite(fs)
        ):
            raise HTTPError(422, "fs_hz must be a finite number")
        return doc[keys[0]], fs
    shown = repr(ctype[:100]) if ctype else "none"
    raise HTTPError(
        415,
        f"unsupported content type {shown}; send Content-Type: application/json or "
        "application/x-npy",
    )


def create_app(
    model_path: str,
    threads: int = 0,
    max_body_bytes: int = MAX_BODY_BYTES,
    batch_window_ms: float = 2.0,
    max_streams: int = MAX_STREAMS,
    stream_ttl_s: float = STREAM_TTL_S,
    allowed_hosts: Iterable[str] | None = None,
) -> Starlette:
    """The HTTP app. Streams idle for ``stream_ttl_s`` are dropped (so abandoned ids never lock
    new streams out); each stream is fed under its own lock, off the event loop, so a large
    chunk on one stream does not hold up the others. ``allowed_hosts``: the names a request's
    ``Host`` may carry (default: the loopback names; see :mod:`tactilesnn.service.security`)."""
    hosts = default_allowed_hosts("127.0.0.1") if allowed_hosts is None else set(allowed_hosts)
    session = PipelineSession(model_path, threads=threads, expose_spikes=True)
    batcher = MicroBatcher(session, batch_window_ms)
    hub = LiveHub()
    streams: OrderedDict[str, StreamState] = OrderedDict()  # least recently used first
    stream_lock = asyncio.Lock()  # guards the table only, never held during inference

    def expire(now: float) -> None:
        while streams:
            sid, st = next(iter(streams.items()))
            if now - st.meta.get("last_used", now) <= stream_ttl_s:
                break
            streams.pop(sid)

    async def classify(request: Request):
        body = await _read_body(request, max_body_bytes)
        data, fs = _parse(body, request.headers.get("content-type", ""), "window")
        if fs is None and request.headers.get("x-fs-hz"):
            try:
                fs = float(request.headers["x-fs-hz"])
            except ValueError as e:
                raise HTTPError(422, "X-Fs-Hz must be a number") from e
        x = session.validate(data, fs)
        scores = await batcher.submit(x)
        idx = scores.argmax(1)
        return JSONResponse(
            {
                "classes": [session.class_names[i] for i in idx],
                "class_index": idx.tolist(),
                "scores": scores.tolist(),
            }
        )

    async def stream(request: Request):
        sid = _check_stream_id(request.path_params["sid"])
        if request.method == "DELETE":
            async with stream_lock:
                existed = streams.pop(sid, None) is not None
            return JSONResponse({"deleted": existed}, status_code=200 if existed else 404)
        body = await _read_body(request, max_body_bytes)
        data, fs = _parse(body, request.headers.get("content-type", ""), "chunk")
        if fs is not None and abs(float(fs) - session.fs_hz) > 1e-6 * session.fs_hz:
            raise HTTPError(
                422, f"sampling rate {fs} Hz does not match the model's {session.fs_hz}"
            )
        async with stream_lock:
            now = time.monotonic()
            expire(now)
            state = streams.get(sid)
            if state is None:
                if len(streams) >= max_streams:
                    raise HTTPError(
                        429,
                        f"too many open streams ({max_streams}); DELETE unused ones or wait "
                        f"{stream_ttl_s:g} s for idle ones to expire",
                    )
                state = streams[sid] = StreamState()
                state.meta["lock"] = asyncio.Lock()
            state.meta["last_used"] = now
            streams.move_to_end(sid)
        async with state.meta["lock"]:  # one chunk at a time per stream, in arrival order
            loop = asyncio.get_running_loop()
            live = hub.active
            results = await loop.run_in_executor(
                None, lambda: session.feed_stream(state, data, detail=live)
            )
            state.meta["last_used"] = time.monotonic()
        for r in results if live else ():
            window, spikes = r.pop("window"), r.pop("spikes")
            hub.publish(window_event(sid, r, window, spikes, session.fs_hz, session.class_names,
                                     session.window // 2))  # fmt: skip
        return JSONResponse({"stream": sid, "results": results})

    async def page(request: Request):
        return HTMLResponse(page_html())

    async def page_script(request: Request):
        return Response(page_script_js(), media_type="text/javascript; charset=utf-8")

    async def live(request: Request):
        queue = hub.subscribe()

        async def events():
            try:
                yield ": connected\n\n"
                while True:
                    try:
                        text = await asyncio.wait_for(queue.get(), timeout=15.0)
                    except asyncio.TimeoutError:
                        yield ": keep-alive\n\n"  # proxies close silent connections
                        continue
                    yield f"data: {text}\n\n"
            finally:
                hub.unsubscribe(queue)

        headers = {"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
        return StreamingResponse(events(), media_type="text/event-stream", headers=headers)

    async def model(request: Request):
        return JSONResponse(session.info())

    async def health(request: Request):
        return JSONResponse({"status": "ok", "batches": batcher.calls, "windows": batcher.windows,
                             "open_streams": len(streams), "live_pages": len(hub.queues),
                             "live_events": hub.published})  # fmt: skip

    @asynccontextmanager
    async def lifespan(app):
        await batcher.start()
        yield
        await batcher.stop()

    async def on_error(request: Request, exc: Exception):
        if isinstance(exc, HTTPError):
            return JSONResponse({"error": exc.message}, status_code=exc.status)
        if isinstance(exc, InputError):
            return JSONResponse({"error": str(exc)}, status_code=422)
        return JSONResponse({"error": f"internal error: {type(exc).__name__}"}, status_code=500)

    app = Starlette(
        routes=[
            Route("/v1/classify", classify, methods=["POST"]),
            Route("/v1/stream/{sid}", stream, methods=["POST", "DELETE"]),
            Route("/v1/model", model, methods=["GET"]),
            Route("/healthz", health, methods=["GET"]),
            Route("/", page, methods=["GET"]),
            Route("/live.js", page_script, methods=["GET"]),
            Route("/v1/live", live, methods=["GET"]),
        ],
        exception_handlers={HTTPError: on_error, InputError: on_error, Exception: on_error},
        lifespan=lifespan,
        middleware=[Middleware(BrowserGuard, allowed_hosts=hosts)],
    )
    app.state.session = session
    app.state.batcher = batcher
    app.state.hub = hub
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
    import uvicorn

    hosts = default_allowed_hosts(host) | set(allowed_hosts)
    uvicorn.run(
        create_app(model_path, threads=threads, stream_ttl_s=stream_ttl_s, allowed_hosts=hosts),
        host=host,
        port=port,
        log_level="info",
        timeout_graceful_shutdown=10,
    )
