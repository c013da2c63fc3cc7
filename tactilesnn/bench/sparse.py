"""Activity-gate benchmark: a 12-taxel stream where only some taxels are touched.

Each taxel is a capacitive-piezo stack (seed 001 readout, 200 samples/s). Touched taxels get the
sliding-scan pressure of one hook-and-loop scan; untouched ones get no pressure, so their readout
is electronic noise and quantisation only. The gate's floor is set from the sensor's own noise
figure (5x the dynamic-channel noise rms). Reported: encode time with and without the gate
(median), fraction of windows skipped, and whether the active windows' spikes are identical.
"""

from __future__ import annotations

import statistics
import time

import numpy as np
import torch

from ..datasets_synth import HookLoopTask
from ..encoders.gwt import GaborScalogram, log_bands
from ..encoders.latency import LatencyCode
from ..encoders.sliding import SlidingEncoder


def taxel_streams(n_taxels: int, touched: int, seed: int = 0) -> tuple[np.ndarray, float]:
    """``[1, n_taxels, samples]`` dynamic-channel streams and the gate floor (relative units)."""
    task = HookLoopTask(seed=seed)
    sensor = task.sensor
    rng = np.random.default_rng(seed)
    scans = [task.scan(k)[0][1] for k in range(touched)]
    n = min(s.size for s in scans)  # scans differ in length by a few strides' speed
    fs_sim = task.protocol.fs_sim_hz
    rows = [s[:n] for s in scans]
    for _ in range(n_taxels - touched):
        quiet = sensor.read(np.zeros(round(n * fs_sim / sensor.fs_hz)), fs_sim, rng)
        rows.append(quiet[1, :n])
    floor = 5.0 * sensor.params.dynamic_noise_rel
    return np.stack(rows)[None].astype(np.float32), floor


def bench_sparse(repeats: int = 5, n_taxels: int = 12) -> dict:
    torch.set_num_threads(1)
    g = GaborScalogram(200.0, log_bands(3, 90, 20))
    code = LatencyCode(stats=("mean", "std"))
    rows = []
    for touched in (1, 3, 6, 12):
        x, floor = taxel_streams(n_taxels, touched)
        ungated = SlidingEncoder(g, code, window=100, hop=50)
        gated = SlidingEncoder(g, code, window=100, hop=50, noise_floor=floor)
        ref, out = ungated.encode(x), gated.encode(x)
        t_un = statistics.median(_time(ungated.encode, x) for _ in range(repeats))
        t_g = statistics.median(_time(gated.encode, x) for _ in range(repeats))
        views = np.lib.stride_tricks.sliding_window_view(x, 100, axis=-1)[:, :, ::50]
        active = gated.active(views[:, :, : ref.shape[1]])
        r = ref.reshape(1, ref.shape[1], n_taxels, -1)
        o = out.reshape(r.shape)
        bi, ci, wi = np.nonzero(active)
        identical = bool(np.array_equal(r[bi, wi, ci], o[bi, wi, ci]))
        rows.append(
            {
                "touched_taxels": touched,
                "taxels": n_taxels,
                "seconds_of_stream": x.shape[-1] / 200.0,
                "ms_ungated": 1000 * t_un,
                "ms_gated": 1000 * t_g,
                "speedup": t_un / t_g,
                "skipped_fraction": gated.last_stats["skipped_fraction"],
                "active_spikes_identical": identical,
            }
        )
    lines = [
        "| touched / taxels | stream s | ungated ms | gated ms | speed-up | windows skipped | "
        "active spikes identical |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['touched_taxels']} / {r['taxels']} | {r['seconds_of_stream']:.1f} | "
            f"{r['ms_ungated']:.1f} | {r['ms_gated']:.1f} | {r['speedup']:.1f}x | "
            f"{100 * r['skipped_fraction']:.0f} % | {r['active_spikes_identical']} |"
        )
    return {"rows": rows, "table": "\n".join(lines)}


def _time(fn, x) -> float:
    t0 = time.perf_counter()
    fn(x)
    return time.perf_counter() - t0
