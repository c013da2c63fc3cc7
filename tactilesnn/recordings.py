"""User recordings in the documented ``.npz`` format -> train / test :class:`WindowDataset`.

Format: ``X`` ``[N, channels, samples]`` float (the sensor's units), ``y`` ``[N]`` int, ``fs``
(Hz, scalar), ``class_names`` ``[C]`` str; optional ``channel_names`` ``[channels]`` str,
``recording`` ``[N]`` (windows of one recording share it: they stay on one side of every split, and
scores are also accumulated per recording) and ``split`` ``[N]`` (0 = train, 1 = test). Read with
``allow_pickle=False``. Event data: ``X`` ``[N, taxels, polarity, bins]`` (events per bin) with
``bin_ms`` instead of ``fs`` (see :func:`events_as_channels`; train with ``--encoder events``) and
optionally ``grid`` ``[rows, cols]`` (row-major taxels; a square taxel count is taken as square) or
``taxel_xy`` ``[taxels, 2]`` (mm, any layout and order: placed on a grid by
:func:`~tactilesnn.core.layout.place_on_grid`).
Sensors at other sampling rates in the same recordings: ``X@<name>`` ``[N, channels, samples]``
with ``fs@<name>`` (and optionally ``channel_names@<name>``) covering the same time span; they are
resampled to ``fs`` and appended as channels ``<name>:<channel>`` (see :func:`merge_streams`).
"""

from __future__ import annotations

import logging
import math
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from .core.checks import (
    check_allocation,
    check_finite,
    check_float32_range,
    check_positive,
    check_rate,
)
from .core.data import GROUP_PREFIX, DataFacts, WindowDataset, condition_text
from .core.files import npy_header
from .core.layout import check_taxel_xy, place_on_grid

log = logging.getLogger("tactilesnn")


def load_data_file(
    path: Path,
    seed: int = 0,
    test_fraction: float = 0.2,
    window_s: float | None = None,
    hop_s: float | None = None,
    fs_hz: float | None = None,
    hold_out: str | None = None,
) -> tuple[WindowDataset, WindowDataset]:
    """Recordings in the documented format, or a folder written by ``tactilesnn generate``
    (:func:`~tactilesnn.core.dataset_folder.read_dataset_folder`) -> ``(train, test)``
    window datasets.

    ``.npz`` with ``X`` ``[N, channels, samples]`` real numbers, ``y`` ``[N]`` integer labels,
    ``fs`` (Hz, one number), ``class_names`` ``[C]`` str; optionally ``channel_names``,
    ``recording`` ``[N]`` (int or str: windows cut from one recording share it, and never straddle
    train / validation / test) and ``split`` ``[N]`` (0 = train, 1 = test). Without ``split``,
    ``test_fraction`` of the recordings (stratified by class, from ``seed``) is held out.
    ``window_s`` (and ``hop_s``): after the split, cut every recording into windows of that
    length (:func:`cut_windows`); they keep their recording's id, so scores are also accumulated
    per recording; with ``class_signal`` ``[N, samples]`` in the data (a generated folder of a
    task that renders it), each window's share of it is its confidence. ``fs_hz``: the
    sampling rate (Hz) of a folder of recordings without timestamps (``--fs``); where the data
    states its rate, a different ``fs_hz`` is refused. ``hold_out``: the test split is the
    recordings of the conditions it names (``"F>=180"``; :func:`hold_out_mask`), the training
    split the others.
    """
    if window_s is None and hop_s is not None:
        raise ValueError("a hop (--data-hop-s) needs a window length (--data-window-s)")
    arrays = read_data_arrays(Path(path), fs_hz)
    return datasets_from_arrays(arrays, path, seed, test_fraction,
                                None if window_s is None else (window_s, hop_s),
                                hold_out=hold_out)  # fmt: skip


#: channels (taxels x polarities for events) a recordings file may hold
MAX_CHANNELS = 1 << 20
#: polarities of an event file
MAX_POLARITIES = 16


def check_sizes(shape: tuple[int, ...], path: Path | str) -> None:
    """Refuse an ``X`` with no window, no sample, or more channels / polarities than any
    sensor has, before anything is built from its sizes (names, encoders)."""
    if len(shape) not in (3, 4):
        return  # the reader names the expected layouts
    if shape[0] == 0 or shape[-1] == 0 or 0 in shape[1:-1]:
        raise ValueError(f"{path}: X holds no data (shape {tuple(shape)})")
    if len(shape) == 4 and shape[2] > MAX_POLARITIES:
        raise ValueError(f"{path}: {shape[2]} polarities (at most {MAX_POLARITIES}); event files "
                         "are X [N, taxels, polarity, bins]")  # fmt: skip
    channels = int(np.prod(shape[1:-1], dtype=np.float64))
    if channels > MAX_CHANNELS:
        raise ValueError(f"{path}: {channels} channels (at most {MAX_CHANNELS})")


#: members of an .npz file a reader looks at; more is not a recordings file
MAX_MEMBERS = 1024
#: longest class or channel name (characters)
MAX_NAME_CHARS = 200


