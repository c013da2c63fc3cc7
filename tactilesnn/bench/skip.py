"""Skip what a scene does not need, measured: ``tactilesnn bench skip``.

Six mechanisms, each as compute saved against output change:

* **encoder activity gate** (``--gate``, the pipeline's GWT encoder as trained and exported): a
  12-taxel capacitive-piezo array (200 S/s) with 1, 3, 6 or 12 taxels touched by a hook-and-loop
  scan, cut into the default task's 100-sample windows (hop 50); gate = 0.1 x the median training
  RMS, fitted on the all-touched scene. Encode time with and without the gate (1 thread, median),
  (window, taxel) pairs skipped, the largest spike-time change on the transformed pairs, and the
  fraction of spike slots that changed (a skipped quiet pair loses the spikes its noise made);
  the same for the exported encoder graphs in onnxruntime (the gated graph encodes only the
  active rows), with its spikes checked against the torch path's;
* **PVDF sensor skipping** (readout simulates only what a contact can reach): from
  :func:`tactilesnn.bench.tasks.skip_pvdf`;
* **capacitive time skipping**: the foam's play-operator hysteresis stepped only where a pad's
  strain changes (no contact, steady holds), against stepping every sample (exact: tolerance 0);
* **capacitive pad skipping**: pads of channels a contact cannot move off their rest code are not
  simulated (exact: the foam's spread bounds each pad's pressure, and strain, capacitance and the
  CDC are monotone), optionally also those it moves by < 1 LSB (codes within 1 LSB);
* **TENG time skipping**: the induced potential is exactly 0 beyond twice the proximity range, so
  it is evaluated only where a pad point is nearer (same to float64 rounding);
* **band restriction** on the touch task (PVDF, 4 kS/s): the default GWT bands (3-90 Hz) cut to
  the charge amplifier's passband (15.9 Hz - 1 kHz, from the sensor model), against all bands:
  encoder time, test accuracy of each trained pipeline, and the restricted model's predictions
  with every band encoded;
* **early decision** of the tempotron (the first class to reach threshold) and of the SNN (the
  first step at which the leading class leads by the margin fitted on the training windows) on
  the default task (10 epochs): the decision time, the window and input spikes it skips and the
  accuracy change.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from ..core.files import write_json_atomic
from .sparse import taxel_streams

GATE = 0.1
WINDOW, HOP = 100, 50


def _windows(x: np.ndarray) -> np.ndarray:
    """``[1, taxels, samples]`` -> ``[windows, taxels, 100]`` (hop 50)."""
    v = np.lib.stride_tricks.sliding_window_view(x[0], WINDOW, axis=-1)[:, ::HOP]
    return np.ascontiguousarray(v.transpose(1, 0, 2))


def _encoder_session(encoder, n_channels: int):
    """The encoder's exported graph (``[B, C, window]`` -> spike times) in onnxruntime, 1 thread."""
    import onnxruntime as ort

    from ..core.onnx_graph import component_to_onnx

    dummy = torch.randn(2, n_channels, WINDOW, generator=torch.Generator().manual_seed(0))
    graph = component_to_onnx(encoder.onnx_module(), (dummy,), ["window"], ["spikes"],
                              encoder.onnx_scripted, exportable=encoder.onnx_exportable)  # fmt: skip
    so = ort.SessionOptions()
    so.intra_op_num_threads = so.inter_op_num_threads = 1
    sess = ort.InferenceSession(graph.SerializeToString(), so, providers=["CPUExecutionProvider"])
    return lambda x: sess.run(None, {"window": x})[0]


