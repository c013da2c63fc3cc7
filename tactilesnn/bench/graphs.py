"""Exported window graphs in onnxruntime, against torch in the same run: ``tactilesnn bench graphs``.

For each case (a calibrated, untrained pipeline: the graphs' arithmetic does not depend on the
weights), the window graph written by each exporter: ``torch.export`` (the product's default;
the LIF code's sample loop a ``Scan`` whose body holds only the potential's recurrence, the
kept spike slots read from each sample's count afterwards) and the TorchScript-based one (a
``Loop`` that updates every converter's ``k`` slots at every sample, the eager step's form).
Each is timed in onnxruntime with one thread on ``windows`` windows, in the batches the
service would use (:attr:`~tactilesnn.service.runtime.PipelineSession.RUN_BUDGET_BYTES` over the
graph's own bytes per window) and one window per call; torch (the pipeline's ``predict``, one
thread) on the same windows. Medians of up to ``repeats`` rounds (fewer once one timing passes
20 s); the ratios are the result (noisy machines: compare them, not the seconds). Every graph's
predictions are checked against torch's (agreement reported; the benchmark exits 1 below 100 %).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from .encoders import median_time

HELP = "exported window graphs (each exporter) in onnxruntime against torch: ms per window"

#: (name, flat pipeline settings, rate Hz, window samples, channels); the third is the material
#: task's README command's code (docs/sensors.md)
CASES = (
    ("lif + readout, 12 ch, 1 kHz, 500 samples", {"encoder": "lif", "model": "readout"},
     1000.0, 500, 12),
    ("lif + readout, 8 ch, 1 kHz, 1500 samples", {"encoder": "lif", "model": "readout"},
     1000.0, 1500, 8),
    ("material's lif (6 converters, 32 slots) + readout, 8 ch, 500 Hz, 1500 samples",
     {"encoder": "lif", "model": "readout", "lif_neurons": 6, "lif_max_spikes": 32,
      "lif_tau_ms": 20.0, "lif_lo": 0.05, "lif_hi": 3.0}, 500.0, 1500, 8),
)  # fmt: skip
QUICK = (("lif + readout, 3 ch, 400 Hz, 200 samples", {"encoder": "lif", "model": "readout"},
          400.0, 200, 3),)  # fmt: skip
EXPORTERS = ("torch.export", "torchscript")


def _pipeline(flat: dict, fs: float, window: int, channels: int, seed: int = 0):
    from ..config import PipelineConfig
    from ..pipeline import SpikePipeline

    cfg = PipelineConfig.from_flat(channels=("all",), **flat)
    names = tuple(f"c{i}" for i in range(channels))
    pipe = SpikePipeline(cfg, fs, window, names, ("a", "b", "c"))
    pipe.calibrate(_windows(24, channels, window, seed))
    return pipe


def _windows(n: int, channels: int, window: int, seed: int) -> np.ndarray:
    """Noise windows at channel levels spread over a decade (silent to busy converters)."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, channels, window)) * rng.uniform(0.2, 3.0, (n, channels, 1))
    return x.astype(np.float32)


def _session(graph):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = so.inter_op_num_threads = 1
    return ort.InferenceSession(graph.SerializeToString(), so, providers=["CPUExecutionProvider"])


