"""Pictures of a run folder: confusion matrix, training curve, and a few test windows as the
pipeline sees them (raw signal -> the encoder's map, if it has one -> spike raster -> scores)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_confusion(cm: np.ndarray, names: tuple[str, ...] | list[str], path: Path) -> None:
    """Confusion matrix as row-normalised recall (%), counts in each cell, readable at any size."""
    plt = _pyplot()
    n = len(names)
    recall = cm / np.maximum(cm.sum(1, keepdims=True), 1)
    fig, ax = plt.subplots(figsize=(3.5 + 0.55 * n, 3.0 + 0.5 * n))
    im = ax.imshow(recall, cmap="Blues", vmin=0.0, vmax=1.0)
    ax.set_xticks(range(n), names, rotation=45 if n > 4 else 0, ha="right" if n > 4 else "center")
    ax.set_yticks(range(n), names)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    size = 10 if n <= 6 else max(5, 12 - n // 2)
    for i in range(cm.shape[0]):
        for j in range(cm.shape[1]):
            dark = recall[i, j] > 0.55  # white text on dark cells, black on light ones
            ax.text(j, i, f"{cm[i, j]}", ha="center", va="center", fontsize=size,
                    color="white" if dark else "black")  # fmt: skip
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04, label="recall")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_training(history: list[float], val_history: list[float], path: Path,
                  solve: dict | None = None) -> None:  # fmt: skip
    """Training error (and validation error if any) per epoch; a model solved in one go
    (``solve``: its ``model_fit`` report with a ``cross_validation`` table) is drawn as what
    the solve did instead: the cross-validated error against the penalty, one line per set of
    read-out instants, the chosen point marked, the final training and validation errors."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.0, 3.2))
    table = (solve or {}).get("cross_validation") or []
    if table and len(history) <= 1:
        for k in sorted({r["instants"] for r in table}, reverse=True):
            rows = sorted((r for r in table if r["instants"] == k), key=lambda r: r["penalty"])
            ax.plot([r["penalty"] for r in rows], [100 * (1 - r["cv_accuracy"]) for r in rows],
                    marker="o", ms=3, label=f"cross-validated, {k} instant(s)")  # fmt: skip
        chosen = [r for r in table if r["penalty"] == solve["penalty"]  # type: ignore[index]
                  and r["instants"] == solve["instants"]]  # type: ignore[index]  # fmt: skip
        if chosen:
            ax.plot([chosen[0]["penalty"]], [100 * (1 - chosen[0]["cv_accuracy"])], "k*", ms=10,
                    label="chosen")  # fmt: skip
        if history:
            ax.axhline(100 * history[0], color="C2", ls="--", lw=1, label="final training error")
        if val_history:
            ax.axhline(100 * (1 - val_history[-1]), color="C3", ls=":", lw=1,
                       label="validation error")  # fmt: skip
        ax.set_xscale("log")
        ax.set_xlabel("penalty (L2, per window)")
        ax.set_title(f"readout solve: {solve.get('solver', '')}", fontsize=8)  # type: ignore[union-attr]
    else:
        epochs = np.arange(1, len(history) + 1)
        ax.plot(epochs, 100 * np.asarray(history), marker="o", ms=3, label="training error")
        if val_history:
            ax.plot(epochs[: len(val_history)], 100 * (1 - np.asarray(val_history)), marker="s",
                    ms=3, label="validation error")  # fmt: skip
        ax.set_xlabel("epoch")
    ax.set_ylabel("error (%)")
    ax.set_ylim(bottom=0)  # from zero: small errors look small
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


#: most test windows drawn side by side (one per class; more classes: this many, spread out)
MAX_WINDOW_COLUMNS = 8


