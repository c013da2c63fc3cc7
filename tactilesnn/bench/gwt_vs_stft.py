"""Seed 001's comparison: GWT vs STFT latency codes into a tempotron, same 100-sample window.

For each seed (dataset generation, split and initialisation), both encoders are trained and tested
on the same scans; the amplitude-only linear baseline is reported alongside, and an ablation,
``gwt_mean``: the GWT code with the band means only (no within-window fluctuation), which is what
a single-frame STFT can express. It separates what the wavelet gains from its log-frequency
resolution (``gwt_mean`` vs ``stft``) from what it gains from time resolution inside the window
(``gwt`` vs ``gwt_mean``). Writes
``results.json`` and ``training_error.png`` (training error vs epoch, seed 001 Figure 8) to ``out``.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import numpy as np

from ..app.runs import RunWriter
from ..baselines import linear_amplitude_baseline
from ..config import PipelineConfig, TrainConfig
from ..datasets_synth import HookLoopTask
from ..training import fit_and_evaluate

log = logging.getLogger("tactilesnn")

SEED_001 = {"gwt": 0.9945, "stft": 0.953}
PIPELINES = {
    "gwt": {"encoder": "gwt"},
    "stft": {"encoder": "stft"},
    "gwt_mean": {"encoder": "gwt", "stats": ("mean",)},
}


def run(
    seeds: int = 5,
    out: Path = Path("bench_out/gwt_vs_stft"),
    overwrite: bool = False,
    epochs: int | None = None,
    difficulty: float = 1.0,
    progress: bool = True,
) -> dict:
    if seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {seeds}")
    writer = RunWriter(Path(out), overwrite=overwrite)
    try:
        results: dict = {"difficulty": difficulty, "seeds": [], "seed_001": SEED_001}
        for seed in range(seeds):
            t0 = time.perf_counter()
            train, test = HookLoopTask(seed=seed, difficulty=difficulty).build(progress=progress)
            row: dict = {
                "seed": seed,
                "n_train": int(train.y.size),
                "n_test": int(test.y.size),
                "baseline_amplitude_linear": linear_amplitude_baseline(
                    train.X, train.y, test.X, test.y
                ),
            }
            for key, kw in PIPELINES.items():
                cfg = PipelineConfig.from_flat(
                    seed=seed, **kw, **({"epochs": epochs} if epochs is not None else {})
                )
                res = fit_and_evaluate(cfg, train, test, progress=progress)
                row[key] = {
                    "test_accuracy": res.metrics["test_accuracy"],
                    "train_error_history": res.history,
                    "fit_seconds": res.metrics["fit_seconds"],
                }
            log.info(
                "seed %d: GWT %.4f STFT %.4f GWT-mean-only %.4f baseline %.4f (%.0f s)",
                seed,
                row["gwt"]["test_accuracy"],
                row["stft"]["test_accuracy"],
                row["gwt_mean"]["test_accuracy"],
                row["baseline_amplitude_linear"],
                time.perf_counter() - t0,
            )
            results["seeds"].append(row)
        results["summary"] = summarise(results["seeds"])
        table = format_table(results["summary"], seeds)
        print(table)
        results["table"] = table
        writer.write_json("results.json", results)
        plot_curves(results["seeds"], writer.file("training_error.png"))
        path = writer.commit()
        print(f"results: {path / 'results.json'}, plot: {path / 'training_error.png'}")
    except BaseException:
        writer.abort()
        raise
    return results


def summarise(rows: list[dict]) -> dict:
    out = {}
    for key in (*PIPELINES, "baseline_amplitude_linear"):
        acc = np.array([r[key]["test_accuracy"] if key in PIPELINES else r[key] for r in rows])
        out[key] = {
            "mean": float(acc.mean()),
            "sd": float(acc.std(ddof=1)) if acc.size > 1 else 0.0,
            "min": float(acc.min()),
            "max": float(acc.max()),
        }
    return out


def format_table(summary: dict, seeds: int) -> str:
    names = {
        "gwt": "GWT -> latency -> tempotron",
        "stft": "STFT -> latency -> tempotron",
        "gwt_mean": "GWT, band means only (ablation)",
        "baseline_amplitude_linear": "linear on mean/RMS (trivial)",
    }
    lines = [
        f"test accuracy over {seeds} seeds (hook vs loop, 100-sample windows)",
        f"| {'pipeline':<32} | mean %  | sd %  | min %  | max %  | seed 001 % |",
        f"|{'-' * 34}|---------|-------|--------|--------|------------|",
    ]
    for key, name in names.items():
        s = summary[key]
        ref = f"{100 * SEED_001[key]:.2f}" if key in SEED_001 else "-"
        lines.append(
            f"| {name:<32} | {100 * s['mean']:7.2f} | {100 * s['sd']:5.2f} | "
            f"{100 * s['min']:6.2f} | {100 * s['max']:6.2f} | {ref:>10} |"
        )
    return "\n".join(lines)


def plot_curves(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for enc, color in (("gwt", "tab:blue"), ("stft", "tab:orange")):
        curves = np.array([r[enc]["train_error_history"] for r in rows]) * 100
        ep = np.arange(1, curves.shape[1] + 1)
        m = curves.mean(0)
        ax.plot(ep, m, color=color, label=enc.upper())
        ax.fill_between(ep, curves.min(0), curves.max(0), color=color, alpha=0.2)
    ax.set_xlabel("epoch")
    ax.set_ylabel("training error (%)")
    ax.set_title("Training error vs epoch (mean, min-max over seeds)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


HELP = "seed 001's comparison: GWT vs STFT latency codes on the hook/loop task over seeds"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seeds", type=int, default=5, help="dataset and training seeds")
    p.add_argument("--epochs", type=int, default=TrainConfig().epochs, help="training epochs")
    p.add_argument("--difficulty", type=float, default=1.0, help="task difficulty multiplier")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out folder")


def main(out: Path | None, options: argparse.Namespace) -> int:
    from . import require_out

    run(seeds=options.seeds, out=Path(require_out(out, "gwt-vs-stft")),
        overwrite=options.overwrite, epochs=options.epochs, difficulty=options.difficulty,
        progress=not options.quiet)  # fmt: skip
    return 0
