"""What a page in the user's browser can do to the service: content types a browser can send
without a preflight, foreign Origins, rebound host names, and markup in stream ids."""

from __future__ import annotations

import io
import json
import re

import numpy as np
import pytest
from starlette.testclient import TestClient

from tactilesnn.service.app import create_app
from tactilesnn.service.live import page_html, page_script_js
from tactilesnn.service.security import default_allowed_hosts
from tests.helpers import exported_model

SMALL = {"seed": 0, "n_planar": 6, "n_concave": 3, "n_convex": 3, "n_test": 2}


@pytest.fixture(scope="session")
def model(tmp_path_factory):
    path, _, test = exported_model(tmp_path_factory.mktemp("sec"), SMALL)
    return str(path), test


@pytest.fixture(scope="session")
def client(model):
    with TestClient(create_app(model[0]), base_url="http://127.0.0.1:8000") as c:
        yield c, model[1]


def _body(test) -> bytes:
    import json

    return json.dumps({"window": test.X[0].tolist()}).encode()


# every content type a page may send cross-site without a CORS preflight, and none at all
@pytest.mark.parametrize(
    "ctype",
    [None, "text/plain", "text/plain;charset=UTF-8", "application/x-www-form-urlencoded",
     "multipart/form-data; boundary=x", "application/jsonx", "text/json"],
)  # fmt: skip
@pytest.mark.slow
@pytest.mark.parametrize("route", ["/v1/classify", "/v1/stream/s"])
def test_simple_request_content_types_are_refused(client, ctype, route):
    c, test = client
    headers = {} if ctype is None else {"content-type": ctype}
    r = c.post(route, content=_body(test), headers=headers)
    assert r.status_code == 415, r.text
    assert "application/json" in r.json()["error"]


def test_json_with_parameters_is_accepted(client):
    c, test = client
    r = c.post("/v1/classify", content=_body(test),
               headers={"content-type": "Application/JSON; charset=utf-8"})  # fmt: skip
    assert r.status_code == 200, r.text


@pytest.mark.parametrize("origin", ["http://evil.example", "null", "http://127.0.0.1:9999",
                                    "http://localhost:8000"])  # fmt: skip
@pytest.mark.parametrize("method", ["POST", "DELETE"])
def test_cross_origin_state_changes_are_refused(client, origin, method):
    c, test = client
    hdr = {"content-type": "application/json", "origin": origin}
    if method == "POST":
        r = c.post("/v1/stream/x", content=_body(test), headers=hdr)
    else:
        r = c.delete("/v1/stream/x", headers=hdr)
    assert r.status_code == 403 and "cross-origin" in r.json()["error"]


def test_same_origin_and_originless_requests_pass(client):
    c, test = client
    hdr = {"content-type": "application/json"}
    assert c.post("/v1/classify", content=_body(test), headers=hdr).status_code == 200
    hdr["origin"] = "http://127.0.0.1:8000"
    assert c.post("/v1/classify", content=_body(test), headers=hdr).status_code == 200
    # a GET cannot change state; a foreign Origin on it is left to the browser's own policy
    assert c.get("/v1/model", headers={"origin": "http://evil.example"}).status_code == 200


@pytest.mark.parametrize("host", ["evil.example", "evil.example:8000", "127.0.0.1.nip.io",
                                  "localhost.evil.example", ""])  # fmt: skip
def test_rebound_host_names_are_refused(client, host):
    c, _ = client
    for path in ("/", "/v1/model", "/healthz", "/live.js"):
        r = c.get(path, headers={"host": host})
        assert r.status_code == 400, (path, host)
        assert "Host" in r.json()["error"] or "host" in r.json()["error"]


@pytest.mark.parametrize("host", ["localhost:8000", "127.0.0.1", "[::1]:8000", "LOCALHOST"])
def test_loopback_names_pass(client, host):
    c, _ = client
    assert c.get("/healthz", headers={"host": host}).status_code == 200


def test_allowed_hosts_follow_the_bind_address():
    assert default_allowed_hosts("127.0.0.1") == {"localhost", "127.0.0.1", "::1"}
    assert "192.168.1.5" in default_allowed_hosts("192.168.1.5")
    assert "evil.example" not in default_allowed_hosts("0.0.0.0")