def check_npz_size(path: Path) -> None:
    """Refuse, from the zip directory and each array's header alone, a file whose arrays would
    not fit in memory (a header may declare terabytes over a tiny body; a compressed member may
    expand a thousandfold): a clear error before any array is read."""
    total = 0
    try:
        with zipfile.ZipFile(path) as z:
            infos = z.infolist()
            if len(infos) > MAX_MEMBERS:
                raise ValueError(f"{path}: {len(infos)} members; a recordings file has a few")
            names = [i.filename for i in infos]
            twice = sorted({n for n in names if names.count(n) > 1})
            if twice:  # which copy a reader takes is up to the reader: refuse, never guess
                raise ValueError(f"{path}: the archive holds {twice[0]!r} {names.count(twice[0])} "
                                 "times; an .npz has each array once (rewrite it with np.savez)")  # fmt: skip
            keys = [n.removesuffix(".npy") for n in names]  # numpy names "X.npy" and "X" alike
            same = sorted({k for k in keys if keys.count(k) > 1})
            if same:
                both = [n for n in names if n.removesuffix(".npy") == same[0]]
                raise ValueError(f"{path}: members {' and '.join(map(repr, both))} are both the "
                                 f"array {same[0]!r}; keep one (rewrite the file with np.savez)")  # fmt: skip
            shapes: dict[str, tuple[int, ...]] = {}
            for info in infos:
                _check_member(info, path)
                size = info.file_size  # the uncompressed size the directory declares
                if info.filename.endswith(".npy"):
                    shape, dtype = _npy_header(z, info.filename)
                    shapes[info.filename[:-4]] = tuple(shape)
                    size = max(size, int(np.prod(shape, dtype=np.float64)) * dtype.itemsize)
                total += size
            _check_lengths(shapes, path)
    except zipfile.BadZipFile as e:
        raise ValueError(f"{path}: not a readable .npz file ({e})") from e
    except (OSError, EOFError, RuntimeError, NotImplementedError) as e:
        raise ValueError(f"{path}: not a readable .npz file ({e})") from e
    check_allocation(total, f"the arrays of {path} (as their headers declare them)")


#: the zip compressions numpy's loader reads (stored, deflate, bzip2, lzma)
ZIP_METHODS = (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED, zipfile.ZIP_BZIP2, zipfile.ZIP_LZMA)
#: arrays with one entry per window, whose length must be X's
PER_WINDOW = ("y", "recording", "split", "scan")


def _check_member(info: zipfile.ZipInfo, path: Path) -> None:
    """A member numpy can read: not encrypted, compressed by a method it knows."""
    if info.flag_bits & 0x1:
        raise ValueError(f"{path}: member {info.filename!r} is encrypted; save the arrays "
                         "without a password (np.savez)")  # fmt: skip
    if info.compress_type not in ZIP_METHODS:
        raise ValueError(f"{path}: member {info.filename!r} is compressed with zip method "
                         f"{info.compress_type}, which numpy cannot read; rewrite the file with "
                         "np.savez or np.savez_compressed")  # fmt: skip


def _check_lengths(shapes: dict[str, tuple[int, ...]], path: Path) -> None:
    """Per-window arrays (``y``, ``recording``, ``split``, ``group_*``) as long as ``X`` (from
    the headers, before a byte of them is read)."""
    if "X" not in shapes or not shapes["X"]:
        return
    n = shapes["X"][0]
    if n == 0:
        raise ValueError(f"{path}: X holds no data (0 windows, shape {shapes['X']})")
    for name, shape in shapes.items():
        if name in PER_WINDOW or name.startswith(GROUP_PREFIX):
            if len(shape) != 1 or shape[0] != n:
                raise ValueError(f"{path}: {name!r} must hold one value per window of X ({n}), "
                                 f"its header declares the shape {shape}")  # fmt: skip


def _npy_header(z: zipfile.ZipFile, member: str) -> tuple[tuple[int, ...], np.dtype]:
    with z.open(member) as f:
        try:
            return npy_header(f)
        except ValueError as e:
            raise ValueError(f"member {member}: not a .npy array ({e})") from e


def _names(values: object, what: str, path: Path | str) -> tuple[str, ...]:
    """Distinct, non-empty names of bounded length (class or channel names)."""
    names = tuple(str(c) for c in np.atleast_1d(values))
    bad = [n for n in names if not n.strip() or len(n) > MAX_NAME_CHARS]
    if bad:
        raise ValueError(f"{path}: {what} must be non-empty and at most {MAX_NAME_CHARS} "
                         f"characters, got {bad[0][:40]!r}")  # fmt: skip
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise ValueError(f"{path}: {what} holds duplicates {dup[:5]}")
    return names


def read_data_arrays(path: Path, fs_hz: float | None = None) -> dict[str, np.ndarray]:
    """The arrays of the documented format from ``path``: an ``.npz`` (converted when it holds
    timestamps instead of ``fs``), a folder written by ``tactilesnn generate``, or a folder of
    recordings as they come (:mod:`tactilesnn.readers`). ``fs_hz``: the rate (Hz) the user
    states (``--fs``): required for recordings without timestamps, checked against any rate
    the data states."""
    from .readers import needs_reading, read_recordings

    path = Path(path)
    if fs_hz is not None and not (math.isfinite(fs_hz) and fs_hz > 0):
        raise ValueError(f"--fs must be a positive number of Hz, got {fs_hz}")
    if fs_hz is not None:
        check_rate(fs_hz, "--fs")
    if path.is_dir():
        if needs_reading(path):
            arrays, conv = read_recordings(path, fs_hz=fs_hz)
            log.info("read %s", conv.line())
            return arrays
        from .core.dataset_folder import read_dataset_folder

        return _check_stated_rate(read_dataset_folder(path), fs_hz, path)
    if not path.exists():
        raise FileNotFoundError(f"data file {path} does not exist")
    if not path.is_file():
        raise ValueError(f"{path}: not a regular file (a device, FIFO or socket, or a link to "
                         "one); give the .npz file or folder of recordings itself")  # fmt: skip
    if path.suffix.lower() in (".csv", ".tsv", ".npy", ".txt"):
        raise ValueError(f"{path}: one {path.suffix} file is one recording; --data takes a folder "
                         "of them (one recording per file, labelled by sub-folder or by the file "
                         "name up to the first _), or an .npz (see README)")  # fmt: skip
    check_npz_size(path)  # from the headers, before any array is read
    try:
        with np.load(path, allow_pickle=False) as f:
            arrays = {k: np.asarray(f[k]) for k in f.files}
    except (OSError, ValueError, EOFError, RuntimeError, NotImplementedError,
            zipfile.BadZipFile) as e:  # fmt: skip
        raise ValueError(f"{path}: not a readable .npz file ({e})") from e
    if needs_reading(path, set(arrays)):
        arrays, conv = read_recordings(path, arrays, fs_hz)
        log.info("read %s", conv.line())
        return arrays
    return _check_stated_rate(arrays, fs_hz, path)


