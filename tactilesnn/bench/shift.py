"""``tactilesnn bench shift``: trained at some conditions, tested at others.

Each row holds out whole conditions of a real file (``train --data FILE --hold-out SPEC``: the
test recordings were pressed harder, slid faster, or recorded in runs no training recording
came from) and runs the defaults as ``train`` runs them (the encoder compared by leaving whole
condition values out, :func:`~tactilesnn.selection.select_encoder`), beside the scikit-learn
references of ``bench real`` (:func:`.real.references`) and the amplitude-only logistic
regression on the identical split, and beside the defaults' accuracy within the training
conditions (a random fifth of their recordings held out). Writes ``shift.json`` and, with
``--docs``, the page generated from it.
"""

from __future__ import annotations

import argparse
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.data import GROUP_PREFIX, DataFacts, WindowDataset

log = logging.getLogger("tactilesnn")

#: the references' name of the amplitude-only baseline (:data:`.real.AMPLITUDE_BASELINE`)
AMPLITUDE = "logreg_amplitude"


@dataclass(frozen=True)
class Shift:
    """One row of a real file: the file under the data root, the hold-out (None: the file's own
    ``split``), what differs between training and test, and the conditions added to it (none:
    its own)."""

    path: str
    hold_out: Callable[[dict[str, np.ndarray]], str] | None
    what: str
    conditions: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]] | None = None

    def load(self, root: Path, seed: int) -> tuple[WindowDataset, WindowDataset, str]:
        return load(root, self, seed)


@dataclass(frozen=True)
class SynthShift:
    """One row made on purpose: a synthetic task rendered for training at each value of
    ``train`` and for testing at ``test`` of its parameter ``name`` (the sensor models are the
    lever: the scenes differ only there). The training values are its conditions, so the
    selection leaves one out to choose."""

    task: str
    name: str
    train: tuple[float, ...]
    test: float
    what: str
    path: None = None
    n_samples: int | None = None  # the task's own default when None

    def load(self, root: Path, seed: int) -> tuple[WindowDataset, WindowDataset, str]:
        from dataclasses import replace

        from ..datasets_synth import get_task

        size = {} if self.n_samples is None else {"n_samples": self.n_samples}
        parts, values = [], {}
        for k, v in enumerate(self.train):
            part = get_task(self.task, seed=seed + 1000 * k, **{self.name: v}, **size).build()[0]
            part = replace(part, scan=part.scan + 10**6 * k)  # one recording id space
            values.update({int(s): v for s in np.unique(part.scan)})
            parts.append(part)
        train = parts[0]
        for part in parts[1:]:
            train = train.concat(part)
        # the windows as a file of them would be read (train --data's policy, not the task's
        # own pipeline): analog, cut already
        facts = DataFacts(events=False)
        train = replace(train, conditions={self.name: values}, facts=facts)
        test = get_task(self.task, seed=seed + 999, **{self.name: self.test}, **size).build()[1]
        return train, replace(test, facts=facts), f"{self.name}={self.test:g}"


