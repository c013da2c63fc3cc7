"""Load test of the inference service on loopback (bounded: fixed duration, N clients).

Starts uvicorn in a background thread on a free 127.0.0.1 port, then N client threads send
``.npy`` requests over keep-alive connections for ``seconds``: first single windows, then batches
of 32. Reports requests/s, windows/s, p50 / p99 latency and errors (expected: zero).
"""

from __future__ import annotations

import argparse
import http.client
import io
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


def run(model: str, clients: int = 8, seconds: float = 10.0) -> dict:
    import uvicorn

    from ...service.app import create_app

    app = create_app(model)
    session = app.state.session
    port = _free_port()
    server = uvicorn.Server(
        uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", access_log=False)
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.05)
    rng = np.random.default_rng(0)
    rows = []
    try:
        for batch in (1, 32):
            x = rng.standard_normal((batch, len(session.channels), session.window)).astype(
                np.float32
            )
            buf = io.BytesIO()
            np.save(buf, x, allow_pickle=False)
            lat: list[float] = []
            errors: list = []
            stop = time.perf_counter() + seconds
            threads = [
                threading.Thread(target=_client, args=(port, buf.getvalue(), stop, lat, errors))
                for _ in range(clients)
            ]
            t0 = time.perf_counter()
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            wall = time.perf_counter() - t0
            lat_ms = sorted(1000 * v for v in lat)
            rows.append(
                {
                    "batch": batch,
                    "clients": clients,
                    "seconds": round(wall, 2),
                    "requests_per_s": len(lat) / wall,
                    "windows_per_s": batch * len(lat) / wall,
                    "p50_ms": statistics.median(lat_ms) if lat_ms else None,
                    "p99_ms": lat_ms[int(0.99 * (len(lat_ms) - 1))] if lat_ms else None,
                    "errors": len(errors),
                }
            )
    finally:
        server.should_exit = True
        thread.join(timeout=15)
    lines = [
        f"load test: {clients} clients x {seconds:g} s per case, loopback, model {model}",
        "| windows / request | requests/s | windows/s | p50 ms | p99 ms | errors |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['batch']} | {r['requests_per_s']:.0f} | {r['windows_per_s']:.0f} | "
            f"{r['p50_ms']:.2f} | {r['p99_ms']:.2f} | {r['errors']} |"
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
