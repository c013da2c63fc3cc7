"""Service fairness: latency of a small stream while another stream feeds one 8 MB chunk.

Usage: ``python benchmarks/service_fairness.py MODEL.onnx [--port 8765]``. Starts ``tactilesnn
serve``, measures stream B's request latency alone (2 s), then while stream A posts an 8 MB
``.npy`` chunk (tens of thousands of windows); prints one JSON line with medians and the maximum.
"""

from __future__ import annotations

import argparse
import io
import json
import shutil
import subprocess
import threading
import time

import httpx
import numpy as np


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a.astype(np.float32), allow_pickle=False)
    return buf.getvalue()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("--port", type=int, default=8765)
    args = ap.parse_args()
    base = f"http://127.0.0.1:{args.port}"
    exe = shutil.which("tactilesnn") or "tactilesnn"
    srv = subprocess.Popen([exe, "serve", args.model, "--port", str(args.port)],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        for _ in range(150):
            try:
                info = httpx.get(f"{base}/v1/model").json()
                break
            except httpx.HTTPError:
                time.sleep(0.2)
        c, w = len(info["channels"]), info["window_samples"]
        rng = np.random.default_rng(0)
        big = _npy(rng.standard_normal((c, (8 << 20) // 4 // c - 64)))
        small = _npy(rng.standard_normal((c, w)))
        hdr = {"content-type": "application/x-npy"}
        lat: list[float] = []

        def feed_b(stop: threading.Event) -> None:
            with httpx.Client() as cl:
                while not stop.is_set():
                    t = time.perf_counter()
                    cl.post(f"{base}/v1/stream/B", content=small, headers=hdr, timeout=60)
                    lat.append(time.perf_counter() - t)

        stop = threading.Event()
        th = threading.Thread(target=feed_b, args=(stop,))
        th.start()
        time.sleep(2.0)
        stop.set()
        th.join()
        alone = float(np.median(lat))
        lat.clear()
        stop = threading.Event()
        th = threading.Thread(target=feed_b, args=(stop,))
        th.start()
        time.sleep(0.3)
        t = time.perf_counter()
        r = httpx.post(f"{base}/v1/stream/A", content=big, headers=hdr, timeout=600)
        took = time.perf_counter() - t
        stop.set()
        th.join()
        print(json.dumps({
            "a_chunk_seconds": round(took, 2), "a_windows": len(r.json()["results"]),
            "b_alone_median_ms": round(1e3 * alone, 2),
            "b_during_a_median_ms": round(1e3 * float(np.median(lat)), 2),
            "b_during_a_max_ms": round(1e3 * max(lat), 1), "b_requests_during_a": len(lat),
        }))  # fmt: skip
    finally:
        srv.terminate()
        srv.wait()


if __name__ == "__main__":
    main()
