"""Recordings as they come -> the arrays of the documented ``--data`` format.

:func:`read_recordings` accepts, besides the documented ``.npz`` (``X [N, channels, samples]``,
``y``, ``fs``, ``class_names``):

- ``.npz`` arrays ``[trials, samples, channels]`` or ``[trials, channels, samples]`` with a
  timestamp array ``t`` (``[trials, samples]`` or ``[samples]``, seconds) instead of ``fs``: the
  samples axis is the one whose length matches ``t``; ``fs`` is inferred from the median step,
  the jitter reported, and trials whose steps vary by more than :data:`MAX_JITTER` are
  resampled onto a uniform grid (linear interpolation);
- a folder of ``.csv`` / ``.tsv`` (read by :func:`~tactilesnn.core.tables.read_table`: header
  line or not, delimiter and decimal mark, byte-order marks, title lines and empty columns as a
  spreadsheet saves them; a time column found by its name, e.g. ``timestamp`` or ``time_ms``, or
  as a first column of steadily increasing values; else the rate must be given, ``--fs HZ``)
  or ``.npy`` (``[samples, channels]``) files, one recording each, labelled by their sub-folder
  (``folder/<class>/*.csv``) or else by the file name up to the first ``_`` / ``-`` / space
  (``BeigeCotton_F120_V-100mmps_0.csv`` -> ``BeigeCotton``); symbolic links are followed.
  Recordings at other rates than most are resampled to theirs (said in the printout).
  Recordings of different lengths are cut into windows of the shortest one's length among those
  at least half the median length (at least :data:`MIN_WINDOW` samples; shorter ones are left
  out, said in the log), every half window; windows keep their recording's id, so they never
  straddle a split and scores are also summed per recording. Conditions the file names state
  (``Class_F150_V-50mmps_3.csv``: ``F`` = 150, ``V`` = -50) or sub-folder levels below the
  class's become ``group_<name>`` arrays (:func:`conditions_from_names`).

Every conversion is logged in one line (layout found, rate, jitter, what was resampled or cut);
a file that is almost right gets an error naming the fix.
"""

from __future__ import annotations

import logging
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .core.checks import check_allocation
from .core.data import GROUP_PREFIX, condition_text
from .core.files import npy_header
from .core.tables import Table, read_table

log = logging.getLogger("tactilesnn")

#: relative spread of a trial's sampling steps (std / median) above which it is resampled
MAX_JITTER = 0.01
#: shortest window a folder of recordings is cut into (samples)
MIN_WINDOW = 16
#: a time column's name (case-insensitive), with an optional unit: ``time``, ``Time (s)``,
#: ``timestamp_ms``, ``t[us]``, ``ts_ns``
TIME_NAME = re.compile(
    r"^(timestamps?|times?|t|ts|zeit|temps|tiempo)\s*[\[(_\- ]?\s*"
    r"(?P<unit>s|sec|secs|seconds|ms|msec|millis|milliseconds|us|µs|usec|microseconds|ns|nsec|"
    r"nanoseconds)?\s*[\])]?$",
    re.IGNORECASE,
)
#: seconds per unit named in a time column's name
UNITS = {"s": 1.0, "sec": 1.0, "secs": 1.0, "seconds": 1.0, "ms": 1e-3, "msec": 1e-3,
         "millis": 1e-3, "milliseconds": 1e-3, "us": 1e-6, "usec": 1e-6, "microseconds": 1e-6,
         "ns": 1e-9, "nsec": 1e-9, "nanoseconds": 1e-9}  # fmt: skip
#: first-column names of a sample counter (dropped; it gives no rate)
INDEX_NAMES = ("index", "idx", "sample", "samples", "sample_index", "frame", "n", "row", "#")
#: how a rate was known from timestamps stepping by exactly one unit that no name states
WHOLE_UNITS = "whole units"
#: a stated rate (``--fs``) within this fraction of the data's own is the same rate
RATE_TOLERANCE = 0.01
#: recordings whose rates differ by more than this fraction are at different rates (less is
#: timing jitter, taken up by the uniform grid)
MIXED_RATES = 0.05
#: share of recordings that may be left out as stray short files (see :func:`_window_length`)
STRAY_SHARE = 0.02
RECORDING_SUFFIXES = (".csv", ".tsv", ".npy")
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