def _classes_from_labels(y: np.ndarray, path: Path | str) -> dict[str, np.ndarray]:
    """``y`` and ``class_names`` from labels alone (a file without ``class_names``): integer
    labels keep their values as names (``0..C-1`` stay as they are; other values are numbered in
    sorted order), text labels are numbered in sorted order."""
    y = np.asarray(y)
    if y.ndim != 1 or y.dtype.kind not in "iuUS":
        return {}  # the loader names what is wrong with y
    values, idx = np.unique(y, return_inverse=True)
    names = [v.decode(errors="replace") if isinstance(v, bytes) else str(v) for v in values]
    log.info("%s: no class_names; %d classes named by the labels' values (%s)", path,
             len(names), ", ".join(names[:6]) + (" ..." if len(names) > 6 else ""))  # fmt: skip
    return {"y": idx.astype(np.int64), "class_names": np.array(names)}


def _check_stated_rate(arrays: dict[str, np.ndarray], fs_hz: float | None, path: Path
                       ) -> dict[str, np.ndarray]:  # fmt: skip
    """``--fs`` where the data states its rate: the same rate, else a refusal."""
    if fs_hz is None or "fs" not in arrays:
        return arrays
    try:
        stated = float(np.asarray(arrays["fs"], np.float64).reshape(-1)[0])
    except (TypeError, ValueError, IndexError):
        return arrays  # the loader names what is wrong with fs
    if abs(stated - fs_hz) > 0.01 * fs_hz:
        raise ValueError(f"{path} states fs = {stated:g} Hz; --fs says {fs_hz:g} Hz: drop --fs "
                         "(the file's rate is used) or correct the file")  # fmt: skip
    return arrays


def cut_windows(ds: WindowDataset, window_s: float, hop_s: float | None = None,
                class_signal: np.ndarray | None = None) -> WindowDataset:  # fmt: skip
    """Cut each recording ``[C, S]`` into windows of ``round(window_s * fs)`` samples, one every
    ``round(hop_s * fs)`` samples (default: half a window); the tail shorter than a window is
    dropped. Each window keeps its recording's label and id (``scan``), so its windows stay on
    one side of a split and their scores can be summed per recording, and its confidence.
    ``class_signal`` ``[N, S]`` (>= 0, any unit: the magnitude of the recording's class's own
    signal per sample, as a renderer knows it) sets each window's confidence instead: its share
    of its recording's signal over :data:`FULL_CONFIDENCE_SHARE`, at most 1 (a recording
    without any: 1)."""
    window_s = check_positive(window_s, "the window length (--data-window-s, seconds)")
    hop_s = window_s / 2 if hop_s is None else check_positive(hop_s, "the hop (--data-hop-s)")
    n_win = round(window_s * ds.fs_hz)
    hop = max(1, round(hop_s * ds.fs_hz))
    n, c, s = ds.X.shape
    if n_win < 2 or n_win > s:
        raise ValueError(
            f"a {window_s} s window is {n_win} samples at {ds.fs_hz:g} Hz; it must be 2..{s} "
            f"(the recordings' length, {s / ds.fs_hz:g} s)"
        )
    starts = np.arange(0, s - n_win + 1, hop)
    check_allocation(n * starts.size * c * n_win * ds.X.itemsize, "the cut windows")
    view = np.lib.stride_tricks.sliding_window_view(ds.X, n_win, axis=2)[:, :, starts]
    X = np.ascontiguousarray(view.transpose(0, 2, 1, 3)).reshape(-1, c, n_win)
    rep = np.repeat(np.arange(n), starts.size)
    log.info("cut %d recordings into %d windows of %d samples (hop %d)", n, X.shape[0], n_win, hop)
    conf = None if ds.confidence is None else ds.confidence[rep]
    if class_signal is not None:
        conf = window_confidence(class_signal, n, s, n_win, starts)
    return WindowDataset(X, ds.y[rep], ds.scan[rep], ds.fs_hz, ds.class_names, ds.channel_names,
                         confidence=conf, facts=ds.facts, conditions=ds.conditions)  # fmt: skip


#: a window holding this share of its recording's class signal (or more) is trained on its
#: label alone; one holding less, on a mixture of its label and the uniform target. iCub
#: Braille, calibrated model, LIF code, one seed, k = 1 and 2 (six draws; docs/sim2real.md):
#: synthetic only per slide 60.2 % with hard labels, 71.9 % at 0.1, 71.4 % at 0.25
FULL_CONFIDENCE_SHARE = 0.1


