"""``tactilesnn calibrate``: fit a task's sensor model to a user's recordings.

Reads the recordings as ``train --data`` reads them (an ``.npz``, a folder of recordings, a
generated folder), keeps the ones named by ``--recordings`` (all by default: the file's order),
asks the task to fit its scene (:meth:`~tactilesnn.datasets_synth.tasks.trial.TrialTask.calibrate`)
and writes the fit file (JSON; ``generate`` / ``train --task`` read it with ``--task-kw
calibration=FILE``) and, with ``--plot``, the one picture that compares the recordings' statistics
with the model's before and after the fit (slides rendered by the task at the recordings' rate).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

log = logging.getLogger("tactilesnn")


def load_recordings(path: Path, fs_hz: float | None = None):
    """Whole recordings ``X [N, channels, samples]`` float64, labels, rate and class names."""
    from ..recordings import read_data_arrays

    a = read_data_arrays(Path(path), fs_hz)
    X = np.asarray(a["X"], np.float64)
    if X.ndim != 3:
        raise ValueError(f"{path}: recordings must be [N, channels, samples], got {X.shape}")
    if not np.isfinite(X).all():
        raise ValueError(f"{path}: the recordings hold NaN or Inf")
    names = tuple(str(n) for n in a["class_names"])
    return X, np.asarray(a["y"], np.int64), float(a["fs"]), names


def render_like(task_name: str, fs_hz: float, samples: int, class_names: tuple[str, ...], n: int,
                calibration: str = "", seed: int = 0) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """``n`` slides of the task at the recordings' rate and length, classes as named there."""
    from ..datasets_synth import get_task

    letters = "".join(c.strip().lower() for c in class_names)
    task = get_task(task_name, seed=seed, n_samples=max(n, 2 * len(letters)), letters=letters,
                    fs_frames_hz=fs_hz, duration_s=samples / fs_hz, calibration=calibration)  # fmt: skip
    X = np.empty((n, len(task.channel_names), samples))
    y = np.empty(n, np.int64)
    for i in range(n):
        X[i], y[i], _ = task.sample(i)
    return X, y


def calibrate(data: Path, task: str, out: Path, recordings: list[int] | None = None,
              budget_s: float = 600.0, evaluations: int = 1200, seed: int = 0,
              plot: Path | None = None, optimiser: str = "cma",
              overwrite: bool = False, fs_hz: float | None = None, progress: bool = True,
              known: dict[str, float] | None = None) -> list[str]:  # fmt: skip
    """Fit, write ``out`` (and ``plot``); the lines to print."""
    from ..datasets_synth import TASKS
    from ..datasets_synth.calibration import plot_statistics, slide_statistics, statistic_distances

    out = Path(out)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists; pass --overwrite to replace it")
    if plot is not None and Path(plot).exists() and not overwrite:
        raise FileExistsError(f"{plot} exists; pass --overwrite to replace it")
    if not (np.isfinite(budget_s) and budget_s > 0):
        raise ValueError(f"--budget-s must be a positive number of seconds, got {budget_s}")
    if evaluations < 10:
        raise ValueError(f"--evaluations must be >= 10, got {evaluations}")
    _trial_task(task, "calibrated")
    X, y, fs, names = load_recordings(data, fs_hz)
    if recordings is not None:
        idx = np.asarray(recordings, np.int64)
        if (
            idx.size == 0
            or idx.min() < 0
            or idx.max() >= len(X)
            or len(set(idx.tolist())) != idx.size
        ):
            raise ValueError(f"--recordings must be distinct indices in 0..{len(X) - 1}")
        X, y = X[idx], y[idx]
    t0 = time.perf_counter()
    fit = TASKS[task].calibrate(
        X,
        y,
        fs,
        names,
        budget_s=budget_s,
        seed=seed,
        progress=progress,
        max_evals=evaluations,
        optimiser=optimiser,
        known=known,
    )
    fit.fitted_on.update(data=str(Path(data).name), recordings=None if recordings is None
                         else [int(i) for i in recordings])  # fmt: skip
    fit.save(out, overwrite=overwrite)
    d = fit.objective["distances"]
    lines = [f"calibrated {task} on {len(X)} recordings of {Path(data).name} in "
             f"{time.perf_counter() - t0:.0f} s ({fit.objective['evaluations']} evaluations, "
             f"{fit.objective['optimiser']}): mean response {100 * d['mean_response']:.1f} % of "
             f"its variance unexplained, correlation off by {d['correlation']:.2f}",
             f"wrote {out}"]  # fmt: skip
    if plot is not None:
        n = max(30, 10 * len(names))
        real = slide_statistics(X, y, fs, len(names))
        fits = {}
        for label, cal in (("model's defaults", ""), ("calibrated", str(out))):
            S, ys = render_like(task, fs, X.shape[-1], names, n, cal, seed)
            fits[label] = slide_statistics(S, ys, fs, len(names))
            dist = statistic_distances(real, fits[label])
            lines.append(f"{label}: " + ", ".join(f"{k} {v:.3f}" for k, v in dist.items()))
        plot_statistics(real, fits, names, fs, Path(plot),
                        title=f"{Path(data).name}: real against the {task} task's sensor model")  # fmt: skip
        lines.append(f"wrote {plot}")
    return lines


