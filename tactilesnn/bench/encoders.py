"""Scalogram speed and accuracy against the libraries users would pick instead.

Workloads (issue: encoders): W1 = 1 channel, 200 Hz, 60 s, 32 bands 2-90 Hz; W2 = 12 channels,
2 kHz, 10 s, 64 bands 5-900 Hz; W3 = a batch of 256 x 1 channel x 1,000 samples, 32 bands
(200 Hz, 2-90 Hz). Each implementation runs single-threaded and with the machine's default threads
(where it has a thread setting); the figure is the median of repeated runs. Accuracy is the
maximum magnitude error against a float64 reference (our float64 transform, itself tested against
a float64 direct convolution), relative to the scalogram's peak; libraries with another
normalisation (PyWavelets L2, ssqueezepy / fCWT L1) are compared after a least-squares gain per
band (their *shape* error). Optional peers (ssqueezepy, fCWT) are skipped when not installed.

``--fft``: the FFT backends (scipy's pocketfft, ducc0, pyFFTW where installed) inside our
full-rate transform on W1-W3 and a long many-channel workload (W4: 39 channels, 1 kHz, 30 s,
48 bands 2-450 Hz), 1 and 2 threads, against fCWT with like-for-like (periodic) edges.

``--sparse``: the activity gate on a 12-taxel stream where only some taxels are touched; reports
the time saved and checks that spikes of the active part are identical to the ungated run.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import os
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..core.files import write_text_atomic
from ..encoders.gwt import GaborScalogram, log_bands
from ..encoders.stft import STFTScalogram

CMOR = "cmor1.5-1.0"


@dataclass(frozen=True)
class Workload:
    name: str
    batch: int
    channels: int
    fs_hz: float
    seconds: float
    f_lo_hz: float
    f_hi_hz: float
    bands: int

    @property
    def samples(self) -> int:
        return round(self.fs_hz * self.seconds)

    def signal(self) -> np.ndarray:
        rng = np.random.default_rng(0)
        t = np.arange(self.samples) / self.fs_hz
        chirp = np.sin(
            2 * np.pi * (self.f_lo_hz + (self.f_hi_hz - self.f_lo_hz) * t / t[-1] / 2) * t
        )
        x = 0.5 * chirp + rng.standard_normal((self.batch, self.channels, self.samples))
        return x.astype(np.float64)

    def freqs(self) -> np.ndarray:
        return log_bands(self.f_lo_hz, self.f_hi_hz, self.bands)


WORKLOADS = (
    Workload("W1", 1, 1, 200.0, 60.0, 2.0, 90.0, 32),
    Workload("W2", 1, 12, 2000.0, 10.0, 5.0, 900.0, 64),
    Workload("W3", 256, 1, 200.0, 5.0, 2.0, 90.0, 32),
)
LONG = Workload("W4", 1, 39, 1000.0, 30.0, 2.0, 450.0, 48)


def median_time(fn: Callable[[], object], repeats: int, budget_s: float = 20.0) -> float:
    """Median wall time (s) of ``fn`` over up to ``repeats`` runs (fewer if one is very slow)."""
    fn()  # warm-up: plans, caches, JIT
    times: list[float] = []
    start = time.perf_counter()
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
        if time.perf_counter() - start > budget_s and len(times) >= 1:
            break
    return statistics.median(times)


def shape_error(ref: np.ndarray, got: np.ndarray, edge: int) -> float:
    """Max |ref - g * got| / max|ref| after a least-squares gain g per band (edges excluded)."""
    r = ref[..., edge:-edge].reshape(-1, ref.shape[-2], ref.shape[-1] - 2 * edge)
    g_ = got[..., edge:-edge].reshape(r.shape)
    gain = (r * g_).sum(axis=(0, 2)) / np.maximum((g_ * g_).sum(axis=(0, 2)), 1e-300)
    return float(np.abs(r - gain[None, :, None] * g_).max() / np.abs(r).max())


Factory = Callable[[int], Callable[[], np.ndarray]]


def _peers(w: Workload, x: np.ndarray) -> dict[str, Factory]:
    """Factories ``threads -> zero-arg function returning [B, C, F, T] magnitudes``."""
    peers: dict[str, Factory] = {"pywt-cwt-fft": _pywt(w, x, "fft")}
    if w.name != "W2":  # ~3 s per call (2.75 s measured here): too slow to repeat at W2
        peers["pywt-cwt-conv"] = _pywt(w, x, "conv")
    if importlib.util.find_spec("ssqueezepy"):
        peers["ssqueezepy-cwt"] = _ssqueezepy(w, x)
    if importlib.util.find_spec("fcwt"):
        peers["fcwt"] = _fcwt(w, x)
    return peers


def _pywt(w: Workload, x: np.ndarray, method: str) -> Factory:
    import pywt

    freqs, flat = w.freqs(), x.reshape(-1, x.shape[-1])
    scales = pywt.frequency2scale(CMOR, freqs / w.fs_hz)

    def make(threads: int):
        def run():
            c, _ = pywt.cwt(flat, scales, CMOR, sampling_period=1 / w.fs_hz, method=method, axis=-1)
            return np.abs(c).transpose(1, 0, 2).reshape(x.shape[0], x.shape[1], len(freqs), -1)

        return run

    return make


def _ssqueezepy(w: Workload, x: np.ndarray) -> Factory:
    freqs, flat = w.freqs(), x.reshape(-1, x.shape[-1])

    def ssq(threads: int):
        os.environ["SSQ_PARALLEL"] = "1" if threads > 1 else "0"
        from ssqueezepy import Wavelet, cwt

        wav = Wavelet("morlet")
        # measured here: its default Morlet peaks at scale 2.1297 fs / f; scales must ascend
        sc = (2.1297 * w.fs_hz / freqs)[::-1].copy()
        rows32 = flat.astype(np.float32)

        def run():
            wx, _ = cwt(rows32, wav, scales=sc, fs=w.fs_hz, padtype="reflect")
            mag = np.abs(np.asarray(wx))[..., ::-1, :]
            return mag.reshape(x.shape[0], x.shape[1], len(freqs), -1)

        return run

    return ssq


def _fcwt(w: Workload, x: np.ndarray) -> Factory:
    freqs, flat = w.freqs(), x.reshape(-1, x.shape[-1])

    def fc(threads: int):
        import fcwt

        morl = fcwt.Morlet(2.0)  # keep a reference: fCWT segfaults if it is collected
        scales_obj = fcwt.Scales(morl, fcwt.FCWT_LOGSCALES, int(w.fs_hz), float(freqs[0]),
                                 float(freqs[-1]), len(freqs))  # fmt: skip
        engine = fcwt.FCWT(morl, threads, True, False)
        rows = flat.astype(np.float32)
        out = np.zeros((len(freqs), x.shape[-1]), dtype=np.complex64)

        def run():
            res = np.empty((rows.shape[0], len(freqs), x.shape[-1]), np.float32)
            with _quiet_stdout():  # fCWT prints a notice per call from C
                for i, r in enumerate(rows):
                    engine.cwt(r, scales_obj, out)
                    res[i] = np.abs(out)[::-1]  # fCWT orders high -> low frequency
            run.keep = (morl, scales_obj, engine)  # type: ignore[attr-defined]
            return res.reshape(x.shape[0], x.shape[1], len(freqs), -1)

        return run

    return fc


@contextlib.contextmanager
def _quiet_stdout():
    """Silence C-level writes to stdout (file descriptor 1) for the duration."""
    import sys

    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


def bench_gwt(w: Workload, repeats: int, hop: int, threads_list: list[int]) -> list[dict]:
    x = w.signal()
    freqs = w.freqs()
    ref = GaborScalogram(w.fs_hz, freqs).transform(x, np.float64, workers=os.cpu_count())
    # fCWT's edge treatment (the window taken as one period: no edge extension), judged
    # against its own float64 run
    cyclic = GaborScalogram(w.fs_hz, freqs, padding="periodic")
    refs = {"periodic": cyclic.transform(x, np.float64, workers=os.cpu_count())}
    edge = max(1, x.shape[-1] // 20)
    rows = []
    for threads in threads_list:
        torch.set_num_threads(threads)
        ours = {
            "tactilesnn-gwt f32": GaborScalogram(w.fs_hz, freqs),
            f"tactilesnn-gwt f32 hop={hop}": GaborScalogram(w.fs_hz, freqs, hop=hop),
            "tactilesnn-gwt f32 periodic": cyclic,
        }
        for name, g in ours.items():
            out = g.transform(x, np.float32, workers=threads)
            r = refs.get(g.padding, ref)
            err = float(np.abs(out - r[..., :: g.hop]).max() / np.abs(r).max())
            t = median_time(lambda g=g, th=threads: g.transform(x, np.float32, workers=th), repeats)
            rows.append(_row(w, name, threads, t, err, "abs", g.hop))
        for name, factory in _peers(w, x).items():
            if name.startswith("pywt") and threads > 1:
                continue  # no thread setting: the 1-thread figure stands for both
            try:  # an installed peer may still fail to load (fCWT without libfftw3-single3)
                fn = factory(threads)
                out = fn()
            except Exception as e:  # an optional peer that fails must not stop the benchmark
                rows.append({"workload": w.name, "impl": name, "threads": threads, "error": str(e)})
                continue
            if name.startswith("pywt"):
                err, kind = shape_error(ref, out, edge), "shape"
            else:  # another wavelet family: its difference from cmor1.5 is not an accuracy figure
                err, kind = None, "other wavelet"
            rows.append(_row(w, name, threads, median_time(fn, repeats), err, kind, 1))
    torch.set_num_threads(threads_list[-1])
    return rows


def bench_stft(
    w: Workload, repeats: int, threads_list: list[int], nperseg: int = 100
) -> list[dict]:
    """STFT + latency code (one spike per band per 100-sample frame, hop 50) on a workload.

    Ours: Hann STFT pooled into the Gabor bands, then the latency code. Baseline: ``torch.stft``
    magnitudes, latency-coded per bin (no band pooling: strictly less work than ours).
    """
    from scipy import signal

    from ..encoders.latency import LatencyCode

    x = w.signal()
    hop = nperseg // 2
    rows = []
    code = LatencyCode(duration_ms=1000 * nperseg / w.fs_hz)
    ref = STFTScalogram(w.fs_hz, w.freqs(), nperseg=nperseg, hop=hop)(torch.from_numpy(x)).numpy()

    def per_frame(s: torch.Tensor) -> torch.Tensor:  # [B, C, F, T] -> [B*T, C, F, 1]
        return s.permute(0, 3, 1, 2).reshape(-1, s.shape[1], s.shape[2], 1)

    for threads in threads_list:
        torch.set_num_threads(threads)
        ours = STFTScalogram(w.fs_hz, w.freqs(), nperseg=nperseg, hop=hop)
        xt = torch.from_numpy(x.astype(np.float32))
        flat = xt.reshape(-1, x.shape[-1])
        win = torch.hann_window(nperseg)
        with torch.no_grad():
            out = ours(xt).numpy()
            t_ours = median_time(lambda o=ours, v=xt: code(per_frame(o(v))), repeats)

            def base(flat=flat, win=win):
                mag = torch.stft(flat, nperseg, hop, window=win, center=False, return_complex=True)
                return code(per_frame(mag.abs().unsqueeze(1)))

            t_base = median_time(base, repeats)
        err = float(np.abs(out - ref).max() / np.abs(ref).max())
        rows.append(_row(w, "tactilesnn-stft bands + latency", threads, t_ours, err, "abs", hop))
        rows.append(_row(w, "torch.stft |X| + latency", threads, t_base, None, "-", hop))
        if threads == 1:

            def sstft():
                return np.abs(signal.stft(x, w.fs_hz, nperseg=nperseg, noverlap=nperseg - hop)[2])

            rows.append(
                _row(w, "scipy.signal.stft only", 1, median_time(sstft, repeats), None, "-", hop)
            )
    torch.set_num_threads(threads_list[-1])
    return rows


def bench_fft(w: Workload, repeats: int, threads_list: list[int]) -> list[dict]:
    """Our full-rate GWT with each installed FFT backend (both edge modes) and fCWT."""
    from ..core.fft_backend import available

    x = w.signal()
    freqs = w.freqs()
    rows = []
    scalograms = {p: GaborScalogram(w.fs_hz, freqs, padding=p) for p in ("periodic", "reflect")}
    refs = {p: g.transform(x, np.float64, fft="scipy") for p, g in scalograms.items()}
    for threads in threads_list:
        torch.set_num_threads(threads)
        for padding, g in scalograms.items():
            for backend in available():

                def fn(g=g, th=threads, b=backend):
                    return g.transform(x, np.float32, workers=th, fft=b)

                ref = refs[padding]
                err = float(np.abs(fn() - ref).max() / np.abs(ref).max())
                name = f"tactilesnn-gwt {padding} [{backend}]"
                rows.append(_row(w, name, threads, median_time(fn, repeats), err, "abs", 1))
        if importlib.util.find_spec("fcwt"):
            try:
                fn = _fcwt(w, x)(threads)
                fn()
            except Exception as e:  # an optional peer that fails must not stop the benchmark
                rows.append(
                    {"workload": w.name, "impl": "fcwt", "threads": threads, "error": str(e)}
                )
                continue
            rows.append(_row(w, "fcwt (periodic edges)", threads, median_time(fn, repeats), None,
                             "other wavelet", 1))  # fmt: skip
    torch.set_num_threads(threads_list[-1])
    return rows


def fft_summary(rows: list[dict]) -> str:
    """Per workload and threads: each backend's time over scipy's and fCWT's over the best ours."""
    lines = ["| workload | threads | edges | scipy ms | ducc0 / scipy | pyfftw / scipy | "
             "fCWT ms | best ours / fCWT |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    keys = sorted({(r["workload"], r["threads"]) for r in rows})
    for wl, th in keys:
        sel = {r["impl"]: r for r in rows if (r["workload"], r["threads"]) == (wl, th)}
        fc = sel.get("fcwt (periodic edges)")
        for padding in ("periodic", "reflect"):
            base = sel.get(f"tactilesnn-gwt {padding} [scipy]")
            if base is None:
                continue
            ratio = {
                b: f"{sel[k]['ms'] / base['ms']:.2f}" if (k := f"tactilesnn-gwt {padding} [{b}]")
                in sel else "-"
                for b in ("ducc0", "pyfftw")
            }  # fmt: skip
            best = min(r["ms"] for k, r in sel.items() if k.startswith(f"tactilesnn-gwt {padding}"))
            vs = f"{best / fc['ms']:.2f}" if fc else "-"
            lines.append(f"| {wl} | {th} | {padding} | {base['ms']:.1f} | {ratio['ducc0']} | "
                         f"{ratio['pyfftw']} | {fc['ms'] if fc else float('nan'):.1f} | {vs} |")  # fmt: skip
    return "\n".join(lines)


def _row(w: Workload, impl: str, threads: int, t: float, err: float | None, kind: str, hop: int):
    work = w.batch * w.channels * w.samples * w.bands
    return {
        "workload": w.name,
        "impl": impl,
        "threads": threads,
        "ms": 1000 * t,
        "throughput_Msamplebands_s": work / t / 1e6,
        "max_err_rel_peak": err,
        "err_kind": kind,
        "hop": hop,
    }


def format_rows(rows: list[dict], mine_prefix: str = "tactilesnn-gwt") -> str:
    """Markdown table; the last column is each row's time over ours (same workload, threads)."""
    lines = [
        "| workload | implementation | threads | ms (median) | M sample-bands/s | max err / peak | "
        "time / ours |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "error" in r:
            lines.append(
                f"| {r['workload']} | {r['impl']} | {r['threads']} | failed: {r['error'][:60]} | | | |"
            )
            continue
        mine = [
            q
            for q in rows
            if q["workload"] == r["workload"]
            and q["threads"] == r["threads"]
            and q["impl"].startswith(mine_prefix)
            and "error" not in q
        ]
        ratio = " / ".join(f"{r['ms'] / q['ms']:.1f}" for q in mine) if mine else ""
        err = (
            "-"
            if r["max_err_rel_peak"] is None
            else f"{r['max_err_rel_peak']:.1e} ({r['err_kind']})"
        )
        lines.append(
            f"| {r['workload']} | {r['impl']} | {r['threads']} | {r['ms']:.2f} | "
            f"{r['throughput_Msamplebands_s']:.0f} | {err} | {ratio} |"
        )
    return "\n".join(lines)


def run(
    out: Path | None, repeats: int = 7, hop: int = 10, sparse: bool = False, fft: bool = False
) -> dict:
    threads_list = sorted({1, torch.get_num_threads()})
    results: dict = {"threads": threads_list, "gwt": [], "stft": []}
    if fft:
        threads_list = [1, 2]
        results["fft"] = []
        for w in (*WORKLOADS, LONG):
            results["fft"] += bench_fft(w, repeats, threads_list)
        results["table_fft"] = format_rows(results["fft"], "tactilesnn-gwt periodic [scipy]")
        results["summary_fft"] = fft_summary(results["fft"])
        print("Full-rate GWT by FFT backend (last column: time over ours, scipy backend, periodic)")
        print(results["table_fft"])
        print("\nSummary (ratios < 1: faster)")
        print(results["summary_fft"])
    elif sparse:
        from .sparse import bench_sparse

        results["sparse"] = bench_sparse(repeats)
        print(results["sparse"]["table"])
    else:
        for w in WORKLOADS:
            results["gwt"] += bench_gwt(w, repeats, hop, threads_list)
        results["stft"] = bench_stft(WORKLOADS[0], repeats, threads_list)
        results["table_gwt"] = format_rows(results["gwt"])
        print("Scalogram (GWT / CWT), complex Morlet bands")
        print(results["table_gwt"])
        print("\nSTFT + latency code (100-sample Hann frames, hop 50) on W1")
        print(format_rows(results["stft"], "tactilesnn-stft"))
    if out is not None:
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out, json.dumps(results, indent=2))
        print(f"results: {out}")
    return results


HELP = "GWT / STFT encoders against PyWavelets, ssqueezepy, fCWT and scipy (speed, error)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--repeats", type=int, default=7, help="timed runs per case")
    p.add_argument("--sparse", action="store_true", help="the activity-gate benchmark instead")
    p.add_argument("--fft", action="store_true",
                   help="FFT backends (scipy, ducc0, pyFFTW) in the full-rate GWT against fCWT")  # fmt: skip


def main(out: Path | None, options: argparse.Namespace) -> int:
    run(Path(out) / "encoders.json" if out else None, repeats=options.repeats,
        sparse=options.sparse, fft=options.fft)  # fmt: skip
    return 0