def window_confidence(class_signal: np.ndarray, n: int, samples: int, n_win: int,
                      starts: np.ndarray) -> np.ndarray:  # fmt: skip
    """Per window (recording-major, as :func:`cut_windows` orders them): its share of its
    recording's ``class_signal [n, samples]`` over :data:`FULL_CONFIDENCE_SHARE`, clipped to
    [0, 1]; 1 for a recording whose signal is all zero. float32 ``[n * len(starts)]``."""
    sig = np.asarray(class_signal, np.float64)
    if sig.shape != (n, samples) or not np.all(np.isfinite(sig)) or np.any(sig < 0):
        raise ValueError(f"class_signal must be [{n}, {samples}] finite and >= 0, got "
                         f"{sig.shape}")  # fmt: skip
    c = np.concatenate([np.zeros((n, 1)), np.cumsum(sig, 1)], 1)
    part = c[:, starts + n_win] - c[:, starts]  # [n, windows]
    total = c[:, -1:]
    share = np.divide(part, total, out=np.ones_like(part), where=total > 0)
    return np.clip(share / FULL_CONFIDENCE_SHARE, 0.0, 1.0).astype(np.float32).reshape(-1)


def expected_class_signal(signal: np.ndarray, signal_y: np.ndarray,
                          y: np.ndarray) -> np.ndarray:  # fmt: skip
    """For recordings whose class's signal nobody measured (real ones, labels ``y [N]``): the
    mean over the rendered recordings of the same class of their class signal ``signal [M,
    S]`` (labels ``signal_y [M]``), float32 ``[N, S]``: what :func:`cut_windows`'s
    ``class_signal`` turns into window confidences. It assumes the recordings follow the
    rendered trials' protocol (the same rate, length and timing: a calibrated model's slides
    rendered at the recordings' rate and length, whose timing the fit matched to them)."""
    sig = np.asarray(signal, np.float64)
    sy, y = np.asarray(signal_y), np.asarray(y)
    if sig.ndim != 2 or sy.shape != (sig.shape[0],):
        raise ValueError(f"signal must be [M, samples] with one label each, got {sig.shape} "
                         f"and {sy.shape} labels")  # fmt: skip
    if not np.all(np.isfinite(sig)) or np.any(sig < 0):
        raise ValueError("signal must be finite and >= 0")
    missing = sorted(set(np.unique(y).tolist()) - set(sy.tolist()))
    if missing:
        raise ValueError(f"no rendered recording of class(es) {missing} to take the signal from")
    if y.size == 0:
        return np.zeros((0, sig.shape[1]), np.float32)
    means = {c: sig[sy == c].mean(0) for c in np.unique(y).tolist()}
    return np.stack([means[c] for c in y.tolist()]).astype(np.float32).reshape(len(y), -1)


def datasets_from_arrays(
    arrays: dict[str, np.ndarray], path: Path | str, seed: int, test_fraction: float = 0.2,
    window: tuple[float, float | None] | None = None, hold_out: str | None = None,
) -> tuple[WindowDataset, WindowDataset]:  # fmt: skip
    """:func:`load_data_file` on arrays already in memory (``path`` names them in errors);
    ``window``: ``(window_s, hop_s)`` to cut each split into (:func:`cut_windows`, with the
    recordings' ``class_signal`` where the arrays hold one); ``hold_out``: the test split is the
    recordings whose condition matches (:func:`hold_out_mask`: ``"F>=180"``, ``"run=3,4"``)."""
    if "X" in arrays:
        check_sizes(np.shape(arrays["X"]), path)
    facts = DataFacts(False)
    if "X" in arrays and arrays["X"].ndim == 4:  # events [N, taxels, polarity, bins]
        layout = layout_of(arrays["X"].shape[1], arrays.get("taxel_xy"), arrays.get("grid"), path)
        facts = DataFacts(True, *(layout or (None, ())))
        arrays = events_as_channels(arrays, path)
    if any(k.startswith("X@") for k in arrays):
        arrays = merge_streams(arrays, path)
    missing = [k for k in ("X", "y", "fs") if k not in arrays]
    if missing:
        raise ValueError(
            f"{path}: missing {missing}; expected X [N, channels, samples], y [N], fs and "
            "optionally class_names"
        )
    if "class_names" not in arrays:
        arrays = {**arrays, **_classes_from_labels(arrays["y"], path)}
    X, y_raw, fs_arr = arrays["X"], arrays["y"], arrays["fs"]
    if X.dtype.kind not in "fiu":
        raise ValueError(f"{path}: X must hold real numbers, got dtype {X.dtype}")
    if X.ndim != 3:
        raise ValueError(f"{path}: X must be [N, channels, samples], got shape {X.shape}")
    if X.shape[0] == 0 or X.shape[1] == 0 or X.shape[2] < 2:
        raise ValueError(f"{path}: X needs >= 1 window, channel and >= 2 samples, got {X.shape}")
    if fs_arr.size != 1 or fs_arr.dtype.kind not in "fiu":
        raise ValueError(f"{path}: fs must be one sampling rate in Hz, got {fs_arr!r}")
    fs = float(fs_arr.reshape(()))
    if not np.isfinite(fs) or fs <= 0:
        raise ValueError(f"{path}: fs must be a positive sampling rate in Hz, got {fs}")
    check_rate(fs, f"{path}: fs")
    if y_raw.shape != (X.shape[0],):
        raise ValueError(f"{path}: y must be [N={X.shape[0]}], got shape {y_raw.shape}")
    if y_raw.dtype.kind not in "iu":
        if y_raw.dtype.kind != "f" or not np.array_equal(y_raw, np.round(y_raw)):
            raise ValueError(f"{path}: y must hold integer class indices, got dtype {y_raw.dtype}")
    y = y_raw.astype(np.int64)
    names = _names(arrays["class_names"], "class_names", path)
    if len(names) < 2:
        raise ValueError(f"{path}: class_names must name at least two classes")
    if y.min() < 0 or y.max() >= len(names):
        raise ValueError(f"{path}: labels must index class_names (0..{len(names) - 1})")
    ch = tuple(f"ch{i}" for i in range(X.shape[1]))
    if "channel_names" in arrays:
        ch = _names(arrays["channel_names"], "channel_names", path)
        if len(ch) != X.shape[1]:
            raise ValueError(f"{path}: channel_names must be {X.shape[1]} distinct names")
    if X.dtype.kind == "f":  # checked in place: a float64 copy of a large file would double it
        check_finite(X, f"{path}: X")
        check_float32_range(X, f"{path}: X")
    groups = recording_ids(arrays.get("recording"), y.size, path)
    conditions = read_conditions(arrays, groups, path)
    if hold_out is not None:
        if "split" in arrays:
            raise ValueError(f"{path}: the file gives its own split; drop --hold-out or the split")
        split = hold_out_mask(hold_out, conditions, groups, path).astype(np.int64)
        if split.all() or not split.any():
            raise ValueError(f"{path}: --hold-out {hold_out} leaves "
                             f"{'no training' if split.all() else 'no test'} recording")  # fmt: skip
    else:
        split = _split(arrays, y, groups, test_fraction, seed, path)

    signal = _class_signal(arrays, X.shape, path)
    _check_split_memory(X, split, fs, window, path)

    def take(m: np.ndarray) -> WindowDataset:
        ds = WindowDataset(rows_as_float32(X, m), y[m], groups[m], fs, names, ch, facts=facts,
                           conditions=conditions)  # fmt: skip
        if window is None:
            return ds
        return cut_windows(ds, *window, class_signal=None if signal is None else signal[m])

    return take(split == 0), take(split == 1)


