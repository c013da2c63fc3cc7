"""``tactilesnn bench fit``: ``train --data`` timed stage by stage, against scikit-learn.

Every visible real set found under ``--data-root`` (read in place) and the generated stand-ins of
common shapes (:mod:`.standins`: 1,000 x 22 x 600 @ 100 Hz electrode-like drift, 1,000 x 1 x
13,200 @ 2.2 kHz vibration, a folder of 800 16-taxel CSVs at 357 Hz, 300 x 39 x 2 x 325 event
bins, 560 x 5 x 50 @ 10 Hz glove grasps of 28 objects) go through ``tactilesnn train --data
FILE --quiet`` with no other flag, each in a fresh process as a user runs it (fit and verified
export): its wall time, peak resident memory (of that process alone), the stages' seconds from
its ``metrics.json`` and its accuracy per window and per recording. On the identical split,
scikit-learn references are fitted and timed (logistic
regression on log band powers, random forests on summary statistics and on counts in ten time
slices); each row prints the best reference's accuracy and the ratio of the run's time to that
reference's. ``--busy`` runs each set a second time beside one CPU-bound process and prints the
ratio to the quiet time. Writes ``fit.json`` and ``fit.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ..core.stages import peak_rss_bytes
from . import add_data_root, data_root, require_out, write_result
from .busy import NEIGHBOUR
from .standins import STANDINS, make

HELP = "train --data timed stage by stage on real sets and stand-ins, against scikit-learn"

#: the visible real sets: name -> path under the data root
REAL = {
    "braille_icub_abc": "braille_icub_abc/braille_abc_icub.npz",
    "fabric_slide": "fabric_slide/fabric",
    "st_mnist": "st_mnist/st_mnist_events.npz",
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_data_root(p, "the real sets")
    p.add_argument("--sets", nargs="*", default=None,
                   help=f"sets to run (default: every real set found and every stand-in: "
                        f"{', '.join([*REAL, *STANDINS])})")  # fmt: skip
    p.add_argument("--busy", action="store_true",
                   help="also time each run beside one CPU-bound process")  # fmt: skip
    p.add_argument("--no-references", action="store_true", help="skip the scikit-learn rows")
    p.add_argument("--docs", default=None,
                   help="also write the page docs/fit.md (and its JSON beside it) here")  # fmt: skip


def run_train(data: Path, out: Path, neighbour: bool = False) -> dict:
    """``tactilesnn train --data data --out out --quiet`` in a fresh process: wall seconds, its
    own peak RSS (bytes, from its rusage), exit status, and its ``metrics.json`` (None if it
    wrote none)."""
    cmd = [sys.executable, "-c", "import sys; from tactilesnn.cli import main; sys.exit(main())",
           "train", "--data", str(data), "--out", str(out), "--quiet", "--overwrite"]  # fmt: skip
    out.parent.mkdir(parents=True, exist_ok=True)
    log_path = out.with_name(out.name + ".log")
    busy = subprocess.Popen(NEIGHBOUR, start_new_session=True) if neighbour else None
    try:
        with open(log_path, "w") as log_file:
            t0 = time.perf_counter()
            proc = subprocess.Popen(cmd, stdout=log_file, stderr=subprocess.STDOUT)
            peak = 0
            while True:  # its own high-water mark, read while it runs (see peak_rss_bytes)
                pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
                if pid:
                    break
                peak = max(peak, peak_rss_bytes(proc.pid))
                time.sleep(0.05)
            wall = time.perf_counter() - t0
    finally:
        if busy is not None:
            busy.kill()
            busy.wait()
    code = os.waitstatus_to_exitcode(status)
    metrics_file = out / "metrics.json"
    metrics = json.loads(metrics_file.read_text()) if metrics_file.is_file() else None
    if not peak:  # no /proc: the rusage (which may count the forked benchmark's pages)
        peak = int(usage.ru_maxrss) * 1024
    return {"seconds": wall, "peak_rss_bytes": peak, "returncode": code,
            "metrics": metrics, "output_tail": log_path.read_text()[-2000:]}  # fmt: skip


def references(path: Path, seed: int = 0) -> dict[str, dict]:
    """scikit-learn references on the split ``train --data`` makes of ``path`` (same reader,
    cut and seed): accuracy per window and seconds (features, fit and predict) each."""
    from sklearn.ensemble import RandomForestClassifier
    from sklearn.linear_model import LogisticRegression
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    from ..recordings import auto_window, load_data_file
    from .real import log_spectrum, summary_stats

    cut = auto_window(path) or (None, None)
    train, test = load_data_file(path, seed, window_s=cut[0], hop_s=cut[1])

    def slices(X: np.ndarray, fs: float) -> np.ndarray:
        n = X.shape[-1] // 10 * 10
        return X[..., :n].reshape(*X.shape[:-1], 10, -1).sum(-1).reshape(len(X), -1)

    models = {
        "logreg_logspec": (log_spectrum, lambda: make_pipeline(
            StandardScaler(), LogisticRegression(max_iter=3000))),
        "rf_summary": (lambda X, fs: summary_stats(X), lambda: RandomForestClassifier(
            300, random_state=seed, n_jobs=-1)),
        "rf_time_slices": (slices, lambda: RandomForestClassifier(
            300, random_state=seed, n_jobs=-1)),
    }  # fmt: skip
    out = {}
    for name, (features, model) in models.items():
        t0 = time.perf_counter()
        clf = model().fit(features(train.X, train.fs_hz), train.y)
        acc = float((clf.predict(features(test.X, test.fs_hz)) == test.y).mean())
        out[name] = {"accuracy": acc, "seconds": time.perf_counter() - t0}
    return out


def row(name: str, quiet: dict, busy: dict | None, refs: dict[str, dict]) -> dict:
    """One table row from a run (and its busy twin) and the references."""
    m = quiet["metrics"] or {}
    best = max(refs.items(), key=lambda kv: kv[1]["accuracy"]) if refs else None
    onnx = m.get("onnx", {})
    return {
        "set": name,
        "seconds": quiet["seconds"],
        "peak_rss_gb": quiet["peak_rss_bytes"] / 1e9,
        "ok": quiet["returncode"] == 0,
        "exported": bool(onnx) and "error" not in onnx,
        "stages": m.get("stage_seconds", {}),
        "encoder": (m.get("encoder_selection") or {}).get("chosen"),
        "per_window": m.get("test_accuracy"),
        "per_recording": m.get("test_accuracy_per_recording"),
        "amplitude_baseline": m.get("trivial_amplitude_baseline_accuracy"),
        "reference": None if best is None else {"name": best[0], **best[1]},
        "time_ratio_to_reference": None if best is None else quiet["seconds"] / best[1]["seconds"],
        "busy_seconds": None if busy is None else busy["seconds"],
        "busy_ratio": None if busy is None else busy["seconds"] / quiet["seconds"],
        "references": refs,
    }


def _pct(v: float | None) -> str:
    return "-" if v is None else f"{100 * v:.2f} %"


def _ratio(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f}x"


def table(rows: list[dict]) -> str:
    head = ("| set | train --data (s) | beside a busy process (s) | peak RSS | stages (s) | "
            "encoder | per window | per recording | best scikit-learn reference | time / "
            "reference |\n|---|---|---|---|---|---|---|---|---|---|")  # fmt: skip
    lines = [head]
    for r in rows:
        st = ", ".join(f"{k} {v:.0f}" for k, v in r["stages"].items())
        ref = r["reference"]
        busy = ("-" if r["busy_seconds"] is None
                else f"{r['busy_seconds']:.0f} ({r['busy_ratio']:.2f}x)")  # fmt: skip
        lines.append(
            f"| {r['set']} | {r['seconds']:.0f}{'' if r['exported'] else ' (no export)'} | {busy} | "
            f"{r['peak_rss_gb']:.2f} GB | {st} | {r['encoder'] or '-'} | {_pct(r['per_window'])} | "
            f"{_pct(r['per_recording'])} | "
            f"{'-' if ref is None else ref['name'] + ' ' + _pct(ref['accuracy'])} | "
            f"{_ratio(r['time_ratio_to_reference'])} |"
        )
    return "\n".join(lines)


PAGE_HEAD = """# Time to result: `train --data` on files as they come

