"""The real iCub file and the synthetic slides rendered to match it: loading, rendering, the per-
taxel statistics and taxel matching.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from itertools import pairwise
from pathlib import Path

import numpy as np

from ...core.data import WindowDataset

log = logging.getLogger("tactilesnn")


REAL_FILE = "braille_icub_abc/braille_abc_icub.npz"
#: the braille task's randomisation knobs (each also a field of BrailleTask)
KNOBS = ("gain_spread", "offset_counts", "drift_counts", "speed_spread", "force_spread", "force_ramp",
         "position_mm", "taxel_noise")  # fmt: skip
SPECTRUM_BANDS_HZ = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0)


def load_real(root: Path) -> WindowDataset:
    """The real file's whole slides ``[45, 12, samples]`` as the reader converts them."""
    from ...recordings import read_data_arrays

    a = read_data_arrays(Path(root) / REAL_FILE)
    X = np.asarray(a["X"], np.float32)
    names = tuple(str(n) for n in a["class_names"])
    return WindowDataset(X, np.asarray(a["y"], np.int64), np.arange(len(X), dtype=np.int64),
                         float(a["fs"]), names, tuple(f"ch{i}" for i in range(X.shape[1])))  # fmt: skip


def render_synthetic(real: WindowDataset, n: int, seed: int, progress: bool = False,
                     class_signal: bool = False, **knobs: float) -> tuple:  # fmt: skip
    """``(slides, force rise N [n])``: ``n`` slides of the ``braille`` task at the real file's
    rate and length, letters named as the real classes (``A`` -> ``a``); recording ids from
    10^6 up. With ``class_signal``, ``(slides, rise, letter's signal [n, samples])`` (the
    task's ``info["class_signal"]``: what :func:`cut` turns into window confidences)."""
    from tqdm.auto import tqdm

    from ...datasets_synth import get_task

    letters = "".join(c.lower() for c in real.class_names)
    samples = real.X.shape[-1]
    task = get_task("braille", seed=seed, n_samples=max(n, 2 * len(letters)), letters=letters,
                    fs_frames_hz=real.fs_hz, duration_s=samples / real.fs_hz, **knobs)  # fmt: skip
    X = np.empty((n, len(task.channel_names), samples), np.float32)
    y = np.empty(n, np.int64)
    rise = np.empty(n)
    signal = np.empty((n, samples), np.float32) if class_signal else None
    for i in tqdm(range(n), desc="render braille", disable=not progress):
        X[i], y[i], info = task.sample(i, class_signal=class_signal)
        rise[i] = info["force_rise_N"]
        if signal is not None:
            signal[i] = info["class_signal"]
    ds = WindowDataset(X, y, 10**6 + np.arange(n, dtype=np.int64), real.fs_hz,
                       real.class_names, real.channel_names)  # fmt: skip
    return (ds, rise) if signal is None else (ds, rise, signal)


def real_force_rise(root: Path) -> np.ndarray | None:
    """Per real slide: the rise (N) of the arm's force over the letter (robot state columns 6-8
    read as a force vector in N: its norm's peak minus its median over the first 10 %)."""
    with np.load(Path(root) / REAL_FILE, allow_pickle=False) as f:
        if "robot_state" not in f.files:
            return None
        r = np.asarray(f["robot_state"], np.float64)
    if r.ndim != 3 or r.shape[-1] < 9:
        return None
    norm = np.linalg.norm(r[..., 6:9], axis=-1)
    return norm.max(1) - np.median(norm[:, : max(2, norm.shape[1] // 10)], 1)


def real_arm_speed_mm_s(root: Path, slides: np.ndarray, fs_hz: float) -> float | None:
    """The arm's sliding speed (mm/s) over ``slides``: the median over those slides of the
    least-squares slope of robot state column 1 (the fingertip's position along the slide, m),
    one sample per frame at ``fs_hz``. ``None`` when the file has no robot state."""
    with np.load(Path(root) / REAL_FILE, allow_pickle=False) as f:
        if "robot_state" not in f.files:
            return None
        r = np.asarray(f["robot_state"], np.float64)[np.asarray(slides), :, 1]
    t = np.arange(r.shape[1]) / float(fs_hz)
    slopes = np.polyfit(t, 1000.0 * r.T, 1)[0]
    return float(np.median(np.abs(slopes)))


# ---------------------------------------------------------------- signal statistics
def taxel_stats(X: np.ndarray, fs_hz: float) -> dict[str, np.ndarray]:
    """Per taxel (medians over slides): ``rest``, ``range``, ``peak_s`` (from mid-slide); and
    ``spectrum``: mean log10 power (counts^2 / Hz) per band of :data:`SPECTRUM_BANDS_HZ`."""
    X = np.asarray(X, np.float64)
    s = X.shape[-1]
    rest = np.median(X[..., : max(2, s // 10)], axis=-1)  # [N, C]
    rng_ = np.percentile(X, 99, axis=-1) - np.percentile(X, 1, axis=-1)
    rise = X - rest[..., None]
    peak = (rise.argmax(-1) - s / 2) / fs_hz
    peak = np.where(rise.max(-1) > 0, peak, np.nan)
    f = np.fft.rfftfreq(s, 1 / fs_hz)
    p = np.abs(np.fft.rfft(X - X.mean(-1, keepdims=True), axis=-1)) ** 2 / (s * fs_hz)
    edges = SPECTRUM_BANDS_HZ
    bands = [p[..., (f >= lo) & (f < hi)].mean(-1) for lo, hi in pairwise(edges)]
    spec = np.log10(np.maximum(np.mean(bands, axis=(1, 2)), 1e-12))
    # a taxel that never rises above rest has no peak time (0: mid-slide)
    seen = ~np.isnan(peak)
    peak_med = np.array([np.median(peak[seen[:, c], c]) if seen[:, c].any() else 0.0
                         for c in range(peak.shape[1])])  # fmt: skip
    return {"rest": np.median(rest, 0), "range": np.median(rng_, 0), "peak_s": peak_med,
            "spectrum": spec}  # fmt: skip


def match_taxels(real: dict[str, np.ndarray], synth: dict[str, np.ndarray]) -> np.ndarray:
    """For each real channel, the synthetic channel that plays its part (Hungarian assignment
    on the standardised rest level, range and peak time; no labels used)."""
    from scipy.optimize import linear_sum_assignment

    feats = []
    for key in ("rest", "range", "peak_s"):
        both = np.concatenate([real[key], synth[key]])
        sd = both.std() or 1.0
        feats.append((real[key][:, None] - synth[key][None, :]) / sd)
    cost = np.sqrt(sum(f**2 for f in feats))
    rows, cols = linear_sum_assignment(cost)
    return cols[np.argsort(rows)]


def reorder(ds: WindowDataset, order: np.ndarray) -> WindowDataset:
    return replace(ds, X=np.ascontiguousarray(ds.X[:, order]))