def test_extra_and_wildcard_hosts(model):
    with TestClient(create_app(model[0], allowed_hosts=["sensor-pc"]),
                    base_url="http://sensor-pc:8000") as c:  # fmt: skip
        assert c.get("/healthz").status_code == 200
        assert c.get("/healthz", headers={"host": "127.0.0.1"}).status_code == 400
    with TestClient(create_app(model[0], allowed_hosts=["*"]), base_url="http://any") as c:
        assert c.get("/healthz").status_code == 200


def test_page_headers_forbid_inline_script_and_framing(client):
    c, _ = client
    r = c.get("/")
    csp = r.headers["content-security-policy"]
    assert (
        "script-src 'self'" in csp
        and "unsafe-inline" not in csp.split("script-src")[1].split(";")[0]
    )
    assert "frame-ancestors 'none'" in csp and r.headers["x-frame-options"] == "DENY"
    assert r.headers["x-content-type-options"] == "nosniff"
    assert "<script>" not in r.text and '<script src="/live.js">' in r.text
    js = c.get("/live.js")
    assert js.status_code == 200 and js.headers["content-type"].startswith("text/javascript")
    # error answers carry the headers too
    assert c.post("/v1/classify", content=b"x").headers["x-content-type-options"] == "nosniff"


def test_page_script_never_parses_event_text_as_html():
    js = page_script_js()
    for sink in ("innerHTML", "outerHTML", "insertAdjacentHTML", "document.write", "eval(",
                 "new Function", "setTimeout(\""):  # fmt: skip
        assert sink not in js, sink
    assert not re.search(r"<script(?![^>]*\bsrc=)", page_html())


@pytest.mark.parametrize("sid", ["a" * 129, "bad\nid", "tab\there", "nul\x00"])
def test_stream_ids_are_bounded_and_printable(client, sid):
    c, test = client
    buf = io.BytesIO()
    np.save(buf, test.X[0], allow_pickle=False)
    from tactilesnn.service.client import stream_path

    r = c.post(stream_path(sid), content=buf.getvalue(),
               headers={"content-type": "application/x-npy"})  # fmt: skip
    assert r.status_code == 422 and "stream id" in r.json()["error"]


# ---------------------------------------------------------------- bounded bodies, 4xx not 5xx
@pytest.mark.parametrize(
    ("body", "status", "match"),
    [
        (b'{"window": [[1]], "fs_hz": 1' + b"0" * 400 + b"}", 422, "fs_hz"),
        (b'{"window": [[1]], "fs_hz": ' + b"9" * 5000 + b"}", 400, "malformed JSON"),
        (b'{"window": [[1]], "fs_hz": -5}', 422, "fs_hz"),
        (b'{"window": [[' + b"9" * 5000 + b"]]}", 400, "malformed JSON"),
        (b'{"window": [[1e400]]}', 422, ""),
        (b'{"window": [[' + b"1" * 30 + b"]]}", 422, ""),
        (b'{"window": {"a": 1}}', 422, ""),
        (b'"just a string"', 400, "object"),
    ],
)
def test_bad_numbers_get_4xx(client, body, status, match):
    c, _ = client
    for route, key in (("/v1/classify", b"window"), ("/v1/stream/n", b"chunk")):
        r = c.post(route, content=body.replace(b"window", key),
                   headers={"content-type": "application/json"})  # fmt: skip
        assert r.status_code == status, (route, r.text)
        assert match in r.json()["error"]