def compare(data: Path, task: str, out: Path, plot: Path | None = None, n: int = 240,
            overwrite: bool = False, fs_hz: float | None = None, seed: int = 0) -> list[str]:  # fmt: skip
    """``calibrate --statistics-only``: the recordings' statistics next to the task's sensor model
    at its defaults (no fit: for a sensor the task cannot be fitted to, as FabricSlide's
    16-taxel finger through the ``texture`` task's capacitive stack), written as JSON (and the
    picture), with what the model cannot express."""
    from ..core.files import write_json_atomic
    from ..datasets_synth import get_task
    from ..datasets_synth.calibration import compare_statistics, plot_comparison, slide_statistics

    out = Path(out)
    for path in (out, plot):
        if path is not None and Path(path).exists() and not overwrite:
            raise FileExistsError(f"{path} exists; pass --overwrite to replace it")
    _trial_task(task, "compared (its model renders scans, not trials)")
    X, y, fs, names = load_recordings(data, fs_hz)
    t = get_task(task, seed=seed)
    model_names = tuple(t.class_names)
    Xm = np.empty((n, len(t.channel_names), t.window))
    ym = np.arange(n) % len(model_names)
    for i in range(n):
        Xm[i], ym[i], _ = t.sample(i)
    real = slide_statistics(X, y, fs, len(names))
    model = slide_statistics(Xm, ym, t.fs_hz, len(model_names))
    result = compare_statistics(real, model, names, model_names, fs, t.fs_hz)
    result.update(data=Path(data).name, task=task, recordings=len(X), model_samples=n,
                  real={k: real[k] for k in ("rest", "range", "noise", "spectrum")},
                  model={k: model[k] for k in ("rest", "range", "noise", "spectrum")},
                  spectrum_bands_hz=real["spectrum_bands_hz"])  # fmt: skip
    write_json_atomic(out, result)
    lines = [f"{Path(data).name} ({len(X)} recordings, {X.shape[1]} channels, {fs:.4g} Hz) against "
             f"the {task} task's sensor model ({n} samples, {Xm.shape[1]} channels, "
             f"{t.fs_hz:.4g} Hz): spectrum shapes {result['spectrum_shape_rms_decades']:.2f} "
             "decades apart (rms)", *(f"the model cannot express: {g}" for g in
                                     result["cannot_express"]), f"wrote {out}"]  # fmt: skip
    if plot is not None:
        plot_comparison(real, model, names, model_names, fs, t.fs_hz, Path(plot),
                        title=f"{Path(data).name} against the {task} task's sensor model")  # fmt: skip
        lines.append(f"wrote {plot}")
    return lines


def _trial_task(task: str, what: str) -> type:
    """The class of ``task`` if it renders trials (a sensor model that can be fitted and its
    statistics compared), else a ValueError naming those that do."""
    from ..datasets_synth import TASKS
    from ..datasets_synth.tasks.trial import TrialTask

    cls = TASKS.get(task)  # (unknown: the error lists the tasks)
    if not issubclass(cls, TrialTask):
        able = sorted(n for n in TASKS.names() if issubclass(TASKS.get(n), TrialTask))
        raise ValueError(f"the {task} task cannot be {what}; tasks that can: {', '.join(able)}")
    return cls
