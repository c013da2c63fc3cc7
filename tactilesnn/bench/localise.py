"""``tactilesnn bench localise``: contact position and force direction on the piezoresistive
chip array (task ``localise``), the spike pipeline against the seed's least-squares inverse.

For ``target=position`` (a ``cells x cells`` grid) and ``target=direction`` (8 sectors): the
``train --data`` defaults (encoder chosen on held-out recordings, ``readout`` model) trained on
the task's training split; on its test split, the error of the predicted cell's centre against
the true contact point (mm) and of the predicted sector's centre against the true tangential
force direction (degrees). References on the same test samples: the seed's least-squares solve
(:func:`~tactilesnn.datasets_synth.sensors.piezoresistive.solve_contact` on the stress read at the hold:
continuous, no classes), logistic regression on the hold readings (the same classes), and the
floor a perfect classifier reaches (the true class's centre). Writes ``localise.json`` and
``localise.md``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

HOLD_FRAMES = 10


def _angle_error(a_deg: np.ndarray, b_deg: np.ndarray) -> np.ndarray:
    return np.abs((np.asarray(a_deg) - np.asarray(b_deg) + 180.0) % 360.0 - 180.0)


def least_squares(X: np.ndarray, depth_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Seed 002's inverse per sample: ``X [N, 100, frames]`` -> (centres ``[N, 2]`` mm,
    tangential force angles ``[N]`` degrees), from the mean of the last frames (the hold)."""
    from ..datasets_synth.sensors.piezoresistive import chip_positions, solve_contact, solve_stress

    chips = chip_positions()
    hold = X[..., -HOLD_FRAMES:].mean(-1).reshape(len(X), 25, 4).astype(np.float64)
    centres, angles = np.empty((len(X), 2)), np.empty(len(X))
    for i, r in enumerate(hold):
        s, lam = solve_stress(r)
        c, f = solve_contact(chips, s, lam, depth_mm)
        centres[i], angles[i] = c, np.degrees(np.arctan2(f[2], f[1]))
    return centres, angles


def _errors(task, pred: np.ndarray, info: list[dict]) -> np.ndarray:
    if task.target == "position":
        truth = np.array([i["center_mm"] for i in info])
        guess = np.array([task.cell_center_mm(int(p)) for p in pred])
        return np.linalg.norm(guess - truth, axis=1)
    truth = np.array([i["angle_deg"] for i in info])
    return _angle_error(45.0 * np.asarray(pred), truth)


def _row(method: str, err: np.ndarray, acc: float | None, unit: str) -> dict:
    return {"method": method, "unit": unit, "median": float(np.median(err)), "mean": float(err.mean()),
            "p90": float(np.percentile(err, 90)), "accuracy": acc}  # fmt: skip


def run_target(target: str, seed: int, n_samples: int, cells: int, epochs: int | None,
               progress: bool) -> list[dict]:  # fmt: skip
    from sklearn.linear_model import LogisticRegression
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    from ..baselines import amplitude_stats, fit_amplitude_baseline
    from ..data_policy import DATA_ENCODER_CANDIDATES
    from ..datasets_synth import get_task
    from ..selection import select_encoder
    from ..training import fit_and_evaluate
    from .real import default_config

    task = get_task("localise", seed=seed, n_samples=n_samples, target=target, cells=cells)
    train, test = task.build(progress=progress)
    info = [task.sample(int(i))[2] for i in test.scan]
    unit = "mm" if target == "position" else "deg"
    rows = []
    t0 = time.perf_counter()
    cfg = with_epochs(default_config(False, None, "readout", seed), epochs)
    cfg, report = select_encoder(cfg, train, DATA_ENCODER_CANDIDATES)
    res = fit_and_evaluate(cfg, train, test, progress=progress)
    pred = res.pipeline.predict(test.X)
    row = _row(f"{report['chosen']} + readout (spikes)", _errors(task, pred, info),
               float((pred == test.y).mean()), unit)  # fmt: skip
    row["seconds"] = time.perf_counter() - t0
    rows.append(row)

    def hold(ds):
        return ds.X[..., -HOLD_FRAMES:].mean(-1)

    lr = make_pipeline(StandardScaler(), LogisticRegression(max_iter=2000, C=1.0))
    lr.fit(hold(train), train.y)
    p_lr = lr.predict(hold(test))
    rows.append(_row("logistic regression on the hold readings", _errors(task, p_lr, info),
                     float((p_lr == test.y).mean()), unit))  # fmt: skip
    p_amp = fit_amplitude_baseline(train.X, train.y).predict(amplitude_stats(test.X))
    rows.append(_row("logistic regression on window mean and RMS (amplitude baseline)",
                     _errors(task, p_amp, info), float((p_amp == test.y).mean()), unit))  # fmt: skip
    centres, angles = least_squares(test.X, task.depth_mm)
    if target == "position":
        err = np.linalg.norm(centres - np.array([i["center_mm"] for i in info]), axis=1)
    else:
        err = _angle_error(angles, [i["angle_deg"] for i in info])
    rows.append(_row("least squares (seed 002, continuous)", err, None, unit))
    rows.append(_row("floor: the true class's centre", _errors(task, test.y, info), 1.0, unit))
    for r in rows:
        r["target"] = target
    return rows


def with_epochs(cfg, epochs: int | None):
    from dataclasses import replace

    return cfg if epochs is None else cfg.replace(train=replace(cfg.train, epochs=epochs))


def table(rows: list[dict]) -> str:
    lines = ["| target | method | median error | mean | 90th percentile | class accuracy % |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        acc = "-" if r["accuracy"] is None else f"{100 * r['accuracy']:.1f}"
        u = r["unit"]
        lines.append(f"| {r['target']} | {r['method']} | {r['median']:.2f} {u} | {r['mean']:.2f} {u} | "
                     f"{r['p90']:.2f} {u} | {acc} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def run(out: Path, seed: int = 0, n_samples: int = 1200, cells: int = 3, epochs: int | None = None,
        progress: bool = True) -> list[dict]:  # fmt: skip
    rows = []
    for target in ("position", "direction"):
        rows += run_target(target, seed, n_samples, cells, epochs, progress)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "localise.json").write_text(json.dumps(rows, indent=2))
    text = table(rows)
    (out / "localise.md").write_text(text)
    print(text)
    return rows


HELP = (
    "contact position (mm) and force direction (deg) on the piezoresistive array vs least squares"
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seed", type=int, default=0, help="task and training seed")
    p.add_argument("--samples", type=int, default=1200, help="presses rendered per target")
    p.add_argument("--cells", type=int, default=3, help="position classes: a cells x cells grid")
    p.add_argument("--epochs", type=int, default=None, help="epochs (default: the model's own)")


def main(out: Path | None, options: argparse.Namespace) -> int:
    from . import require_out

    run(Path(require_out(out, "localise")), seed=options.seed, n_samples=options.samples,
        cells=options.cells, epochs=options.epochs, progress=not options.quiet)  # fmt: skip
    return 0