def _check_split_memory(X: np.ndarray, split: np.ndarray, fs: float,
                        window: tuple[float, float] | None, path: Path | str) -> None:  # fmt: skip
    """Refuse, before any copy, splits whose float32 rows and cut windows would not fit beside
    the recordings already read (each part is checked alone later; together they may not)."""
    _, c, s = X.shape
    per_row = 4 * c * s
    if window is not None:
        n_win, hop = round(window[0] * fs), max(1, round((window[1] or window[0] / 2) * fs))
        if 2 <= n_win <= s:
            per_row += 4 * c * n_win * (1 + (s - n_win) // hop)
    rows = max(int((split == 0).sum()), int((split == 1).sum()))
    check_allocation(X.nbytes + rows * per_row, f"{path}: the recordings, a split's float32 copy "
                     "and its cut windows together", fraction=0.9)  # fmt: skip


def read_conditions(arrays: dict[str, np.ndarray], groups: np.ndarray,
                    path: Path | str) -> dict[str, dict[int, Any]] | None:  # fmt: skip
    """The file's ``group_<name> [N]`` arrays as ``{name: {recording id: value}}`` (numbers or
    text; one value per recording, else ValueError), or None where it states none."""
    out: dict[str, dict[int, Any]] = {}
    for key in sorted(k for k in arrays if k.startswith(GROUP_PREFIX)):
        name, v = key[len(GROUP_PREFIX) :], np.asarray(arrays[key])
        if not name or v.shape != groups.shape or v.dtype.kind not in "fiuUS":
            raise ValueError(f"{path}: {key} must be [N={groups.size}] numbers or names, one "
                             f"per row, got {v.dtype} {v.shape}")  # fmt: skip
        table: dict[int, Any] = {}
        for g, value in zip(groups.tolist(), v.tolist(), strict=True):
            if table.setdefault(g, value) != value:
                raise ValueError(f"{path}: {key} gives recording {g} two values "
                                 f"({table[g]!r}, {value!r}); a condition is the recording's")  # fmt: skip
        out[name] = table
    return out or None


#: ``--hold-out`` forms: ``NAME=V1,V2`` (those values) or ``NAME>=X`` (and ``>``, ``<=``, ``<``)
HOLD_OUT = re.compile(r"^\s*(?P<name>[A-Za-z_]\w*)\s*(?P<op>>=|<=|=|>|<)\s*(?P<values>.+?)\s*$")


def hold_out_mask(spec: str, conditions: dict[str, dict[int, Any]] | None, groups: np.ndarray,
                  path: Path | str) -> np.ndarray:  # fmt: skip
    """Which rows' recordings ``spec`` holds out for testing: ``NAME=V1,V2`` (the values, as
    text or numbers) or a bound on a numeric condition, ``NAME>=X`` / ``>`` / ``<=`` / ``<``."""
    m = HOLD_OUT.match(spec)
    if m is None:
        raise ValueError(f"--hold-out {spec!r}: expected NAME=V1,V2 or NAME>=X (>, <=, <)")
    name, op, text = m.group("name"), m.group("op"), m.group("values")
    table = (conditions or {}).get(name)
    if table is None:
        raise ValueError(f"--hold-out {spec}: {path} states no condition {name!r} (it states "
                         f"{sorted(conditions or {}) or 'none'}: group_<name> arrays, or fields "
                         "of the file names such as F150)")  # fmt: skip
    values = np.asarray([table[g] for g in groups.tolist()])
    if op == "=":
        wanted = [w.strip() for w in text.split(",")]
        as_text = np.asarray([condition_text(v) for v in values])
        mask = np.isin(as_text, [condition_text(w) for w in wanted])
        missing = sorted(set(map(condition_text, wanted)) - set(as_text.tolist()))
        if missing:
            raise ValueError(f"--hold-out {spec}: no recording has {name} = {', '.join(missing)} "
                             f"(values: {', '.join(sorted(set(as_text.tolist()))[:12])})")  # fmt: skip
        return mask
    if values.dtype.kind not in "fiu":
        raise ValueError(f"--hold-out {spec}: {name} holds names, not numbers: use {name}=A,B")
    try:
        bound = float(text)
    except ValueError:
        raise ValueError(f"--hold-out {spec}: {text!r} is not a number") from None
    compare = {">=": np.greater_equal, ">": np.greater, "<=": np.less_equal, "<": np.less}[op]
    return compare(values.astype(np.float64), bound)


def _split(arrays: dict[str, np.ndarray], y: np.ndarray, groups: np.ndarray, test_fraction: float,
           seed: int, path: Path | str) -> np.ndarray:  # fmt: skip
    """``[N]`` 0 (train) / 1 (test): the file's ``split`` (checked: both sets, no recording in
    both), else ``test_fraction`` of the recordings by class from ``seed``."""
    split = arrays.get("split")
    if split is None:
        return split_by_recording(y, groups, test_fraction, seed)
    split = np.asarray(split)
    if split.shape != y.shape or not np.isin(split, (0, 1)).all():
        raise ValueError(f"{path}: split must be [N] of 0 (train) / 1 (test)")
    if not ((split == 0).any() and (split == 1).any()):
        raise ValueError(f"{path}: split must put windows in both train (0) and test (1)")
    straddle = np.intersect1d(groups[split == 0], groups[split == 1])
    if straddle.size and "recording" in arrays:
        raise ValueError(f"{path}: split puts recording(s) {straddle[:5].tolist()} in both sets")
    return split


def _class_signal(arrays: dict[str, np.ndarray], shape: tuple[int, ...],
                  path: Path | str) -> np.ndarray | None:  # fmt: skip
    """The optional ``class_signal [N, samples]`` (>= 0, finite: how much of each sample is the
    class's own signal, as a renderer knows it; ``tactilesnn generate`` writes it for tasks
    that can render a trial without its class), checked against ``X``."""
    sig = arrays.get("class_signal")
    if sig is None:
        return None
    sig = np.asarray(sig)
    if sig.shape != (shape[0], shape[-1]) or sig.dtype.kind not in "fiu":
        raise ValueError(f"{path}: class_signal must be [N={shape[0]}, samples={shape[-1]}] "
                         f"numbers, got {sig.shape} {sig.dtype}")  # fmt: skip
    if not np.all(np.isfinite(sig)) or np.any(sig < 0):
        raise ValueError(f"{path}: class_signal must be finite and >= 0")
    return sig


#: recordings at least this long (and of ``AUTO_CUT_MIN_SAMPLES``) are cut by default
AUTO_CUT_MIN_S = 2.0
AUTO_CUT_MIN_SAMPLES = 256


#: rows converted to float32 at a time when a split is taken from another dtype
CONVERT_ROWS_BYTES = 32 << 20


def rows_as_float32(X: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``X[mask]`` as float32, converted a block of rows at a time: the split of a file of
    another dtype (ST-MNIST's uint8 counts, float64 recordings) without a float32 copy of the
    whole file first (that copy was 556 MB of ST-MNIST's 2.33 GB peak)."""
    idx = np.flatnonzero(mask)
    if X.dtype == np.float32:
        return X[idx]
    out = np.empty((idx.size, *X.shape[1:]), np.float32)
    step = max(1, CONVERT_ROWS_BYTES // max(1, int(np.prod(X.shape[1:])) * 4))
    for i in range(0, idx.size, step):
        out[i : i + step] = X[idx[i : i + step]]
    return out


def auto_cut(samples: int, fs_hz: float, has_recording_ids: bool) -> tuple[float, float] | None:
    """The default cut of ``train --data`` (``(window_s, hop_s)``, or None for whole rows):
    analog rows without ``recording`` ids lasting >= 2 s and >= 256 samples are cut into windows
    of a quarter of a row every eighth (7 windows per recording, scores summed per recording), so
    a long recording becomes a sequence of windows rather than one."""
    if has_recording_ids or samples < AUTO_CUT_MIN_SAMPLES or samples / fs_hz < AUTO_CUT_MIN_S:
        return None
    window = samples // 4
    return window / fs_hz, (window // 2) / fs_hz


def auto_window(path: Path) -> tuple[float, float] | None:
    """:func:`auto_cut` for the analog ``.npz`` at ``path`` (reads only headers and ``fs``)."""
    if not Path(path).is_file():  # a FIFO or device: the loader refuses it by name
        return None
    try:
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
        has_ids = "recording.npy" in names
        shape = _npy_shape(path, "X.npy")
        with np.load(path, allow_pickle=False) as f:
            if "fs.npy" in names:
                fs, samples = float(np.asarray(f["fs"]).reshape(-1)[0]), shape[-1]
            else:  # timestamps instead of a rate (converted by the reader)
                t = np.asarray(f["t"] if "t.npy" in names else f["timestamps"], np.float64)
                fs, samples = 1.0 / float(np.median(np.diff(t, axis=-1))), t.shape[-1]
    except (OSError, KeyError, ValueError, IndexError, RuntimeError, NotImplementedError,
            zipfile.BadZipFile):  # fmt: skip
        return None  # the loader reports what is wrong with the file
    if len(shape) != 3 or not np.isfinite(fs) or fs <= 0:
        return None
    return auto_cut(samples, fs, has_ids)


def _npy_shape(path: Path, member: str) -> tuple[int, ...]:
    """Shape of ``member`` of the ``.npz`` at ``path`` from its header (no data read)."""
    with zipfile.ZipFile(path) as z, z.open(member) as f:
        return npy_header(f)[0]


def event_layout(path: Path) -> tuple[str, tuple[int, ...]] | None:
    """``(grid "ROWSxCOLS", cells)`` of an event file's taxels (headers and the small arrays
    only; :func:`layout_of`), or None (not an event file, or no grid)."""
    if not Path(path).is_file():
        return None
    try:
        shape = _npy_shape(path, "X.npy")
        with zipfile.ZipFile(path) as z:
            names = set(z.namelist())
        if len(shape) != 4:
            return None
        if "taxel_xy.npy" in names:
            check_allocation(16 * shape[1], "taxel_xy")
        small = {}
        with np.load(path, allow_pickle=False) as f:
            for key in ("taxel_xy", "grid"):
                if f"{key}.npy" in names:
                    small[key] = f[key]
    except (OSError, KeyError, ValueError, RuntimeError, NotImplementedError,
            zipfile.BadZipFile):  # fmt: skip
        return None  # the loader reports what is wrong with the file
    return layout_of(shape[1], small.get("taxel_xy"), small.get("grid"), path)


def layout_of(taxels: int, taxel_xy: np.ndarray | None, grid: np.ndarray | None,
              path: Path | str) -> tuple[str, tuple[int, ...]] | None:  # fmt: skip
    """``(grid "ROWSxCOLS", cells)`` of ``taxels`` event taxels: from their ``taxel_xy``
    ``[taxels, 2]`` (mm) when given (:func:`~tactilesnn.core.layout.place_on_grid`: any layout,
    any order), else the declared ``grid`` ``[2]`` (rows x cols must equal the taxels) or a
    square when the taxel count is one (>= 4), the taxels filling it row by row; else None."""
    if taxel_xy is not None:
        rows, cols, cells = place_on_grid(check_taxel_xy(taxel_xy, taxels, f"{path}: taxel_xy"))
        return f"{rows}x{cols}", tuple(int(c) for c in cells)
    if grid is not None:
        g = np.asarray(grid).reshape(-1)
        if g.size != 2 or g.dtype.kind not in "iu" or int(g[0]) * int(g[1]) != taxels:
            raise ValueError(
                f"{path}: grid must be [rows, cols] with rows x cols = {taxels} taxels"
            )
        return f"{int(g[0])}x{int(g[1])}", ()
    side = math.isqrt(taxels)
    return (f"{side}x{side}", ()) if side >= 2 and side * side == taxels else None


def data_facts(path: Path) -> DataFacts:
    """The :class:`DataFacts` of the file or folder at ``path`` (headers only; a file the
    loader will refuse has no facts, and the loader says why)."""
    path = Path(path)
    if not is_event_file(path):
        return DataFacts(False, auto_cut=auto_window(path))
    layout = event_layout(path)
    grid, cells = layout if layout is not None else (None, ())
    return DataFacts(True, grid, cells)


def is_event_file(path: Path) -> bool:
    """True if ``path`` is an ``.npz`` whose ``X`` is ``[N, taxels, polarity, bins]`` (reads only
    the array header)."""
    try:
        shape = _npy_shape(path, "X.npy")
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return False
    return len(shape) == 4


def merge_streams(arrays: dict[str, np.ndarray], path: Path) -> dict[str, np.ndarray]:
    """Append every extra stream ``X@<name>`` (at ``fs@<name>`` Hz) to ``X`` as channels
    ``<name>:<channel>``, resampled to ``fs`` with an anti-aliasing polyphase filter
    (:func:`scipy.signal.resample_poly`, rational factor). Streams must span the window's time
    (``samples / fs`` equal within one sample of the slower stream); windows of the main stream
    and of every extra stream share the row index, so each row is one recording segment."""
    from fractions import Fraction

    from scipy.signal import resample_poly

    out = {k: v for k, v in arrays.items() if "@" not in k}
    if "X" not in out or "fs" not in out:
        raise ValueError(f"{path}: extra streams (X@...) need the main X and fs")
    X = np.asarray(out["X"])
    fs = float(np.asarray(out["fs"]).reshape(-1)[0])
    if X.ndim != 3 or not np.isfinite(fs) or fs <= 0:
        raise ValueError(f"{path}: the main stream needs X [N, channels, samples] and fs > 0")

    def channel_names(key: str, n: int) -> list[str]:
        given = arrays.get(key)
        return [str(c) for c in np.atleast_1d(given)] if given is not None else [
            f"ch{i}" for i in range(n)]  # fmt: skip

    names = channel_names("channel_names", X.shape[1])
    parts = [X.astype(np.float64)]
    for key in sorted(k for k in arrays if k.startswith("X@")):
        name = key[2:]
        if f"fs@{name}" not in arrays:
            raise ValueError(f"{path}: stream {key} needs its sampling rate fs@{name}")
        xs = np.asarray(arrays[key])
        fs_s = np.asarray(arrays[f"fs@{name}"])
        if fs_s.size != 1 or fs_s.dtype.kind not in "fiu" or not float(fs_s.reshape(-1)[0]) > 0:
            raise ValueError(f"{path}: fs@{name} must be one positive sampling rate in Hz")
        fs_s = float(fs_s.reshape(-1)[0])
        if xs.ndim != 3 or xs.shape[0] != X.shape[0] or xs.dtype.kind not in "fiu":
            raise ValueError(
                f"{path}: {key} must be real [N={X.shape[0]}, channels, samples], got {xs.shape}"
            )
        if abs(xs.shape[2] / fs_s - X.shape[2] / fs) > 1.0 / min(fs, fs_s):
            raise ValueError(
                f"{path}: {key} spans {xs.shape[2] / fs_s:.4g} s but X spans "
                f"{X.shape[2] / fs:.4g} s: streams of one recording must cover the same time"
            )
        if xs.dtype.kind == "f":
            check_finite(xs, f"{path}: {key}")
        ratio = Fraction(fs / fs_s).limit_denominator(1000)
        up = resample_poly(xs.astype(np.float64), ratio.numerator, ratio.denominator, axis=-1)
        fixed = np.zeros((xs.shape[0], xs.shape[1], X.shape[2]))
        m = min(up.shape[2], X.shape[2])
        fixed[..., :m] = up[..., :m]
        if m < X.shape[2]:  # rounding of the length: hold the last value
            fixed[..., m:] = up[..., m - 1 : m]
        parts.append(fixed)
        sub = channel_names(f"channel_names@{name}", xs.shape[1])
        if len(sub) != xs.shape[1]:
            raise ValueError(f"{path}: channel_names@{name} must name {xs.shape[1]} channels")
        names += [f"{name}:{c}" for c in sub]
    out["X"] = np.concatenate(parts, axis=1).astype(X.dtype if X.dtype.kind == "f" else np.float64)
    out["channel_names"] = np.array(names)
    log.info("%s: %d stream(s) resampled to %g Hz and appended as channels", path,
             len(parts) - 1, fs)  # fmt: skip
    return out


def events_as_channels(arrays: dict[str, np.ndarray], path: Path) -> dict[str, np.ndarray]:
    """Event file ``X [N, taxels, polarity, bins]`` (events per bin) -> ``[N, taxels x polarity,
    bins]`` with channels ``<taxel>:<polarity>`` and ``fs = 1000 / bin_ms`` (Hz).

    ``bin_ms`` (or ``fs``) gives the bin width; without either a bin is taken as 1 ms (logged).
    Optional ``channel_names`` name the taxels, ``polarity_names`` the polarities (default
    ``on`` / ``off`` for two).
    """
    out = dict(arrays)
    X = arrays["X"]
    n, taxels, pols, bins = X.shape
    if "fs" not in arrays:
        if "bin_ms" in arrays:
            b = np.asarray(arrays["bin_ms"])
            if b.size != 1 or b.dtype.kind not in "fiu":
                raise ValueError(f"{path}: bin_ms must be one number (ms per bin)")
            bin_ms = float(b.reshape(()))
            if not (np.isfinite(bin_ms) and 1e-6 <= bin_ms <= 1e6):
                raise ValueError(
                    f"{path}: bin_ms must be a number of ms in [1e-6, 1e6], got {bin_ms}"
                )
        else:
            bin_ms = 1.0
            log.warning("%s: event bins have no stated width (bin_ms): taken as 1 ms", path)
        out["fs"] = np.array(1000.0 / bin_ms)
    taxel_names = [f"taxel{i}" for i in range(taxels)]
    if "channel_names" in arrays:
        taxel_names = [str(c) for c in np.atleast_1d(arrays["channel_names"])]
        if len(taxel_names) != taxels:
            raise ValueError(f"{path}: channel_names must name the {taxels} taxels")
    pol_names = ["on", "off"] if pols == 2 else [f"p{j}" for j in range(pols)]
    if "polarity_names" in arrays:
        pol_names = [str(c) for c in np.atleast_1d(arrays["polarity_names"])]
        if len(pol_names) != pols:
            raise ValueError(f"{path}: polarity_names must name the {pols} polarities")
    if "taxel_xy" in arrays:
        check_taxel_xy(arrays["taxel_xy"], taxels, f"{path}: taxel_xy")
    out["X"] = X.reshape(n, taxels * pols, bins)
    out["channel_names"] = np.array([f"{t}:{p}" for t in taxel_names for p in pol_names])
    return out


def recording_ids(recording: np.ndarray | None, n: int, path: Path) -> np.ndarray:
    """``recording`` labels (any ints or strings) -> group ids ``[n]`` int64 (each window its
    own group when absent)."""
    if recording is None:
        return np.arange(n, dtype=np.int64)
    rec = np.asarray(recording)
    if rec.shape != (n,) or rec.dtype.kind not in "iuUS":
        raise ValueError(f"{path}: recording must be [N={n}] integers or strings")
    return np.unique(rec, return_inverse=True)[1].astype(np.int64)


def split_by_recording(
    y: np.ndarray, groups: np.ndarray, test_fraction: float, seed: int
) -> np.ndarray:
    """0 / 1 per window: ``test_fraction`` of the recordings per class go to test (at least one
    per class that has two or more); every window of a recording goes with it."""
    rng = np.random.default_rng([seed, 104729])
    ids = np.unique(groups)
    counts = np.zeros((ids.size, int(y.max()) + 1), np.int64)
    np.add.at(counts, (np.searchsorted(ids, groups), y), 1)
    label = counts.argmax(1)  # a recording's majority label
    test: list[int] = []
    for c in np.unique(label):
        mine = rng.permutation(ids[label == c])
        if mine.size >= 2:
            k = min(mine.size - 1, max(1, round(test_fraction * mine.size)))
            test += mine[:k].tolist()
    if not test:
        raise ValueError("too few recordings to hold out a test split; add a 'split' array")
    return np.isin(groups, test).astype(np.int64)
