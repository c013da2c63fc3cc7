"""``tactilesnn convert``: recordings as they come -> one ``.npz`` in the documented format, or,
with ``dry_run``, a description of what would be read (files, classes, channels, the rate and
where it came from, lengths, what was dropped), written nowhere."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.data import condition_text
from ..core.files import write_npz_atomic
from ..readers import Conversion, needs_reading, read_recordings
from ..recordings import datasets_from_arrays, read_data_arrays
from .runs import RunExistsError

log = logging.getLogger("tactilesnn")


@dataclass
class ConvertReport:
    """What was (or would be) written: shapes, rate, classes with their recording counts, and
    the reader's notes."""

    out: Path | None
    shape: tuple[int, ...]
    fs_hz: float
    classes: dict[str, int]
    channels: list[str]
    windows: int
    notes: list[str]
    #: each condition the data states: ``{name: {value: recordings}}`` (``--hold-out`` names)
    conditions: dict[str, dict[str, int]] = field(default_factory=dict)

    def lines(self) -> list[str]:
        head = (f"wrote {self.out}" if self.out else "would read") + (
            f": X {list(self.shape)} at {self.fs_hz:.6g} Hz, {len(self.classes)} classes, "
            f"{len(self.channels)} channels, {self.windows} windows"
        )
        shown = ", ".join(self.channels[:8]) + (" ..." if len(self.channels) > 8 else "")
        counts = ", ".join(f"{k} ({v})" for k, v in self.classes.items())
        conds = [f"  condition {name} (recordings): "
                 + ", ".join(f"{v} ({n})" for v, n in values.items())
                 for name, values in self.conditions.items()]  # fmt: skip
        hint = (["  test on unseen conditions: tactilesnn train --data FILE --hold-out "
                 f"'{next(iter(self.conditions))}=VALUE'"] if self.conditions else [])  # fmt: skip
        return [head, f"  channels: {shown}", f"  classes (recordings): {counts}", *conds, *hint,
                *(f"  {n}" for n in self.notes)]  # fmt: skip


def convert(source: Path, out: Path | None, fs_hz: float | None = None, overwrite: bool = False,
            dry_run: bool = False) -> ConvertReport:  # fmt: skip
    """Read ``source`` (an ``.npz``, a folder of recordings or a generated folder; ``fs_hz``: the
    rate where no timestamps give it) and write it to ``out`` atomically (refused if ``out``
    exists unless ``overwrite``); ``dry_run``: read and describe only."""
    source = Path(source)
    if not dry_run:
        if out is None:
            raise ValueError("convert needs --out FILE.npz (or --dry-run)")
        if Path(out).exists() and not overwrite:
            raise RunExistsError(f"{out} exists; pass --overwrite to replace it")
    notes: list[str] = []
    if source.is_dir() and needs_reading(source):
        arrays, conv = read_recordings(source, fs_hz=fs_hz)
        notes = _notes(conv)
    else:
        arrays = read_data_arrays(source, fs_hz)
    train, test = datasets_from_arrays(arrays, source, seed=0)  # checks the result
    names = list(train.class_names)  # (a file without class_names: named from its labels)
    rec = arrays.get("recording")
    ids = np.asarray(rec) if rec is not None else np.arange(len(arrays["y"]))
    per_class = {
        n: int(np.unique(ids[np.asarray(arrays["y"]) == i]).size) for i, n in enumerate(names)
    }
    channels = arrays.get("channel_names")
    n_ch = int(np.asarray(arrays["X"]).shape[1])
    report = ConvertReport(
        None if dry_run else Path(out),  # type: ignore[arg-type]
        tuple(np.asarray(arrays["X"]).shape),
        float(np.asarray(arrays["fs"]).reshape(-1)[0]) if "fs" in arrays else float("nan"),
        per_class,
        [str(c) for c in channels] if channels is not None else [f"ch{i}" for i in range(n_ch)],
        len(train) + len(test),
        notes,
        _conditions(train.concat(test)),
    )
    if not dry_run:
        write_npz_atomic(Path(out), arrays)  # type: ignore[arg-type]
    return report


def _conditions(data) -> dict[str, dict[str, int]]:
    """Each condition's values with their recording counts."""
    out: dict[str, dict[str, int]] = {}
    for name, table in sorted((data.conditions or {}).items()):
        values = list(table.values())
        out[name] = {condition_text(v): values.count(v)
                     for v in sorted(set(values), key=lambda x: (str(type(x)), x))}  # fmt: skip
    return out


def _notes(conv: Conversion) -> list[str]:
    return [f"{conv.layout}; fs {conv.fs_hz:.6g} Hz (timing jitter {100 * conv.jitter:.1f} %)",
            *conv.notes]  # fmt: skip
