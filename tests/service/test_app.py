"""HTTP service: classify (JSON / .npy, single / batched), stream, metadata, and bad input."""

import io
import sys

import numpy as np
import pytest
from starlette.testclient import TestClient

from tactilesnn.app.run import load_run
from tactilesnn.config import PipelineConfig
from tactilesnn.datasets_synth import HookLoopTask
from tactilesnn.export import export_pipeline
from tactilesnn.service.app import create_app
from tests.helpers import run_task

SMALL = {"seed": 0, "n_planar": 10, "n_concave": 5, "n_convex": 5, "n_test": 4}


@pytest.fixture(scope="session")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("svc")
    run, _ = run_task(
        "hook_loop", SMALL, PipelineConfig.from_flat(epochs=2), tmp / "r", progress=False
    )
    pipe, _ = load_run(run)
    test = HookLoopTask(**SMALL).build()[1]
    export_pipeline(pipe, tmp / "m.onnx", test.X[:32])
    app = create_app(str(tmp / "m.onnx"), max_body_bytes=200_000)
    with TestClient(app, base_url="http://127.0.0.1") as client:
        yield client, pipe, test


def npy(arr):
    buf = io.BytesIO()
    np.save(buf, np.asarray(arr, dtype=np.float32), allow_pickle=False)
    return buf.getvalue()


@pytest.mark.slow
def test_classify_json_npy_single_and_batched(served):
    client, pipe, test = served
    ref = pipe.predict(test.X[:5])
    r = client.post("/v1/classify", json={"window": test.X[0].tolist(), "fs_hz": 200})
    assert r.status_code == 200 and r.json()["class_index"] == [int(ref[0])]
    r = client.post("/v1/classify", json={"windows": test.X[:5].tolist()})
    assert r.json()["class_index"] == ref.tolist()
    r = client.post(
        "/v1/classify", content=npy(test.X[:5]), headers={"content-type": "application/x-npy"}
    )
    assert r.json()["classes"] == [pipe.class_names[i] for i in ref]
    assert client.get("/healthz").json()["status"] == "ok"
    info = client.get("/v1/model").json()
    assert info["fs_hz"] == 200.0 and info["window_samples"] == 100


@pytest.mark.parametrize(
    ("body", "ctype", "status", "message"),
    [
        (b"{not json", "application/json", 400, "malformed JSON"),
        (b"", "application/json", 400, "empty"),
        (b'{"window": [[1, 2], [3, 4]]}', "application/json", 422, "channels"),
        (b'{"window": [["a"]]}', "application/json", 422, "numeric"),
        (b'{"wave": []}', "application/json", 422, "window"),
        (b'{"window": [[1]], "fs_hz": 1000}', "application/json", 422, "sampling rate"),
        (b"\x93NUMPY garbage", "application/x-npy", 400, ".npy"),
        (b"hello", "text/plain", 415, "content type"),
        (b"x" * 300_000, "application/json", 413, "limit"),
        (b'{"window": [[1]], "fs_hz": NaN}', "application/json", 422, "finite"),
        (b'{"window": "\xff\xfe"}', "application/json", 400, "malformed JSON"),
        (b"[" * 100_000 + b"]" * 100_000, "application/json", 400, "nested too deeply"),
    ],
)
def test_bad_requests_get_specific_4xx(served, body, ctype, status, message):
    client, _, _ = served
    r = client.post("/v1/classify", content=body, headers={"content-type": ctype})
    assert r.status_code == status
    assert message in r.json()["error"]


def test_nan_names_its_position(served):
    client, _, test = served
    x = test.X[:2].copy()
    x[1, 1, 17] = np.nan
    r = client.post("/v1/classify", content=npy(x), headers={"content-type": "application/x-npy"})
    assert r.status_code == 422 and "batch 1, channel 1, sample 17" in r.json()["error"]


def test_streaming_endpoint(served):
    client, pipe, test = served
    stream = np.concatenate(list(test.X[:3]), axis=1)  # 300 samples
    results = []
    for chunk in np.array_split(stream, 4, axis=1):
        r = client.post(
            "/v1/stream/s1", content=npy(chunk), headers={"content-type": "application/x-npy"}
        )
        assert r.status_code == 200
        results += r.json()["results"]
    assert [r["window_index"] for r in results] == list(range(5))  # hop 50 over 300 samples
    assert results[0]["class"] == pipe.class_names[int(pipe.predict(test.X[:1])[0])]
    assert client.delete("/v1/stream/s1").status_code == 200
    assert client.delete("/v1/stream/s1").status_code == 404


def test_inference_path_imports_no_torch(tmp_path, served):
    code = (
        "import sys; from tactilesnn.service import runtime, app, client; "
        "print('torch' in sys.modules)"
    )
    import subprocess

    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.slow
def test_idle_streams_expire_and_ids_are_url_encoded(tmp_path, served):
    import time

    from tactilesnn.export import export_pipeline
    from tactilesnn.service.client import stream_path

    _, pipe, test = served
    model = tmp_path / "m.onnx"

    export_pipeline(pipe, model, test.X[:8])
    app = create_app(str(model), max_streams=3, stream_ttl_s=0.3)
    chunk = npy(test.X[0][:, :10])
    with TestClient(app, base_url="http://127.0.0.1") as c:
        for i in range(3):
            assert c.post(f"/v1/stream/s{i}", content=chunk,
                          headers={"content-type": "application/x-npy"}).status_code == 200  # fmt: skip
        r = c.post("/v1/stream/new", content=chunk, headers={"content-type": "application/x-npy"})
        assert r.status_code == 429 and "expire" in r.json()["error"]
        time.sleep(0.4)  # the three abandoned streams go idle past the TTL
        r = c.post("/v1/stream/new", content=chunk, headers={"content-type": "application/x-npy"})
        assert r.status_code == 200
        a, b = stream_path("sensor?A"), stream_path("sensor?B")
        assert a != b and "?" not in a
        for path, sid in ((a, "sensor?A"), (b, "sensor?B")):
            r = c.post(path, content=chunk, headers={"content-type": "application/x-npy"})
            assert r.status_code == 200 and r.json()["stream"] == sid  # two streams, not one


