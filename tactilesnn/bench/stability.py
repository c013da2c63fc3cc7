"""Numerical stress suite with a verdict per stage: ``tactilesnn bench stability``.

Every stage reports its worst error against a stated tolerance (``passed``), and any NaN / Inf
where none is allowed fails it. Stages:

* ``amplitude_span``: GWT and STFT codes of ``a x`` for ``a`` over 1e-12..1e30 equal those of
  ``x`` (the codes are normalised per window; float32 input beyond its range is refused);
* ``pvdf_full_range``: PVDF readout of presses over 5 decades of force (0.001-100 N) is finite,
  and its GWT code finite and non-silent at every level;
* ``dc_step_impulse``: zeros, a large DC offset, a step and an impulse give finite spike times
  for every encoder, and zeros give no spike;
* ``near_nyquist``: a sine at 0.44 fs peaks in the top band (at 0.45 fs), finite;
* ``long_stream``: the GWT of a long stream in chunks equals the one-shot transform (1e7
  samples; ``quick``: 1e6), max difference / peak;
* ``float32_drift``: the float32 GWT of that stream against float64, max difference / peak;
* ``tempotron_long_window``: exact V_max over a 60 s window with 2,000 input spikes, float32 vs
  float64, relative difference;
* ``snn_long``: an LIF layer over 1e5 steps, float32 vs float64 (spike count agreement and
  membrane difference; the reset-by-subtraction membrane stays bounded);
* ``onnx_vs_torch`` / ``int8_vs_float32``: a small trained pipeline exported (verified) and
  quantised; score difference and accuracy change.

Writes ``stability.json`` and prints the table; the command exits 1 if a stage fails.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from ..core.files import write_json_atomic

FS = 200.0


def _stage(name: str, tol: float, fn: Callable[[], tuple[float, str]]) -> dict:
    t0 = time.perf_counter()
    try:
        worst, detail = fn()
        ok = bool(np.isfinite(worst)) and worst <= tol
    except Exception as e:  # a crash is a failed stage, reported with its message
        worst, detail, ok = math.inf, f"{type(e).__name__}: {e}", False
    return {"stage": name, "worst": float(worst), "tolerance": tol, "passed": ok,
            "detail": detail, "seconds": time.perf_counter() - t0}  # fmt: skip


def _encoder(name: str, window: int = 200, channels: int = 1, fs: float = FS, **kw):
    from ..encoders import build_encoder
    from ..encoders.base import ENCODERS

    return build_encoder(ENCODERS.config_class(name)(**kw), fs, window, channels)


def _time_diff(a: np.ndarray, b: np.ndarray) -> float:
    """Max spike-time difference (ms); a slot spiking in one only counts as infinite."""
    if not np.array_equal(np.isfinite(a), np.isfinite(b)):
        return math.inf
    fin = np.isfinite(a)
    return float(np.abs(a[fin] - b[fin]).max()) if fin.any() else 0.0


def amplitude_span(quick: bool) -> tuple[float, str]:
    rng = np.random.default_rng(0)
    x = rng.standard_normal((4, 1, 200)).astype(np.float32)
    scales = [1e-12, 1e-6, 1.0, 1e6, 1e12, 1e30] if not quick else [1e-12, 1.0, 1e30]
    worst = 0.0
    for name in ("gwt", "cgwt", "stft"):
        enc = _encoder(name)
        ref = enc.encode(x).numpy()
        for a in scales:
            worst = max(worst, _time_diff(enc.encode((x * a).astype(np.float32)).numpy(), ref))
    from ..config import PipelineConfig
    from ..pipeline import SpikePipeline  # inputs beyond float32 are refused, not wrapped

    pipe = SpikePipeline(PipelineConfig.from_flat(channels=("all",)), FS, 200, ("c",), ("a", "b"))
    try:
        pipe.encode(x.astype(np.float64) * 1e39)
        return math.inf, "a 1e39 input was not refused"
    except ValueError:
        pass
    return worst, f"max spike-time change over scales {scales[0]:g}..{scales[-1]:g} (ms)"


def pvdf_full_range(quick: bool) -> tuple[float, str]:
    from ..datasets_synth.sensors.pvdf import PVDFTriangle

    sensor = PVDFTriangle()
    fs = sensor.fs_hz
    n = int(0.5 * fs)
    shape = 0.5 * (1 - np.cos(2 * np.pi * np.arange(n) / n))
    forces = np.geomspace(1e-3, 1e2, 3 if quick else 6)
    enc = _encoder("gwt", window=n, channels=12, fs=fs, f_lo_hz=2.0, f_hi_hz=0.4 * fs)
    silent, bad = 0, 0
    for f in forces:
        out = sensor.read(f * shape, sensor.taxels_mm[0], 4.0, fs, np.random.default_rng(0))
        bad += int(~np.isfinite(out).all())
        s = enc.encode(out[None]).numpy()
        bad += int(np.isnan(s).any())
        silent += int(not np.isfinite(s).any())
    return float(
        bad + silent
    ), f"{len(forces)} force levels 1e-3..1e2 N: {bad} non-finite, {silent} silent codes"


def dc_step_impulse(quick: bool) -> tuple[float, str]:
    n = 200
    noise = 1e-3 * np.random.default_rng(0).standard_normal(n)
    cases = {"zeros": np.zeros(n), "dc": 1e3 + noise, "impulse": np.eye(1, n, n // 2)[0],
             "step": np.r_[np.zeros(n // 2), np.ones(n // 2)]}  # fmt: skip
    bad = 0
    for name in ("gwt", "cgwt", "stft", "lif", "delta"):
        enc = _encoder(name)
        enc.fit(np.stack([c[None] for c in cases.values()]).astype(np.float32) + 1e-3)
        for case, x in cases.items():
            s = enc.encode(x[None, None].astype(np.float32)).numpy()
            bad += int(np.isnan(s).any())
            if case == "zeros" and name in ("gwt", "cgwt", "stft"):
                bad += int(np.isfinite(s).any())
    return float(
        bad
    ), "NaN spike times, or spikes from an all-zero window (gwt/cgwt/stft/lif/delta)"


def near_nyquist(quick: bool) -> tuple[float, str]:
    enc = _encoder("gwt", f_hi_hz=0.45 * FS)
    t = np.arange(200) / FS
    x = np.sin(2 * np.pi * 0.44 * FS * t).astype(np.float32)[None, None]
    from ..encoders.scalogram_latency import unit_peak

    mag = enc.scalogram(unit_peak(torch.from_numpy(x))).numpy()[0, 0].mean(-1)
    top = int(np.argmax(mag))
    ok = top == len(mag) - 1 and np.isfinite(mag).all()
    return (0.0 if ok else 1.0), f"peak band {top} of {len(mag) - 1} at {enc.freqs_hz[top]:.1f} Hz"


def _long_stream(quick: bool):
    from ..encoders.gwt import GaborScalogram, log_bands

    n = 1_000_000 if quick else 10_000_000
    x = np.random.default_rng(5).standard_normal((1, 1, n)).astype(np.float32)
    return x, GaborScalogram(FS, log_bands(3, 90, 8), hop=10)


def long_stream(quick: bool) -> tuple[float, str]:
    x, g = _long_stream(quick)
    one = g.transform(x)
    chunked = g.transform_chunked(x, chunk_samples=65_536)
    return float(
        np.abs(chunked - one).max() / one.max()
    ), f"{x.shape[-1]:.0e} samples, 65,536-sample chunks vs one shot, max abs difference / peak"


def float32_drift(quick: bool) -> tuple[float, str]:
    x, g = _long_stream(quick)
    f32 = g.transform_chunked(x, chunk_samples=1 << 20, dtype=np.float32)
    f64 = g.transform_chunked(x, chunk_samples=1 << 20, dtype=np.float64)
    err = np.abs(f32 - f64)
    # drift would show as an error growing along the stream: compare the last tenth with the first
    k = err.shape[-1] // 10
    grow = float(err[..., -k:].max() / max(err[..., :k].max(), 1e-30))
    return float(
        err.max() / np.abs(f64).max()
    ), f"max abs(f32 - f64) / peak; last / first tenth error ratio {grow:.2f}"


def tempotron_long_window(quick: bool) -> tuple[float, str]:
    from ..models.tempotron import Tempotron

    rng = np.random.default_rng(0)
    dur = 60_000.0
    t = torch.from_numpy(np.sort(rng.uniform(0, dur, (4, 500, 4)), axis=-1))
    m = Tempotron(500, 3, dur, tau_ms=200.0)
    with torch.no_grad():
        v32, _ = m(t.float())
        v64, _ = m.double()(t)
    rel = float((v32.double() - v64).abs().max() / v64.abs().max())
    return rel, "exact V_max, 60 s window, 4 x 500 afferents x 4 spikes: abs(f32 - f64) / max"


def snn_long(quick: bool) -> tuple[float, str]:
    from ..models.functional import lif_scan

    steps = 20_000 if quick else 100_000
    g = torch.Generator().manual_seed(0)
    cur = 0.3 * torch.rand(steps, 4, 32, generator=g, dtype=torch.float64)
    s64, _ = lif_scan(cur, torch.zeros(4, 32, dtype=torch.float64), 0.9, 1.0, True)
    s32, u32 = lif_scan(cur.float(), torch.zeros(4, 32), 0.9, 1.0, True)
    counts64, counts32 = s64.sum(0), s32.double().sum(0)
    rel = float(((counts32 - counts64).abs() / counts64.clamp_min(1)).max())
    bounded = bool(u32.abs().max() < 10 and torch.isfinite(u32).all())
    return (
        (rel if bounded else math.inf),
        f"{steps} steps: max relative spike-count difference "
        f"f32 vs f64 (membrane bounded: {bounded})",
    )


def _small_run(tmp: Path):
    from ..config import PipelineConfig
    from ..datasets_synth import HookLoopTask
    from ..training import fit_and_evaluate

    task = HookLoopTask(seed=0, n_planar=10, n_concave=5, n_convex=5, n_test=4)
    train, test = task.build()
    res = fit_and_evaluate(PipelineConfig.from_flat(epochs=2, model="readout"), train, test)
    return res.pipeline, test


def onnx_and_int8(quick: bool) -> list[dict]:
    from ..export import export_pipeline, quantize_int8

    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        state: dict = {}

        def onnx() -> tuple[float, str]:
            pipe, test = _small_run(tmp)
            rep = export_pipeline(pipe, tmp / "m.onnx", test.X)
            state.update(pipe=pipe, test=test)
            return rep["max_score_diff"], f"{rep['n_checked']} windows, end to end score diff"

        def int8() -> tuple[float, str]:
            test = state["test"]
            q = quantize_int8(tmp / "m.onnx", test.X, test.y)
            return abs(q["accuracy_change"]), (f"accuracy {100 * q['float_accuracy']:.2f} -> "
                                               f"{100 * q['int8_accuracy']:.2f} %")  # fmt: skip

        return [_stage("onnx_vs_torch", 1e-4, onnx), _stage("int8_vs_float32", 0.02, int8)]


STAGES: tuple[tuple[str, float, Callable[[bool], tuple[float, str]]], ...] = (
    ("amplitude_span", 1e-3, amplitude_span),
    ("pvdf_full_range", 0.0, pvdf_full_range),
    ("dc_step_impulse", 0.0, dc_step_impulse),
    ("near_nyquist", 0.0, near_nyquist),
    ("long_stream", 1e-5, long_stream),
    ("float32_drift", 1e-5, float32_drift),
    ("tempotron_long_window", 1e-5, tempotron_long_window),
    ("snn_long", 0.02, snn_long),
)


def run(
    out: Path | None, quick: bool = False, progress: bool = True, overwrite: bool = False
) -> tuple[list[dict], bool]:
    from tqdm.auto import tqdm

    if out is not None and (Path(out) / "stability.json").exists() and not overwrite:
        raise FileExistsError(f"{out}/stability.json exists; pass --overwrite to replace it")

    rows = []
    for name, tol, fn in tqdm(STAGES, desc="bench stability", disable=not progress):
        rows.append(_stage(name, tol, lambda fn=fn: fn(quick)))
    rows += onnx_and_int8(quick)
    ok = all(r["passed"] for r in rows)
    print(format_table(rows))
    print("all stages passed" if ok else "FAILED: " + ", ".join(r["stage"] for r in rows
                                                               if not r["passed"]))  # fmt: skip
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        write_json_atomic(Path(out) / "stability.json", {"quick": quick, "stages": rows, "ok": ok})
    return rows, ok


def format_table(rows: list[dict]) -> str:
    lines = ["| stage | worst | tolerance | pass | what | s |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['stage']} | {r['worst']:.2e} | {r['tolerance']:.0e} | "
                     f"{'yes' if r['passed'] else '**NO**'} | {r['detail']} | "
                     f"{r['seconds']:.1f} |")  # fmt: skip
    return "\n".join(lines)


HELP = "numerical stability: float32 vs float64 over the sensors' full range, long sequences"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from . import add_quick_and_overwrite

    add_quick_and_overwrite(p, "stability.json")


def main(out: Path | None, options: argparse.Namespace) -> int:
    from . import require_out

    _, ok = run(Path(require_out(out, "stability")), quick=options.quick,
                progress=not options.quiet, overwrite=options.overwrite)  # fmt: skip
    return 0 if ok else 1
