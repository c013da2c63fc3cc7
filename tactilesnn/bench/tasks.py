"""Synthetic-task benchmark: generation throughput, trivial baseline, skip-compute savings.

For every registered task: samples/s of ``generate`` on ``workers`` processes (median of
``repeats`` runs into temporary folders), windows per sample, and the linear amplitude baseline
(logistic regression on per-channel mean / RMS) on the task's default train / test split.

Skip-compute (``skip_pvdf``): a sparse scene on the PVDF triangle (a 40 s recording with four
light pokes at one spot) rendered with and without skipping the taxels and time a contact cannot
reach; reports the median time of each, the ratio, and the largest output difference in pC next
to the amplifier's noise rms.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from ..baselines import linear_amplitude_baseline
from ..datasets_synth import TASKS, get_task
from ..datasets_synth.generate import generate
from ..datasets_synth.sensors.pvdf import PVDFTriangle


def generation_rate(name: str, n: int, workers: int, repeats: int) -> dict:
    times, windows = [], 0
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            m = generate(name, n, 0, Path(tmp) / "d", shard_size=max(1, n // (4 * workers)),
                         workers=workers, progress=False)  # fmt: skip
            times.append(time.perf_counter() - t0)
            windows = m["n_windows"]
    med = statistics.median(times)
    return {"samples_per_s": n / med, "windows_per_sample": windows / n, "seconds": med}


def skip_pvdf(repeats: int = 5, seconds: float = 40.0) -> dict:
    sensor = PVDFTriangle()
    fs = sensor.fs_hz
    n = int(seconds * fs)
    res = {}
    for skip in (False, True):
        times, outs = [], []
        for rep in range(repeats):
            rng = np.random.default_rng(rep)
            f = np.zeros(n)
            for _ in range(4):
                i, length = int(rng.integers(0, n - 1600)), int(rng.integers(320, 1200))
                f[i : i + length] += (
                    rng.uniform(0.2, 1.4)
                    * 0.5
                    * (1 - np.cos(2 * np.pi * np.arange(length) / length))
                )
            c = sensor.taxels_mm[rng.integers(12)] + rng.uniform(-2, 2, 2)
            t0 = time.perf_counter()
            outs.append(sensor.read(f, c, 4.0, fs, np.random.default_rng(100 + rep), skip=skip))
            times.append(time.perf_counter() - t0)
        res[skip] = (statistics.median(times), np.stack(outs))
    diff = float(np.abs(res[True][1] - res[False][1]).max())
    noise_pC = sensor.params.noise_uV * 1e-6 * sensor.params.cf_pF
    return {"full_s": res[False][0], "skip_s": res[True][0],
            "speedup": res[False][0] / res[True][0], "max_diff_pC": diff,
            "noise_rms_pC": noise_pC, "peak_pC": float(np.abs(res[False][1]).max())}  # fmt: skip


def run(n: int = 200, workers: int = 2, repeats: int = 3, progress: bool = True) -> dict:
    from tqdm.auto import tqdm

    out: dict = {"tasks": {}}
    print(f"{'task':22s} {'classes':>7s} {'samples/s':>10s} {'win/sample':>10s} {'train/test':>11s} "
          f"{'amp. baseline':>13s}")  # fmt: skip
    bar = tqdm(sorted(TASKS), desc="bench tasks", unit="task", disable=not progress)
    for name in bar:
        bar.set_postfix_str(name)
        rate = generation_rate(name, n, workers, repeats)
        task = get_task(name)
        tr, te = task.build()
        base = linear_amplitude_baseline(tr.X, tr.y, te.X, te.y)
        rec = dict(rate, classes=len(task.class_names), train=int(tr.y.size),
                   test=int(te.y.size), baseline=base, shape=list(tr.X.shape[1:]),
                   fs_hz=task.fs_hz)  # fmt: skip
        out["tasks"][name] = rec
        bar.write(f"{name:22s} {rec['classes']:7d} {rate['samples_per_s']:10.1f} "
                  f"{rate['windows_per_sample']:10.1f} {tr.y.size:5d}/{te.y.size:<5d} "
                  f"{100 * base:12.2f}%")  # fmt: skip
    sk = skip_pvdf()
    out["skip_pvdf"] = sk
    print(f"skip-compute, PVDF 40 s / 4 light pokes: full {1000 * sk['full_s']:.1f} ms, skip "
          f"{1000 * sk['skip_s']:.1f} ms ({sk['speedup']:.1f}x); max difference "
          f"{sk['max_diff_pC']:.1e} pC (noise rms {sk['noise_rms_pC']:.1e} pC, peak "
          f"{sk['peak_pC']:.2f} pC)")  # fmt: skip
    return out


HELP = "every synthetic task: generation speed, sizes, amplitude-only baseline"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--workers", type=int, default=2, help="generation processes")
    p.add_argument("--references", action="store_true",
                   help="also each task's spike pipeline (--data defaults) against the "
                   "non-spiking references of bench real")  # fmt: skip
    p.add_argument("--seeds", type=int, default=1, help="with --references: seeds")
    p.add_argument("--pipelines", nargs="+", default=["default+readout"],
                   help="with --references: spike pipelines")  # fmt: skip
    p.add_argument("--epochs", type=int, default=None, help="with --references: epochs")


def main(out: Path | None, options: argparse.Namespace) -> int:
    from . import real, require_out, write_result

    if options.references:
        require_out(out, "tasks --references")
    write_result(out, "tasks.json", run(workers=options.workers, progress=not options.quiet))
    if options.references:  # each task as a user's file: spike pipeline vs strong references
        real.run(Path(out) / "references", datasets=list(real.synthetic_datasets()),
                 seeds=options.seeds, pipelines=options.pipelines, epochs=options.epochs,
                 progress=not options.quiet)  # fmt: skip
    return 0
