"""Load test of the inference service on loopback (bounded: fixed duration, N clients).

Starts uvicorn in a background thread on a free 127.0.0.1 port, then N client threads send
``.npy`` requests over keep-alive connections for ``seconds``: first single windows, then batches
of 32. Reports requests/s, windows/s, p50 / p99 latency and errors (expected: zero).
"""

from __future__ import annotations

import argparse
import http.client
import io
import json
import math
import socket
import statistics
import threading
import time
from pathlib import Path

import numpy as np


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _client(port: int, body: bytes, stop: float, lat: list, errors: list) -> None:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    headers = {"Content-Type": "application/x-npy"}
    while time.perf_counter() < stop:
        t0 = time.perf_counter()
        try:
            conn.request("POST", "/v1/classify", body=body, headers=headers)
            r = conn.getresponse()
            r.read()
            if r.status != 200:
                errors.append(r.status)
            else:
                lat.append(time.perf_counter() - t0)
        except Exception as e:  # count, reconnect, go on
            errors.append(type(e).__name__)
            conn.close()
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    conn.close()


def _rss_bytes() -> int:
    try:
        for line in open("/proc/self/status"):
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _stalled(port: int, declared: int, sent: int, stop: float, errors: list) -> None:
    """A client that declares ``declared`` body bytes, sends ``sent`` and stalls until ``stop``
    (the service answers 408 after its body timeout, or 503 beyond its upload budget)."""
    try:
        conn = socket.create_connection(("127.0.0.1", port), timeout=60)
        conn.sendall(b"POST /v1/classify HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: "
                     b"application/json\r\nContent-Length: %d\r\n\r\n" % declared)  # fmt: skip
        chunk = b" " * (1 << 20)
        for i in range(0, sent, len(chunk)):
            conn.sendall(chunk[: min(len(chunk), sent - i)])
        conn.settimeout(max(0.05, stop - time.perf_counter()))
        try:
            conn.recv(64)  # an early answer (503 / 408), or the case ends
        except OSError:
            pass
        conn.close()
    except OSError as e:
        errors.append(type(e).__name__)


def _big_client(port: int, body: bytes, ctype: str, stop: float, errors: list) -> None:
    """A client posting ``body`` (an 8 MB JSON document or ``.npy`` batch, ``ctype``) back to
    back until ``stop``."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    while time.perf_counter() < stop:
        try:
            conn.request("POST", "/v1/classify", body=body, headers={"Content-Type": ctype})
            r = conn.getresponse()
            r.read()
            if r.status != 200:
                errors.append(r.status)
        except Exception as e:
            errors.append(type(e).__name__)
            conn.close()
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    conn.close()


def _half_open(port: int, n: int, stop: float, errors: list, closed: list) -> None:
    """``n`` connections that each send half a request line and nothing more, reopened as the
    service closes them, until ``stop`` (``closed[0]``: how many it closed)."""
    import selectors

    sel = selectors.DefaultSelector()

    def open_one() -> None:
        try:
            c = socket.create_connection(("127.0.0.1", port), timeout=5)
            c.sendall(b"POST /v1/classify HT")
            c.setblocking(False)
            sel.register(c, selectors.EVENT_READ)
        except OSError as e:
            errors.append(type(e).__name__)

    for _ in range(n):
        open_one()
    while time.perf_counter() < stop:
        for key, _ in sel.select(timeout=0.1):
            c = key.fileobj
            try:
                data = c.recv(4096)
            except OSError:
                data = b""
            if not data:  # closed by the service: open another in its place
                sel.unregister(c)
                c.close()
                closed[0] += 1
                open_one()
    for key in list(sel.get_map().values()):
        key.fileobj.close()
    sel.close()


def _keep_alive(port: int, n: int, every_s: float, stop: float, errors: list) -> None:
    """``n`` keep-alive clients that each poll ``/healthz`` every ``every_s`` seconds (``0``:
    once, then stay idle) on one connection, reopened when the service closes it, until
    ``stop``."""
    conns: list[http.client.HTTPConnection | None] = [None] * n
    due = [time.perf_counter()] * n
    while time.perf_counter() < stop:
        for i in range(n):
            if time.perf_counter() < due[i]:
                continue
            try:
                if conns[i] is None:
                    conns[i] = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
                conns[i].request("GET", "/healthz")
                conns[i].getresponse().read()
            except (OSError, http.client.HTTPException) as e:
                errors.append(type(e).__name__)
                conns[i].close()
                conns[i] = None
            due[i] = time.perf_counter() + every_s if every_s else math.inf
        time.sleep(0.01)
    for c in conns:
        if c is not None:
            c.close()


def _case(port: int, session, batch: int, clients: int, seconds: float, hostile: str) -> dict:
    """Normal clients' latency for ``seconds`` beside the ``hostile`` ones (see :func:`run`)."""
    x = np.random.default_rng(0).standard_normal((batch, len(session.channels), session.window))
    buf = io.BytesIO()
    np.save(buf, x.astype(np.float32), allow_pickle=False)
    lat: list[float] = []
    errors: list = []
    hostile_errors: list = []
    stop = time.perf_counter() + seconds
    bad: list[threading.Thread] = []
    if hostile.startswith("stalled"):
        n, sent = (8, 7 << 20) if hostile == "stalled-8x7MB" else (120, 1 << 10)
        bad = [threading.Thread(target=_stalled, args=(port, 8 << 20, sent, stop, hostile_errors))
               for _ in range(n)]  # fmt: skip
    elif hostile == "json-8MB":
        rows = int((7.5 * 2**20) / (len(session.channels) * session.window * 12))
        body = json.dumps({"windows": np.round(np.repeat(x[:1], max(1, rows), 0), 6).tolist()})
        bad = [threading.Thread(target=_big_client, args=(port, body.encode(), "application/json",
                                                          stop, hostile_errors))]  # fmt: skip
    elif hostile == "npy-8MB":
        rows = int((7.9 * 2**20) / (len(session.channels) * session.window * 4))
        big = io.BytesIO()
        np.save(big, np.repeat(x[:1], max(1, rows), 0).astype(np.float32), allow_pickle=False)
        bad = [threading.Thread(target=_big_client, args=(port, big.getvalue(), "application/x-npy",
                                                          stop, hostile_errors))]  # fmt: skip
    elif hostile in ("idle-600", "polling-600"):
        every = 3.0 if hostile.startswith("polling") else 0.0
        bad = [threading.Thread(target=_keep_alive, args=(port, 150, every, stop, hostile_errors))
               for _ in range(4)]  # fmt: skip
    elif hostile == "half-open-300":
        closed = [0]
        bad = [threading.Thread(target=_half_open, args=(port, 300, stop, hostile_errors,
                                                         closed))]  # fmt: skip
    rss0, held_max, rss_max = _rss_bytes(), 0, 0
    for t in bad:
        t.start()
    good = [threading.Thread(target=_client, args=(port, buf.getvalue(), stop, lat, errors))
            for _ in range(clients)]  # fmt: skip
    t0 = time.perf_counter()
    for t in good:
        t.start()
    while any(t.is_alive() for t in good):
        held_max = max(held_max, session_uploads(port))
        rss_max = max(rss_max, _rss_bytes())
        time.sleep(0.1)
    for t in (*good, *bad):
        t.join()
    wall = time.perf_counter() - t0
    lat_ms = sorted(1000 * v for v in lat)
    return {"batch": batch, "clients": clients, "hostile": hostile, "seconds": round(wall, 2),
            "requests_per_s": len(lat) / wall, "windows_per_s": batch * len(lat) / wall,
            "p50_ms": statistics.median(lat_ms) if lat_ms else None,
            "p99_ms": lat_ms[int(0.99 * (len(lat_ms) - 1))] if lat_ms else None,
            "errors": len(errors), "upload_bytes_held_max": held_max,
            "rss_growth_mb": max(0, rss_max - rss0) / 2**20}  # fmt: skip