def read_recordings(path: Path, arrays: dict[str, np.ndarray] | None = None,
                    fs_hz: float | None = None) -> tuple[dict[str, np.ndarray], Conversion]:  # fmt: skip
    """``path`` (a folder of recordings, or an ``.npz`` whose ``arrays`` are given) -> the
    documented arrays and what was done (see the module docstring). ``fs_hz``: the sampling
    rate (Hz) the user states (``--fs``), required where no timestamps tell it."""
    path = Path(path)
    if path.is_dir():
        return _read_folder(path, fs_hz)
    if arrays is None:
        raise ValueError(f"{path}: give the arrays of the .npz")
    out, conv = _timestamped(arrays, path)
    if fs_hz is not None and abs(conv.fs_hz - fs_hz) > RATE_TOLERANCE * fs_hz:
        raise ValueError(f"{path}: its timestamps say {conv.fs_hz:.6g} Hz, --fs says {fs_hz:g} "
                         "Hz; drop --fs or correct it")  # fmt: skip
    return out, conv


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
    t, unit_note = _in_seconds(t, path)
    Xc, fs, jitter, resampled = _uniform(Xc, t, path)
    out = {k: v for k, v in arrays.items() if k not in ("X", "t", "timestamps")}
    out.update(X=Xc, fs=np.array(fs))
    if "class_names" not in out:
        out["y"], out["class_names"] = _labels(arrays.get("y"), path)
    conv = Conversion(f"{path.name}: X {layout} with timestamps", fs, jitter, resampled)
    if unit_note:
        conv.notes.append(unit_note)
    return out, conv


def _in_seconds(t: np.ndarray, path: Path) -> tuple[np.ndarray, str]:
    """Timestamps ``[trials, samples]`` in seconds; steps of 1 or more are taken in the unit
    :func:`_tick_unit` finds (said in the note). Trials at rates more than
    :data:`RATE_TOLERANCE` apart are refused: one array holds one rate."""
    if not np.isfinite(t).all():
        raise ValueError(f"{path}: timestamps hold NaN or Inf")
    dt = np.diff(t, axis=-1)
    if (dt <= 0).any():
        raise ValueError(f"{path}: timestamps must increase within each trial")
    steps = np.median(dt, axis=-1)
    lo, hi = int(np.argmin(steps)), int(np.argmax(steps))
    if steps[hi] > (1 + MIXED_RATES) * steps[lo]:
        raise ValueError(f"{path}: trials at different rates (trial {lo}: a step of "
                         f"{steps[lo]:.6g}, trial {hi}: {steps[hi]:.6g}); one X array holds one "
                         "rate: resample the trials to one rate, or store each rate in its own "
                         "file")  # fmt: skip
    if float(np.median(steps)) < 1.0:
        return t, ""
    unit, how = _tick_unit(t.reshape(-1)[: t.shape[-1]])
    return t * unit, (f"timestamps step by {float(np.median(steps)):g}: taken as {how} in units "
                      f"of {unit:g} s; give fs (Hz) in the file to state the rate")  # fmt: skip


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
def _recording_files(folder: Path) -> tuple[list[Path], int]:
    """The recording files under ``folder`` and how many symbolic links were followed to them.
    Links (to files or class folders) are followed wherever they point; a link that leads
    nowhere, or back into a folder already walked, is refused by name."""
    files: list[Path] = []
    links, seen = 0, set()
    for root, dirs, names in os.walk(folder, followlinks=True):
        real = os.path.realpath(root)
        if real in seen:
            raise ValueError(f"{root}: a symbolic link leads back into {real}, which is read "
                             "already; remove the link")  # fmt: skip
        seen.add(real)
        links += sum(os.path.islink(os.path.join(root, d)) for d in dirs)
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for name in sorted(names):
            p = Path(root, name)
            if name.startswith(".") or p.suffix.lower() not in RECORDING_SUFFIXES:
                continue
            if not p.exists():
                raise ValueError(f"{p}: a symbolic link to nothing ({os.readlink(p)}); remove it "
                                 "or restore its target")  # fmt: skip
            if not p.is_file():  # reading a FIFO blocks, a device never ends
                raise ValueError(f"{p}: not a regular file (a FIFO, device or socket, or a link "
                                 "to one); remove it from the recordings folder")  # fmt: skip
            links += p.is_symlink()
            files.append(p)
            if len(files) > MAX_FILES:
                raise ValueError(f"{folder}: more than {MAX_FILES} files; at most {MAX_FILES} "
                                 "recordings")  # fmt: skip
    return sorted(files), links