@pytest.mark.slow
def test_soak_thousands_of_abandoned_streams_never_lock_out(tmp_path, served):
    """2,000 streams opened and abandoned against a 64-stream table with a short TTL: the
    table never holds more than its limit, every stream opened after the TTL is accepted (no
    lockout), and the Python heap does not grow with the number of streams ever opened."""
    import time
    import tracemalloc

    from tactilesnn.export import export_pipeline

    _, pipe, test = served
    model = tmp_path / "m.onnx"
    export_pipeline(pipe, model, test.X[:8])
    app = create_app(str(model), max_streams=64, stream_ttl_s=0.05)
    chunk = npy(test.X[0][:, :60])  # under one window: each abandoned stream keeps a buffer
    hdr = {"content-type": "application/x-npy"}
    codes: dict[int, int] = {}
    with TestClient(app, base_url="http://127.0.0.1") as c:
        tracemalloc.start()
        for wave in range(20):
            for i in range(100):
                r = c.post(f"/v1/stream/w{wave}-{i}", content=chunk, headers=hdr)
                codes[r.status_code] = codes.get(r.status_code, 0) + 1
            assert c.get("/healthz").json()["open_streams"] <= 64
            if wave == 1:
                base = tracemalloc.get_traced_memory()[0]
            time.sleep(0.06)  # the wave goes idle past the TTL
        grown = tracemalloc.get_traced_memory()[0] - base
        tracemalloc.stop()
        r = c.post("/v1/stream/after", content=chunk, headers=hdr)
        assert r.status_code == 200
    # a wave may fill the table (then 429 until idle ones expire); never a 5xx, and at least
    # the table's capacity is accepted in every wave
    assert set(codes) <= {200, 429} and codes[200] >= 20 * 64
    assert grown < 8 << 20  # bounded: 18 more waves of 100 streams add no lasting memory


@pytest.mark.slow
def test_the_service_serves_a_stream_graph(tmp_path):
    from tactilesnn.export.stream_graph import export_stream

    cfg = PipelineConfig.from_flat(encoder="cgwt", epochs=2)
    run, _ = run_task("hook_loop", SMALL, cfg, tmp_path / "r", progress=False)
    pipe, _ = load_run(run)
    test = HookLoopTask(**SMALL).build()[1]
    export_pipeline(pipe, tmp_path / "w.onnx", test.X[:32])
    export_stream(pipe, tmp_path / "s.onnx", test.X[:32])
    stream = np.concatenate(list(test.X[:3]), axis=1)
    got = {}
    for name in ("w", "s"):
        with TestClient(
            create_app(str(tmp_path / f"{name}.onnx")), base_url="http://127.0.0.1"
        ) as c:
            one = c.post("/v1/classify", json={"window": test.X[0].tolist()}).json()
            results = []
            for chunk in np.array_split(stream, 4, axis=1):
                r = c.post("/v1/stream/a", content=npy(chunk),
                           headers={"content-type": "application/x-npy"})  # fmt: skip
                assert r.status_code == 200
                results += r.json()["results"]
            got[name] = (one, results)
    # classify: a window from a fresh state is the window graph's transform
    assert got["s"][0]["classes"] == got["w"][0]["classes"]
    assert np.allclose(got["s"][0]["scores"], got["w"][0]["scores"], atol=1e-4)
    # the stream: same windows; the first equals the window graph's (a fresh state), the later
    # ones continue the bank's state instead of restarting it at each window
    assert [r["window_index"] for r in got["s"][1]] == [r["window_index"] for r in got["w"][1]]
    assert np.allclose(got["s"][1][0]["scores"], got["w"][1][0]["scores"], atol=1e-4)

    # a stream graph stepping one frame per call: a window's scores every frame; the live page
    # still gets a window every half window, timed by the step
    import json

    step = pipe.encoder.hop
    export_stream(pipe, tmp_path / "f.onnx", test.X[:32], step=step)
    app = create_app(str(tmp_path / "f.onnx"))
    with TestClient(app, base_url="http://127.0.0.1") as c:
        q = app.state.hub.subscribe()
        r = c.post(
            "/v1/stream/f", content=npy(stream), headers={"content-type": "application/x-npy"}
        )
        results = r.json()["results"]
        events = [json.loads(q.get_nowait()) for _ in range(q.qsize())]
    w = pipe.window
    assert len(results) == (stream.shape[1] - w) // step + 1
    every = (w // 2) // step
    assert [e["window_index"] for e in events] == list(range(0, len(results), every))
    assert [e["t_s"] for e in events] == [
        k * step / pipe.fs_hz for k in range(0, len(results), every)
    ]
    assert np.allclose(results[0]["scores"], got["w"][1][0]["scores"], atol=1e-4)
    assert np.allclose(results[every]["scores"], got["s"][1][1]["scores"], atol=1e-4)