def _abs_speed(a: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """FabricSlide's speed without its direction (the file names sign it: V-50mmps)."""
    return {"speed": np.abs(a[GROUP_PREFIX + "V"])}


#: the iCub file's slides come in runs of five, one letter each (its README; docs/sim2real.md)
ICUB_RUN_SLIDES = 5


def _icub_runs(a: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    rec = np.asarray(a.get("recording", np.arange(len(a["y"]))))
    return {"run": rec // ICUB_RUN_SLIDES}


def _last_run_per_class(a: dict[str, np.ndarray]) -> str:
    runs, y = _icub_runs(a)["run"], np.asarray(a["y"])
    held = sorted({int(runs[y == c].max()) for c in np.unique(y)})
    return "run=" + ",".join(map(str, held))


ROWS: dict[str, Shift | SynthShift] = {
    "fabric_force": Shift("fabric_slide/fabric", lambda a: "F>=180",
                          "pressed harder (test F180-F250, train F120-F150)"),
    "fabric_speed": Shift("fabric_slide/fabric", lambda a: "speed>=100",
                          "slid faster (test 100-150 mm/s, train 10-50)", _abs_speed),
    "icub_runs": Shift("braille_icub_abc/braille_abc_icub.npz", _last_run_per_class,
                       "recording runs no training slide came from (one per letter)",
                       _icub_runs),
    "stmnist_source": Shift("st_mnist/st_mnist_events.npz", None,
                            "the source's own split (its test writers' digits)"),
    "synth_texture_speed": SynthShift("texture", "speed_mm_s", (40.0, 60.0), 100.0,
                                      "synthetic texture scans, test slid at 100 mm/s, "
                                      "train at 40 and 60"),
    "synth_texture_force": SynthShift("texture", "pressure_kpa", (0.5, 1.0), 3.0,
                                      "synthetic texture scans, test pressed at 3 kPa, "
                                      "train at 0.5 and 1 kPa"),
}  # fmt: skip


def load(root: Path, shift: Shift, seed: int) -> tuple[WindowDataset, WindowDataset, str]:
    """``(train, test, hold-out spec)`` of a row, read and cut as ``train --data`` reads the
    file (its default cut), with the row's conditions added."""
    from ..recordings import auto_window, datasets_from_arrays, read_data_arrays

    path = Path(root) / shift.path
    arrays = dict(read_data_arrays(path))
    if shift.conditions is not None:
        arrays.update({GROUP_PREFIX + k: v for k, v in shift.conditions(arrays).items()})
    spec = None if shift.hold_out is None else shift.hold_out(arrays)
    cut = auto_window(path)
    train, test = datasets_from_arrays(arrays, path, seed, window=cut, hold_out=spec)
    return train, test, spec or "the file's split"


def run_defaults(train: WindowDataset, test: WindowDataset, leave_out: str | None,
                 seed: int) -> tuple[dict, object]:  # fmt: skip
    """The defaults as ``train --data`` runs them (the encoder chosen leaving whole values of
    ``leave_out`` out) -> ``(row part, the fitted pipeline)``."""
    from ..resolve import resolve
    from ..selection import resolved_config
    from ..training import fit_and_evaluate

    t0 = time.perf_counter()
    config, sel = resolved_config(resolve({"seed": seed}, facts=train.facts), train, leave_out)
    validation = None if sel is None else sel["validation"]
    chosen = config.encoder_type if sel is None else sel["chosen"]
    fitted = fit_and_evaluate(config, train, test)
    m = fitted.metrics
    return {"per_window": m["test_accuracy"],
            "per_recording": m.get("test_accuracy_per_recording"),
            "encoder": chosen, "model": config.model_type,
            "validation": validation, "seconds": time.perf_counter() - t0}, fitted.pipeline  # fmt: skip


def within(train: WindowDataset, seed: int) -> dict:
    """The defaults within the training conditions: a fifth of their recordings (by class)
    held out at random."""
    from ..recordings import split_by_recording

    split = split_by_recording(train.y, train.scan, 0.2, seed)
    part, _ = run_defaults(train.subset(split == 0), train.subset(split == 1), None, seed)
    return part


def one_row(name: str, shift: Shift | SynthShift, root: Path, seed: int, with_within: bool) -> dict:
    """A row: the defaults, the references and the amplitude-only baseline on the identical
    split, the within-condition figure."""
    from ..recordings import HOLD_OUT
    from .real import references

    t0 = time.perf_counter()
    train, test, spec = shift.load(root, seed)
    match = HOLD_OUT.match(spec)
    leave_out = spec if match and train.conditions else None
    log.info("bench shift %s: %s, %d train / %d test windows", name, spec, train.y.size,
             test.y.size)  # fmt: skip
    defaults, pipe = run_defaults(train, test, leave_out, seed)
    refs = {k: list(v) for k, v in references(train, test, pipe, seed).items()}
    row = {"row": name, "shift": shift.what, "hold_out": spec, "seed": seed,
           "train_windows": int(train.y.size), "test_windows": int(test.y.size),
           "test_recordings": int(np.unique(test.scan).size), "defaults": defaults,
           "references": refs}  # fmt: skip
    if with_within:
        row["within"] = within(train, seed)
    row["seconds"] = time.perf_counter() - t0
    log.info("bench shift %s: defaults %.1f %% per window (%s), best reference %s", name,
             100 * defaults["per_window"], defaults["encoder"], best_reference(row))  # fmt: skip
    return row


def best_reference(row: dict) -> str:
    """The reference scoring best per recording where every one has that figure, else per
    window."""
    refs = row["references"]
    key = 1 if all(v[1] is not None for v in refs.values()) else 0
    return max(refs, key=lambda k: refs[k][key])


def run(out: Path, data_root: Path, rows: list[str] | None = None, seeds: int = 1,
        with_within: bool = True) -> dict:  # fmt: skip
    """Every row found under ``data_root`` (missing files skipped, said), ``seeds`` seeds each;
    ``shift.json`` in ``out``."""
    from . import write_result

    names = rows or list(ROWS)
    unknown = sorted(set(names) - set(ROWS))
    if unknown:
        raise ValueError(f"unknown row(s) {unknown}; choose from {list(ROWS)}")
    result_rows = []
    for name in names:
        path = ROWS[name].path
        if path is not None and not (Path(data_root) / path).exists():
            log.warning("bench shift: %s not found under %s, skipped", ROWS[name].path,
                        data_root)  # fmt: skip
            continue
        for seed in range(seeds):
            result_rows.append(one_row(name, ROWS[name], Path(data_root), seed, with_within))
    result = {"rows": result_rows}
    write_result(out, "shift.json", result)
    return result


PAGE_HEAD = """# Trained at some conditions, tested at others (`tactilesnn bench shift`)

Generated from `shift.json` by `{command}` ({machine}). Each row holds out whole conditions of
a real file (`train --data FILE --hold-out SPEC`; ST-MNIST: the source's own split), or renders
a synthetic task's training scenes at some values of one parameter and its test scenes at
another (`synth_*`: the sensor models make the shift on purpose), runs the defaults as `train`
runs them (the encoder compared by leaving whole condition values out) and, on the identical
split, the scikit-learn references of `bench real` and the amplitude-only logistic regression
(per-channel mean and sd). "Within" is the defaults on the training conditions alone, a fifth of their
recordings held out. Per window / per recording (scores summed over a recording's windows), %.
The goal: the defaults at or above the best reference minus 2 points and above the amplitude-only
baseline.

"""


def _pct(v: float | None) -> str:
    return "-" if v is None else f"{100 * v:.1f}"


def table(rows: list[dict]) -> str:
    """The page's table of ``rows`` (one line per row and seed)."""
    lines = ["| row | what shifts | hold-out | defaults (encoder) | within | best reference | "
             "amplitude-only | goal |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        d, refs = r["defaults"], r["references"]
        best = best_reference(r)
        key = 1 if all(v[1] is not None for v in refs.values()) and d["per_recording"] else 0
        mine = d["per_recording"] if key else d["per_window"]
        met = mine >= refs[best][key] - 0.02 and mine > refs[AMPLITUDE][key]
        w = r.get("within")
        lines.append(
            f"| {r['row']} | {r['shift']} | `{r['hold_out']}` | {_pct(d['per_window'])} / "
            f"{_pct(d['per_recording'])} ({d['encoder']}) | "
            f"{'-' if w is None else _pct(w['per_window']) + ' / ' + _pct(w['per_recording'])} | "
            f"{best} {_pct(refs[best][0])} / {_pct(refs[best][1])} | "
            f"{_pct(refs[AMPLITUDE][0])} / {_pct(refs[AMPLITUDE][1])} | "
            f"{'met' if met else 'not met'} |"
        )
    return "\n".join(lines) + "\n"


def page(rows: list[dict], command: str, machine: str) -> str:
    return PAGE_HEAD.format(command=command, machine=machine) + table(rows)


HELP = "shift: the defaults trained at some conditions and tested at others, beside references"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from . import add_data_root

    add_data_root(p, "fabric_slide/, braille_icub_abc/ and st_mnist/")
    p.add_argument("--rows", nargs="+", choices=list(ROWS), help="rows to run (default: all)")
    p.add_argument("--seeds", type=int, default=1, help="seeds per row")
    p.add_argument("--no-within", action="store_true",
                   help="skip the within-condition runs (half the time)")  # fmt: skip
    p.add_argument("--docs", default=None, help="also write the page (and its JSON) here")


def main(out: Path | None, options: argparse.Namespace) -> int:
    import json
    import os

    from . import data_root, require_out

    result = run(Path(require_out(out, "shift")), data_root(options, "shift"), options.rows,
                 options.seeds, not options.no_within)  # fmt: skip
    if options.docs:
        from ..core.files import write_text_atomic

        command = "tactilesnn bench shift --out DIR" + (
            f" --rows {' '.join(options.rows)}" if options.rows else "")  # fmt: skip
        machine = f"{os.cpu_count()} CPUs, {time.strftime('%Y-%m-%d')}"
        docs = Path(options.docs)
        result.update(command=command, machine=machine)
        write_text_atomic(docs.with_suffix(".json"), json.dumps(result, indent=2))
        write_text_atomic(docs, page(result["rows"], command, machine))
    print(table(result["rows"]))
    return 0