def _label_of(p: Path, folder: Path) -> str:
    rel = p.relative_to(folder)
    if len(rel.parts) > 1:  # folder/<class>/file
        return readable_name(rel.parts[0])
    return readable_name(re.split(r"[_\-\s]", p.stem, maxsplit=1)[0] or p.stem)


#: a file-name field that states a condition: letters, then a number, then an optional unit
#: (``F150`` -> ``F`` = 150, ``V-50mmps`` -> ``V`` = -50)
CONDITION_FIELD = re.compile(r"^([A-Za-z]+)(-?\d+(?:\.\d+)?)([A-Za-z/]*)$")


def conditions_from_names(files: list[Path], folder: Path) -> dict[str, np.ndarray]:
    """Conditions ``{name: [recordings]}`` stated by every file: fields of the file name after
    the class (``Class_F150_V-50mmps_3.csv``: ``F`` = 150, ``V`` = -50; a bare number, the
    repetition, is none) and the sub-folder levels below the class's (``folder/<class>/<day>/
    file.csv``: ``level1`` = the day's folder name). A field only some files state is none."""
    found: list[dict[str, object]] = []
    for p in files:
        rel = p.relative_to(folder)
        fields: dict[str, object] = {f"level{i}": readable_name(part)
                                     for i, part in enumerate(rel.parts[1:-1], 1)}  # fmt: skip
        tokens = p.stem.split("_")[1:] if len(rel.parts) == 1 else p.stem.split("_")
        for token in tokens:
            m = CONDITION_FIELD.match(token)
            if m and m.group(1) not in fields:
                fields[m.group(1)] = float(m.group(2))
        found.append(fields)
    common = set.intersection(*(set(f) for f in found)) if found else set()
    out = {}
    for name in sorted(common):
        values = [f[name] for f in found]
        if len(set(values)) > 1:  # one value everywhere says nothing about a condition
            out[name] = np.asarray(values)
    return out


def readable_name(name: str) -> str:
    """A file or folder name as text: bytes that are not UTF-8 (a folder written under another
    locale, kept by Python as surrogate escapes that no file or JSON can hold) as ``\\xff``
    escapes, so two such names stay distinct and every run file can be written."""
    return os.fsencode(name).decode("utf-8", "backslashreplace")


@dataclass
class _Recording:
    """One file read: ``X [channels, samples]`` float32, channel names, its rate (Hz) when its
    timestamps tell it, how the rate was known, timing jitter, whether it was resampled."""

    X: np.ndarray
    names: list[str]
    fs_hz: float | None
    rate_from: str
    jitter: float = 0.0
    resampled: bool = False
    notes: list[str] = field(default_factory=list)


