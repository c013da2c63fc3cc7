"""Live view: the events carry what the model saw, and a real browser draws them as they come."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from scipy import signal as sps

from tactilesnn.app.run import load_run
from tactilesnn.config import PipelineConfig
from tactilesnn.datasets_synth import HookLoopTask
from tactilesnn.export import export_pipeline
from tactilesnn.service.live import LiveHub, spectrogram, window_event
from tactilesnn.service.runtime import PipelineSession, StreamState
from tests.helpers import run_task

SMALL = {"seed": 0, "n_planar": 10, "n_concave": 5, "n_convex": 5, "n_test": 4}
HOSTILE_ID = '<img src=x onerror="document.body.dataset.pwned=1">'


@pytest.fixture(scope="session")
def exported(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("live")
    cfg = PipelineConfig.from_flat(epochs=2, model="readout")
    run, _ = run_task("hook_loop", SMALL, cfg, tmp / "r", progress=False)
    pipe, _ = load_run(run)
    test = HookLoopTask(**SMALL).build()[1]
    export_pipeline(pipe, tmp / "m.onnx", test.X[:32])
    return tmp / "m.onnx", pipe, test


@pytest.mark.slow
def test_exposed_spikes_are_the_encoders_and_scores_unchanged(exported):
    path, pipe, test = exported
    x = test.X[:16]
    plain = PipelineSession(str(path))
    live = PipelineSession(str(path), expose_spikes=True)
    assert live.has_spikes and not plain.has_spikes
    scores, spikes = live.run_detail(x)[:2]
    np.testing.assert_array_equal(scores, plain.run(x))
    ref = pipe.encode(x).numpy()
    assert np.array_equal(np.isfinite(spikes), np.isfinite(ref))
    fin = np.isfinite(ref)
    assert np.abs(spikes[fin] - ref[fin]).max() < 0.05  # ms (float32 graph vs FFT)
    # stream detail: window arrays in order, one per classified window
    st = StreamState()
    stream = np.concatenate([test.X[0], test.X[1]], axis=1)
    res = live.feed_stream(st, stream, detail=True)
    assert len(res) == 3 and np.array_equal(res[0]["window"], test.X[0])
    assert np.array_equal(res[2]["window"], test.X[1])


def test_event_contents_against_references():
    fs = 200.0
    t = np.arange(100) / fs
    x = np.stack([np.sin(2 * np.pi * 50 * t), 1e-3 * np.ones_like(t)]).astype(np.float32)
    spec, freqs = spectrogram(x, fs)
    f_ref, _, s_ref = sps.stft(x.astype(np.float64).sum(0) - 0, fs=fs, window="hann", nperseg=32,
                               noverlap=24, boundary=None, padded=False, detrend="constant")  # fmt: skip
    np.testing.assert_allclose(freqs, f_ref)
    assert freqs[np.argmax(spec.mean(1))] == pytest.approx(50.0, abs=fs / 32)
    assert np.argmax(np.abs(s_ref).mean(1)) == np.argmax(spec.mean(1))
    spikes = np.full((3, 2), np.inf, np.float32)
    spikes[0, 0], spikes[2, 1] = 12.5, 400.0
    ev = window_event("s", {"window_index": 4, "class": "a", "scores": [0.1, 0.9]}, x, spikes,
                      fs, ["a", "b"], 50, ["static", "dynamic"])  # fmt: skip
    assert ev["channels"] == ["static", "dynamic"] and ev["n_channels"] == 2
    assert ev["raster"] == [[0, 12.5], [2, 400.0]] and ev["n_afferents"] == 3
    assert ev["t_s"] == pytest.approx(1.0) and ev["duration_ms"] == pytest.approx(500.0)
    np.testing.assert_allclose(np.asarray(ev["signal"]) * ev["signal_scale"], x, atol=1e-4)


def test_a_slow_page_drops_old_events_instead_of_blocking():
    import asyncio

    hub = LiveHub()
    q = hub.subscribe()
    for i in range(100):
        hub.publish({"i": i})
    assert q.qsize() == q.maxsize and '"i":99' in list(q._queue)[-1]  # newest kept
    hub.unsubscribe(q)
    assert not hub.active
    asyncio.run(asyncio.sleep(0))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_until_up(server: subprocess.Popen, url: str, timeout_s: float = 60.0) -> None:
    """Until the service at ``url`` answers ``/healthz`` (fails if it exits or takes too long)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            urllib.request.urlopen(url + "/healthz", timeout=1).read()
            return
        except OSError:
            if time.monotonic() > deadline or server.poll() is not None:
                pytest.fail(f"service did not start: {server.stderr.read()[-2000:]}")
            time.sleep(0.2)