@pytest.mark.slow
def test_a_stalled_upload_times_out_and_the_upload_budget_is_bounded(model):
    """Real sockets on a running server: uploads are counted as they arrive against a 10 MB
    budget: one that sent 6 MB and stalls holds it until the body timeout (408); a second
    large one that would pass the budget gets 503 at once; small requests still pass."""
    import socket
    import threading
    import time

    import uvicorn

    from tactilesnn.service.app import ByteBudget, HTTPError

    app = create_app(model[0], body_timeout_s=1.5, inflight_bytes=10_000_000)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="error"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    service = app.state.service
    try:
        while not server.started:
            time.sleep(0.02)

        def send(length: int, body: bytes) -> socket.socket:
            conn = socket.create_connection(("127.0.0.1", port), timeout=10)
            conn.sendall(b"POST /v1/classify HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: "
                         b"application/json\r\nContent-Length: %d\r\n\r\n%s" % (length, body))  # fmt: skip
            return conn

        t0 = time.monotonic()
        stalled = send(8_000_000, b'{"window": [[' + b"1," * 3_000_000)  # 6 MB, then nothing
        while service.uploads.held < 5_000_000 and time.monotonic() - t0 < 5:
            time.sleep(0.02)
        assert service.uploads.held > 5_000_000  # what it sent is held, counted
        second = send(8_000_000, b"{" + b" " * 5_000_000)  # would pass the 10 MB budget
        assert b" 503 " in second.recv(4096).split(b"\r\n")[0]
        small = send(len(_body(model[1])), _body(model[1]))  # small requests are not starved
        assert b" 200 " in small.recv(4096).split(b"\r\n")[0]
        first_line = stalled.recv(4096).split(b"\r\n")[0]
        assert b" 408 " in first_line and time.monotonic() - t0 < 8
        for c in (stalled, second, small):
            c.close()
        time.sleep(0.1)
        assert service.uploads.held == 0  # released after the timeout
    finally:
        server.should_exit = True
        thread.join(timeout=10)

    budget = ByteBudget(100, free_bytes=10)
    budget.take(60)
    with pytest.raises(HTTPError) as e:
        budget.take(60)
    assert e.value.status == 503 and budget.held == 60
    budget.give(60)
    assert budget.held == 0


@pytest.mark.slow
def test_large_json_bodies_are_parsed_in_another_process(model, monkeypatch):
    """A large body is parsed in the parser process (no GIL held here); a small one inline."""
    import tactilesnn.service.app as app_module

    seen = []
    real = app_module._parse

    def spy(*a):
        seen.append(len(a[0]))
        return real(*a)

    monkeypatch.setattr(app_module, "_parse", spy)
    _, test = model
    with TestClient(create_app(model[0]), base_url="http://127.0.0.1") as c:
        big = json.dumps({"windows": np.repeat(test.X[:1], 40, 0).tolist()}).encode()
        assert len(big) > app_module.PARSE_INLINE_BYTES
        r = c.post("/v1/classify", content=big, headers={"content-type": "application/json"})
        assert r.status_code == 200 and len(r.json()["classes"]) == 40
        bad = json.dumps({"windows": [[[1.0, 2.0], [3.0]]] * 9000}).encode()  # ragged, large
        r = c.post("/v1/classify", content=bad, headers={"content-type": "application/json"})
        assert r.status_code == 422 and len(bad) > app_module.PARSE_INLINE_BYTES
        small = _body(test)
        assert c.post("/v1/classify", content=small,
                      headers={"content-type": "application/json"}).status_code == 200  # fmt: skip
    assert seen == [len(small)]  # only the small body was parsed in this process


# ---------------------------------------------------------------- hostile models
@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("class_names", '"hookloop"', "class_names"),
        ("class_names", '["hook", "hook"]', "duplicates"),
        ("class_names", '["hook", ""]', "non-empty"),
        ("channels", "[1, 2]", "channels"),
        ("channels", '{"a": 1}', "channels"),
        ("channels", '["a", "b", "c"]', "metadata says"),
        ("fs_hz", "nan", "fs_hz"),
        ("window_samples", "1e9", "window_samples"),
        ("encoder_channels", "[7]", "encoder_channels"),
        ("bytes_per_window", "-1", "bytes_per_window"),
        ("state_inputs", '["h_state"]', "state inputs"),
    ],
)
def test_tampered_metadata_is_refused_at_load(model, tmp_path, key, value, match):
    import onnx

    from tactilesnn.service.runtime import PipelineSession

    m = onnx.load(model[0])
    for p in m.metadata_props:
        if p.key == key:
            p.value = value
    bad = tmp_path / "bad.onnx"
    onnx.save(m, str(bad))
    with pytest.raises(ValueError, match=match):
        PipelineSession(str(bad))


def test_nan_weights_are_refused_at_load(model, tmp_path):
    import onnx
    from onnx import numpy_helper

    from tactilesnn.service.runtime import PipelineSession

    m = onnx.load(model[0])
    init = next(i for i in m.graph.initializer
                if i.data_type == onnx.TensorProto.FLOAT and np.prod(i.dims) > 1)  # fmt: skip
    arr = numpy_helper.to_array(init).copy()
    arr.flat[0] = np.nan
    init.CopyFrom(numpy_helper.from_array(arr, init.name))
    bad = tmp_path / "nan.onnx"
    onnx.save(m, str(bad))
    with pytest.raises(ValueError, match="holds NaN"):
        PipelineSession(str(bad))