def _read_folder(folder: Path, fs_hz: float | None = None) -> tuple[dict, Conversion]:
    files, links = _recording_files(folder)
    if not files:
        raise ValueError(f"{folder}: no .csv, .tsv or .npy recordings (and no manifest.json)")
    recs = [_read_one(p) for p in files]
    names = recs[0].names
    for p, r in zip(files, recs, strict=True):
        if r.names != names:
            raise ValueError(f"{p}: columns {r.names[:5]} differ from {files[0].name}'s "
                             f"{names[:5]}; every recording needs the same channels in the same "
                             "order")  # fmt: skip
    labels = [_label_of(p, folder) for p in files]
    classes = sorted(set(labels))
    if len(classes) < 2:
        raise ValueError(f"{folder}: every file has the label {classes[0]!r}; put each class in "
                         "its own sub-folder or start file names with the class (Class_*.csv)")  # fmt: skip
    fs, rate_note, resampled = _common_rate(recs, files, fs_hz, folder)
    X_all = [r.X for r in recs]
    jitter = float(np.median([r.jitter for r in recs]))
    lengths = np.array([x.shape[1] for x in X_all])
    window = _window_length(lengths)
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
            X[k], y[k], rec[k] = X_all[i][:, s : s + window], classes.index(labels[i]), i
            k += 1
    notes = [f"{len(files)} recordings of {lengths.min()}-{lengths.max()} samples, "
             f"{len(classes)} classes, {len(names)} channels; cut into {n_windows} windows of "
             f"{window} samples every {hop}"]  # fmt: skip
    if (~keep).any():
        short = [files[i].name for i in np.flatnonzero(~keep)]
        more = " ..." if len(short) > 3 else ""
        notes.append(f"{len(short)} recording(s) shorter than {window} samples left out "
                     f"(a stray few under half the median length): {', '.join(short[:3])}{more}")  # fmt: skip
    notes.append(rate_note)
    if links:
        notes.append(f"{links} symbolic link(s) followed")
    seen: dict[str, list[str]] = {}  # each distinct note once, with the files it holds for
    for p, r in zip(files, recs, strict=True):
        for n in r.notes:
            seen.setdefault(n, []).append(p.name)
    for n, where in seen.items():
        notes.append(
            f"{n} ({where[0]}" + (f" and {len(where) - 1} more)" if len(where) > 1 else ")")
        )
    arrays = {"X": X, "y": y, "recording": rec, "fs": np.array(fs),
              "class_names": np.array(classes), "channel_names": np.array(names)}  # fmt: skip
    for name, values in conditions_from_names(files, folder).items():
        arrays[GROUP_PREFIX + name] = values[rec]
        notes.append(f"condition {name!r} from the file names: "
                     f"{', '.join(map(condition_text, np.unique(values)[:8]))}"
                     f"{' ...' if np.unique(values).size > 8 else ''}")  # fmt: skip
    resampled += sum(r.resampled for r in recs)
    return arrays, Conversion(f"{folder.name}/: a folder of recordings", fs, jitter, resampled,
                              notes)  # fmt: skip


def _window_length(lengths: np.ndarray) -> int:
    """Windows as long as the shortest recording, except that a few stray short ones (under half
    the median length, at most :data:`STRAY_SHARE` of the recordings or one) are left out
    rather than shortening every window."""
    short = lengths < np.median(lengths) / 2
    if 0 < short.sum() <= max(1, STRAY_SHARE * len(lengths)):
        return max(MIN_WINDOW, int(lengths[~short].min()))
    return max(MIN_WINDOW, int(lengths.min()))


def _common_rate(recs: list[_Recording], files: list[Path], fs_hz: float | None,
                 folder: Path) -> tuple[float, str, int]:  # fmt: skip
    """One rate for every recording: ``fs_hz`` (``--fs``) where given, else the recordings'
    own (timestamps); recordings at another rate are resampled (polyphase, anti-aliased) to the
    rate most of them have. Returns ``(fs, note, recordings resampled)``."""
    timed = [r for r in recs if r.fs_hz is not None]
    if fs_hz is not None:
        for p, r in zip(files, recs, strict=True):
            known = r.fs_hz is not None and r.rate_from not in ("ticks", WHOLE_UNITS)
            if known and abs(r.fs_hz - fs_hz) > RATE_TOLERANCE * fs_hz:
                raise ValueError(f"{p}: its timestamps ({r.rate_from}) say {r.fs_hz:.6g} Hz, "
                                 f"--fs says {fs_hz:g} Hz; drop --fs or correct it")  # fmt: skip
        for r in recs:
            r.fs_hz = fs_hz
        return fs_hz, f"rate {fs_hz:g} Hz from --fs", 0
    if len(timed) < len(recs):
        p = files[next(i for i, r in enumerate(recs) if r.fs_hz is None)]
        raise ValueError(f"{p}: no time column (a column named time / timestamp, with or without "
                         "a unit such as time_ms, or a first column of steadily increasing "
                         "values), so the sampling rate cannot be known: give it with --fs HZ")  # fmt: skip
    ambiguous = next((i for i, r in enumerate(recs) if r.rate_from == WHOLE_UNITS), None)
    if ambiguous is not None:
        raise ValueError(f"{files[ambiguous]}: its time column steps by exactly 1 with no unit in "
                         "its name: seconds (1 Hz) or milliseconds (1,000 Hz)? name the column "
                         "time_s or time_ms, or give the rate with --fs HZ")  # fmt: skip
    rates = np.array([r.fs_hz for r in recs])
    keys = np.round(np.log(rates) / np.log1p(MIXED_RATES)).astype(np.int64)
    values, counts = np.unique(keys, return_counts=True)
    ref = float(np.median(rates[keys == values[np.argmax(counts)]]))
    other = np.flatnonzero(np.abs(rates - ref) > MIXED_RATES * ref)
    how = sorted({r.rate_from for r in recs})
    note = f"rate {ref:.6g} Hz from the timestamps ({', '.join(how)})"
    if "ticks" in how:
        note += ("; timestamps are ticks of unstated unit (taken as ms, us or ns by their step): "
                 "--fs HZ states the rate")  # fmt: skip
    for i in other:
        recs[i].X = _resample(recs[i].X, recs[i].fs_hz, ref)
    if len(other):
        shown = ", ".join(f"{files[i].name} at {rates[i]:.4g} Hz" for i in other[:3])
        note += (f"; {len(other)} recording(s) at other rates resampled to {ref:.6g} Hz "
                 f"(polyphase, anti-aliased): {shown}{' ...' if len(other) > 3 else ''}")  # fmt: skip
    return ref, note, len(other)


