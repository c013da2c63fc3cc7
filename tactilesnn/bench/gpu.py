"""Encoding on a GPU against the CPU: ``tactilesnn bench gpu``.

The same windows (12 channels at 2 kHz, 1,000 samples each, random) through every analog
encoder on the CPU and on ``--device``: the medians of 3 timings of ``SpikePipeline.encode``
and how far the device's spike times are from the CPU's. One JSON line per encoder (and
``OUT/gpu.json``); exit status 1 if an encoder's spikes differ beyond the GPU tests' tolerance,
2 without the device. The GPU tests themselves are ``pytest -m gpu`` (they skip without one);
the prepared device check is both: ``pytest -m gpu && tactilesnn bench gpu --out DIR``.
``--device cpu`` runs it anywhere (a smoke test of the benchmark itself).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from ..config import PipelineConfig
from ..pipeline import SpikePipeline
from . import write_result

HELP = "encoding on a GPU against the CPU: time and spike-time agreement per encoder"
ENCODERS = ("gwt", "stft", "cgwt", "delta", "lif", "bands")
#: the GPU tests' tolerance on spike times (ms) and on silent slots agreeing
MAX_TIME_DIFF_MS = 0.05
MIN_SAME_SILENCE = 0.999


def _pipeline(encoder: str, X: np.ndarray) -> SpikePipeline:
    cfg = PipelineConfig.from_flat(encoder=encoder, model="readout", channels=("all",))
    names = tuple(f"taxel{i}" for i in range(X.shape[1]))
    pipe = SpikePipeline(cfg, 2000.0, X.shape[-1], names, ("a", "b"))
    pipe.calibrate(X[:64])
    return pipe


def _median_s(fn, repeats: int = 3) -> float:
    fn()  # warm-up: caches, kernels, plans
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()  # encode returns CPU tensors: the device's work is done when it returns
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def run(device: str = "cuda", windows: int = 512, encoders=ENCODERS) -> list[dict]:
    """One row per encoder: CPU and device seconds, speed-up, agreement."""
    X = np.random.default_rng(0).standard_normal((windows, 12, 1000)).astype(np.float32)
    rows = []
    for name in encoders:
        pipe = _pipeline(name, X)
        cpu = pipe.encode(X).numpy()
        dev = pipe.encode(X, device=device).numpy()
        same = float((np.isfinite(cpu) == np.isfinite(dev)).mean())
        both = np.isfinite(cpu) & np.isfinite(dev)
        diff = float(np.abs(cpu[both] - dev[both]).max()) if both.any() else 0.0
        t_cpu = _median_s(lambda p=pipe: p.encode(X))
        t_dev = _median_s(lambda p=pipe: p.encode(X, device=device))
        rows.append({"encoder": name, "device": device, "windows": windows,
                     "device_name": _device_name(device), "cpu_s": round(t_cpu, 4),
                     "device_s": round(t_dev, 4), "speedup": round(t_cpu / t_dev, 2),
                     "same_silence": same, "max_time_diff_ms": diff,
                     "ok": same >= MIN_SAME_SILENCE and diff < MAX_TIME_DIFF_MS})  # fmt: skip
        print(json.dumps(rows[-1]), flush=True)
    return rows


def _device_name(device: str) -> str:
    if device.startswith("cuda"):
        return torch.cuda.get_device_name(torch.device(device))
    return "cpu"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default="cuda", help="where to encode besides the CPU")
    p.add_argument("--windows", type=int, default=512, help="windows encoded per timing")


def main(out: Path | None, options: argparse.Namespace) -> int:
    if options.device.startswith("cuda") and not torch.cuda.is_available():
        print("no CUDA GPU here: nothing to check", file=sys.stderr)
        return 2
    rows = run(options.device, options.windows)
    write_result(out, "gpu.json", {"rows": rows})
    return 0 if all(r["ok"] for r in rows) else 1
