"""Recordings as they come -> the arrays of the documented ``--data`` format.

:func:`read_recordings` accepts, besides the documented ``.npz`` (``X [N, channels, samples]``,
``y``, ``fs``, ``class_names``):

- ``.npz`` arrays ``[trials, samples, channels]`` or ``[trials, channels, samples]`` with a
  timestamp array ``t`` (``[trials, samples]`` or ``[samples]``, seconds) instead of ``fs``: the
  samples axis is the one whose length matches ``t``; ``fs`` is inferred from the median step,
  the jitter reported, and trials whose steps vary by more than :data:`MAX_JITTER` are
  resampled onto a uniform grid (linear interpolation);
- a folder of ``.csv`` (a header line of column names, a timestamp column such as ``timestamp``
  or ``time``, one column per channel) or ``.npy`` (``[samples, channels]``) files, one recording
  each, labelled by their sub-folder (``folder/<class>/*.csv``) or else by the file name up to the
  first ``_`` / ``-`` / space (``BeigeCotton_F120_V-100mmps_0.csv`` -> ``BeigeCotton``).
  Recordings of different lengths are cut into windows of the shortest one's length (at least
  :data:`MIN_WINDOW` samples; shorter ones are left out, said in the log), every half window;
  windows keep their recording's id, so they never straddle a split and scores are also summed
  per recording.

Every conversion is logged in one line (layout found, rate, jitter, what was resampled or cut);
a file that is almost right gets an error naming the fix.
"""

from __future__ import annotations

import csv
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .core.checks import check_allocation

log = logging.getLogger("tactilesnn")

#: relative spread of a trial's sampling steps (std / median) above which it is resampled
MAX_JITTER = 0.01
#: shortest window a folder of recordings is cut into (samples)
MIN_WINDOW = 16
#: column names taken as the timestamp (case-insensitive)
TIME_COLUMNS = ("timestamp", "timestamps", "time", "t", "time_s", "times", "ts")
MAX_FILES = 100_000


@dataclass
class Conversion:
    """What :func:`read_recordings` did, for the log and ``tactilesnn convert``."""

    layout: str
    fs_hz: float
    jitter: float = 0.0
    resampled: int = 0
    notes: list[str] = field(default_factory=list)

    def line(self) -> str:
        text = f"{self.layout}; fs {self.fs_hz:.4g} Hz (timing jitter {100 * self.jitter:.1f} %)"
        if self.resampled:
            text += f"; {self.resampled} recording(s) resampled onto a uniform grid"
        return "; ".join([text, *self.notes])


def needs_reading(path: Path, members: set[str] | None = None) -> bool:
    """True if ``path`` is not in the documented format and :func:`read_recordings` converts it
    (a folder without a ``manifest.json``; an ``.npz`` with timestamps instead of ``fs``)."""
    path = Path(path)
    if path.is_dir():
        return not (path / "manifest.json").is_file() and any(_recording_files(path))
    return (
        members is not None
        and "fs" not in members
        and "X" in members
        and ("t" in members or "timestamps" in members)
    )


def read_recordings(path: Path, arrays: dict[str, np.ndarray] | None = None
                    ) -> tuple[dict[str, np.ndarray], Conversion]:  # fmt: skip
    """``path`` (a folder of recordings, or an ``.npz`` whose ``arrays`` are given) -> the
    documented arrays and what was done (see the module docstring)."""
    path = Path(path)
    if path.is_dir():
        return _read_folder(path)
    if arrays is None:
        raise ValueError(f"{path}: give the arrays of the .npz")
    return _timestamped(arrays, path)