def encoder_gate(repeats: int = 5, quick: bool = False) -> list[dict]:

    from ..encoders import build_encoder
    from ..encoders.base import ENCODERS

    torch.set_num_threads(1)
    cfg = ENCODERS.config_class("gwt")
    train, _ = taxel_streams(12, 12, seed=1)
    Xtr = _windows(train)
    gated = build_encoder(cfg(gate=GATE), 200.0, WINDOW, 12).fit(Xtr)
    plain = build_encoder(cfg(), 200.0, WINDOW, 12)
    rows = []
    ort_plain = _encoder_session(plain, 12)
    ort_gated = _encoder_session(gated, 12)
    for touched in (1, 3) if quick else (1, 3, 6, 12):
        x, _ = taxel_streams(12, touched)
        X = _windows(x)
        if quick:
            X = X[:64]
        ref = plain.encode(X).numpy()
        gated.gate_counts = [0, 0]
        out = gated.encode(X).numpy()
        skipped = gated.skip_stats()["activity_gate"]["skipped_fraction"]
        t_plain = statistics.median(_time(plain.encode, X) for _ in range(repeats))
        t_gated = statistics.median(_time(gated.encode, X) for _ in range(repeats))
        both = np.isfinite(ref) & np.isfinite(out)
        Xf = X.astype(np.float32)
        o_plain = statistics.median(_time(ort_plain, Xf) for _ in range(repeats))
        o_gated = statistics.median(_time(ort_gated, Xf) for _ in range(repeats))
        got = ort_gated(Xf)
        fin = np.isfinite(out)
        rows.append({
            "touched_taxels": touched, "windows": int(X.shape[0]),
            "ms_ungated": 1000 * t_plain, "ms_gated": 1000 * t_gated,
            "speedup": t_plain / t_gated, "skipped_fraction": skipped,
            "max_time_change_ms_transformed": float(np.abs(ref[both] - out[both]).max())
            if both.any() else 0.0,
            "slots_changed_fraction": float((np.isfinite(ref) != np.isfinite(out)).mean()),
            "ort_ms_ungated": 1000 * o_plain, "ort_ms_gated": 1000 * o_gated,
            "ort_speedup": o_plain / o_gated,
            "ort_gated_same_slots": bool(np.array_equal(np.isfinite(got), fin)),
            "ort_gated_max_diff_ms": float(np.abs(got[fin] - out[fin]).max())
            if fin.any() else 0.0,
        })  # fmt: skip
    return rows


def capacitive_time_skip(repeats: int = 5, quick: bool = False) -> dict:
    """Capacitive triangle, 10 s at 10 kS/s with a 1 s press and a 0.2 s hold: the foam's
    hysteresis stepped only where a pad's strain changes vs at every sample."""
    from ..datasets_synth.sensors.capacitive_triangle import CapacitiveTriangle

    sensor = CapacitiveTriangle()
    fs = 10_000.0
    f = np.zeros(int((2 if quick else 10) * fs))
    f[2000:12000] = 5 * np.sin(np.linspace(0, np.pi, 10_000))
    f[14000:16000] = 2.0
    p = sensor.taxel_pressure_Pa(f, np.zeros(2), 12.0)
    full = statistics.median(_time(sensor.strain_every_sample, p) for _ in range(repeats))
    runs = statistics.median(_time(sensor.strain, p) for _ in range(repeats))
    same = bool(np.array_equal(sensor.strain(p), sensor.strain_every_sample(p)))
    return {"every_sample_s": full, "skipping_s": runs, "speedup": full / runs, "identical": same}


CAP_TOL_LSB = 1.0


