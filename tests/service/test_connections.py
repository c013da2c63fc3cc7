"""Connections and clients that cannot hold the service: header deadlines, eviction of half-open
connections, fair slices of large batches, one log line for a client that hangs up."""

import asyncio
import contextlib
import logging
import socket
import threading
import time

import numpy as np
import pytest

from tactilesnn.service import connections
from tactilesnn.service.app import MicroBatcher, create_app
from tactilesnn.service.connections import GuardedH11Protocol, server_config
from tests.helpers import exported_model

SMALL = {"seed": 0, "n_planar": 6, "n_concave": 3, "n_convex": 3, "n_test": 2}


@pytest.fixture(scope="session")
def model(tmp_path_factory):
    path, _, test = exported_model(tmp_path_factory.mktemp("conn"), SMALL)
    return str(path), test


@contextlib.contextmanager
def running(app):
    import uvicorn

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    # log_config None: uvicorn leaves logging alone, so caplog sees its records
    server = uvicorn.Server(server_config(app, "127.0.0.1", port, log_config=None,
                                          access_log=False))  # fmt: skip
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        while not server.started:
            time.sleep(0.02)
        yield port
    finally:
        server.should_exit = True
        thread.join(timeout=15)


def _half_open(port: int) -> socket.socket:
    c = socket.create_connection(("127.0.0.1", port), timeout=10)
    c.sendall(b"POST /v1/classify HT")  # half a request line, then nothing
    return c


def _closed_within(c: socket.socket, seconds: float) -> bool:
    c.settimeout(seconds)
    try:
        return c.recv(64) == b""
    except TimeoutError:
        return False
    except ConnectionResetError:
        return True


def _classify(port: int, test) -> int:
    import http.client
    import io

    buf = io.BytesIO()
    np.save(buf, test.X[:1].astype(np.float32), allow_pickle=False)
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    conn.request("POST", "/v1/classify", body=buf.getvalue(),
                 headers={"Content-Type": "application/x-npy"})  # fmt: skip
    r = conn.getresponse()
    r.read()
    conn.close()
    return r.status


@pytest.mark.slow
def test_half_open_connections_are_closed_at_the_header_deadline(model, monkeypatch):
    monkeypatch.setattr(GuardedH11Protocol, "header_timeout_s", 0.5)
    with running(create_app(model[0])) as port:
        idle = socket.create_connection(("127.0.0.1", port), timeout=10)  # sends nothing
        half = _half_open(port)
        assert _classify(port, model[1]) == 200  # a normal request meanwhile
        assert _closed_within(half, 5.0) and _closed_within(idle, 5.0)


@pytest.mark.slow
def test_half_open_connections_cannot_keep_normal_clients_out(model, monkeypatch):
    """More waiting connections than the eviction threshold: each new one closes the oldest
    waiting one, and normal requests are answered throughout (not 503)."""
    monkeypatch.setattr(GuardedH11Protocol, "header_timeout_s", 60.0)
    monkeypatch.setattr(GuardedH11Protocol, "evict_above", 8)
    before = connections.CLOSED["evicted"]
    with running(create_app(model[0])) as port:
        first = [_half_open(port) for _ in range(8)]
        later = [_half_open(port) for _ in range(8)]
        time.sleep(0.3)
        statuses = [_classify(port, model[1]) for _ in range(5)]
        assert statuses == [200] * 5
        assert sum(_closed_within(c, 2.0) for c in first) >= 6  # the oldest went first
        assert connections.CLOSED["evicted"] - before >= 8
        for c in first + later:
            c.close()


@pytest.mark.slow
def test_a_client_that_hangs_up_mid_upload_is_one_log_line(model, caplog):
    with running(create_app(model[0], body_timeout_s=10)) as port, caplog.at_level(logging.INFO):
        c = socket.create_connection(("127.0.0.1", port), timeout=10)
        c.sendall(b"POST /v1/classify HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: "
                  b"application/json\r\nContent-Length: 1000000\r\n\r\n" + b" " * 200_000)  # fmt: skip
        time.sleep(0.3)
        c.close()
        t0 = time.monotonic()
        while "hung up" not in caplog.text and time.monotonic() - t0 < 5:
            time.sleep(0.05)
        assert _classify(port, model[1]) == 200
    hung = [r for r in caplog.records if "hung up" in r.getMessage()]
    assert len(hung) == 1 and "Traceback" not in caplog.text
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]


class _Session:
    """Scores = the windows' first value; records each call's windows."""

    def __init__(self):
        self.calls = []

    def run(self, x):
        self.calls.append(x[:, 0, 0].copy())
        return x[:, 0, :1].astype(np.float64)


def test_a_large_batch_is_sliced_and_shares_calls_in_turn():
    """Client A's 100 windows and client B's one window, submitted together: B's window runs
    in the first call (beside one slice of A's), and every answer is its own windows' scores."""

    async def scenario():
        session = _Session()
        b = MicroBatcher(session, window_ms=1.0, max_batch=24, slice_windows=16)
        await b.start()
        xa = np.arange(100, dtype=np.float32)[:, None, None] * np.ones((1, 1, 3), np.float32)
        xb = np.full((1, 1, 3), -1.0, np.float32)
        ra, rb = await asyncio.gather(b.submit(xa, "A"), b.submit(xb, "B"))
        await b.stop()
        return session.calls, ra, rb

    calls, ra, rb = asyncio.run(scenario())
    assert -1.0 in calls[0] and len(calls[0]) <= 24
    np.testing.assert_array_equal(ra[:, 0], np.arange(100))
    assert rb[0, 0] == -1.0
    assert max(len(c) for c in calls) <= 24 and sum(len(c) for c in calls) == 101


def _idle_keep_alive(port: int) -> socket.socket:
    """A connection that made one request, read its answer and stays open (keep-alive)."""
    c = socket.create_connection(("127.0.0.1", port), timeout=10)
    c.sendall(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    got = b""
    while b"\r\n\r\n" not in got:
        got += c.recv(4096)
    head, _, body = got.partition(b"\r\n\r\n")
    length = int(next(v for k, _, v in (h.partition(b":") for h in head.split(b"\r\n")[1:])
                      if k.strip().lower() == b"content-length"))  # fmt: skip
    while len(body) < length:
        body += c.recv(4096)
    return c


@pytest.mark.slow
def test_idle_keep_alive_connections_are_evicted_oldest_first(model, monkeypatch):
    """Idle keep-alive connections (each answered once, nothing in flight) beyond the eviction
    threshold: each new connection closes the longest idle one (8 open, 4 more idle ones evict
    4, the first normal request one more), and normal requests are answered throughout."""
    monkeypatch.setattr(GuardedH11Protocol, "header_timeout_s", 60.0)
    monkeypatch.setattr(GuardedH11Protocol, "evict_above", 8)
    before = connections.CLOSED["idle evicted"]
    with running(create_app(model[0])) as port:
        first = [_idle_keep_alive(port) for _ in range(8)]
        later = [_idle_keep_alive(port) for _ in range(4)]
        statuses = [_classify(port, model[1]) for _ in range(5)]
        assert statuses == [200] * 5
        # (checked within uvicorn's 5 s keep-alive timeout, which closes idle ones anyway)
        assert not any(_closed_within(c, 0.1) for c in later)  # the newest kept
        closed = [_closed_within(c, 0.2) for c in first]
        assert closed == [True] * 5 + [False] * 3  # the longest idle went first
        assert connections.CLOSED["idle evicted"] - before == 5
        for c in first + later:
            c.close()