# ---------------------------------------------------------------- timestamped arrays
def _timestamped(arrays: dict[str, np.ndarray], path: Path) -> tuple[dict, Conversion]:
    X = np.asarray(arrays["X"])
    key = "t" if "t" in arrays else "timestamps"
    try:
        t = np.asarray(arrays[key], dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{path}: {key} must be numbers (seconds), got {e}") from None
    if t.ndim not in (1, 2) or t.shape[-1] < 2:
        raise ValueError(f"{path}: {key} must be the samples' times in seconds, [samples] or "
                         f"[trials, samples] with at least 2 samples, got shape {t.shape}")  # fmt: skip
    if X.ndim != 3:
        raise ValueError(f"{path}: X must be [trials, samples, channels] or [trials, channels, "
                         f"samples], got shape {X.shape}")  # fmt: skip
    n_t = t.shape[-1]
    axes = [a for a in (1, 2) if X.shape[a] == n_t]
    if not axes:
        raise ValueError(f"{path}: the timestamps t have {n_t} entries per trial but X is "
                         f"{X.shape}: no axis of X has that many samples")  # fmt: skip
    if len(axes) == 2:
        raise ValueError(f"{path}: X is {X.shape}: samples and channels have the same length, "
                         "so the layout is ambiguous; store X as [N, channels, samples] with fs "
                         "(Hz) instead of t")  # fmt: skip
    layout = "[trials, samples, channels]" if axes[0] == 1 else "[trials, channels, samples]"
    Xc = np.ascontiguousarray(X.transpose(0, 2, 1) if axes[0] == 1 else X, dtype=np.float32)
    if t.ndim == 1:
        t = np.broadcast_to(t, (Xc.shape[0], n_t))
    if t.shape != (Xc.shape[0], n_t):
        raise ValueError(f"{path}: t must be [samples] or [trials={Xc.shape[0]}, samples], got "
                         f"{t.shape}")  # fmt: skip
    Xc, fs, jitter, resampled = _uniform(Xc, t, path)
    out = {k: v for k, v in arrays.items() if k not in ("X", "t", "timestamps")}
    out.update(X=Xc, fs=np.array(fs))
    if "class_names" not in out:
        out["y"], out["class_names"] = _labels(arrays.get("y"), path)
    return out, Conversion(f"{path.name}: X {layout} with timestamps", fs, jitter, resampled)


def _uniform(X: np.ndarray, t: np.ndarray, path: Path) -> tuple[np.ndarray, float, float, int]:
    """Trials ``X [N, C, S]`` sampled at times ``t [N, S]`` (s) -> on a uniform grid at the
    median step; ``(X, fs, jitter, trials resampled)``."""
    if not np.isfinite(t).all():
        raise ValueError(f"{path}: timestamps hold NaN or Inf")
    dt = np.diff(t, axis=1)
    if (dt <= 0).any():
        raise ValueError(f"{path}: timestamps must increase within each trial")
    step = float(np.median(dt))
    jitter_per_trial = dt.std(axis=1) / step
    resample = jitter_per_trial > MAX_JITTER
    out = X
    if resample.any():
        out = X.copy()
        grid = np.arange(X.shape[2]) * step
        for i in np.flatnonzero(resample):
            ti = t[i] - t[i, 0]
            for c in range(X.shape[1]):  # within the trial's span; the end held past it
                out[i, c] = np.interp(grid, ti, X[i, c])
    return out, 1.0 / step, float(np.median(jitter_per_trial)), int(resample.sum())


def _labels(y: np.ndarray | None, path: Path) -> tuple[np.ndarray, np.ndarray]:
    if y is None:
        raise ValueError(f"{path}: missing y (one label per trial)")
    y = np.asarray(y)
    if y.dtype.kind in "iu":
        names = np.array([str(v) for v in np.unique(y)])
        lookup = {v: i for i, v in enumerate(np.unique(y))}
        return np.array([lookup[v] for v in y], np.int64), names
    names, idx = np.unique(y.astype(str), return_inverse=True)
    return idx.astype(np.int64), names


# ---------------------------------------------------------------- a folder of recordings
def _recording_files(folder: Path) -> list[Path]:
    files = sorted(p for p in folder.rglob("*") if p.suffix.lower() in (".csv", ".npy")
                   and p.is_file() and not p.name.startswith("."))  # fmt: skip
    if len(files) > MAX_FILES:
        raise ValueError(f"{folder}: {len(files)} files; at most {MAX_FILES} recordings")
    return files


def _label_of(p: Path, folder: Path) -> str:
    rel = p.relative_to(folder)
    if len(rel.parts) > 1:  # folder/<class>/file
        return rel.parts[0]
    return re.split(r"[_\-\s]", p.stem, maxsplit=1)[0] or p.stem


def _read_folder(folder: Path) -> tuple[dict, Conversion]:
    files = _recording_files(folder)
    if not files:
        raise ValueError(f"{folder}: no .csv or .npy recordings (and no manifest.json)")
    recs, names, steps, jitters, resampled = [], None, [], [], 0
    for p in files:
        data, cols, step, jitter, was_resampled = _read_one(p)
        if names is None:
            names = cols
        elif cols != names:
            raise ValueError(f"{p}: columns {cols[:5]}... differ from {files[0].name}'s")
        recs.append(data)
        if step is not None:
            steps.append(step)
            jitters.append(jitter)
        resampled += was_resampled
    labels = [_label_of(p, folder) for p in files]
    classes = sorted(set(labels))
    if len(classes) < 2:
        raise ValueError(f"{folder}: every file has the label {classes[0]!r}; put each class in "
                         "its own sub-folder or start file names with the class (Class_*.csv)")  # fmt: skip
    step = float(np.median(steps)) if steps else None
    fs, unit_note = _rate(step, files[0])
    jitter = float(np.median(jitters)) if jitters else 0.0
    lengths = np.array([r.shape[1] for r in recs])
    window = max(MIN_WINDOW, int(lengths.min()))
    keep = lengths >= window
    hop = max(1, window // 2)
    n_windows = int(sum((n - window) // hop + 1 for n in lengths[keep]))
    check_allocation(4 * n_windows * len(names) * window, f"the windows of {folder}")
    X = np.empty((n_windows, len(names), window), np.float32)
    y = np.empty(n_windows, np.int64)
    rec = np.empty(n_windows, np.int64)
    k = 0
    for i in np.flatnonzero(keep):
        for s in range(0, lengths[i] - window + 1, hop):
            X[k], y[k], rec[k] = recs[i][:, s : s + window], classes.index(labels[i]), i
            k += 1
    notes = [f"{len(files)} recordings of {lengths.min()}-{lengths.max()} samples, "
             f"{len(classes)} classes, {len(names)} channels; cut into {n_windows} windows of "
             f"{window} samples every {hop}"]  # fmt: skip
    if (~keep).any():
        notes.append(f"{int((~keep).sum())} recording(s) shorter than {window} samples left out")
    if unit_note:
        notes.append(unit_note)
    arrays = {"X": X, "y": y, "recording": rec, "fs": np.array(fs),
              "class_names": np.array(classes), "channel_names": np.array(names)}  # fmt: skip
    return arrays, Conversion(f"{folder.name}/: a folder of recordings", fs, jitter, resampled,
                              notes)  # fmt: skip


def _rate(step: float | None, example: Path) -> tuple[float, str]:
    """The sampling rate from the median timestamp step. Fractional steps are taken as seconds;
    integer ticks have no stated unit: they are taken as milliseconds, and the note says so
    (the encoders' bands scale with the rate, so a wrong unit does not change what is learnt)."""
    if step is None:
        return (
            1.0,
            f"no timestamp column in {example.name}: rate taken as 1 Hz (bands are relative)",
        )
    if step < 1.0:
        return 1.0 / step, ""
    return 1000.0 / step, (f"timestamps in {example.name} step by {step:g} ticks of unstated "
                           f"unit: taken as ms ({1000.0 / step:.4g} Hz); the rate only scales "
                           "the reported frequencies")  # fmt: skip


def _read_one(p: Path) -> tuple[np.ndarray, list[str], float | None, float, bool]:
    """One recording -> ``(X [channels, samples] float32, channel names, median timestamp step
    or None, timing jitter, resampled?)``; irregular timestamps are resampled (:func:`_uniform`)."""
    if p.suffix.lower() == ".npy":
        a = np.load(p, allow_pickle=False)
        if a.ndim != 2 or a.dtype.kind not in "fiu":
            raise ValueError(f"{p}: a recording .npy must be numeric [samples, channels]")
        names = [f"ch{i}" for i in range(a.shape[1])]
        return np.ascontiguousarray(a.T, dtype=np.float32), names, None, 0.0, False
    with open(p, newline="") as f:
        header = next(csv.reader(f), None)
    if not header:
        raise ValueError(f"{p}: empty CSV file")
    cols = [h.strip() for h in header]
    try:
        data = np.loadtxt(p, delimiter=",", skiprows=1, dtype=np.float64, ndmin=2)
    except ValueError as e:
        raise ValueError(f"{p}: a recording CSV holds a header line and numbers ({e})") from e
    if data.shape[1] != len(cols):
        raise ValueError(f"{p}: {data.shape[1]} values per row but {len(cols)} column names")
    tcol = next((i for i, c in enumerate(cols) if c.lower() in TIME_COLUMNS), None)
    chans = [i for i in range(len(cols)) if i != tcol]
    if not np.isfinite(data[:, chans]).all():
        raise ValueError(f"{p}: non-finite values in the channels")
    X = np.ascontiguousarray(data[:, chans].T, dtype=np.float32)
    if tcol is None or len(data) < 2:
        return X, [cols[i] for i in chans], None, 0.0, False
    t = data[:, tcol]
    dt = np.diff(t)
    if (dt < 0).any():
        raise ValueError(f"{p}: the timestamps ({cols[tcol]}) must increase (row "
                         f"{int(np.argmax(dt < 0)) + 2} goes back in time)")  # fmt: skip
    if (dt == 0).any():  # a repeated row (seen at the end of real recordings): keep the first
        keep = np.r_[True, dt > 0]
        X, t = np.ascontiguousarray(X[:, keep]), t[keep]
    X3, fs, jitter, resampled = _uniform(X[None], t[None], p)
    return X3[0], [cols[i] for i in chans], 1.0 / fs, jitter, bool(resampled)
