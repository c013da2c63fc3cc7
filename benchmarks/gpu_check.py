"""One short device check for a machine with a CUDA GPU: the device tests, then encoding there.

Usage (repository root, a few minutes): ``PYTHONPATH=. python3 benchmarks/gpu_check.py [--out
DIR]``. Runs ``tests/test_device.py`` and ``tests/models/test_lif_triton.py`` with pytest (the
GPU tests skip nowhere else), then encodes the same windows (12 channels at 2 kHz, 1,000
samples each, random) with every encoder on the CPU and on ``--device``: the medians of 3
timings of ``SpikePipeline.encode`` and how far the device's spike times are from the CPU's.
Prints one JSON line per encoder (and writes them to ``DIR/gpu_check.jsonl``); exits 1 if a
test failed or an encoder's spikes differ beyond the GPU test's tolerance, 2 without the
device. ``--device cpu --no-tests`` runs it anywhere (a smoke test of the script itself).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

ENCODERS = ("gwt", "stft", "cgwt", "delta", "lif", "bands")
TESTS = ("tests/test_device.py", "tests/models/test_lif_triton.py")


def _pipeline(encoder: str, X: np.ndarray):
    from tactilesnn.config import PipelineConfig
    from tactilesnn.pipeline import SpikePipeline

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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--windows", type=int, default=512)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--no-tests", action="store_true")
    args = ap.parse_args()
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        print("no CUDA GPU here: nothing to check", file=sys.stderr)
        return 2
    ok = True
    if not args.no_tests:
        rc = subprocess.call([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                              *TESTS])  # fmt: skip
        ok = rc == 0
    X = np.random.default_rng(0).standard_normal((args.windows, 12, 1000)).astype(np.float32)
    lines = []
    for name in ENCODERS:
        pipe = _pipeline(name, X)
        cpu = pipe.encode(X).numpy()
        dev = pipe.encode(X, device=args.device).numpy()
        same = float((np.isfinite(cpu) == np.isfinite(dev)).mean())
        both = np.isfinite(cpu) & np.isfinite(dev)
        diff = float(np.abs(cpu[both] - dev[both]).max()) if both.any() else 0.0
        t_cpu = _median_s(lambda p=pipe: p.encode(X))
        t_dev = _median_s(lambda p=pipe: p.encode(X, device=args.device))
        row = {"encoder": name, "device": args.device, "windows": args.windows,
               "cpu_s": round(t_cpu, 4), "device_s": round(t_dev, 4),
               "speedup": round(t_cpu / t_dev, 2), "same_silence": same,
               "max_time_diff_ms": diff}  # fmt: skip
        ok &= same > 0.999 and diff < 0.05
        lines.append(json.dumps(row))
        print(lines[-1], flush=True)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "gpu_check.jsonl").write_text("\n".join(lines) + "\n")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