def classes_drawn(y: np.ndarray, n_classes: int, per_class: int = 1) -> tuple[list[int], list[int]]:
    """``(classes drawn, classes present in y)`` for :func:`plot_windows`: every class present,
    or :data:`MAX_WINDOW_COLUMNS` ``// per_class`` of them spread evenly."""
    present = [c for c in range(n_classes) if (y == c).any()]
    if len(present) * per_class <= MAX_WINDOW_COLUMNS:
        return present, present
    keep = max(1, MAX_WINDOW_COLUMNS // per_class)
    idx = np.unique(np.linspace(0, len(present) - 1, keep).round().astype(int))
    return [present[i] for i in idx], present


def plot_windows(pipe, X: np.ndarray, y: np.ndarray, path: Path, per_class: int = 1) -> None:
    """One column per picked test window (``per_class`` of each class present, at most
    :data:`MAX_WINDOW_COLUMNS` columns: with more classes, that many spread evenly over them,
    said in the title): the pipeline's input channels (a.u. over ms), the encoder's map if it
    has one (log magnitude, band centres in Hz), the spike raster (afferent vs ms) and the
    class scores."""
    plt = _pyplot()
    shown, present = classes_drawn(np.asarray(y), len(pipe.class_names), per_class)
    picks = [int(i) for c in shown for i in np.flatnonzero(y == c)[:per_class]]
    if not picks:
        return
    Xs = np.asarray(X)[picks]
    encoded = pipe.encode(Xs)
    spikes, scores = encoded.numpy(), pipe.scores(encoded).numpy()
    sel = pipe.channel_idx
    maps = [pipe.encoder.feature_map(x[sel]) for x in Xs]
    rows = 4 if maps[0] is not None else 3
    fig, axes = plt.subplots(rows, len(picks), figsize=(3.2 * len(picks) + 0.6, 2.0 * rows),
                             squeeze=False)  # fmt: skip
    t_ms = np.arange(pipe.window) * 1000.0 / pipe.fs_hz
    for col, (x, s, sc, fm) in enumerate(zip(Xs, spikes, scores, maps, strict=True)):
        truth, guess = pipe.class_names[int(y[picks[col]])], pipe.class_names[int(sc.argmax())]
        ax = axes[0, col]
        _plot_input(fig, ax, x[sel], t_ms, [pipe.channel_names[c] for c in sel], col == 0)
        ax.set_title(f"true: {truth} · predicted: {guess}", fontsize=9,
                     color="black" if truth == guess else "C3")  # fmt: skip
        r = 1
        if fm is not None:
            mag, freqs = fm
            ax = axes[r, col]
            im = ax.imshow(np.log10(mag + 1e-6 * mag.max() + 1e-30), aspect="auto",
                           origin="lower", extent=(0, t_ms[-1], 0, len(freqs)), cmap="magma")  # fmt: skip
            bar = fig.colorbar(im, ax=ax, fraction=0.05, pad=0.02)
            bar.ax.tick_params(labelsize=6)
            bar.set_label("log10 magnitude", fontsize=6)
            ticks = np.linspace(0, len(freqs) - 1, min(4, len(freqs))).astype(int)
            ax.set_yticks(ticks + 0.5, [f"{freqs[i]:.0f}" for i in ticks], fontsize=7)
            if col == 0:
                ax.set_ylabel("band (Hz)")
            r += 1
        ax = axes[r, col]
        a, k = np.nonzero(np.isfinite(s))
        ax.scatter(s[a, k], a, s=10, c="k", marker="|", linewidths=0.8)
        ax.set_xlim(0, pipe.duration_ms)
        ax.set_ylim(-1, s.shape[0])
        if col == 0:
            ax.set_ylabel("afferent")
        ax.set_xlabel("spike time (ms)", fontsize=8)
        ax = axes[r + 1, col]
        ax.bar(
            range(len(sc)), sc, color=["C1" if i == sc.argmax() else "C0" for i in range(len(sc))]
        )
        ax.set_xticks(range(len(sc)), pipe.class_names, rotation=45 if len(sc) > 4 else 0,
                      fontsize=7, ha="right" if len(sc) > 4 else "center")  # fmt: skip
        if col == 0:
            ax.set_ylabel("score")
    if len(shown) < len(present):
        fig.suptitle(f"test windows of {len(shown)} of the {len(present)} classes (spread "
                     "evenly; the confusion matrix has them all)", fontsize=9)  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


#: inputs of at most this many channels are drawn as lines (with a legend), more as an image
MAX_LINES = 8


def _plot_input(fig, ax, x: np.ndarray, t_ms: np.ndarray, names: list[str], first: bool) -> None:
    """Every channel of one window ``x [channels, samples]`` (sensor units over ms): lines with
    a legend for a few channels, an image with a colour bar (every channel) for more."""
    if len(names) <= MAX_LINES:
        for row, name in zip(x, names, strict=True):
            ax.plot(t_ms, row, lw=0.7, label=name)
        if first:
            ax.legend(fontsize=6, loc="upper right")
            ax.set_ylabel("input (sensor units)")
    else:
        im = ax.imshow(x, aspect="auto", origin="lower", cmap="viridis", interpolation="nearest",
                       extent=(0, t_ms[-1], -0.5, len(names) - 0.5))  # fmt: skip
        bar = fig.colorbar(im, ax=ax, fraction=0.05, pad=0.02)
        bar.ax.tick_params(labelsize=6)
        bar.set_label("sensor units", fontsize=6)
        ticks = np.linspace(0, len(names) - 1, min(6, len(names))).astype(int)
        ax.set_yticks(ticks, [names[i][:10] for i in ticks], fontsize=6)
        if first:
            ax.set_ylabel(f"all {len(names)} channels")
    ax.set_xlabel("ms", fontsize=8)


# ---------------------------------------------------------------- cost against error
def pareto_front(rows: list[dict], cost_key: str = "ms_per_signal_s_batch1") -> None:
    """Mark ``row["front"]``: no other row has lower-or-equal error and cost, one strictly."""
    timed = [r for r in rows if r.get(cost_key) is not None]
    for r in rows:
        r["front"] = False
    for r in timed:
        e, c = r["test_error"], r[cost_key]
        r["front"] = not any(
            (o["test_error"] <= e and o[cost_key] <= c) and (o["test_error"] < e or o[cost_key] < c)
            for o in timed
        )


def plot_cost_error(
    rows: list[dict],
    path: Path,
    title: str,
    cost_key: str = "ms_per_signal_s_batch1",
    xlabel: str = "compute per second of signal (ms, 1 thread, batch 1)",
) -> None:
    """Test error vs ``cost_key`` (log axes) with 95 % intervals; the rows marked ``front`` in
    red and labelled (``label``, else config and precision)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    marks = {"torch float32": "o", "onnxruntime float32": "s", "onnxruntime int8": "^"}
    for r in rows:
        if r.get(cost_key) is None:
            continue
        err = max(r["test_error"], 1e-4)
        ax.errorbar(r[cost_key], 100 * err, yerr=100 * r["test_error_ci95"],
                    fmt=marks.get(r.get("precision"), "o"), ms=7 if r["front"] else 4,
                    color="C3" if r["front"] else "C0", alpha=0.9 if r["front"] else 0.45,
                    elinewidth=0.6)  # fmt: skip
        if r["front"]:
            label = r.get("label") or f"{r['config']}\n{r['precision']}"
            ax.annotate(label, (r[cost_key], 100 * err), fontsize=6, xytext=(4, 4),
                        textcoords="offset points")  # fmt: skip
    ax.set_xscale("log")
    ax.set_yscale("log")
    log_ticks(ax)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("test error (%)")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def log_ticks(ax) -> None:
    """Log axes labelled at 1, 2 and 5 of each decade as plain numbers, minor ticks unlabelled:
    matplotlib's default labels every minor tick of an axis spanning less than a decade, and
    those labels ran into each other (``2x10^-1 3x10^-1 ...``)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        axis.set_minor_formatter(NullFormatter())
