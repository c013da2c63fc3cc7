"""``tactilesnn bench real``: spike pipelines on real recordings against non-spiking references.

Every real dataset found under ``--data-root`` (default ``../shared/data``; never copied into the
repository) x the spike pipelines with the ``--data`` defaults (no per-dataset flag), against
references fitted on the identical split:

* ``logreg_logspec``: logistic regression on each channel's log power spectrum (16 log-spaced
  bands of the window's periodogram, plus the channel mean), standardised;
* ``logreg_peaknorm_wave``: logistic regression on the raw waveforms divided by each window's
  peak (decimated to at most 4,096 values), the reference that beat the material task;
* ``rf_counts``: random forest (300 trees) on per-channel totals (event counts, or the mean
  and mean absolute value of an analog channel);
* ``rf_summary``: random forest (300 trees) on per-channel summary statistics (mean, sd, mean
  absolute difference, max, min), the data READMEs' reference;
* ``logreg_amplitude``: the amplitude-only baseline every run prints (logistic regression on
  each channel's mean and RMS): a spike pipeline below it has lost what plain levels carry;
* ``mlp_spikes``: a small non-spiking MLP (one hidden layer of 128) on the very spike times
  the default encoder produces (``1 - t / window`` per slot, 0 when silent).

Mean and sd over seeds (split and training seed), per window and, where recordings hold several
windows, per recording (scores accumulated). Each spike row is judged against the best reference
per window (within :data:`WINDOW_POINTS`) and per recording (within :data:`RECORDING_POINTS`), and
against the amplitude-only baseline (never below). Writes ``real.json``, ``real.md`` and
``real.png``.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..config import PipelineConfig
from ..data_policy import DATA_ENCODER_CANDIDATES
from ..datasets_synth import WindowDataset
from ..recordings import DataFacts, auto_window, load_data_file
from ..resolve import resolve

log = logging.getLogger("tactilesnn")

Loader = Callable[[Path, int], tuple[WindowDataset, WindowDataset]]


def _as_train_reads(rel: str) -> Loader:
    """A shipped file or folder read as ``train --data`` reads it, as it comes (the reader's
    conversion and the default cut: :func:`~tactilesnn.recordings.auto_window`)."""

    def load(root: Path, seed: int) -> tuple[WindowDataset, WindowDataset]:
        path = root / rel
        cut = auto_window(path) or (None, None)
        return load_data_file(path, seed, window_s=cut[0], hop_s=cut[1])

    return load


#: shipped real datasets: name -> (file that must exist under the root, loader, event data?)
REAL_DATASETS: dict[str, tuple[str, Loader, bool]] = {
    "braille_icub_abc": (
        "braille_icub_abc/braille_abc_icub.npz",
        _as_train_reads("braille_icub_abc/braille_abc_icub.npz"),
        False,
    ),
    "fabric_slide": ("fabric_slide/fabric", _as_train_reads("fabric_slide/fabric"), False),
    "st_mnist": (
        "st_mnist/st_mnist_events.npz",
        _as_train_reads("st_mnist/st_mnist_events.npz"),
        True,
    ),
}


def _synthetic(task: str) -> Loader:
    def load(root: Path, seed: int) -> tuple[WindowDataset, WindowDataset]:
        from ..datasets_synth import get_task

        return get_task(task, seed=seed).build()

    return load


def synthetic_datasets() -> dict[str, tuple[str | None, Loader, bool]]:
    """Every registered synthetic task as ``synth:<task>`` (its default size and split), for the
    same spike-vs-reference check as the real files (``--datasets synth:material ...``)."""
    from ..datasets_synth import TASKS

    return {f"synth:{t}": (None, _synthetic(t), False) for t in sorted(TASKS)}


#: spike pipelines: (label, encoder or None for the --data default, model, data it applies to,
#: settings over the --data defaults)
PIPELINES = (
    ("default+tempotron", None, "tempotron", "any", {}),
    ("default+readout", None, "readout", "any", {}),
    ("default+snn", None, "snn", "any", {}),
    # a random forest on the readout's traces (does not extrapolate: the sim-to-real read-out)
    ("default+forest", None, "forest", "any", {}),
    ("lif+readout", "lif", "readout", "analog", {}),  # a level converter: not for event counts
    # the Gabor latency code on the windowed FFT scalogram and on the causal (streamable) bank
    ("gwt+readout", "gwt", "readout", "analog", {}),
    ("cgwt+readout", "cgwt", "readout", "analog", {}),
    # transform -> code: Gabor band envelopes into LIF converters (the bands encoder's defaults)
    ("gwt>lif+readout", "bands", "readout", "analog", {}),
    # convolutions need a taxel grid, every afferent on it (as train --data gives a grid file)
    # (pinned as measured: train --data gives a grid file's csnn 12 epochs on a cosine schedule,
    # its time step and constant from the window, the grid from the file)
    (
        "events+csnn",
        "events",
        "csnn",
        "events",
        {
            "level_neurons": 0,
            "epochs": 40,
            "lr_schedule": "constant",
            "csnn_dt_ms": 5.0,
            "csnn_tau_ms": 50.0,
            "csnn_grid": "auto",
        },
    ),
    # the continuous code and the stream model: scored per window and as it runs frame by frame
    # (40 epochs pinned as measured: the stream model's own default is 15)
    ("frames+stream", "frames", "stream", "analog", {"epochs": 40}),
)


def default_config(events: bool, encoder: str | None, model: str, seed: int,
                   settings: dict | None = None,
                   facts: DataFacts | None = None) -> PipelineConfig:  # fmt: skip
    """What ``tactilesnn train --data FILE [--encoder E] --model M --seed S [settings]`` would
    use (:func:`~tactilesnn.resolve.resolve`; ``facts``: the file's, else those of an analog or
    ``events`` file without a grid)."""
    given = {"model": model, "seed": seed, **(settings or {})}
    if encoder is not None:
        given["encoder"] = encoder
    return resolve(given, facts=facts or DataFacts(events)).config


# ---------------------------------------------------------------- non-spiking references
def log_spectrum(X: np.ndarray, fs: float, n_bands: int = 16) -> np.ndarray:
    """``[N, C, W]`` -> per channel log power in ``n_bands`` log-spaced bands + the mean."""
    X = np.asarray(X, dtype=np.float64)
    mean = X.mean(-1)
    spec = np.abs(np.fft.rfft(X - mean[..., None], axis=-1)) ** 2
    f = np.fft.rfftfreq(X.shape[-1], 1.0 / fs)
    edges = np.geomspace(max(f[1], 1e-3), f[-1] + 1e-9, n_bands + 1)
    idx = np.clip(np.searchsorted(edges, f, side="right") - 1, 0, n_bands - 1)
    power = np.zeros((*X.shape[:2], n_bands))
    for b in range(n_bands):
        sel = (idx == b) & (f > 0)
        if sel.any():
            power[..., b] = spec[..., sel].mean(-1)
    feats = np.log10(power + 1e-12 * (power.max() + 1e-300))
    return np.concatenate([feats.reshape(len(X), -1), mean], axis=1)


def peak_normalised(X: np.ndarray, max_features: int = 4096) -> np.ndarray:
    """The raw waveforms, each window divided by its peak ``|x|``, flattened (decimated so at
    most ``max_features`` values remain)."""
    X = np.asarray(X, dtype=np.float64)
    step = max(1, int(np.ceil(X.shape[1] * X.shape[2] / max_features)))
    X = X[..., ::step]
    peak = np.abs(X).max(axis=(1, 2), keepdims=True)
    return (X / np.where(peak > 0, peak, 1.0)).reshape(len(X), -1)


def counts(X: np.ndarray) -> np.ndarray:
    """Per-channel totals: the mean and mean absolute value over the window."""
    X = np.asarray(X, dtype=np.float64)
    return np.concatenate([X.mean(-1), np.abs(X).mean(-1)], axis=1)


def summary_stats(X: np.ndarray) -> np.ndarray:
    """Per channel: mean, sd, mean absolute sample-to-sample difference, max, min."""
    X = np.asarray(X, dtype=np.float64)
    diff = np.abs(np.diff(X, axis=-1)).mean(-1) if X.shape[-1] > 1 else np.zeros(X.shape[:2])
    return np.concatenate([X.mean(-1), X.std(-1), diff, X.max(-1), X.min(-1)], axis=1)


#: trees of the reference forests
FOREST_TREES = 300
#: the defaults' goal against the best reference: points per window and per recording
WINDOW_POINTS, RECORDING_POINTS = 2.0, 1.0
AMPLITUDE_BASELINE = "logreg_amplitude"


def spike_features(spikes, duration_ms: float) -> np.ndarray:
    t = spikes.numpy().reshape(spikes.shape[0], -1)
    return np.where(np.isfinite(t), 1.0 - t / duration_ms, 0.0)


def references(
    train: WindowDataset, test: WindowDataset, pipe, seed: int
) -> dict[str, tuple[float, float | None]]:
    """Each non-spiking reference on the identical split -> (test accuracy per window, per
    recording from its class probabilities summed over the recording's windows, or None).
    ``pipe``: the fitted spike pipeline whose spikes ``mlp_spikes`` reads; ``None`` leaves that
    one out (the references on the waveforms alone)."""
    from sklearn.base import clone
    from sklearn.ensemble import RandomForestClassifier
    from sklearn.linear_model import LogisticRegression
    from sklearn.neural_network import MLPClassifier
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    from ..baselines import amplitude_stats

    def scored(clf, f_train: np.ndarray, f_test: np.ndarray) -> tuple[float, float | None]:
        return fit_and_score(clf, f_train, train, f_test, test)

    lr = make_pipeline(StandardScaler(), LogisticRegression(max_iter=3000))
    rf = RandomForestClassifier(n_estimators=FOREST_TREES, random_state=seed, n_jobs=-1)
    mlp = make_pipeline(
        StandardScaler(),
        MLPClassifier((128,), max_iter=300, early_stopping=len(train.y) >= 50, random_state=seed),
    )
    lr_wave = make_pipeline(StandardScaler(), LogisticRegression(max_iter=3000, C=0.1))
    out = {
        "logreg_logspec": scored(lr, log_spectrum(train.X, train.fs_hz),
                                 log_spectrum(test.X, test.fs_hz)),
        "logreg_peaknorm_wave": scored(lr_wave, peak_normalised(train.X), peak_normalised(test.X)),
        "rf_counts": scored(rf, counts(train.X), counts(test.X)),
        "rf_summary": scored(clone(rf), summary_stats(train.X), summary_stats(test.X)),
        AMPLITUDE_BASELINE: scored(clone(lr), amplitude_stats(train.X), amplitude_stats(test.X)),
    }  # fmt: skip
    if pipe is not None:
        out["mlp_spikes"] = scored(mlp, spike_features(pipe.encode(train.X), pipe.duration_ms),
                                   spike_features(pipe.encode(test.X), pipe.duration_ms))  # fmt: skip
    return out


def fit_and_score(clf, f_train: np.ndarray, train: WindowDataset, f_test: np.ndarray,
                  test: WindowDataset) -> tuple[float, float | None]:  # fmt: skip
    """A scikit-learn classifier fitted on ``train``'s features ``f_train`` (its windows'
    confidences, where set, as soft targets: :func:`soft_target_rows`) and scored on ``test``'s
    ``f_test`` -> (accuracy per window, per recording from the class probabilities summed over
    the recording's windows, or None)."""
    from ..training import recording_accuracy

    if train.confidence is None:
        clf.fit(f_train, train.y)
    else:  # the same soft targets as the spike pipeline's: each window once per class
        rows, labels, weights = soft_target_rows(train.y, train.confidence,
                                                 len(train.class_names))  # fmt: skip
        last = clf.steps[-1][0] + "__" if hasattr(clf, "steps") else ""
        clf.fit(f_train[rows], labels, **{last + "sample_weight": weights})
    proba = np.zeros((test.y.size, len(test.class_names)))
    proba[:, clf.classes_] = clf.predict_proba(f_test)
    per_rec = recording_accuracy(proba, test.y, test.scan)
    acc = float((proba.argmax(1) == test.y).mean())
    return acc, None if per_rec is None else per_rec["test_accuracy_per_recording"]


def soft_target_rows(y: np.ndarray, confidence: np.ndarray,
                     n_classes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Soft targets (:func:`~tactilesnn.models.softmax_fit.soft_targets`) as weighted hard
    rows, for a scikit-learn classifier's ``sample_weight``: ``(window index, label, weight)``
    of every (window, class) pair with a weight above zero. A weighted cross-entropy over these
    rows is the soft-target one."""
    import torch

    from ..models.softmax_fit import soft_targets

    q = soft_targets(torch.as_tensor(np.asarray(y)), n_classes,
                     torch.as_tensor(np.asarray(confidence, np.float64))).numpy()  # fmt: skip
    rows, labels = np.nonzero(q > 0)
    return rows, labels, q[rows, labels]


#: what runs with no ``--pipelines``: what ``train --data`` trains with no flag on each kind of
#: file (the README's and the page's rows), minutes a dataset; the others (the tempotron's
#: selection and 40 epochs took ~12 min a seed on the 45-slide iCub file) by name, or ``all``
DEFAULT_PIPELINES = ("default+readout", "events+csnn")


def chosen_pipelines(names: list[str] | None) -> list[tuple]:
    """The :data:`PIPELINES` entries named (None: :data:`DEFAULT_PIPELINES`; ``["all"]``: every
    one); ValueError naming the choices for an unknown name."""
    if names is None:
        names = list(DEFAULT_PIPELINES)
    elif list(names) == ["all"]:
        names = [p[0] for p in PIPELINES]
    chosen = [p for p in PIPELINES if p[0] in names]
    if len(chosen) != len(set(names)):
        raise ValueError(f"unknown pipeline(s) {sorted(set(names) - {p[0] for p in chosen})}; "
                         f"choose from {[p[0] for p in PIPELINES]} or all")  # fmt: skip
    return chosen


# ---------------------------------------------------------------- the benchmark
def run(
    out: Path,
    data_root: Path,
    seeds: int = 3,
    datasets: list[str] | None = None,
    pipelines: list[str] | None = None,
    epochs: int | None = None,
    progress: bool = True,
) -> dict:
    data_root = Path(data_root)
    rows: list[dict] = []
    known = {**REAL_DATASETS, **synthetic_datasets()}
    names = datasets or list(REAL_DATASETS)
    unknown = sorted(set(names) - set(known))
    if unknown:
        raise ValueError(f"unknown dataset(s) {unknown}; choose from {sorted(known)}")
    chosen = chosen_pipelines(pipelines)
    for name in names:
        rel, loader, events = known[name]
        if rel is not None and not (data_root / rel).exists():
            log.warning("bench real: %s not found under %s, skipped", rel, data_root)
            continue
        for seed in range(seeds):
            rows += _one_split(name, seed, *loader(data_root, seed), events, chosen, epochs,
                               progress)  # fmt: skip
    summary = summarise(rows)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "real.json").write_text(json.dumps({"rows": rows, "summary": summary}, indent=2))
    (out / "real.md").write_text(table(summary))
    plot(summary, out / "real.png")
    print(table(summary))
    return {"rows": rows, "summary": summary}


def _one_split(name: str, seed: int, train, test, events: bool, chosen: list, epochs: int | None,
               progress: bool) -> list[dict]:  # fmt: skip
    """Rows of one dataset split: each spike pipeline, then the references on the same split."""
    from ..selection import fit_encoder_to_data, select_encoder
    from ..training import fit_and_evaluate

    log.info("%s seed %d: %d train / %d test windows, %d channels @ %g Hz", name, seed,
             train.y.size, test.y.size, train.X.shape[1], train.fs_hz)  # fmt: skip
    rows: list[dict] = []
    ref_pipe = None
    for label, enc, model, applies, settings in chosen:
        if applies == ("analog" if events else "events"):
            continue
        cfg = default_config(events, enc, model, seed, settings, train.facts)
        if epochs is not None:
            cfg = cfg.replace(train=replace(cfg.train, epochs=epochs))
        t0 = time.perf_counter()
        if enc is None and not events:  # as train --data: the encoder chosen on held-out
            cfg, _ = select_encoder(cfg, train, DATA_ENCODER_CANDIDATES)  # recordings
        elif not events:  # as train --data --encoder E: its bands follow the data
            cfg = fit_encoder_to_data(cfg, train)
        res = fit_and_evaluate(cfg, train, test, progress=progress)
        m = res.metrics
        rows.append({
            "dataset": name, "seed": seed, "method": label, "kind": "spike",
            "encoder": cfg.encoder_type,
            "accuracy": m["test_accuracy"],
            "accuracy_per_recording": m.get("test_accuracy_per_recording"),
            "seconds": time.perf_counter() - t0,
            # a model that decides before the window ends: its accuracy then, and when
            "early_accuracy": m.get("early_decision", {}).get("accuracy"),
            "early_window_fraction": None if "early_decision" not in m else
            1.0 - m["early_decision"]["window_skipped_fraction"],
            # a stream model run frame by frame over the test recordings, state carried
            "frame_stream": m.get("frame_stream"),
        })  # fmt: skip
        if enc is None and ref_pipe is None:
            ref_pipe = res.pipeline
    if ref_pipe is not None:
        t0 = time.perf_counter()
        for label, (acc, rec) in references(train, test, ref_pipe, seed).items():
            rows.append({"dataset": name, "seed": seed, "method": label, "kind": "reference",
                         "accuracy": acc, "accuracy_per_recording": rec,
                         "seconds": time.perf_counter() - t0})  # fmt: skip
    return rows


def summarise(rows: list[dict]) -> list[dict]:
    """Mean and sd over seeds per (dataset, method); the gap to the best reference."""
    keys = sorted({(r["dataset"], r["method"], r["kind"]) for r in rows})
    out = []
    for ds, method, kind in keys:
        sel = [r for r in rows if r["dataset"] == ds and r["method"] == method]
        acc = np.array([r["accuracy"] for r in sel])
        rec = [r["accuracy_per_recording"] for r in sel if r["accuracy_per_recording"] is not None]
        out.append({
            "dataset": ds, "method": method, "kind": kind, "seeds": len(sel),
            "mean": float(acc.mean()), "sd": float(acc.std(ddof=1)) if acc.size > 1 else 0.0,
            "per_recording_mean": float(np.mean(rec)) if rec else None,
            "seconds_mean": float(np.mean([r["seconds"] for r in sel])),
            **_early_means(sel),
        })  # fmt: skip
    for ds in {s["dataset"] for s in out}:
        _judge([s for s in out if s["dataset"] == ds])
    return out


def _judge(sel: list[dict]) -> None:
    """Gaps of each row to the best reference per window and per recording (points), and for
    spike rows whether they meet the goal (and stay above the amplitude-only baseline)."""
    refs = [s for s in sel if s["kind"] == "reference"]
    if not refs:
        return
    best_win = max(s["mean"] for s in refs)
    recs = [s["per_recording_mean"] for s in refs if s["per_recording_mean"] is not None]
    best_rec = max(recs) if recs else None
    amp = next((s["mean"] for s in refs if s["method"] == AMPLITUDE_BASELINE), None)
    for s in sel:
        s["gap_window_points"] = 100 * (s["mean"] - best_win)
        rec = s["per_recording_mean"]
        s["gap_recording_points"] = (
            None if rec is None or best_rec is None else 100 * (rec - best_rec)
        )
        # recordings cut into windows are judged per recording (the answer a user wants)
        per_rec = s["gap_recording_points"] is not None
        s["gap_to_best_reference_points"] = (
            s["gap_recording_points"] if per_rec else s["gap_window_points"]
        )
        s["gap_measured_on"] = "per recording" if per_rec else "window"
        if s["kind"] == "spike":
            ok = s["gap_window_points"] >= -WINDOW_POINTS and (
                not per_rec or s["gap_recording_points"] >= -RECORDING_POINTS
            )
            s["above_amplitude_baseline"] = amp is None or s["mean"] >= amp
            s["meets_goal"] = bool(ok and s["above_amplitude_baseline"])


def _early_means(rows: list[dict]) -> dict:
    """Mean early-decision accuracy and decision time (fraction of the window) over seeds."""
    acc = [r["early_accuracy"] for r in rows if r.get("early_accuracy") is not None]
    frac = [r["early_window_fraction"] for r in rows if r.get("early_window_fraction") is not None]
    return {"early_accuracy_mean": float(np.mean(acc)) if acc else None,
            "early_window_fraction_mean": float(np.mean(frac)) if frac else None}  # fmt: skip


def table(summary: list[dict]) -> str:
    head = ("dataset", "method", "kind", "per window % (mean +- sd)", "per recording %",
            "vs best reference per window / per recording (points)",
            f"goal (window -{WINDOW_POINTS:g}, recording -{RECORDING_POINTS:g}, >= amplitude)",
            "early decision: accuracy % at % of the window", "s / run")  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in summary:
        rec = "-" if s["per_recording_mean"] is None else f"{100 * s['per_recording_mean']:.2f}"
        gw, gr = s.get("gap_window_points"), s.get("gap_recording_points")
        gaps = f"{'-' if gw is None else f'{gw:+.2f}'} / {'-' if gr is None else f'{gr:+.2f}'}"
        goal = "-" if "meets_goal" not in s else ("met" if s["meets_goal"] else (
            "short" if s["above_amplitude_baseline"] else "short, below amplitude"))  # fmt: skip
        lines.append(
            f"| {s['dataset']} | {s['method']} | {s['kind']} | {100 * s['mean']:.2f} +- "
            f"{100 * s['sd']:.2f} (n={s['seeds']}) | {rec} | {gaps} | {goal} | {_early_cell(s)} | "
            f"{s['seconds_mean']:.1f} |"
        )
    return "\n".join(lines) + "\n"


def _early_cell(s: dict) -> str:
    if s.get("early_accuracy_mean") is None:
        return "-"
    return f"{100 * s['early_accuracy_mean']:.2f} at {100 * s['early_window_fraction_mean']:.0f}"


def plot(summary: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = sorted({s["dataset"] for s in summary})
    fig, axes = plt.subplots(1, max(1, len(sets)), figsize=(6 * max(1, len(sets)), 4),
                             squeeze=False)  # fmt: skip
    for ax, ds in zip(axes[0], sets, strict=False):
        rows = [s for s in summary if s["dataset"] == ds]
        colours = ["tab:blue" if s["kind"] == "spike" else "tab:grey" for s in rows]
        ax.barh([s["method"] for s in rows], [100 * s["mean"] for s in rows],
                xerr=[100 * s["sd"] for s in rows], color=colours)  # fmt: skip
        ax.set_xlim(0, 100)
        ax.set_xlabel("test accuracy (%)")
        ax.set_title(f"{ds} (blue: spike pipelines, grey: references)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


HELP = "real recordings: the defaults against non-spiking references on the same split"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from . import add_data_root

    add_data_root(p, "the real datasets")
    p.add_argument("--datasets", nargs="+", help="subset of datasets (default: the real ones "
                   "found); synth:<task> runs the same check on a synthetic task")  # fmt: skip
    p.add_argument("--pipelines", nargs="+",
                   help=f"spike pipelines by name, or all (default: {' '.join(DEFAULT_PIPELINES)}"
                   ", what train --data trains with no flag; the others take longer)")  # fmt: skip
    p.add_argument("--seeds", type=int, default=3, help="dataset and training seeds")
    p.add_argument("--epochs", "--bench-epochs", type=int, default=None,
                   help="epochs (default: each model's own default, as train --data)")  # fmt: skip
    p.add_argument("--docs", default=None,
                   help="also write the page docs/real.md (and its JSON beside it) here")  # fmt: skip


PAGE_HEAD = """# Real recordings against non-spiking references

Generated by `tactilesnn bench real` from its JSON (`real.json` beside this page; a test checks
that the table below is the one the JSON gives). Each spike pipeline is trained as `tactilesnn
train --data FILE` trains it (`default+*`: no flag but the model; the encoder chosen on held-out
training recordings), every reference (logistic regression on log band powers and on the
peak-normalised wave, random forests on counts and summary statistics, an MLP on spike features,
the amplitude-only baseline) on the identical split; mean +- sd over seeds. Command:

```sh
{command}
```

Machine: {machine}.

"""


#: the row the README shows per dataset: what ``train --data FILE`` with no flag trains
README_ROWS = {"braille_icub_abc": ("iCub Braille A/B/C", "default+readout"),
               "fabric_slide": ("FabricSlide, 966 CSVs", "default+readout"),
               "st_mnist": ("ST-MNIST events (10 x 10 taxels)", "events+csnn")}  # fmt: skip


def readme_table(summary: list[dict]) -> str:
    """The README's table: per dataset, the no-flag defaults against the best reference (per
    window / per recording, mean over seeds)."""

    def pct(v: float | None) -> str:
        return "-" if v is None else f"{100 * v:.2f}"

    lines = ["| set, as it comes (seeds) | defaults, % per window / recording | best reference | gap "
             "(points) |", "|---|---|---|---|"]  # fmt: skip
    for ds, (label, method) in README_ROWS.items():
        rows = [s for s in summary if s["dataset"] == ds]
        mine = next((s for s in rows if s["method"] == method), None)
        refs = [s for s in rows if s["kind"] == "reference"]
        if mine is None or not refs:
            continue
        best = max(refs, key=lambda r: r["mean"])
        gap = f"{mine['gap_window_points']:+.2f}"
        if mine.get("gap_recording_points") is not None:
            gap += f" / {mine['gap_recording_points']:+.0f}"
        lines.append(f"| {label} ({mine['seeds']}) | {pct(mine['mean'])} / "
                     f"{pct(mine['per_recording_mean'])} | {best['method']} {pct(best['mean'])} / "
                     f"{pct(best['per_recording_mean'])} | {gap} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def page(summary: list[dict], command: str, machine: str) -> str:
    """The docs page of a run's summary (:data:`PAGE_HEAD` and :func:`table`)."""
    return PAGE_HEAD.format(command=command, machine=machine) + table(summary)


def main(out: Path | None, options: argparse.Namespace) -> int:
    import os

    from . import data_root, require_out, write_result

    synthetic_only = bool(options.datasets) and all(
        d.startswith("synth:") for d in options.datasets)  # fmt: skip
    root = Path(options.data_root or ".") if synthetic_only else data_root(options, "real")
    result = run(Path(require_out(out, "real")), data_root=root,
                 seeds=options.seeds, datasets=options.datasets, pipelines=options.pipelines,
                 epochs=options.epochs, progress=not options.quiet)  # fmt: skip
    if options.docs:
        parts = ["tactilesnn bench real --out DIR", f"--seeds {options.seeds}"]
        if options.datasets:
            parts.append("--datasets " + " ".join(options.datasets))
        if options.pipelines:
            parts.append("--pipelines " + " ".join(options.pipelines))
        command = " ".join(parts)
        machine = f"{os.cpu_count()} CPUs, {time.strftime('%Y-%m-%d')}"
        docs = Path(options.docs)
        write_result(docs.parent, docs.with_suffix(".json").name,
                     {**result, "command": command, "machine": machine})  # fmt: skip
        docs.write_text(page(result["summary"], command, machine))
        readme = docs.resolve().parent.parent / "README.md"
        if readme.is_file():
            readme.write_text(with_readme_table(readme.read_text(), result["summary"]))
    return 0


README_BEGIN = (
    "<!-- generated by `tactilesnn bench real --docs docs/real.md` from docs/real.json -->"
)
README_END = "<!-- end of the generated table -->"


def with_readme_table(text: str, summary: list[dict]) -> str:
    """The README ``text`` with its generated block (between :data:`README_BEGIN` and
    :data:`README_END`) replaced by :func:`readme_table` of ``summary``."""
    i, j = text.find(README_BEGIN), text.find(README_END)
    if i < 0 or j < i:
        raise ValueError("README.md has no generated bench real block")
    return text[: i + len(README_BEGIN)] + "\n" + readme_table(summary) + text[j:]
