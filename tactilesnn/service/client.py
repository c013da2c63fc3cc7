"""Python client of the inference service (standard library + numpy only)."""

from __future__ import annotations

import io
import json
import urllib.error
import urllib.parse
import urllib.request

import numpy as np


class ServiceError(RuntimeError):
    def __init__(self, status: int, message: str) -> None:
        super().__init__(f"HTTP {status}: {message}")
        self.status, self.message = status, message


def stream_path(stream_id: str) -> str:
    """URL path of a stream: the id percent-encoded (``sensor?A`` and ``sensor?B`` stay two
    streams; a bare ``?`` would start the query string)."""
    if not stream_id:
        raise ValueError("stream id must not be empty")
    return "/v1/stream/" + urllib.parse.quote(stream_id, safe="")


class Client:
    """``Client("http://127.0.0.1:8000").classify(window)`` -> dict of classes and scores."""

    def __init__(self, base_url: str, timeout: float = 30.0) -> None:
        self.base = base_url.rstrip("/")
        self.timeout = timeout

    def _call(self, method: str, path: str, body: bytes | None = None, ctype: str | None = None):
        req = urllib.request.Request(self.base + path, data=body, method=method)
        if ctype:
            req.add_header("Content-Type", ctype)
        try:
            with urllib.request.urlopen(req, timeout=self.timeout) as r:
                return json.loads(r.read())
        except urllib.error.HTTPError as e:
            try:
                msg = json.loads(e.read()).get("error", "")
            except ValueError:
                msg = str(e)
            raise ServiceError(e.code, msg) from None

    def classify(self, window: np.ndarray, binary: bool = True) -> dict:
        """``[channels, samples]`` or ``[batch, channels, samples]`` -> classes and scores."""
        arr = np.asarray(window, dtype=np.float32)
        if binary:
            buf = io.BytesIO()
            np.save(buf, arr, allow_pickle=False)
            return self._call("POST", "/v1/classify", buf.getvalue(), "application/x-npy")
        key = "window" if arr.ndim == 2 else "windows"
        body = json.dumps({key: arr.tolist()}).encode()
        return self._call("POST", "/v1/classify", body, "application/json")

    def stream(self, stream_id: str, chunk: np.ndarray) -> list[dict]:
        buf = io.BytesIO()
        np.save(buf, np.asarray(chunk, dtype=np.float32), allow_pickle=False)
        path = stream_path(stream_id)
        return self._call("POST", path, buf.getvalue(), "application/x-npy")["results"]

    def close_stream(self, stream_id: str) -> None:
        self._call("DELETE", stream_path(stream_id))

    def model(self) -> dict:
        return self._call("GET", "/v1/model")

    def health(self) -> dict:
        return self._call("GET", "/healthz")