def case(name: str, flat: dict, fs: float, window: int, channels: int, windows: int,
         repeats: int) -> dict:  # fmt: skip
    """One case's row: per exporter, nodes, export seconds, ms per window (service batches and
    single windows), prediction agreement with torch; torch's ms per window."""
    from ..export.onnx import build_graph
    from ..service.runtime import PipelineSession

    pipe = _pipeline(flat, fs, window, channels)
    X = _windows(windows, channels, window, seed=1)
    want = pipe.predict(X)
    torch_s = median_time(lambda: pipe.predict(X), repeats)
    row: dict = {"case": name, "windows": windows, "afferents": pipe.n_afferents,
                 "slots": pipe.max_spikes, "torch_ms_per_window": 1e3 * torch_s / windows}  # fmt: skip
    for exporter in EXPORTERS:
        t0 = time.perf_counter()
        graph = build_graph(pipe, exporter)
        export_s = time.perf_counter() - t0
        sess = _session(graph)
        feed = sess.get_inputs()[0].name
        per = (
            pipe.graph_bytes_per_window() if exporter == "torch.export" else pipe.bytes_per_window()
        )
        batch = max(1, PipelineSession.RUN_BUDGET_BYTES // per)

        def batched(sess=sess, feed=feed, batch=batch):
            return np.concatenate([sess.run(None, {feed: X[i : i + batch]})[0]
                                   for i in range(0, windows, batch)])  # fmt: skip

        got = batched().argmax(1)
        one = max(1, min(windows, 20))
        row[exporter] = {
            "nodes": len(graph.graph.node), "export_s": export_s, "batch": int(batch),
            "bytes_per_window": int(per),
            "ms_per_window": 1e3 * median_time(batched, repeats) / windows,
            "ms_per_window_one_at_a_time": 1e3 * median_time(
                lambda sess=sess, feed=feed, one=one: [sess.run(None, {feed: X[i : i + 1]})
                                              for i in range(one)], repeats) / one,
            "agreement": float((got == want).mean()),
        }  # fmt: skip
    new, old = row["torch.export"], row["torchscript"]
    row["scan_speedup_over_loop"] = old["ms_per_window"] / new["ms_per_window"]
    row["scan_speedup_over_loop_one_at_a_time"] = (old["ms_per_window_one_at_a_time"]
                                                   / new["ms_per_window_one_at_a_time"])  # fmt: skip
    row["scan_against_torch"] = row["torch_ms_per_window"] / new["ms_per_window"]
    return row


def run(quick: bool = False, windows: int = 180, repeats: int = 3, progress: bool = True) -> dict:
    torch.set_num_threads(1)
    rows = []
    for name, flat, fs, window, channels in QUICK if quick else CASES:
        rows.append(case(name, flat, fs, window, channels, 12 if quick else windows, repeats))
        if progress:
            r = rows[-1]
            print(f"{name}: torch.export Scan {r['torch.export']['ms_per_window']:.2f} ms per "
                  f"window ({r['scan_speedup_over_loop']:.2f}x the Loop's "
                  f"{r['torchscript']['ms_per_window']:.2f}; one at a time "
                  f"{r['scan_speedup_over_loop_one_at_a_time']:.2f}x), torch "
                  f"{r['torch_ms_per_window']:.2f} ({r['scan_against_torch']:.2f}x)",
                  flush=True)  # fmt: skip
    return {"rows": rows, "threads": 1, "repeats": repeats}


def markdown(res: dict) -> str:
    """The docs' table of a result (docs/benchmarks.md pastes it; ``--from-json`` re-renders)."""
    lines = ["| case | afferents x slots | torch.export `Scan`: ms per window (batch), one at a "
             "time | TorchScript `Loop`: ms per window (batch), one at a time | Scan / Loop "
             "speed-up (batched, one at a time) | torch eager ms per window | Scan / torch |",
             "|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in res["rows"]:
        new, old = r["torch.export"], r["torchscript"]
        lines.append(
            f"| {r['case']} | {r['afferents']} x {r['slots']} | {new['ms_per_window']:.2f} "
            f"({new['batch']}), {new['ms_per_window_one_at_a_time']:.2f} | "
            f"{old['ms_per_window']:.2f} ({old['batch']}), "
            f"{old['ms_per_window_one_at_a_time']:.2f} | {r['scan_speedup_over_loop']:.2f}x, "
            f"{r['scan_speedup_over_loop_one_at_a_time']:.2f}x | "
            f"{r['torch_ms_per_window']:.2f} | {r['scan_against_torch']:.2f}x |"
        )
    return "\n".join(lines)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quick", action="store_true", help="one small case (as the tests run)")
    p.add_argument("--windows", type=int, default=180, help="windows per case (default 180)")
    p.add_argument("--repeats", type=int, default=3, help="rounds per timing (median)")
    p.add_argument("--from-json", type=Path, help="print the table of a saved graphs.json")


def main(out: Path | None, options: argparse.Namespace) -> int:
    from ..core.checks import check_int
    from . import write_result

    if options.from_json is not None:
        print(markdown(json.loads(options.from_json.read_text())))
        return 0
    check_int(options.windows, "--windows", 1)
    check_int(options.repeats, "--repeats", 1)
    res = run(options.quick, options.windows, options.repeats, not options.quiet)
    write_result(out, "graphs.json", res)
    if not options.quiet:
        print(markdown(res))
    bad = [(r["case"], e) for r in res["rows"] for e in EXPORTERS if r[e]["agreement"] < 1.0]
    for name, exporter in bad:
        print(f"FAIL {name}: the {exporter} graph's predictions differ from torch's")
    return 1 if bad else 0