Generated by `tactilesnn bench fit` from its JSON (`fit.json` beside this page; a test checks that
the table below is the one the JSON gives). Each row: `tactilesnn train --data FILE --quiet` with
no other flag, in a fresh process (fit, evaluation and the verified ONNX export), its wall time,
its own peak resident memory and its stages' seconds (`metrics.json` `stage_seconds`); the best of
three scikit-learn references fitted on the identical split (logistic regression on log band
powers, random forests on summary statistics and on counts in ten time slices) and the ratio of
the run's time to that reference's. Stand-ins are generated with numpy
(`tactilesnn/bench/standins.py`: their shapes are those of real files the project does not
have; their accuracy says how hard they are, not how good a sensor is). Command:

```sh
{command}
```

Machine: {machine}.

"""


def page(rows: list[dict], command: str, machine: str) -> str:
    """The docs page of a run's rows (:data:`PAGE_HEAD` and :func:`table`)."""
    return PAGE_HEAD.format(command=command, machine=machine) + table(rows) + "\n"


def main(out: Path | None, options: argparse.Namespace) -> int:
    out = Path(require_out(out, "fit"))
    root = data_root(options, "fit")
    sets = options.sets or [*REAL, *STANDINS]
    unknown = [s for s in sets if s not in REAL and s not in STANDINS]
    if unknown:
        raise ValueError(f"unknown sets {unknown}; known: {', '.join([*REAL, *STANDINS])}")
    rows = []
    for name in sets:
        path = root / REAL[name] if name in REAL else make(name, out / "standins")
        if not path.exists():
            print(f"{name}: {path} not found, skipped")
            continue
        quiet = run_train(path, out / "runs" / name)
        if quiet["returncode"] != 0:
            print(f"{name}: train --data failed ({quiet['returncode']}):\n{quiet['output_tail']}")
        busy = (
            run_train(path, out / "runs" / f"{name}_busy", neighbour=True) if options.busy else None
        )
        refs = {} if options.no_references else references(path)
        r = row(name, quiet, busy, refs)
        rows.append(r)
        print(table([r]).splitlines()[-1], flush=True)
    text = table(rows)
    print(text)
    (out / "fit.md").write_text(text + "\n")
    command = "tactilesnn bench fit --out DIR" + (" --busy" if options.busy else "")
    machine = f"{os.cpu_count()} CPUs, {time.strftime('%Y-%m-%d')}"
    result = {"rows": rows, "command": command, "machine": machine}
    write_result(out, "fit.json", result)
    if options.docs:
        docs = Path(options.docs)
        write_result(docs.parent, docs.with_suffix(".json").name, result)
        docs.write_text(page(rows, command, machine))
    return 0 if all(r["ok"] for r in rows) else 1
