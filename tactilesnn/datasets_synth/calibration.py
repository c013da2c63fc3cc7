"""Fitting a sensor model to a user's recordings: statistics, the fitted configuration, its file.

A calibration compares real recordings with the same scene rendered by a sensor model, through
:func:`slide_statistics` (per taxel rest level and range, the cross-taxel correlation, the band
power and the mean response per class), and writes what it fitted as a :class:`SensorFit`: a
plain JSON file (``tactilesnn.sensor_fit``, no pickle) that a task reads back
(``get_task("braille", calibration="fit.json")``, ``generate --task-kw calibration=...``).
What is fitted, and how, belongs to the task that knows the scene
(:meth:`~.tasks.braille.BrailleTask.calibrate`); this module holds what every calibration shares.

Array contract: recordings ``X [N, channels, samples]`` in the sensor's units at ``fs_hz``, labels
``y [N]`` int in ``[0, classes)``.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from ..core.files import replace_atomically, write_text_atomic

#: the file's kind and the version this code writes and reads
FIT_KIND = "tactilesnn.sensor_fit"
FIT_VERSION = 1
#: a fit file is small (a few KB): anything larger is refused before parsing
MAX_FIT_BYTES = 1 << 20
#: the bands (Hz) of :func:`slide_statistics`' power spectrum (to the Nyquist rate of the data)
SPECTRUM_BANDS_HZ = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0)


@dataclass
class SensorFit:
    """A sensor model fitted to recordings (lengths mm, forces N, times s, levels in counts).

    ``sensor``: the registered sensor model's name; ``params``: its parameter dataclass's fields
    that differ from the defaults; ``channels``: per channel (the recordings' order) ``gain``
    (relative), ``offset`` (counts), ``noise`` (counts rms), ``drift`` (counts rms of a slow
    walk over a recording); ``scene``: the task's scene values (force, speed, timing, track);
    ``randomisation``: the widths the task draws around them; ``objective``: the distances per
    statistic at the end of the fit; ``fitted_on``: what it saw (recordings, classes, rate)."""

    task: str
    sensor: str
    params: dict[str, Any]
    channels: dict[str, list[float]]
    scene: dict[str, float]
    randomisation: dict[str, float]
    objective: dict[str, Any] = field(default_factory=dict)
    fitted_on: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps({"kind": FIT_KIND, "version": FIT_VERSION, **asdict(self)}, indent=1)

    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Write atomically; an existing file is kept unless ``overwrite``."""
        path = Path(path)
        if path.exists() and not overwrite:
            raise FileExistsError(f"{path} exists; pass overwrite (--overwrite) to replace it")
        write_text_atomic(path, self.to_json())
        return path

    @classmethod
    def load(cls, path: str | Path) -> SensorFit:
        """Read a fit file (JSON only; size, kind, version and fields checked)."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"sensor fit file not found: {path}")
        if path.stat().st_size > MAX_FIT_BYTES:
            raise ValueError(f"{path} is over {MAX_FIT_BYTES} bytes: not a sensor fit file")
        try:
            raw = json.loads(path.read_text())
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            raise ValueError(f"{path} is not a sensor fit file (JSON): {e}") from None
        return cls.from_dict(raw, str(path))

    @classmethod
    def from_dict(cls, raw: Any, where: str = "sensor fit") -> SensorFit:
        if not isinstance(raw, dict) or raw.get("kind") != FIT_KIND:
            raise ValueError(f"{where} is not a {FIT_KIND} file")
        if raw.get("version") != FIT_VERSION:
            raise ValueError(f"{where}: version {raw.get('version')!r} unknown "
                             f"(this code reads {FIT_VERSION})")  # fmt: skip
        need = ("task", "sensor", "params", "channels", "scene", "randomisation")
        missing = [k for k in need if k not in raw]
        if missing:
            raise ValueError(f"{where} lacks {', '.join(missing)}")
        for k in ("params", "channels", "scene", "randomisation"):
            if not isinstance(raw[k], dict):
                raise ValueError(f"{where}: {k} must be an object")
        for k in ("scene", "randomisation"):
            for name, v in raw[k].items():
                if not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ValueError(f"{where}: {k}.{name} must be a finite number, got {v!r}")
        for name, v in raw["channels"].items():
            a = np.asarray(v, dtype=np.float64) if isinstance(v, list) else None
            if a is None or a.ndim != 1 or not np.isfinite(a).all():
                raise ValueError(f"{where}: channels.{name} must be a list of finite numbers")
        keep = {k: raw[k] for k in (*need, "objective", "fitted_on") if k in raw}
        return cls(**keep)


# ---------------------------------------------------------------- statistics
def rest_level(X: np.ndarray) -> np.ndarray:
    """Per recording and channel ``[N, C]``: the median of the first 10 % (the rest segment)."""
    return np.median(X[..., : max(2, X.shape[-1] // 10)], axis=-1)


def slide_statistics(X: np.ndarray, y: np.ndarray, fs_hz: float, n_classes: int) -> dict:
    """The statistics a calibration matches (float64, medians over recordings where noted):

    ``rest [C]`` (median rest level), ``range [C]`` (median 99th - 1st percentile), ``peak_s
    [C]`` (median time of the largest rise above rest, s from mid-recording; 0 where a channel
    never rises), ``correlation [C, C]`` (Pearson correlation of the channels over all samples
    of all recordings; 0 for a constant channel), ``spectrum [bands]`` (log10 mean power,
    units^2 / Hz, per band of :data:`SPECTRUM_BANDS_HZ` below the Nyquist rate), ``noise [C]``
    (rms of the rest segment's first differences / sqrt 2) and ``mean [classes, C, samples]``
    (the mean recording per class)."""
    X = np.asarray(X, np.float64)
    y = np.asarray(y)
    _n, c, s = X.shape
    rest = rest_level(X)
    rng_ = np.percentile(X, 99, axis=-1) - np.percentile(X, 1, axis=-1)
    rise = X - rest[..., None]
    peak = np.where(rise.max(-1) > 0, (rise.argmax(-1) - s / 2) / fs_hz, np.nan)
    seen = ~np.isnan(peak)
    peak_med = np.array([np.median(peak[seen[:, i], i]) if seen[:, i].any() else 0.0
                         for i in range(c)])  # fmt: skip
    flat = X.transpose(1, 0, 2).reshape(c, -1)
    sd = flat.std(1)
    live = sd > 1e-9
    corr = np.zeros((c, c))
    if live.any():
        corr[np.ix_(live, live)] = np.corrcoef(flat[live])
    f = np.fft.rfftfreq(s, 1 / fs_hz)
    p = np.abs(np.fft.rfft(X - X.mean(-1, keepdims=True), axis=-1)) ** 2 / (s * fs_hz)
    bands = [(lo, hi) for lo, hi in pairwise(SPECTRUM_BANDS_HZ) if lo < fs_hz / 2]
    spec = np.array([np.log10(max(p[..., (f >= lo) & (f < hi)].mean(), 1e-12)) if
                     ((f >= lo) & (f < hi)).any() else np.nan for lo, hi in bands])  # fmt: skip
    head = X[..., : max(3, s // 10)]
    noise = np.sqrt(np.mean(np.diff(head, axis=-1) ** 2, axis=(0, 2)) / 2)
    mean = np.stack([X[y == k].mean(0) if (y == k).any() else np.full((c, s), np.nan)
                     for k in range(n_classes)])  # fmt: skip
    return {"rest": np.median(rest, 0), "range": np.median(rng_, 0), "peak_s": peak_med,
            "correlation": corr, "spectrum": spec, "spectrum_bands_hz": bands, "noise": noise,
            "mean": mean}  # fmt: skip


def statistic_distances(real: dict, synth: dict) -> dict[str, float]:
    """How far two :func:`slide_statistics` are apart, per statistic (0 = equal):

    ``mean_response``: the fraction of the real class means' variance (about each channel's
    mean) the synthetic class means leave unexplained; ``class_difference``: the same for what
    tells the classes apart (each class mean less the mean over classes: a response common to
    every class, such as a slow rise, does not count); ``rest`` and ``range``: rms difference
    over the real channels' range (counts / counts); ``correlation``: mean absolute difference
    of the off-diagonal correlations; ``spectrum``: rms difference in decades."""
    rm, sm = real["mean"], synth["mean"]
    cen = rm - rm.mean(axis=(0, 2), keepdims=True)
    fuv = float(((sm - rm) ** 2).sum() / max((cen**2).sum(), 1e-12))
    rd, sd = rm - rm.mean(0, keepdims=True), sm - sm.mean(0, keepdims=True)
    between = float(((sd - rd) ** 2).sum() / max((rd**2).sum(), 1e-12))
    scale = max(float(np.max(real["range"])), 1e-9)
    c = real["correlation"].shape[0]
    off = ~np.eye(c, dtype=bool)
    spec = np.asarray(real["spectrum"]) - np.asarray(synth["spectrum"])
    return {"mean_response": fuv, "class_difference": between,
            "rest": float(np.sqrt(np.mean((real["rest"] - synth["rest"]) ** 2)) / scale),
            "range": float(np.sqrt(np.mean((real["range"] - synth["range"]) ** 2)) / scale),
            "correlation": float(np.abs(real["correlation"] - synth["correlation"])[off].mean()),
            "spectrum": float(np.sqrt(np.nanmean(spec**2)))}  # fmt: skip


def plot_statistics(real: dict, fits: dict[str, dict], class_names: tuple[str, ...], fs_hz: float,
                    path: Path, title: str = "") -> None:  # fmt: skip
    """The one picture of a calibration: per-taxel rest and range, the correlation matrices,
    the band power and the mean response per class (sum over taxels of the rise above rest),
    real against each of ``fits`` (label -> :func:`slide_statistics`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_fit = len(fits)
    fig, axes = plt.subplots(2, 2 + n_fit, figsize=(4.6 * (2 + n_fit), 8.4))
    x = np.arange(real["rest"].size)
    width = 0.8 / (1 + n_fit)
    ax = axes[0, 0]
    for j, (label, st) in enumerate([("real", real), *fits.items()]):
        ax.bar(
            x + (j - n_fit / 2) * width, st["range"], width, label=f"{label}: range", color=f"C{j}"
        )
        ax.plot(x, st["rest"], "os^v"[j % 4], color=f"C{j}", mfc="none", label=f"{label}: rest")
    ax.set_xticks(x)
    ax.set_xlabel("taxel (the recordings' channel order)")
    ax.set_ylabel("counts")
    ax.set_title("per-taxel rest level and range")
    ax.legend(fontsize=7)
    ax = axes[1, 0]
    mids = [np.sqrt(lo * hi) for lo, hi in real["spectrum_bands_hz"]]
    for j, (label, st) in enumerate([("real", real), *fits.items()]):
        ax.semilogx(mids, st["spectrum"], "os^v"[j % 4] + "-", color=f"C{j}", label=label)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("log10 power (counts^2 / Hz)")
    ax.set_title("band power (mean over taxels, recordings)")
    ax.legend(fontsize=8)
    for j, (label, st) in enumerate([("real", real), *fits.items()]):
        ax = axes[0, 1 + j]
        ax.imshow(st["correlation"], vmin=-1, vmax=1, cmap="RdBu_r")
        ax.set_title(f"cross-taxel correlation: {label}")
        ax.set_xlabel("taxel")
        ax.set_ylabel("taxel")
    t = (np.arange(real["mean"].shape[-1]) - real["mean"].shape[-1] / 2) / fs_hz
    for j, (label, st) in enumerate(fits.items()):
        ax = axes[1, 1 + j]
        for k, name in enumerate(class_names):
            for s, style in ((real, "-"), (st, "--")):
                m = s["mean"][k]
                ax.plot(t, (m - np.median(m[:, : m.shape[-1] // 10], -1, keepdims=True)).sum(0),
                        style, color=f"C{k}", label=f"{name} {'real' if s is real else label}")  # fmt: skip
        ax.set_xlabel("time from mid-recording (s)")
        ax.set_ylabel("sum over taxels of the rise above rest")
        ax.set_title(f"mean response per class: real (solid), {label} (dashed)")
        ax.legend(fontsize=6, ncol=2)
    axes[1, -1].set_visible(False)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    replace_atomically(Path(path), lambda tmp: fig.savefig(tmp, dpi=100, format="png"), ".png")
    plt.close(fig)


def spectrum_shape(st: dict, bands: list | None = None) -> np.ndarray:
    """The band power as fractions of the total over ``bands`` (default: all of the
    statistics'; log10, NaN where a band is not resolved): unit-free, so recordings and a model
    in other units (counts against dC/C) compare by the shape of their spectra."""
    have = {tuple(b): v for b, v in zip(st["spectrum_bands_hz"], st["spectrum"], strict=True)}
    keys = [tuple(b) for b in (bands if bands is not None else st["spectrum_bands_hz"])]
    p = np.array([10.0 ** have[b] if b in have and np.isfinite(have[b]) else np.nan for b in keys])
    return np.log10(np.maximum(p / np.nansum(p), 1e-12))


def common_bands(a: dict, b: dict) -> list:
    """The spectrum bands both statistics resolve."""

    def ok(st: dict) -> set:
        return {tuple(x) for x, v in zip(st["spectrum_bands_hz"], st["spectrum"], strict=True)
                if np.isfinite(v)}  # fmt: skip

    return sorted(ok(a) & ok(b))


def compare_statistics(real: dict, model: dict, real_classes: tuple[str, ...],
                       model_classes: tuple[str, ...], real_fs_hz: float,
                       model_fs_hz: float) -> dict:  # fmt: skip
    """What can be compared between recordings and a sensor model that need not share channels,
    classes or rate (:func:`slide_statistics` of each), and what the model cannot express."""
    bands = common_bands(real, model)
    shape = spectrum_shape(real, bands) - spectrum_shape(model, bands)
    cr, cm = real["correlation"], model["correlation"]

    def mean_offdiag(c: np.ndarray) -> float:
        off = ~np.eye(c.shape[0], dtype=bool)
        return float(c[off].mean()) if off.any() else float("nan")

    shared = sorted({c.lower() for c in real_classes} & {c.lower() for c in model_classes})
    gaps = []
    if real["rest"].size != model["rest"].size:
        gaps.append(f"{real['rest'].size} channels in the recordings, {model['rest'].size} in the "
                    "model: no channel-to-pad map to fit")  # fmt: skip
    if len(shared) < len(real_classes):
        missing = sorted({c.lower() for c in real_classes} - {c.lower() for c in model_classes})
        gaps.append(f"classes the model does not render: {', '.join(missing)}")
    if abs(real_fs_hz - model_fs_hz) > 1e-6 * real_fs_hz:
        gaps.append(
            f"rate {real_fs_hz:.4g} Hz in the recordings, {model_fs_hz:.4g} Hz in the model"
        )
    return {"spectrum_shape_rms_decades": float(np.sqrt(np.nanmean(shape**2))),
            "spectrum_shape_bands_hz": [list(b) for b in bands],
            "spectrum_shape_real": spectrum_shape(real, bands).tolist(),
            "spectrum_shape_model": spectrum_shape(model, bands).tolist(),
            "mean_cross_channel_correlation": {"real": mean_offdiag(cr), "model": mean_offdiag(cm)},
            "shared_classes": shared, "cannot_express": gaps}  # fmt: skip


def plot_comparison(real: dict, model: dict, real_classes: tuple[str, ...],
                    model_classes: tuple[str, ...], real_fs_hz: float, model_fs_hz: float,
                    path: Path, title: str = "") -> None:  # fmt: skip
    """The statistics picture for recordings and a model that need not share channels, classes
    or rate: per-channel rest and range, both correlation matrices, the spectra's shapes, and
    each one's mean activity per class (summed |change from rest| over channels)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(15, 8.4))
    for ax, st, label in ((axes[0, 0], real, "recordings"), (axes[1, 0], model, "model")):
        x = np.arange(st["rest"].size)
        ax.bar(x, st["range"], 0.6, label="range (99th - 1st percentile)")
        ax.plot(x, st["rest"], "o", color="k", mfc="none", label="rest level")
        ax.set_yscale("symlog", linthresh=1.0)
        ax.set_title(f"per-channel rest and range: {label}")
        ax.set_xlabel("channel")
        ax.legend(fontsize=7)
    for ax, st, label in ((axes[0, 1], real, "recordings"), (axes[1, 1], model, "model")):
        ax.imshow(st["correlation"], vmin=-1, vmax=1, cmap="RdBu_r")
        ax.set_title(f"cross-channel correlation: {label}")
    ax = axes[0, 2]
    bands = common_bands(real, model)
    mids = [np.sqrt(lo * hi) for lo, hi in bands]
    for st, label, m in ((real, "recordings", "o-"), (model, "model", "s--")):
        ax.semilogx(mids, spectrum_shape(st, bands), m, label=label)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("log10 share of the power")
    ax.set_title("the spectra's shapes over the bands both resolve")
    ax.legend()
    ax = axes[1, 2]
    for st, names, fs, style in ((real, real_classes, real_fs_hz, "-"),
                                 (model, model_classes, model_fs_hz, "--")):  # fmt: skip
        for k, name in enumerate(names):
            m = st["mean"][k]
            if not np.isfinite(m).all():
                continue
            act = np.abs(m - np.median(m[:, : max(2, m.shape[-1] // 10)], -1, keepdims=True)).sum(0)
            ax.plot(np.arange(act.size) / fs, act / max(act.max(), 1e-12), style, lw=1, label=name)
    ax.set_xlabel("time in the window (s)")
    ax.set_ylabel("mean activity (normalised)")
    ax.set_title("mean activity per class: recordings (solid), model (dashed)")
    ax.legend(fontsize=6, ncol=2)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    replace_atomically(Path(path), lambda tmp: fig.savefig(tmp, dpi=100, format="png"), ".png")
    plt.close(fig)