def _resample(X: np.ndarray, fs_from: float, fs_to: float) -> np.ndarray:
    """``X [channels, samples]`` at ``fs_from`` -> at ``fs_to`` (Hz), polyphase with SciPy's
    anti-aliasing filter; the ratio is taken to 1 part in 1000."""
    from fractions import Fraction

    from scipy.signal import resample_poly

    ratio = Fraction(fs_to / fs_from).limit_denominator(1000)
    out = resample_poly(X.astype(np.float64), ratio.numerator, ratio.denominator, axis=1)
    return np.ascontiguousarray(out, dtype=np.float32)


def _read_one(p: Path) -> _Recording:
    """One recording file -> :class:`_Recording`; irregular timestamps are resampled onto a
    uniform grid (:func:`_uniform`)."""
    if p.suffix.lower() == ".npy":
        return _read_npy(p)
    table = read_table(p)
    names, values = table.names, table.values
    tcol, unit, how = _time_column(table)
    notes = list(table.notes)
    counter = _counter_column(table, tcol)
    if counter is not None:
        notes.append(f"column {names[counter]!r} holds row numbers (dropped)")
    chans = [i for i in range(len(names)) if i not in (tcol, counter)]
    if not chans:
        raise ValueError(f"{p}: only a time column ({names[tcol]!r}); a recording needs at "
                         "least one channel column")  # fmt: skip
    X = np.ascontiguousarray(values[:, chans].T, dtype=np.float32)
    if not table.header:
        notes.append("no header line: channels named col1, col2, ... by position")
    if how == "index":
        notes.append(f"column {names[tcol]!r} holds sample numbers (dropped; no rate)")
    if tcol is None or how == "index" or len(values) < 2:
        return _Recording(X, [names[i] for i in chans], None, "", notes=notes)
    t = values[:, tcol]
    line_numbers = table.line_numbers
    dt = np.diff(t)
    if (dt < 0).any():
        raise ValueError(f"{p}: the timestamps ({names[tcol]}) must increase (line "
                         f"{line_numbers[int(np.argmax(dt < 0)) + 1]} goes back in time)")  # fmt: skip
    if (dt == 0).any():  # a repeated row (seen at the end of real recordings): keep the first
        keep = np.r_[True, dt > 0]
        X, t = np.ascontiguousarray(X[:, keep]), t[keep]
    if len(t) < 2:
        return _Recording(X, [names[i] for i in chans], None, "", notes=notes)
    if how == "by value":
        notes.append(f"column {names[tcol]!r} taken as time (steadily increasing values)")
    rate_from = f"column {names[tcol]!r}"
    if unit is None:
        unit, rate_from = _tick_unit(t)
    X3, _, jitter, resampled = _uniform(X[None], t[None], p)  # in ticks: the grid exact
    fs = (1.0 / unit) / float(np.median(np.diff(t)))
    return _Recording(X3[0], [names[i] for i in chans], fs, rate_from, jitter, bool(resampled),
                      notes)  # fmt: skip