def capacitive_taxel_skip(repeats: int = 5, quick: bool = False) -> list[dict]:
    """Capacitive triangle (12 pads, 5 kS/s contact, 16-bit CDC): a 3 mm probe presses 1, 3, 6
    or 12 pads in turn (a light 0.1 N touch, 0.4 s each); channels left out exactly (their code cannot leave
    rest) and with a 1 LSB tolerance, against simulating every pad."""
    from ..datasets_synth.sensors.capacitive_triangle import CapacitiveTriangle

    sensor = CapacitiveTriangle()
    fs, press = 5000.0, 2000
    rows = []
    for touched in (1, 3) if quick else (1, 3, 6, 12):
        f = np.zeros(press * (touched + 1))
        centre = np.zeros((f.size, 2))
        for k in range(touched):
            seg = slice(press * k + press // 2, press * (k + 1) + press // 2)
            f[seg] = 0.1 * np.sin(np.linspace(0, np.pi, press))
            centre[seg] = sensor.taxels_mm[(7 + 5 * k) % 12] + 0.3
        row: dict = {"touched_taxels": touched}
        full = sensor.read(f, centre, 3.0, fs, skip=False)[1]
        for name, kw in (("full", {"skip": False}), ("exact", {}),
                         ("tol", {"skip_tol_lsb": CAP_TOL_LSB})):  # fmt: skip
            args = (f, centre, 3.0, fs)
            row[f"{name}_s"] = statistics.median(
                _time(lambda a, kw=kw: sensor.read(*a, **kw), args) for _ in range(repeats)
            )
            codes = sensor.read(f, centre, 3.0, fs, **kw)[1]
            row[f"{name}_skipped_channels"] = sensor.last_skipped_channels
            row[f"{name}_max_diff_lsb"] = float(np.abs(codes - full).max())
        rows.append(row)
    return rows


def teng_time_skip(repeats: int = 5, quick: bool = False) -> dict:
    """TENG finger (8 electrodes x 9 pad points, 500 S/s), 60 s with one 2 s press: the
    induced potential evaluated only within twice the proximity range vs everywhere."""
    from ..datasets_synth.sensors.teng import TENGArray, layout

    sensor = TENGArray(layout("finger8"))
    n = int((10 if quick else 60) * sensor.fs_hz)
    rng = np.random.default_rng(0)
    gap = np.full((8, 9, n), 10.0) + rng.uniform(0, 1, (8, 9, 1))
    gap[:, :, 1000:2000] = np.linspace(5, -1, 1000) + rng.uniform(-0.5, 0.5, (8, 9, 1))
    full = statistics.median(_time(lambda g: sensor.induced_pad_V(g, skip=False), gap)
                             for _ in range(repeats))  # fmt: skip
    runs = statistics.median(_time(sensor.induced_pad_V, gap) for _ in range(repeats))
    diff = float(np.abs(sensor.induced_pad_V(gap) - sensor.induced_pad_V(gap, skip=False)).max())
    return {"full_s": full, "skipping_s": runs, "speedup": full / runs, "max_diff_V": diff}


def band_restriction(repeats: int = 5, quick: bool = False) -> dict:
    """Touch task, default GWT + tempotron, with and without the PVDF readout's passband."""
    from ..config import PipelineConfig
    from ..datasets_synth import get_task
    from ..datasets_synth.sensors.pvdf import PVDFParams
    from ..training import fit_and_evaluate

    lo, hi = PVDFParams().passband_hz
    train, test = get_task("touch", n_samples=160 if quick else 800).build()
    out: dict = {"passband_hz": [lo, hi]}
    for name, extra in (("all_bands", {}), ("restricted", {"passband_lo_hz": lo,
                                                            "passband_hi_hz": hi})):  # fmt: skip
        cfg = PipelineConfig.from_flat(channels=("all",), epochs=2 if quick else 10, **extra)
        res = fit_and_evaluate(cfg, train, test)
        pipe = res.pipeline
        x = pipe.encoder_input(test.X[:64])
        secs = statistics.median(_time(pipe.encoder.encode, x) for _ in range(repeats))
        out[name] = {"test_accuracy": res.metrics["test_accuracy"], "encode_ms_64": 1000 * secs,
                     **res.metrics.get("band_restriction", {})}  # fmt: skip
    out["speedup"] = out["all_bands"]["encode_ms_64"] / out["restricted"]["encode_ms_64"]
    return out


#: the models whose early decision is measured
EARLY_MODELS = ("tempotron", "snn")


def early_decision(quick: bool = False) -> dict:
    """Per model of :data:`EARLY_MODELS`: ``metrics.json``'s early decision and the full-window
    accuracy on the same test split."""
    from ..config import PipelineConfig
    from ..datasets_synth import get_task
    from ..training import fit_and_evaluate

    kw = {"n_planar": 12, "n_concave": 6, "n_convex": 6, "n_test": 6} if quick else {}
    train, test = get_task("hook_loop", **kw).build()
    out = {}
    for model in EARLY_MODELS:
        cfg = PipelineConfig.from_flat(model=model, epochs=2 if quick else 10)
        res = fit_and_evaluate(cfg, train, test)
        e = res.metrics["early_decision"]
        out[model] = {**e, "full_window_accuracy": res.metrics["test_accuracy"],
                      "window_ms": res.pipeline.duration_ms}  # fmt: skip
    return out


def _time(fn, x) -> float:
    t0 = time.perf_counter()
    fn(x)
    return time.perf_counter() - t0


def run(out: Path | None, quick: bool = False, overwrite: bool = False) -> dict:
    from .tasks import skip_pvdf

    if out is not None and (Path(out) / "skip.json").exists() and not overwrite:
        raise FileExistsError(f"{out}/skip.json exists; pass --overwrite to replace it")

    gate = encoder_gate(repeats=3 if quick else 7, quick=quick)
    pvdf = skip_pvdf(repeats=2 if quick else 5, seconds=10.0 if quick else 40.0)
    cap = capacitive_time_skip(repeats=2 if quick else 5, quick=quick)
    cap_taxels = capacitive_taxel_skip(repeats=2 if quick else 5, quick=quick)
    teng = teng_time_skip(repeats=2 if quick else 5, quick=quick)
    early = early_decision(quick)
    bands = band_restriction(repeats=2 if quick else 5, quick=quick)
    res = {
        "band_restriction": bands,
        "encoder_gate": gate,
        "pvdf": pvdf,
        "capacitive": cap,
        "capacitive_taxels": cap_taxels,
        "teng": teng,
        "early_decision": early,
    }
    print(format_report(res))
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        write_json_atomic(Path(out) / "skip.json", res)
    return res


def format_report(res: dict) -> str:
    lines = [
        f"Encoder activity gate (GWT, gate {GATE} x median training RMS), 12 taxels:",
        "| touched | windows | ungated ms | gated ms | speed-up | (window, taxel) skipped | "
        "max change on transformed (ms) | spike slots changed | onnxruntime ungated / gated ms |"
        " speed-up | gated graph vs torch |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in res["encoder_gate"]:
        lines.append(
            f"| {r['touched_taxels']} / 12 | {r['windows']} | {r['ms_ungated']:.1f} | "
            f"{r['ms_gated']:.1f} | {r['speedup']:.1f}x | {100 * r['skipped_fraction']:.0f} % | "
            f"{r['max_time_change_ms_transformed']:.1e} | {100 * r['slots_changed_fraction']:.1f} % |"
            f" {r['ort_ms_ungated']:.1f} / {r['ort_ms_gated']:.1f} | {r['ort_speedup']:.1f}x | "
            f"{'same' if r['ort_gated_same_slots'] else 'DIFFERENT'} slots, "
            f"{r['ort_gated_max_diff_ms']:.1e} ms |"
        )
    return "\n".join([*lines, *_sensor_lines(res), *_encoder_model_lines(res)])


def _sensor_lines(res: dict) -> list[str]:
    """The report's lines on what the sensor models skip."""
    lines = []
    p = res["pvdf"]
    lines.append(
        f"PVDF sensor skipping: full {1000 * p['full_s']:.1f} ms, skip {1000 * p['skip_s']:.1f} ms "
        f"({p['speedup']:.1f}x); max output difference {p['max_diff_pC']:.1e} pC (noise rms "
        f"{p['noise_rms_pC']:.1e} pC)"
    )
    c = res["capacitive"]
    lines.append(
        f"Capacitive foam hysteresis stepped only where strain changes: {1000 * c['skipping_s']:.1f}"
        f" ms vs {1000 * c['every_sample_s']:.1f} ms every sample ({c['speedup']:.1f}x), "
        f"identical: {c['identical']}"
    )
    lines += [
        f"Capacitive pads the contact cannot move off rest (exact) or moves < {CAP_TOL_LSB:g} LSB "
        "(tolerance; CDC noise 4 LSB rms), 3 mm probe at 0.1 N:",
        "| touched | all pads ms | exact: ms, channels skipped | 1 LSB: ms, channels skipped, "
        "max code difference |",
        "|---|---|---|---|",
    ]
    for r in res.get("capacitive_taxels", []):
        lines.append(
            f"| {r['touched_taxels']} / 12 | {1000 * r['full_s']:.1f} | "
            f"{1000 * r['exact_s']:.1f}, {r['exact_skipped_channels']} (difference "
            f"{r['exact_max_diff_lsb']:.0f} LSB) | {1000 * r['tol_s']:.1f}, "
            f"{r['tol_skipped_channels']}, {r['tol_max_diff_lsb']:.0f} LSB |"
        )
    t = res["teng"]
    lines.append(
        f"TENG induced potential only within twice the proximity range: {1000 * t['skipping_s']:.1f}"
        f" ms vs {1000 * t['full_s']:.1f} ms ({t['speedup']:.1f}x), max difference "
        f"{t['max_diff_V']:.1e} V"
    )
    return lines


def _encoder_model_lines(res: dict) -> list[str]:
    """The report's lines on band restriction and early decisions."""
    lines = []
    b = res["band_restriction"]
    r = b["restricted"]
    lines.append(
        f"Band restriction (touch task, PVDF passband {b['passband_hz'][0]:.1f}-"
        f"{b['passband_hz'][1]:.0f} Hz): {r['bands_skipped']} of {r['bands']} bands not "
        f"transformed; encoding 64 windows {b['all_bands']['encode_ms_64']:.1f} -> "
        f"{r['encode_ms_64']:.1f} ms ({b['speedup']:.2f}x); test accuracy "
        f"{100 * r['test_accuracy']:.2f} % vs {100 * b['all_bands']['test_accuracy']:.2f} % "
        f"trained on every band; the restricted model with every band encoded: "
        f"{100 * r['test_accuracy_without_skipping']:.2f} % "
        f"({100 * r['predictions_changed']:.1f} % of predictions changed)"
    )
    for model, e in res["early_decision"].items():
        lines.append(
            f"{model} early decision: decides at {e['mean_decision_ms']:.0f} of "
            f"{e['window_ms']:.0f} ms on average ({100 * e['window_skipped_fraction']:.0f} % of "
            f"the window and {100 * e['input_spikes_skipped_fraction']:.0f} % of the input "
            f"spikes skipped); accuracy {100 * e['accuracy']:.2f} % vs "
            f"{100 * e['full_window_accuracy']:.2f} % on the full window "
            f"({100 * e['agrees_with_full_window']:.1f} % same decision)"
        )
    return lines


HELP = "what skipping (activity gate, band restriction, early decision...) saves, and its cost"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from . import add_quick_and_overwrite

    add_quick_and_overwrite(p, "skip.json")


def main(out: Path | None, options: argparse.Namespace) -> int:
    run(out, quick=options.quick, overwrite=options.overwrite)
    return 0