def _browser() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.browser
def test_live_page_updates_in_a_real_browser(exported, tmp_path):
    """Headless Chromium (Debian package, driven by Playwright) opens the page of a running
    service while demo-stream feeds it; the raster and the scores must change between updates.
    CI installs both (``.ci/run``); elsewhere the test is skipped if they are missing."""
    if os.environ.get("CI"):
        from playwright import sync_api  # installed by the dev extra: its absence is a failure
    else:
        sync_api = pytest.importorskip("playwright.sync_api")
    exe = _browser()
    if exe is None:
        if os.environ.get("CI"):
            pytest.fail("CI must install Debian's chromium for the live-page test")
        pytest.skip("no chromium on this machine")
    path, _, _ = exported
    port = _free_port()
    cli = Path(sys.executable).with_name("tactilesnn")
    server = subprocess.Popen([str(cli), "serve", str(path), "--port", str(port)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # fmt: skip
    url = f"http://127.0.0.1:{port}"
    try:
        _wait_until_up(server, url)
        with sync_api.sync_playwright() as p:
            flags = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                     "--disable-background-networking", "--disable-component-update",
                     "--disable-sync"]  # fmt: skip
            browser = p.chromium.launch(executable_path=exe, args=flags)
            # the page's CSP forbids eval, which Playwright's wait_for_function needs; bypassing
            # it also shows the page itself inserts the hostile stream id as text
            page = browser.new_page(viewport={"width": 1100, "height": 620}, bypass_csp=True)
            page.goto(url + "/")
            strict = browser.new_page()  # the page as users get it, its CSP enforced
            violations: list[str] = []
            strict.on("console", lambda m: violations.append(m.text) if "Policy" in m.text else 0)
            strict.goto(url + "/")
            assert "waiting for a stream" in page.inner_text("#status")
            feeder = threading.Thread(target=subprocess.run, args=(
                [str(cli), "demo-stream", "--url", url, "--seconds", "20", "--speed", "4",
                 "--stream", HOSTILE_ID],),
                kwargs={"capture_output": True})  # fmt: skip
            feeder.start()
            page.wait_for_function("Number(document.body.dataset.updates) >= 2", timeout=60_000)
            js = """id => { const c = document.getElementById(id), d = c.getContext('2d')
                .getImageData(0, 0, c.width, c.height).data; let h = 0;
                for (let i = 0; i < d.length; i += 97) h = (h * 31 + d[i]) % 1000000007; return h; }"""
            first = {c: page.evaluate(js, c) for c in ("raster", "scores", "signal", "spec")}
            n0 = int(page.evaluate("document.body.dataset.updates"))
            page.wait_for_function(f"Number(document.body.dataset.updates) >= {n0 + 3}",
                                   timeout=60_000)  # fmt: skip
            later = {c: page.evaluate(js, c) for c in first}
            assert later["raster"] != first["raster"] and later["scores"] != first["scores"]
            assert later["signal"] != first["signal"]
            assert page.inner_text("#cls") in ("hook", "loop")
            # the stream id is shown as text: no element made of it, no script run
            assert page.inner_text("#info code") == HOSTILE_ID
            assert page.query_selector("#info img") is None
            assert page.evaluate("document.body.dataset.pwned") is None
            assert int(strict.evaluate("document.body.dataset.updates")) > 0, violations
            assert not violations and strict.inner_text("#info code") == HOSTILE_ID
            shot = tmp_path / "live_page.png"
            page.screenshot(path=str(shot))
            assert shot.stat().st_size > 10_000
            if os.environ.get("TACTILESNN_SCREENSHOT"):  # refresh the README's picture
                shutil.copy(shot, os.environ["TACTILESNN_SCREENSHOT"])
            browser.close()
            feeder.join(timeout=60)
    finally:
        server.terminate()
        server.wait(timeout=30)


@pytest.mark.slow
def test_sigterm_with_live_pages_open_stops_at_once(exported):
    """Open live pages (event streams that never end by themselves) must not hold the shutdown
    until uvicorn's 10 s grace period runs out, nor leave an ERROR in the log."""
    import signal

    path, _, _ = exported
    port = _free_port()
    server = subprocess.Popen([sys.executable, "-m", "tactilesnn.service", str(path), "--port",
                               str(port)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              text=True)  # fmt: skip
    url = f"http://127.0.0.1:{port}"
    try:
        _wait_until_up(server, url)
        pages = [urllib.request.urlopen(url + "/v1/live", timeout=30) for _ in range(3)]
        for page in pages:
            assert page.readline().startswith(b": connected")
        health = urllib.request.urlopen(url + "/healthz", timeout=5).read()
        assert b'"live_pages":3' in health.replace(b" ", b"")
        t0 = time.monotonic()
        server.send_signal(signal.SIGTERM)
        rc = server.wait(timeout=30)
        took = time.monotonic() - t0
        log = server.stderr.read()
        # uvicorn re-raises the signal once it has shut down: -15 is its orderly exit
        assert rc in (0, -signal.SIGTERM) and took < 8.0, (took, log[-2000:])  # not the 10 s
        assert "Finished server process" in log, log[-2000:]
        assert "ERROR" not in log and "Traceback" not in log, log[-2000:]
        for page in pages:
            page.close()
    finally:
        if server.poll() is None:
            server.kill()