def _read_npy(p: Path) -> _Recording:
    """A ``.npy`` recording ``[samples, channels]``, its header checked before its data is read."""
    try:
        with open(p, "rb") as f:
            shape, dtype = npy_header(f)
    except (ValueError, OSError, EOFError) as e:
        raise ValueError(f"{p}: not a .npy array ({e})") from None
    if len(shape) != 2 or dtype.kind not in "fiu":
        raise ValueError(f"{p}: a recording .npy must be numeric [samples, channels], got "
                         f"{dtype} {tuple(shape)}")  # fmt: skip
    need = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
    if need > p.stat().st_size:
        raise ValueError(f"{p}: its header declares {tuple(shape)} {dtype} ({need} bytes) but "
                         f"the file holds {p.stat().st_size} bytes (truncated or forged)")  # fmt: skip
    check_allocation(4 * int(np.prod(shape, dtype=np.float64)), f"the recording {p}")
    try:
        a = np.load(p, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise ValueError(f"{p}: not a readable .npy array ({e})") from None
    X = np.ascontiguousarray(a.T, dtype=np.float32)
    if not np.isfinite(X).all():
        r, c = np.argwhere(~np.isfinite(X.T))[0]
        raise ValueError(f"{p}: non-finite value at sample {r}, channel {c}")
    return _Recording(X, [f"ch{i}" for i in range(a.shape[1])], None, "")


def _time_column(table: Table) -> tuple[int | None, float | None, str]:
    """``(column, seconds per unit or None, how)`` of the table's time column: by name (its unit
    from the name, e.g. ``time_ms``), else a first column of steadily increasing values; a
    counter stepping by exactly 1 (or named like one) is a sample number (``how == 'index'``)."""
    for j, name in enumerate(table.names):
        m = TIME_NAME.match(name.strip())
        if m:
            unit = m.group("unit")
            return j, (UNITS[unit.lower().replace("µ", "u")] if unit else None), "named"
    if table.names and table.names[0].strip().lower() in INDEX_NAMES:
        return 0, None, "index"
    t = table.values[:, 0]
    if len(t) < 3 or table.values.shape[1] < 2:
        return None, None, ""
    dt = np.diff(t)
    if (dt <= 0).any():
        return None, None, ""
    med = float(np.median(dt))
    if float(np.median(np.abs(dt - med))) > 0.25 * med:
        return None, None, ""  # increasing but not steadily: a channel
    if (dt == 1).all() and (t == np.round(t)).all():
        return 0, None, "index"
    return 0, None, "by value"


def _counter_column(table: Table, tcol: int | None) -> int | None:
    """A first column beside a named time column that numbers the rows: named like a counter
    (``sample``, ``index``...) or unnamed (pandas' row index) and counting up by 1; None if
    there is none."""
    if tcol in (None, 0) or not table.names:
        return None
    name = table.names[0].strip().lower()
    if name not in INDEX_NAMES and name != "":
        return None
    c = table.values[:, 0]
    return 0 if len(c) < 2 or bool((np.diff(c) == 1).all()) else None


def _tick_unit(t: np.ndarray) -> tuple[float, str]:
    """Seconds per unit of timestamps whose unit no name states: fractional steps under 1 are
    seconds; epoch times are recognised by their size (s, ms, us, ns since 1970); other
    integer ticks are taken as ms, us or ns, whichever puts the rate between 10 Hz and 100 kHz
    first (``how == 'ticks'``: the run's printout says so, and ``--fs`` states the rate)."""
    step = float(np.median(np.diff(t)))
    if step < 1.0:
        return 1.0, "seconds"
    t0 = abs(float(t[0]))
    for exponent, unit in ((9, 1.0), (12, 1e-3), (15, 1e-6), (18, 1e-9)):
        if 1.0 * 10**exponent <= t0 < 1e1 * 10**exponent:  # 2001-2286 in that unit
            return unit, "epoch time"
    if step == 1.0:  # whole seconds of a 1 Hz logger, or a 1 kHz clock's ms: the name must say
        return 1e-3, WHOLE_UNITS
    for unit in (1e-3, 1e-6, 1e-9):
        if step * unit <= 0.1:
            return unit, "ticks"
    return 1e-9, "ticks"