def session_uploads(port: int) -> int:
    """The service's ``upload_bytes_held`` (``/healthz``)."""
    try:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
        conn.request("GET", "/healthz")
        held = json.loads(conn.getresponse().read()).get("upload_bytes_held", 0)
        conn.close()
        return int(held)
    except (OSError, ValueError):
        return 0


#: the cases: windows per request and what else reaches the service meanwhile
CASES = (
    (1, "none"),
    (32, "none"),
    (1, "stalled-8x7MB"),
    (1, "stalled-120x1KB"),
    (1, "json-8MB"),
    (1, "npy-8MB"),
    (1, "half-open-300"),
    (1, "idle-600"),
    (1, "polling-600"),
)


def run(model: str, clients: int = 8, seconds: float = 10.0) -> dict:
    """Throughput and latency of ``clients`` normal clients, alone and beside hostile ones:
    8 uploads that send 7 MB of a declared 8 MB and stall, 120 that send 1 KB and stall, and a
    client posting 8 MB JSON bodies back to back (parsed off the event loop)."""
    import uvicorn

    from ..service.app import create_app
    from ..service.connections import server_config

    app = create_app(model)
    session = app.state.session
    port = _free_port()
    server = uvicorn.Server(server_config(app, "127.0.0.1", port, log_level="warning",
                                          access_log=False))  # fmt: skip
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.05)
    try:
        rows = [_case(port, session, batch, clients, seconds, hostile) for batch, hostile in CASES]
    finally:
        server.should_exit = True
        thread.join(timeout=15)
    alone = {r["batch"]: r["p99_ms"] for r in rows if r["hostile"] == "none"}
    for r in rows:
        base = alone.get(r["batch"])
        r["p99_vs_alone"] = (r["p99_ms"] / base) if base and r["p99_ms"] is not None else None
    lines = [
        f"load test: {clients} clients x {seconds:g} s per case, loopback, model {model}",
        "| windows / request | beside | requests/s | windows/s | p50 ms | p99 ms | p99 vs alone | "
        "errors | upload bytes held (max) | RSS growth MB |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ratio = "-" if r["p99_vs_alone"] is None else f"{r['p99_vs_alone']:.2f}x"
        p50 = "-" if r["p50_ms"] is None else f"{r['p50_ms']:.2f}"
        p99 = "-" if r["p99_ms"] is None else f"{r['p99_ms']:.2f}"
        lines.append(
            f"| {r['batch']} | {r['hostile']} | {r['requests_per_s']:.0f} | "
            f"{r['windows_per_s']:.0f} | {p50} | {p99} | {ratio} | {r['errors']} | "
            f"{r['upload_bytes_held_max']} | {r['rss_growth_mb']:.0f} |"
        )
    table = "\n".join(lines)
    print(table)
    return {"rows": rows, "table": table}


HELP = "load test of the HTTP service: throughput and latency with concurrent clients"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, help="model.onnx to load-test")
    p.add_argument("--clients", type=int, default=8, help="concurrent clients")
    p.add_argument("--seconds", type=float, default=10.0, help="duration per case")


def main(out: Path | None, options: argparse.Namespace) -> int:
    from . import write_result

    write_result(out, "serve.json", run(options.model, clients=options.clients,
                                        seconds=options.seconds))  # fmt: skip
    return 0
