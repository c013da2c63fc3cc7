"""``tactilesnn bench sim2real``: the Braille task's synthetic slides against the real iCub file.

The real recordings (``braille_icub_abc``: 45 slides, 12 taxels, A / B / C; never copied into the
repository) and slides of the ``braille`` task rendered at the real file's rate and length are
treated alike: both cut into windows as ``train --data`` cuts the real file, both through the
``train --data`` defaults (the encoder chosen once on the synthetic training set, the ``readout``
model).

1. **Signal statistics** per taxel, real next to synthetic: rest level (median of the first 10 %
   of the slide), range (99th - 1st percentile), peak time (when the taxel's rise above rest is
   largest, seconds from mid-slide) and the power spectrum (log power in 6 bands). The synthetic
   taxels are put in the real file's order by matching these statistics (Hungarian assignment on
   standardised rest, range and peak time, no labels used): the file does not say which of its
   12 channels is which pad.
2. **Synthetic only**: trained on ``--synthetic`` rendered slides, tested on all 45 real ones
   (mean and sd over ``--seeds`` render + training seeds).
3. **Few-shot**: ``k`` real slides per class (``--shots``, ``--draws`` random draws each) for
   training, the other real slides for testing; without synthetic data, and with the synthetic
   slides added to the training set (the real windows repeated to half of it: joint training).
4. **Randomisation knobs**: each of the task's knobs switched off and doubled (the others at
   their defaults), synthetic-only accuracy on the real file, the change against the defaults.
5. **Calibrated** (``--calibrated-draws``, default 3 per ``k``): for each few-shot draw, the
   sensor model is fitted (:meth:`~tactilesnn.datasets_synth.tasks.braille.BrailleTask.calibrate`,
   ``--calibration-budget-s``) to the ``k`` training slides per class *only*, the arm's speed
   held at its measured value (:func:`real_arm_speed_mm_s` over those slides); ``--calibrated-
   synthetic`` slides of the fitted model then train the pipeline (the encoder and the model's
   pretraining capacity, :func:`pretraining_candidates`, chosen by the ``k`` training slides'
   mean log-probability);
   its read-out's standardisation is re-estimated on the ``k`` training slides' windows (labels
   unused: :func:`~tactilesnn.training.adapt_pipeline`; the score before it is kept as
   ``synthetic_only_unadapted``), then it is scored on the other real slides (synthetic only)
   and fine-tuned on the ``k`` real
   slides (:func:`~tactilesnn.training.finetune_pipeline`: the read-out re-fitted with a prior
   centred on the pretrained weights), next to the same pipeline trained on the ``k`` real
   slides alone (real only). No test slide is seen by the calibration, the encoder's choice,
   the training or the fine-tune (there is no early stopping); ``tests/bench/test_sim2real.py``
   checks it. Each draw's fit is trained on with ``--calibrated-seeds`` seeds (default 3: its
   synthetic slides rendered and every pipeline trained again; one fit's synthetic-only score
   spans up to 45 points per slide from seed to seed); a draw's figure is the mean over its
   seeds, the intervals are over draws.

Writes ``sim2real.json`` (the calibrated section as ``synthetic_only_per_slide`` and ``shots:
{k: {real_only_per_window, pretrained_per_window, ...}}``, means over draws), ``sim2real.md``,
``sim2real.png`` and, per calibrated draw, the fit file and its statistics picture
(``fits/k{k}_d{d}.json``, ``.png`` for the first draw of each ``k``).
"""

from __future__ import annotations

import argparse
import copy
import json
import logging
import time
from dataclasses import replace
from itertools import pairwise
from pathlib import Path

import numpy as np

from ..core.data import WindowDataset
from . import add_data_root, data_root

log = logging.getLogger("tactilesnn")

REAL_FILE = "braille_icub_abc/braille_abc_icub.npz"
#: the braille task's randomisation knobs (each also a field of BrailleTask)
KNOBS = ("gain_spread", "offset_counts", "drift_counts", "speed_spread", "force_spread", "force_ramp",
         "position_mm", "taxel_noise")  # fmt: skip
SPECTRUM_BANDS_HZ = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0)


def load_real(root: Path) -> WindowDataset:
    """The real file's whole slides ``[45, 12, samples]`` as the reader converts them."""
    from ..recordings import read_data_arrays

    a = read_data_arrays(Path(root) / REAL_FILE)
    X = np.asarray(a["X"], np.float32)
    names = tuple(str(n) for n in a["class_names"])
    return WindowDataset(X, np.asarray(a["y"], np.int64), np.arange(len(X), dtype=np.int64),
                         float(a["fs"]), names, tuple(f"ch{i}" for i in range(X.shape[1])))  # fmt: skip


def render_synthetic(real: WindowDataset, n: int, seed: int, progress: bool = False,
                     class_signal: bool = False, **knobs: float) -> tuple:  # fmt: skip
    """``(slides, force rise N [n])``: ``n`` slides of the ``braille`` task at the real file's
    rate and length, letters named as the real classes (``A`` -> ``a``); recording ids from
    10^6 up. With ``class_signal``, ``(slides, rise, letter's signal [n, samples])`` (the
    task's ``info["class_signal"]``: what :func:`cut` turns into window confidences)."""
    from tqdm.auto import tqdm

    from ..datasets_synth import get_task

    letters = "".join(c.lower() for c in real.class_names)
    samples = real.X.shape[-1]
    task = get_task("braille", seed=seed, n_samples=max(n, 2 * len(letters)), letters=letters,
                    fs_frames_hz=real.fs_hz, duration_s=samples / real.fs_hz, **knobs)  # fmt: skip
    X = np.empty((n, len(task.channel_names), samples), np.float32)
    y = np.empty(n, np.int64)
    rise = np.empty(n)
    signal = np.empty((n, samples), np.float32) if class_signal else None
    for i in tqdm(range(n), desc="render braille", disable=not progress):
        X[i], y[i], info = task.sample(i, class_signal=class_signal)
        rise[i] = info["force_rise_N"]
        if signal is not None:
            signal[i] = info["class_signal"]
    ds = WindowDataset(X, y, 10**6 + np.arange(n, dtype=np.int64), real.fs_hz,
                       real.class_names, real.channel_names)  # fmt: skip
    return (ds, rise) if signal is None else (ds, rise, signal)


def real_force_rise(root: Path) -> np.ndarray | None:
    """Per real slide: the rise (N) of the arm's force over the letter (robot state columns 6-8
    read as a force vector in N: its norm's peak minus its median over the first 10 %)."""
    with np.load(Path(root) / REAL_FILE, allow_pickle=False) as f:
        if "robot_state" not in f.files:
            return None
        r = np.asarray(f["robot_state"], np.float64)
    if r.ndim != 3 or r.shape[-1] < 9:
        return None
    norm = np.linalg.norm(r[..., 6:9], axis=-1)
    return norm.max(1) - np.median(norm[:, : max(2, norm.shape[1] // 10)], 1)


def real_arm_speed_mm_s(root: Path, slides: np.ndarray, fs_hz: float) -> float | None:
    """The arm's sliding speed (mm/s) over ``slides``: the median over those slides of the
    least-squares slope of robot state column 1 (the fingertip's position along the slide, m),
    one sample per frame at ``fs_hz``. ``None`` when the file has no robot state."""
    with np.load(Path(root) / REAL_FILE, allow_pickle=False) as f:
        if "robot_state" not in f.files:
            return None
        r = np.asarray(f["robot_state"], np.float64)[np.asarray(slides), :, 1]
    t = np.arange(r.shape[1]) / float(fs_hz)
    slopes = np.polyfit(t, 1000.0 * r.T, 1)[0]
    return float(np.median(np.abs(slopes)))


# ---------------------------------------------------------------- signal statistics
def taxel_stats(X: np.ndarray, fs_hz: float) -> dict[str, np.ndarray]:
    """Per taxel (medians over slides): ``rest``, ``range``, ``peak_s`` (from mid-slide); and
    ``spectrum``: mean log10 power (counts^2 / Hz) per band of :data:`SPECTRUM_BANDS_HZ`."""
    X = np.asarray(X, np.float64)
    s = X.shape[-1]
    rest = np.median(X[..., : max(2, s // 10)], axis=-1)  # [N, C]
    rng_ = np.percentile(X, 99, axis=-1) - np.percentile(X, 1, axis=-1)
    rise = X - rest[..., None]
    peak = (rise.argmax(-1) - s / 2) / fs_hz
    peak = np.where(rise.max(-1) > 0, peak, np.nan)
    f = np.fft.rfftfreq(s, 1 / fs_hz)
    p = np.abs(np.fft.rfft(X - X.mean(-1, keepdims=True), axis=-1)) ** 2 / (s * fs_hz)
    edges = SPECTRUM_BANDS_HZ
    bands = [p[..., (f >= lo) & (f < hi)].mean(-1) for lo, hi in pairwise(edges)]
    spec = np.log10(np.maximum(np.mean(bands, axis=(1, 2)), 1e-12))
    # a taxel that never rises above rest has no peak time (0: mid-slide)
    seen = ~np.isnan(peak)
    peak_med = np.array([np.median(peak[seen[:, c], c]) if seen[:, c].any() else 0.0
                         for c in range(peak.shape[1])])  # fmt: skip
    return {"rest": np.median(rest, 0), "range": np.median(rng_, 0), "peak_s": peak_med,
            "spectrum": spec}  # fmt: skip


def match_taxels(real: dict[str, np.ndarray], synth: dict[str, np.ndarray]) -> np.ndarray:
    """For each real channel, the synthetic channel that plays its part (Hungarian assignment
    on the standardised rest level, range and peak time; no labels used)."""
    from scipy.optimize import linear_sum_assignment

    feats = []
    for key in ("rest", "range", "peak_s"):
        both = np.concatenate([real[key], synth[key]])
        sd = both.std() or 1.0
        feats.append((real[key][:, None] - synth[key][None, :]) / sd)
    cost = np.sqrt(sum(f**2 for f in feats))
    rows, cols = linear_sum_assignment(cost)
    return cols[np.argsort(rows)]


def reorder(ds: WindowDataset, order: np.ndarray) -> WindowDataset:
    return replace(ds, X=np.ascontiguousarray(ds.X[:, order]))


# ---------------------------------------------------------------- fits
def slides(real: WindowDataset, idx: np.ndarray) -> WindowDataset:
    """The slides ``idx`` (indices into the file's slides) of ``real``, in file order."""
    return real.subset(np.isin(np.arange(real.y.size), idx))


def cut(ds: WindowDataset, class_signal: np.ndarray | None = None) -> WindowDataset:
    """Windows as ``train --data`` cuts the real file (:func:`~tactilesnn.recordings.auto_cut`);
    with the slides' ``class_signal`` ``[N, samples]``, each window's confidence from it."""
    from ..recordings import auto_cut, cut_windows

    c = auto_cut(ds.X.shape[-1], ds.fs_hz, False)
    return ds if c is None else cut_windows(ds, *c, class_signal=class_signal)


def concat(*parts: WindowDataset) -> WindowDataset:
    a = parts[0]
    return replace(a, X=np.concatenate([p.X for p in parts]), y=np.concatenate([p.y for p in parts]),
                   scan=np.concatenate([p.scan for p in parts]))  # fmt: skip


def fit_score(
    cfg, train: WindowDataset, test: WindowDataset, progress: bool
) -> tuple[float, float]:
    """Accuracy per window and per slide of ``cfg`` fitted on ``train``, tested on ``test``."""
    from ..training import fit_and_evaluate

    m = fit_and_evaluate(cfg, train, test, progress=progress).metrics
    return float(m["test_accuracy"]), float(
        m.get("test_accuracy_per_recording") or m["test_accuracy"]
    )


def base_config(synth_windows: WindowDataset, seed: int, epochs: int | None,
                model: str = "readout"):  # fmt: skip
    """The ``train --data`` defaults (with ``model``), the encoder chosen on the synthetic
    training windows."""
    from ..data_policy import DATA_ENCODER_CANDIDATES
    from ..selection import select_encoder
    from .real import default_config

    cfg = default_config(False, None, model, seed)
    if epochs is not None:
        cfg = cfg.replace(train=replace(cfg.train, epochs=epochs))
    cfg, report = select_encoder(cfg, synth_windows, DATA_ENCODER_CANDIDATES)
    return cfg, report["chosen"]


def with_seed(cfg, seed: int):
    return cfg.replace(train=replace(cfg.train, seed=seed))


def few_shot_split(
    real: WindowDataset, k: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Slide indices: ``k`` per class for training (random), the rest for testing."""
    train = np.concatenate([rng.choice(np.flatnonzero(real.y == c), k, replace=False)
                            for c in range(len(real.class_names))])  # fmt: skip
    return np.sort(train), np.setdiff1d(np.arange(real.y.size), train)


#: slides per recording run in the real file: each letter's 15 trials are three runs of five
#: consecutive slides (the file's README: 5 unperturbed, 10 with a sub-millimetre offset), each
#: run with its own rest levels (:func:`run_rest_spread` measures it)
RUN_SLIDES = 5


def recording_run(slide: np.ndarray) -> np.ndarray:
    """The recording run (:data:`RUN_SLIDES` consecutive slides of one letter) of each slide
    index of the real file."""
    return np.asarray(slide) // RUN_SLIDES


def has_letter_runs(y: np.ndarray) -> bool:
    """Whether every run of :data:`RUN_SLIDES` consecutive slides holds one letter (the iCub
    file's layout; a file laid out otherwise gets no split by run)."""
    y = np.asarray(y)
    runs = recording_run(np.arange(y.size))
    return all(np.unique(y[runs == r]).size == 1 for r in np.unique(runs))


def run_rest_spread(real: WindowDataset) -> dict[str, float]:
    """How far apart the runs' rest levels are: the median over taxels of the spread (sd, counts)
    of the slides' rest levels (median of the first 10 % of the slide) within a run, and of the
    runs' mean levels between runs. Within much smaller than between: a classifier can name a
    run, and with it the letter, from the level before the letter arrives."""
    rest = np.median(real.X[..., : max(1, real.X.shape[-1] // 10)], -1)  # [slides, taxels]
    runs = recording_run(np.arange(len(rest)))
    means = np.stack([rest[runs == r].mean(0) for r in np.unique(runs)])
    within = np.sqrt(np.mean([rest[runs == r].var(0) for r in np.unique(runs)], 0))
    return {"within_run_counts": float(np.median(within)),
            "between_runs_counts": float(np.median(means.std(0)))}  # fmt: skip


def in_seen_runs(test: WindowDataset, train_idx: np.ndarray) -> np.ndarray:
    """Whether each test window's recording run (:func:`recording_run`) holds a training slide."""
    return np.isin(recording_run(test.scan), recording_run(train_idx))


def _seen_run_accuracy(hits: np.ndarray, test: WindowDataset, train_idx: np.ndarray) -> list[float]:
    """Per window accuracy ``[on the test windows of runs a training slide comes from, on the
    others]`` from each test window's ``hits`` (right or not; :func:`in_seen_runs`; NaN where
    a part is empty)."""
    seen = in_seen_runs(test, train_idx)
    return [float(hits[part].mean()) if part.any() else float("nan") for part in (seen, ~seen)]


#: a test window holds the letter where the fitted model places at least this share of the
#: letter's signal in it (the rest: the slide before and after the letter)
LETTER_SHARE = 0.5


def letter_parts(share: np.ndarray, seen: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Masks over the test windows: ``letter`` (the letter's share ``share [N]`` at least
    :data:`LETTER_SHARE`) and ``none`` (the others); with ``seen [N]`` (the window's recording
    run has a training slide) each also split into ``_seen`` and ``_unseen``."""
    letter = np.asarray(share) >= LETTER_SHARE
    parts = {"letter": letter, "none": ~letter}
    if seen is not None:
        for name, m in list(parts.items()):
            parts[f"{name}_seen"], parts[f"{name}_unseen"] = m & seen, m & ~seen
    return parts


def _accuracy(pipe, test: WindowDataset, log_likelihood: bool = False,
              runs_of: np.ndarray | None = None,
              parts: dict[str, np.ndarray] | None = None) -> tuple:  # fmt: skip
    """Per window and per slide (window scores summed) accuracy of a fitted pipeline; with
    ``runs_of`` (the training slides' indices), then per window by recording run
    (:func:`_seen_run_accuracy`); with ``parts`` (masks over the windows, by name), then per
    window on each (NaN where empty); with ``log_likelihood``, last the mean log-probability
    (nats) it gives each window's own class (its scores through a softmax): a proper score,
    which a few windows rank less noisily than accuracy."""
    import torch

    from ..pipeline import recording_accuracy

    scores = pipe.scores(pipe.encode(test.X))
    s = scores.numpy()
    hits = s.argmax(1) == test.y
    per_window = float(hits.mean())
    rec = recording_accuracy(s, test.y, test.scan)
    out = (per_window, float(rec["test_accuracy_per_recording"]) if rec else per_window)
    if runs_of is not None:
        out = (*out, _seen_run_accuracy(hits, test, runs_of))
    if parts is not None:
        out = (*out, {name: float(hits[m].mean()) if m.any() else float("nan")
                      for name, m in parts.items()})  # fmt: skip
    if not log_likelihood:
        return out
    logp = torch.log_softmax(scores.double(), 1)
    return (*out, float(logp[torch.arange(len(test.y)), torch.as_tensor(test.y)].mean()))


def reused_fit(run_dir: Path | None, k: int, d: int) -> Path | None:
    """The fit file an earlier run (``--reuse-fits``) wrote for draw ``d`` of ``k``, or None
    where it has none (that draw is then fitted: more draws than the earlier run had)."""
    if run_dir is None:
        return None
    path = Path(run_dir) / "fits" / f"k{k}_d{d}.json"
    if not path.is_file():
        log.info("%s not found: draw %d of k = %d is fitted", path, d, k)
        return None
    return path


def calibrated_draw(real: WindowDataset, train_idx: np.ndarray, test_idx: np.ndarray,
                    synthetic: int, budget_s: float, seed: int, epochs: int | None,
                    fit_path: Path | None = None, plot_path: Path | None = None,
                    reuse: Path | None = None, train_seed: int | None = None,
                    known: dict[str, float] | None = None, references: bool = False,
                    model: str = "readout") -> dict:  # fmt: skip
    """One few-shot draw of the calibrated protocol (see the module doc): the calibration,
    synthetic-only, real-only and pretrained + fine-tuned accuracies on ``test_idx``. ``reuse``:
    a fit file an earlier run wrote for this very draw (its training slides checked), read
    instead of fitting again. ``seed`` seeds the calibration; ``train_seed`` (default: ``seed``)
    the synthetic slides' render and every pipeline's training. ``known``: values the
    calibration holds fixed (measured, e.g. the arm's speed over the training slides).
    ``references``: also the non-spiking references on the identical split
    (:func:`reference_scores`), as ``row["references"]``. ``model``: the pipelines' model (one
    that adapts and fine-tunes: ``readout``, ``forest``)."""
    from ..core.data import confidence_summary
    from ..datasets_synth.tasks.braille import BrailleTask
    from ..models.base import seeded
    from ..recordings import expected_class_signal
    from ..training import adapt_pipeline, blend_finetuned, finetune_pipeline, fit_pipeline

    if np.intersect1d(train_idx, test_idx).size:
        raise ValueError("a slide is in both the training and the test draw")
    train_real = slides(real, train_idx)
    test_real = slides(real, test_idx)
    t0 = time.perf_counter()
    if reuse is not None:
        from ..datasets_synth.calibration import SensorFit

        fit = SensorFit.load(reuse)
        if fit.fitted_on.get("train_slides") not in (None, train_idx.tolist()) or (
            fit.fitted_on.get("recordings") != train_idx.size
        ):
            raise ValueError(f"{reuse} was fitted to other slides than this draw's")
        t_cal = float(fit.objective.get("seconds", float("nan")))
    else:
        fit = BrailleTask.calibrate(np.asarray(train_real.X, np.float64), train_real.y,
                                    real.fs_hz, real.class_names, budget_s=budget_s, seed=seed,
                                    known=known)  # fmt: skip
        fit.fitted_on["train_slides"] = train_idx.tolist()
        t_cal = time.perf_counter() - t0
    import tempfile

    seed = seed if train_seed is None else int(train_seed)  # from here on: the training's

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(fit_path) if fit_path is not None else Path(tmp) / "fit.json"
        fit.save(path, overwrite=True)
        synth, _, letter = render_synthetic(real, synthetic, seed, False, class_signal=True,
                                            calibration=str(path))  # fmt: skip
        if plot_path is not None:
            from ..datasets_synth.calibration import plot_statistics, slide_statistics

            n_cls = len(real.class_names)
            st_real = slide_statistics(train_real.X, train_real.y, real.fs_hz, n_cls)
            st_syn = slide_statistics(synth.X, synth.y, real.fs_hz, n_cls)
            plot_statistics(st_real, {"calibrated": st_syn}, real.class_names, real.fs_hz,
                            plot_path, title=f"fitted to {train_idx.size} real slides")  # fmt: skip
    # the synthetic windows' confidence: their share of the letter's own signal (the renderer
    # knows it): windows before and after the letter are trained to say nothing, not to read
    # a rest level the robot's letters do not own
    synth_w, train_w, test_w = cut(synth, letter), cut(train_real), cut(test_real)
    # the encoder: the candidate whose synthetic-trained pipeline gives the k real training
    # slides' letters the highest mean log-probability (what transfers; the training slides
    # only, never the test ones). Not their accuracy: on 21-105 windows, of which the windows
    # without the letter are now near-uniform coin flips, it picked the Gabor or STFT code on
    # 7 of 27 draws x seeds, which lost 6-15 points there (docs/sim2real.md)
    from .real import default_config

    base = default_config(False, None, model, seed)
    if epochs is not None:
        base = base.replace(train=replace(base.train, epochs=epochs))
    # the pretraining's capacity likewise (:func:`pretraining_candidates`), chosen with the
    # encoder by the same criterion
    scores, fitted = {}, {}
    candidates = pretraining_candidates(base, synth_w, seed)
    for key, (_, _, pre_cfg, _) in candidates.items():
        with seeded(seed):
            fitted[key] = fit_pipeline(pre_cfg, synth_w, with_past=False).pipeline
        scores[key] = list(_accuracy(fitted[key], train_w, log_likelihood=True))
    best = max(scores, key=lambda n: scores[n][2])  # ties: the earlier candidate
    pre, (chosen, capacity, _, cfg) = fitted[best], candidates[best]
    row: dict = {"train_slides": train_idx.tolist(), "test_slides": int(test_idx.size),
                 "seed": seed,
                 "calibration_s": t_cal, "objective": fit.objective["value"],
                 "distances": fit.objective["distances"], "encoder": chosen,
                 "pretraining_capacity": capacity,
                 "encoder_scores_on_training_slides": scores,
                 "synthetic_confidence": confidence_summary(synth_w.confidence)}  # fmt: skip
    row["synthetic_only_unadapted"], row["synthetic_only_unadapted_per_slide"] = _accuracy(
        pre, test_w
    )
    # the read-out's standardisation re-estimated on the k training slides' windows (labels
    # unused): the synthetic-trained weights then read the real sensor's features on their scale
    # the read-out's features on the synthetic windows, before the re-estimate (the references'
    # forest on the spike pipeline's own features)
    synth_feats = read_out_features(pre, synth_w) if references else None
    row["adapt"] = adapt_pipeline(pre, train_w)
    # each arm also per window on the test slides of recording runs the k slides come from and
    # on the others (a file laid out in runs of one letter): the runs' rest levels name the
    # letter to whatever saw the run
    runs_of = train_idx if has_letter_runs(real.y) else None
    by_run: dict = {
        "seen_fraction": float(np.isin(recording_run(test_idx), recording_run(train_idx)).mean())
    }

    # and on the test windows the fitted model places the letter in and on the others (the
    # slide before and after it: there only a rest level can tell the letters apart)
    test_share = cut(test_real, expected_class_signal(letter, synth.y, test_real.y)).confidence
    parts = letter_parts(test_share, None if runs_of is None else in_seen_runs(test_w, runs_of))
    by_letter: dict = {"letter_fraction": float(parts["letter"].mean())}

    def score(arm: str, pipe) -> None:
        got = _accuracy(pipe, test_w, runs_of=runs_of, parts=parts)
        row[arm], row[f"{arm}_per_slide"] = got[:2]
        if runs_of is not None:
            by_run[arm] = got[2]
        by_letter[arm] = got[-1]

    score("synthetic_only", pre)
    test_feats = None if synth_feats is None else read_out_features(pre, test_w)
    # a second fine-tune: each real training window weighted by its share of the letter as the
    # fitted model renders it at that place in the slide (the class's mean synthetic signal;
    # the fit matched the letter's timing to these slides), as the synthetic windows were
    lettered = cut(train_real, expected_class_signal(letter, synth.y, train_real.y))
    soft = copy.deepcopy(pre)
    with seeded(seed):
        row["finetune_letter"] = finetune_pipeline(soft, lettered)
    score("pretrained_letter", soft)
    with seeded(seed):
        report = finetune_pipeline(pre, train_w)
    score("pretrained_labels", pre)
    # the pretrained arm: the mean of the two fine-tuned read-outs (the labels teach the windows
    # without the letter the session's rest level, the letter's share the letter's windows)
    blend_finetuned(pre, soft)
    score("pretrained", pre)
    row["finetune"] = report
    with seeded(seed):
        alone = fit_pipeline(cfg, train_w, with_past=False).pipeline
    score("real_only", alone)
    if runs_of is not None:
        row["by_run"] = by_run
    row["by_letter"] = by_letter
    if references:
        row["references"] = reference_scores(synth_w, train_w, test_w, seed)
        if test_feats is not None and "synthetic_confidence" in row["references"]:
            row["references"]["synthetic_confidence"]["rf_spike_traces"] = spike_trace_forest(
                synth_feats, synth_w, test_feats, test_w, seed
            )
    return row


def pretraining_candidates(base, synth_w: WindowDataset, seed: int) -> dict[str, tuple]:
    """The pipelines a calibrated draw pretrains on the synthetic windows, by key: every
    encoder candidate of a data file (:data:`~tactilesnn.data_policy.DATA_ENCODER_CANDIDATES`)
    times every capacity its model offers a pretraining
    (:meth:`~tactilesnn.models.base.SpikeModel.pretraining_capacities`; the readout: its
    cross-validation's choice and the strongest penalty). Each value: ``(encoder, capacity
    or None where the model offers one, the pretraining's config, the encoder's config as the
    model configures itself)`` (the last trains the real-only arm: on the real windows the
    model's own choice of capacity stands). Keys: ``encoder`` or ``encoder/capacity``."""
    from ..data_policy import DATA_ENCODER_CANDIDATES
    from ..models.base import MODELS
    from ..selection import candidate_configs

    out: dict[str, tuple] = {}
    for name, c in candidate_configs(base, synth_w, DATA_ENCODER_CANDIDATES).items():
        own = with_seed(c, seed)
        variants = MODELS.component_for(c.model).pretraining_capacities(c.model)
        for tag, m in variants.items():
            several = len(variants) > 1
            out[f"{name}/{tag}" if several else name] = (
                name,
                tag if several else None,
                own.replace(model=m),
                own,
            )
    return out


def reference_scores(synth_w: WindowDataset, train_w: WindowDataset, test_w: WindowDataset,
                     seed: int) -> dict[str, dict[str, list]]:  # fmt: skip
    """The non-spiking references of ``bench real`` (:func:`.real.references`, the waveform
    ones: no spikes) trained on a draw's synthetic windows and, apart, on its real training
    windows; each scored on the draw's test windows -> ``{"synthetic" | "real": {name: [per
    window, per slide]}}``; where the synthetic windows carry confidences, also
    ``"synthetic_confidence"``: the references trained on the same soft targets as the spike
    pipeline (``"synthetic"``: on the labels alone)."""
    from .real import references

    arms = [("synthetic", replace(synth_w, confidence=None)), ("real", train_w)]
    if synth_w.confidence is not None:
        arms.insert(1, ("synthetic_confidence", synth_w))
    return {arm: {name: list(acc) for name, acc in references(train, test_w, None, seed).items()}
            for arm, train in arms}  # fmt: skip


def read_out_features(pipe, ds: WindowDataset) -> np.ndarray | None:
    """The features ``pipe``'s read-out scores ``ds``'s windows from (``[N, features]``, on its
    current standardisation; the columns its fit uses), or None for a model without them."""
    import torch

    features = getattr(pipe.model, "features", None)
    if features is None:
        return None
    with torch.no_grad():
        f = features(pipe.encode(ds.X)).numpy()
    mask = getattr(pipe.model, "instant_mask", None)
    return f if mask is None else f[:, mask.numpy() > 0]


def spike_trace_forest(synth_feats: np.ndarray, synth_w: WindowDataset, test_feats: np.ndarray,
                       test_w: WindowDataset, seed: int) -> list[float]:  # fmt: skip
    """A random forest on the spike pipeline's own read-out features (:func:`read_out_features`):
    trained on the synthetic windows' (the pipeline's synthetic standardisation; their soft
    targets as sample weights, as the references'), scored on the test windows' standardised on
    the k training slides as :func:`~tactilesnn.training.adapt_pipeline` does -> ``[per window,
    per slide]`` (the class probabilities summed per slide). What a read-out that does not
    extrapolate linearly from the fitted model's levels makes of the same spikes."""
    from sklearn.ensemble import RandomForestClassifier

    from .real import FOREST_TREES, fit_and_score

    forest = RandomForestClassifier(n_estimators=FOREST_TREES, min_samples_leaf=2,
                                    random_state=seed, n_jobs=-1)  # fmt: skip
    per_window, per_slide = fit_and_score(forest, synth_feats, synth_w, test_feats, test_w)
    return [per_window, per_window if per_slide is None else float(per_slide)]


def add_references(run_dir: Path, real: WindowDataset, synthetic: int = 200) -> list[dict]:
    """The non-spiking references for an earlier run's calibrated draws (``run_dir/fits/
    k{k}_d{d}.json``; each fit's own training slides, the draw's split recomputed and checked),
    on its first training seed's synthetic slides (render seed = the draw): one row per draw,
    also written into ``run_dir/sim2real.json`` as ``references``."""
    from ..core.files import write_json_atomic
    from ..datasets_synth.calibration import SensorFit

    run_dir = Path(run_dir)
    result = json.loads((run_dir / "sim2real.json").read_text())
    rows = []
    for x in result.get("calibrated", []):
        if x["seed"] != x["draw"]:  # the draw's first training seed only
            continue
        k, d = x["k"], x["draw"]
        tr, te = few_shot_split(real, k, np.random.default_rng([31, k, d]))
        path = run_dir / "fits" / f"k{k}_d{d}.json"
        if SensorFit.load(path).fitted_on.get("train_slides") != tr.tolist():
            raise ValueError(f"{path} was fitted to other slides than draw {d} of k = {k}")
        synth, _, letter = render_synthetic(real, synthetic, d, False, class_signal=True,
                                            calibration=str(path))  # fmt: skip
        train_w = cut(slides(real, tr))
        test_w = cut(slides(real, te))
        synth_w = cut(synth, letter)
        refs = reference_scores(synth_w, train_w, test_w, d)
        if "encoder" in x:  # the forest on the run's chosen encoder's pipeline, fitted again
            from ..models.base import seeded
            from ..training import adapt_pipeline, fit_pipeline
            from .real import default_config

            cands = pretraining_candidates(default_config(False, None, "readout", d), synth_w, d)
            key = x["encoder"] + (f"/{x['pretraining_capacity']}"
                                  if x.get("pretraining_capacity") else "")  # fmt: skip
            if key not in cands:  # a run before the capacities: the model's own choice
                key = next(k for k, v in cands.items() if v[0] == x["encoder"])
            with seeded(d):
                pipe = fit_pipeline(cands[key][2], synth_w, with_past=False).pipeline
            feats = read_out_features(pipe, synth_w)
            adapt_pipeline(pipe, train_w)
            if feats is not None:
                refs["synthetic_confidence"]["rf_spike_traces"] = spike_trace_forest(
                    feats, synth_w, read_out_features(pipe, test_w), test_w, d
                )
        rows.append({"k": k, "draw": d, "seed": d, **refs})
        log.info("references k=%d draw %d done", k, d)
    result["references"] = rows
    write_json_atomic(run_dir / "sim2real.json", result)
    return rows


#: held-out triples of runs (one per letter) :func:`cross_runs` trains real only without
CROSS_RUN_TRIPLES = 9
#: the rest level :func:`rest_referenced` subtracts: each slide's median over its first seconds
REST_S = 0.3


def rest_referenced(ds: WindowDataset, seconds: float = REST_S) -> WindowDataset:
    """``ds`` with each slide's channels minus their median over the slide's first ``seconds``
    (its rest level before the contact reaches the letter)."""
    n = max(1, round(seconds * ds.fs_hz))
    X = ds.X - np.median(ds.X[..., :n], -1, keepdims=True)
    return replace(ds, X=X.astype(np.float32))


def cross_runs(run_dir: Path, real: WindowDataset, triples: int = CROSS_RUN_TRIPLES,
               seed: int = 0) -> dict:  # fmt: skip
    """What many real slides reach on recording runs they never saw: real only (each encoder
    candidate, the read-out as ``train --data`` fits it) trained on every slide of all runs but
    one per letter, tested on the held-out runs' windows, for ``triples`` held-out triples
    (drawn with ``seed``), the slides as recorded and :func:`rest_referenced`; per window, per
    slide, and on the windows that hold the letter and the others (:func:`letter_parts`; the
    letter placed by the run's largest-k draw-0 fit). Written into ``run_dir/sim2real.json``
    as ``cross_run``."""
    import itertools

    from ..core.files import write_json_atomic
    from ..data_policy import DATA_ENCODER_CANDIDATES
    from ..models.base import seeded
    from ..recordings import expected_class_signal
    from ..selection import candidate_configs
    from ..training import fit_pipeline
    from .real import default_config

    if not has_letter_runs(real.y):
        raise ValueError("the file is not laid out in runs of one letter: no runs to hold out")
    run_dir = Path(run_dir)
    result = json.loads((run_dir / "sim2real.json").read_text())
    k = max(int(x) for x in result["shots"])
    fit = run_dir / "fits" / f"k{k}_d0.json"
    synth, _, letter = render_synthetic(real, 60, seed, False, class_signal=True,
                                        calibration=str(fit))  # fmt: skip
    runs = recording_run(np.arange(real.y.size))
    per_letter = [sorted({int(r) for r in runs[real.y == c]}) for c in range(len(real.class_names))]
    combos = list(itertools.product(*per_letter))
    rng = np.random.default_rng(seed)
    picked = [combos[i] for i in rng.choice(len(combos), min(triples, len(combos)), replace=False)]
    base = default_config(False, None, "readout", seed)
    referenced = rest_referenced(real)
    rows = []
    for held in picked:
        te = np.flatnonzero(np.isin(runs, held))
        tr = np.setdiff1d(np.arange(real.y.size), te)
        share = cut(slides(real, te), expected_class_signal(letter, synth.y, real.y[te])).confidence
        parts = letter_parts(share)
        for mode, data in (("recorded", real), ("rest_referenced", referenced)):
            train_w, test_w = cut(slides(data, tr)), cut(slides(data, te))
            for name, cfg in candidate_configs(base, train_w, DATA_ENCODER_CANDIDATES).items():
                with seeded(seed):
                    pipe = fit_pipeline(with_seed(cfg, seed), train_w, with_past=False).pipeline
                got = _accuracy(pipe, test_w, parts=parts)
                rows.append({"held_runs": list(held), "slides": mode, "encoder": name,
                             "per_window": got[0], "per_slide": got[1], **got[-1]})  # fmt: skip
        log.info("cross-run: runs %s held out", held)
    out = {"fit": fit.name, "rest_s": REST_S, "rows": rows}
    result["cross_run"] = out
    write_json_atomic(run_dir / "sim2real.json", result)
    return out


def _cross_run_section(cross: dict, r: dict) -> list[str]:
    """The page's table of :func:`cross_runs`: means over the held-out triples, 95 % intervals."""
    rows = cross["rows"]
    n = len({tuple(x["held_runs"]) for x in rows})
    k1 = (r.get("shots") or {}).get("1", {}).get("by_letter", {}).get("pretrained", {})
    lines = ["", "## What many real slides reach on runs they never saw", "",
             f"Real only trained on every slide of six runs (two per letter; 30 slides), tested "
             f"on the other three runs' windows, {n} held-out triples (`bench sim2real "
             "--cross-runs-from DIR`); the slides as recorded and each slide minus its rest "
             f"level (its median over the first {cross['rest_s']} s, per taxel); `letter` / "
             f"`none`: the windows the fitted model (`{cross['fit']}`) places the letter in and "
             "the others. Per window / per slide / letter / none (%), means over the triples "
             "with 95 % intervals.", "",
             "| slides | encoder | per window | per slide | letter | none |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    for mode in dict.fromkeys(x["slides"] for x in rows):
        for enc in dict.fromkeys(x["encoder"] for x in rows):
            sel = [x for x in rows if x["slides"] == mode and x["encoder"] == enc]
            cells = [_cell([x[key] for x in sel if np.isfinite(x[key])])
                     for key in ("per_window", "per_slide", "letter", "none")]  # fmt: skip
            lines.append(f"| {mode.replace('_', ' ')} | {enc} | " + " | ".join(cells) + " |")
    if k1.get("letter_unseen") is not None:
        lines += ["", f"For comparison, the pretrained arm at k = 1 (three real slides) on the "
                  f"unseen runs' letter windows: {100 * k1['letter_unseen']:.1f} %."]  # fmt: skip
    return lines


def compare_optimisers(real: WindowDataset, shots: tuple[int, ...], optimisers: tuple[str, ...],
                       seeds: int = 2, budget_s: float = 900.0) -> list[dict]:  # fmt: skip
    """The calibration's optimisers side by side: the objective each reaches in the same number
    of evaluations on the training slides of each ``k``'s first draw, per seed."""
    from ..datasets_synth.tasks.braille import BrailleTask

    rows = []
    for k in shots:
        tr, _ = few_shot_split(real, k, np.random.default_rng([31, k, 0]))
        sub = slides(real, tr)
        for name in optimisers:
            for seed in range(seeds):
                t0 = time.perf_counter()
                fit = BrailleTask.calibrate(np.asarray(sub.X, np.float64), sub.y, real.fs_hz,
                                            real.class_names, budget_s=budget_s, seed=seed,
                                            optimiser=name)  # fmt: skip
                rows.append({"k": k, "optimiser": name, "seed": seed,
                             "objective": fit.objective["value"],
                             "evaluations": fit.objective["evaluations"],
                             "seconds": time.perf_counter() - t0,
                             "history": fit.objective["history"]})  # fmt: skip
                log.info("optimiser %s, k=%d, seed %d: objective %.4f (%.0f s)", name, k, seed,
                         rows[-1]["objective"], rows[-1]["seconds"])  # fmt: skip
    return rows


def draw_means(rows: list[dict], key: str | None = None, fn=None) -> list[float]:
    """Per few-shot draw (rows of one ``k`` grouped by their ``draw``; a row without one is its
    own), the mean over its training seeds of ``row[key]`` (or of ``fn(row)``): the draws are
    the independent samples an interval is taken over, the seeds of a draw are not."""
    groups: dict = {}
    for i, r in enumerate(rows):
        groups.setdefault((r.get("k"), r.get("draw", f"row {i}")), []).append(
            r[key] if fn is None else fn(r)
        )
    return [float(np.mean(v)) for v in groups.values()]


def count_draws(rows: list[dict]) -> int:
    """How many few-shot draws ``rows`` hold (the groups of :func:`draw_means`)."""
    return len(draw_means(rows, "k"))


#: the arms :func:`calibrated_draw` splits by recording run (``row["by_run"]``)
RUN_ARMS = ("real_only", "pretrained", "pretrained_labels", "pretrained_letter", "synthetic_only")


def by_run_summary(rows: list[dict]) -> dict:
    """Each arm's per-window accuracy on the test windows of recording runs the training slides
    come from (``seen``) and of the others (``unseen``): means over draws (NaN parts skipped:
    at k = 5 a draw may cover every run), with the test windows' seen fraction."""
    out: dict = {"seen_fraction": float(np.mean(draw_means(
        rows, fn=lambda r: r["by_run"]["seen_fraction"])))}  # fmt: skip
    for arm in RUN_ARMS:
        for i, part in enumerate(("seen", "unseen")):
            v = np.asarray(draw_means(rows, fn=lambda r, a=arm, i=i: r["by_run"][a][i]))
            out[f"{arm}_{part}"] = float(np.nanmean(v)) if np.isfinite(v).any() else None
    return out


def by_letter_summary(rows: list[dict]) -> dict:
    """Each arm's per-window accuracy on each part of :func:`letter_parts` (``{arm: {part:
    mean over draws}}``, NaN parts skipped, None where every draw's is empty), with the test
    windows' letter fraction."""
    out: dict = {"letter_fraction": float(np.mean(draw_means(
        rows, fn=lambda r: r["by_letter"]["letter_fraction"])))}  # fmt: skip
    for arm in RUN_ARMS:
        names = rows[0]["by_letter"][arm]
        out[arm] = {}
        for name in names:
            v = np.asarray(draw_means(rows, fn=lambda r, a=arm, n=name: r["by_letter"][a][n]))
            out[arm][name] = float(np.nanmean(v)) if np.isfinite(v).any() else None
    return out


def summarise_calibrated(rows: list[dict]) -> dict:
    """The calibrated section's summary: means (fractions) over draws (each draw the mean over
    its training seeds), per ``k``; over every ``k`` for the synthetic-only figures."""
    out: dict = {"synthetic_only_per_slide": float(np.mean(draw_means(rows,
                                                                      "synthetic_only_per_slide"))),
                 "synthetic_only_per_window": float(np.mean(draw_means(rows, "synthetic_only"))),
                 "shots": {}}  # fmt: skip
    if all("synthetic_only_unadapted_per_slide" in r for r in rows):
        out["synthetic_only_unadapted_per_slide"] = float(
            np.mean(draw_means(rows, "synthetic_only_unadapted_per_slide"))
        )
    for k in sorted({r["k"] for r in rows}):
        sel = [r for r in rows if r["k"] == k]
        out["shots"][str(k)] = {
            name: float(np.mean(draw_means(sel, key)))
            for name, key in (("real_only_per_window", "real_only"),
                              ("pretrained_per_window", "pretrained"),
                              ("synthetic_only_per_window", "synthetic_only"),
                              ("real_only_per_slide", "real_only_per_slide"),
                              ("pretrained_per_slide", "pretrained_per_slide"),
                              ("synthetic_only_per_slide", "synthetic_only_per_slide"),
                              ("synthetic_only_unadapted_per_slide",
                               "synthetic_only_unadapted_per_slide"),
                              ("pretrained_letter_per_window", "pretrained_letter"),
                              ("pretrained_letter_per_slide", "pretrained_letter_per_slide"),
                              ("pretrained_labels_per_window", "pretrained_labels"),
                              ("pretrained_labels_per_slide", "pretrained_labels_per_slide"))
            if all(key in r for r in sel)
        }  # fmt: skip
        if all("by_run" in r for r in sel):
            out["shots"][str(k)]["by_run"] = by_run_summary(sel)
        if all("by_letter" in r for r in sel):
            out["shots"][str(k)]["by_letter"] = by_letter_summary(sel)
        out["shots"][str(k)]["draws"] = count_draws(sel)
        out["shots"][str(k)]["runs"] = len(sel)
    return out


def run(out: Path, data_root: Path, synthetic: int = 300, seeds: int = 3,
        shots: tuple[int, ...] = (1, 2, 5), draws: int = 5, knobs: tuple[str, ...] = KNOBS,
        knob_synthetic: int = 150, epochs: int | None = None, level_neurons: int | None = None,
        progress: bool = True, calibrated_draws: int = 3, calibration_budget_s: float = 600.0,
        calibrated_synthetic: int = 200, optimisers: tuple[str, ...] = (),
        reuse_fits: Path | None = None, calibrated_seeds: int = 3,
        model: str = "readout") -> dict:  # fmt: skip
    t_start = time.perf_counter()
    real = load_real(data_root)
    real_stats = taxel_stats(real.X, real.fs_hz)
    result: dict = {"real_file": REAL_FILE, "real_slides": int(real.y.size), "fs_hz": real.fs_hz,
                    "synthetic_slides": synthetic, "model": model}  # fmt: skip

    # 1. statistics and the taxel correspondence (from seed 0's slides)
    synth0, synth_rise = render_synthetic(real, synthetic, 0, progress)
    synth_stats = taxel_stats(synth0.X, real.fs_hz)
    rise = real_force_rise(data_root)
    result["force_rise_N"] = {
        name: {"real": None if rise is None else float(np.median(rise[real.y == c])),
               "synthetic": float(np.median(synth_rise[synth0.y == c]))}
        for c, name in enumerate(real.class_names)
    }  # fmt: skip
    order = match_taxels(real_stats, synth_stats)
    matched = {k: v[order] if k != "spectrum" else v for k, v in synth_stats.items()}
    result["statistics"] = {"real": {k: v.tolist() for k, v in real_stats.items()},
                            "synthetic_matched": {k: v.tolist() for k, v in matched.items()},
                            "taxel_order": order.tolist(),
                            "spectrum_bands_hz": list(SPECTRUM_BANDS_HZ)}  # fmt: skip
    real_w = cut(real)

    # 2. synthetic only, every seed; the encoder chosen on seed 0's synthetic windows
    cfg, chosen = base_config(cut(reorder(synth0, order)), 0, epochs, model)
    if level_neurons is not None:  # after the choice: the encoder is the defaults' own
        cfg = cfg.replace(level_neurons=int(level_neurons))
    result["encoder"] = chosen
    result["level_neurons"] = cfg.level_neurons
    rows = []
    for seed in range(seeds):
        synth = synth0 if seed == 0 else render_synthetic(real, synthetic, seed, progress)[0]
        for name, o in (("matched", order), ("file order", np.arange(12))):
            acc = fit_score(with_seed(cfg, seed), cut(reorder(synth, o)), real_w, progress)
            rows.append({"seed": seed, "taxels": name, "accuracy": acc[0], "per_slide": acc[1]})
    result["synthetic_only"] = rows

    # 3. few-shot with and without the synthetic slides
    synth_w = cut(reorder(synth0, order))
    shots_rows = []
    for k in shots:
        for d in range(draws):
            tr, te = few_shot_split(real, k, np.random.default_rng([31, k, d]))
            real_tr = cut(slides(real, tr))
            real_te = cut(slides(real, te))
            reps = max(1, round(synth_w.y.size / real_tr.y.size))
            joint = concat(synth_w, *([real_tr] * reps))
            c = with_seed(cfg, d)
            for arm, train in (("real only", real_tr), ("synthetic + real", joint)):
                acc = fit_score(c, train, real_te, progress)
                shots_rows.append({"k": k, "draw": d, "arm": arm, "accuracy": acc[0],
                                   "per_slide": acc[1], "test_slides": int(te.size)})  # fmt: skip
    result["few_shot"] = shots_rows

    # 4. randomisation knobs (synthetic only, seed 0, knob_synthetic slides)
    from ..datasets_synth import TASKS

    defaults = {f: getattr(TASKS["braille"](), f) for f in KNOBS}
    knob_rows = []
    base = fit_score(
        cfg, cut(reorder(render_synthetic(real, knob_synthetic, 0)[0], order)), real_w, progress
    )
    knob_rows.append({"knob": "defaults", "value": None, "accuracy": base[0], "per_slide": base[1]})
    for knob in knobs:
        for scale in (0.0, 2.0):
            kw = {knob: defaults[knob] * scale}
            if knob == "force_spread":
                kw[knob] = min(kw[knob], 0.9)
            s = render_synthetic(real, knob_synthetic, 0, **kw)[0]
            acc = fit_score(cfg, cut(reorder(s, order)), real_w, progress)
            knob_rows.append({"knob": knob, "value": kw[knob], "accuracy": acc[0], "per_slide": acc[1],
                              "change_points": 100 * (acc[0] - base[0])})  # fmt: skip
    result["knobs"] = knob_rows

    # 5. calibrated: the sensor model fitted to each draw's training slides only
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cal_rows = []
    if calibrated_draws > 0:
        (out / "fits").mkdir(exist_ok=True)
    for k in shots:
        for d in range(calibrated_draws):
            tr, te = few_shot_split(real, k, np.random.default_rng([31, k, d]))
            fit_file = out / "fits" / f"k{k}_d{d}.json"
            # the arm's speed, measured by its encoder on the training slides, held fixed: it
            # trades against the contact's width in time, which k slides cannot tell apart
            speed = real_arm_speed_mm_s(data_root, tr, real.fs_hz)
            known = None if speed is None else {"speed_mm_s": speed}
            old = reused_fit(reuse_fits, k, d)
            # one fit per draw; its synthetic slides and pipelines drawn again per training
            # seed (seed to seed, one fit spans up to 45 points per slide: one run is not a figure)
            for s in range(max(1, int(calibrated_seeds))):
                t0 = time.perf_counter()
                row = calibrated_draw(real, tr, te, calibrated_synthetic, calibration_budget_s,
                                      d, epochs, fit_file,
                                      out / "fits" / f"k{k}_d{d}.png" if d == s == 0 else None,
                                      reuse=old if s == 0 else fit_file,
                                      train_seed=d + 100 * s, known=known,
                                      references=s == 0, model=model)  # fmt: skip
                row.update(k=k, draw=d, seconds=time.perf_counter() - t0)
                cal_rows.append(row)
                log.info("calibrated k=%d draw %d seed %d: synthetic only %.3f / %.3f, real only "
                         "%.3f, pretrained %.3f per window (%.0f s)", k, d, row["seed"],
                         row["synthetic_only"], row["synthetic_only_per_slide"],
                         row["real_only"], row["pretrained"], row["seconds"])  # fmt: skip
    result["calibrated"] = cal_rows
    result["references"] = [{"k": x["k"], "draw": x["draw"], "seed": x["seed"],
                             **x.pop("references")} for x in cal_rows if "references" in x]  # fmt: skip
    if cal_rows:
        result.update(summarise_calibrated(cal_rows))
        if has_letter_runs(real.y):
            result["run_rest_spread"] = run_rest_spread(real)
    if optimisers:
        result["optimisers"] = compare_optimisers(real, shots, optimisers)
    result["seconds"] = time.perf_counter() - t_start

    (out / "sim2real.json").write_text(json.dumps(result, indent=2))
    text = table(result)
    (out / "sim2real.md").write_text(text)
    plot(real, synth0, order, result, out / "sim2real.png")
    print(text)
    return result


# ---------------------------------------------------------------- report
def _ms(values: list[float]) -> str:
    v = 100 * np.asarray(values)
    return f"{v.mean():.1f} +- {v.std(ddof=1) if v.size > 1 else 0.0:.1f}"


def table(r: dict) -> str:
    st = r["statistics"]
    lines = [f"Real: {r['real_slides']} slides of {r['real_file']} ({r['fs_hz']:.2f} Hz); synthetic: "
             f"{r['synthetic_slides']} braille slides per seed; encoder {r['encoder']} + readout, "
             f"level code {r.get('level_neurons', '-')} neurons.", "",
             "| taxel (real order) | rest real / synth | range real / synth | peak s real / synth |",
             "|---|---|---|---|"]  # fmt: skip
    re_, sy = st["real"], st["synthetic_matched"]
    for i in range(len(re_["rest"])):
        lines.append(f"| {i} (synth {st['taxel_order'][i]}) | {re_['rest'][i]:.0f} / {sy['rest'][i]:.0f} | "
                     f"{re_['range'][i]:.0f} / {sy['range'][i]:.0f} | "
                     f"{re_['peak_s'][i]:+.2f} / {sy['peak_s'][i]:+.2f} |")  # fmt: skip
    b = st["spectrum_bands_hz"]
    lines += ["", "| band Hz | " + " | ".join(f"{lo:g}-{hi:g}" for lo, hi in pairwise(b)) + " |",
              "|---|" + "---|" * (len(b) - 1),
              "| log10 power real | " + " | ".join(f"{v:.2f}" for v in re_["spectrum"]) + " |",
              "| log10 power synth | " + " | ".join(f"{v:.2f}" for v in sy["spectrum"]) + " |",
              ""]  # fmt: skip
    fr = r["force_rise_N"]
    lines += ["| letter | " + " | ".join(fr) + " |", "|---|" + "---|" * len(fr),
              "| force rise over the letter, real (N) | " + " | ".join(
                  "-" if v["real"] is None else f"{v['real']:.2f}" for v in fr.values()) + " |",
              "| ... synthetic (N) | " + " | ".join(f"{v['synthetic']:.2f}" for v in fr.values()) + " |",
              ""]  # fmt: skip
    lines += ["| trained on | tested on | per window % | per slide % |", "|---|---|---|---|"]
    for name in ("matched", "file order"):
        sel = [x for x in r["synthetic_only"] if x["taxels"] == name]
        acc, per = _ms([x["accuracy"] for x in sel]), _ms([x["per_slide"] for x in sel])
        lines.append(f"| synthetic only (taxels {name}, {len(sel)} seeds) | all {r['real_slides']} "
                     f"real | {acc} | {per} |")  # fmt: skip
    for k in sorted({x["k"] for x in r["few_shot"]}):
        for arm in ("real only", "synthetic + real"):
            sel = [x for x in r["few_shot"] if x["k"] == k and x["arm"] == arm]
            lines.append(f"| {k} real per class, {arm} ({len(sel)} draws) | the other "
                         f"{sel[0]['test_slides']} real | {_ms([x['accuracy'] for x in sel])} | "
                         f"{_ms([x['per_slide'] for x in sel])} |")  # fmt: skip
    lines += [
        "",
        "| knob | value | synthetic-only accuracy on real % | change (points) |",
        "|---|---|---|---|",
    ]
    for x in r["knobs"]:
        ch = "-" if x["knob"] == "defaults" else f"{x['change_points']:+.1f}"
        val = "-" if x["value"] is None else f"{x['value']:g}"
        lines.append(f"| {x['knob']} | {val} | {100 * x['accuracy']:.1f} | {ch} |")
    if r.get("calibrated"):
        lines += ["", "Calibrated sensor model (fitted to each draw's k training slides per class only):",
                  "", "| k real per class | draws | calibration s | synthetic only per window / per "
                  "slide % | real only per window / per slide % | pretrained + fine-tuned per "
                  "window / per slide % | gain per window (points) | fine-tuned on the "
                  "letter's share per window / per slide % |",
                  "|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for k in sorted({x["k"] for x in r["calibrated"]}):
            sel = [x for x in r["calibrated"] if x["k"] == k]

            def pair(a: str, b: str, sel: list = sel) -> str:
                return f"{_ms(draw_means(sel, a))} / {_ms(draw_means(sel, b))}"

            gain = 100 * np.mean(draw_means(sel, fn=lambda x: x["pretrained"] - x["real_only"]))
            has = all("pretrained_letter" in x for x in sel)
            soft = pair("pretrained_letter", "pretrained_letter_per_slide") if has else "-"
            lines.append(f"| {k} | {count_draws(sel)} | {np.mean([x['calibration_s'] for x in sel]):.0f} | "
                         f"{pair('synthetic_only', 'synthetic_only_per_slide')} | "
                         f"{pair('real_only', 'real_only_per_slide')} | "
                         f"{pair('pretrained', 'pretrained_per_slide')} | {gain:+.1f} | "
                         f"{soft} |")  # fmt: skip
    lines.append(f"\n({r['seconds']:.0f} s)")
    return "\n".join(lines) + "\n"


def plot(real: WindowDataset, synth: WindowDataset, order: np.ndarray, r: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    st = r["statistics"]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.2))
    x = np.arange(len(st["real"]["rest"]))
    ax = axes[0]
    ax.bar(x - 0.2, st["real"]["range"], 0.4, label="real: range", color="tab:blue")
    ax.bar(
        x + 0.2, st["synthetic_matched"]["range"], 0.4, label="synthetic: range", color="tab:orange"
    )
    ax.plot(x, st["real"]["rest"], "o", color="navy", label="real: rest level")
    ax.plot(
        x, st["synthetic_matched"]["rest"], "s", color="darkorange", label="synthetic: rest level"
    )
    ax.set_xticks(x)
    ax.set_xlabel("taxel (real file's order; synthetic matched)")
    ax.set_ylabel("counts (0..255)")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    ax.set_title("per-taxel rest level and range")
    ax = axes[1]
    t = (np.arange(real.X.shape[-1]) - real.X.shape[-1] / 2) / real.fs_hz
    for c, name in enumerate(real.class_names):
        for ds, style, o in ((real, "-", np.arange(12)), (synth, "--", order)):
            X = ds.X[ds.y == c][:, o].astype(np.float64)
            rise = (X - np.median(X[..., : X.shape[-1] // 10], -1, keepdims=True)).sum(1).mean(0)
            ax.plot(
                t,
                rise,
                style,
                color=f"C{c}",
                label=f"{name} {'real' if ds is real else 'synthetic'}",
            )
    ax.set_xlabel("time from mid-slide (s)")
    ax.set_ylabel("sum over taxels of the rise above rest (counts)")
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("mean slide per letter (solid: real, dashed: synthetic)")
    ax = axes[2]
    b = st["spectrum_bands_hz"]
    mids = np.sqrt(np.array(b[:-1]) * np.array(b[1:]))
    ax.semilogx(mids, st["real"]["spectrum"], "o-", label="real")
    ax.semilogx(mids, st["synthetic_matched"]["spectrum"], "s--", label="synthetic")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("log10 power (counts^2 / Hz)")
    ax.legend()
    ax.set_title("power spectrum (mean over taxels and slides)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


HELP = "sim-to-real: the braille task against the real iCub Braille file (statistics, transfer)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_data_root(p, "braille_icub_abc/")
    p.add_argument("--synthetic", type=int, default=300, help="synthetic slides per seed")
    p.add_argument("--seeds", type=int, default=3, help="synthetic-only render + training seeds")
    p.add_argument("--shots", type=int, nargs="+", default=[1, 2, 5], help="real slides per class")
    p.add_argument("--draws", type=int, default=5, help="random draws per few-shot size")
    p.add_argument("--knobs", nargs="*", default=list(KNOBS), choices=KNOBS,
                   help="randomisation knobs to switch off and double (none: skip)")  # fmt: skip
    p.add_argument("--knob-synthetic", type=int, default=150, help="synthetic slides per knob run")
    p.add_argument("--epochs", type=int, default=None, help="epochs (default: the model's own)")
    p.add_argument("--calibrated-draws", type=int, default=3,
                   help="few-shot draws per k, the sensor model fitted to each (0: skip)")  # fmt: skip
    p.add_argument("--calibration-budget-s", type=float, default=600.0,
                   help="at most this many seconds per calibration (it stops at its 1200 "
                   "evaluations before, on two quiet cores)")  # fmt: skip
    p.add_argument("--calibrated-synthetic", type=int, default=200,
                   help="slides rendered by each calibrated model")  # fmt: skip
    p.add_argument("--calibrated-seeds", type=int, default=3,
                   help="training seeds per calibrated draw (the fit reused; a draw's figure is "
                   "the mean over them)")  # fmt: skip
    p.add_argument("--optimisers", nargs="*", default=[], choices=("cma", "optuna-tpe", "random"),
                   help="also compare these calibration optimisers (2 seeds on each k's first "
                   "draw; optuna-tpe needs .[bench])")  # fmt: skip
    p.add_argument("--reuse-fits", default=None,
                   help="an earlier run's --out: its fit files of the same draws are read instead "
                   "of fitting again (the downstream arms only); draws it has no file for are "
                   "fitted")  # fmt: skip
    p.add_argument("--docs", default=None,
                   help="also write the page docs/sim2real.md (and its JSON beside it) here")  # fmt: skip
    p.add_argument("--cross-runs-from", default=None,
                   help="an earlier run's --out: add what real only trained on every slide of "
                   "the other recording runs reaches on held-out runs (the file's runs of one "
                   "letter) to its sim2real.json (no run)")  # fmt: skip
    p.add_argument("--references-from", default=None,
                   help="an earlier run's --out: add the non-spiking references (and a forest "
                   "on the spike read-out's features) on its calibrated draws to its "
                   "sim2real.json (no run)")  # fmt: skip
    p.add_argument("--from-json", default=None,
                   help="only rewrite --docs from a run's sim2real.json (no run)")  # fmt: skip
    p.add_argument("--model", default="readout", choices=("readout", "forest"),
                   help="the pipelines' model (one that adapts and fine-tunes)")  # fmt: skip
    p.add_argument("--level-neurons", type=int, default=None,
                   help="level code neurons (default: train --data's; 0 = scale-invariant)")  # fmt: skip


#: the sensor and scene values of a fit file the page states, with their units
FIT_UNITS = {"cover_spread_mm": "mm", "mount_N_per_mm": "N/mm", "tilt_Nmm_per_rad": "N mm/rad",
             "radius_along_mm": "mm", "radius_across_mm": "mm", "p_half_Pa": "Pa",
             "dot_spacing_mm": "mm (the cell's columns)", "row_spacing_mm": "mm (its rows)",
             "row_mm": "mm", "t_mid_offset_s": "s", "speed_mm_s": "mm/s", "force_N": "N",
             "force_ramp": "(relative)", "force_scale_a": "(relative)", "force_scale_b": "(relative)",
             "force_scale_c": "(relative)", "position_mm": "mm (randomisation sd)",
             "force_spread": "(randomisation, log half-range)",
             "gain_spread": "(randomisation, log sd)", "speed_spread": "(randomisation, log sd)"}  # fmt: skip

PAGE_HEAD = """# Sim-to-real: the `braille` task fitted to the real iCub fingertip

<!-- generated by `tactilesnn bench sim2real --from-json docs/sim2real.json --docs docs/sim2real.md` -->

The `braille` task renders an iCub capacitive fingertip (12 taxels, 8-bit counts) slid over a
Braille cell the way the robot arm of `../shared/data/braille_icub_abc` does it (45 real slides,
letters A, B, C). `tactilesnn calibrate` fits that model to a user's slides; `tactilesnn bench
sim2real` measures what the fitted model buys a classifier of the real sensor, with a protocol
that cannot leak: for each few-shot draw (k real slides per letter), the model is fitted to
those k slides per letter only, its synthetic slides train the `train --data` pipeline (each
window's target weighted by its share of the letter's own signal, which the renderer knows:
the windows before and after the letter are trained to the uniform target, not to a rest level
the letters do not own; the encoder and the read-out's capacity (the penalty its
cross-validation chooses on the synthetic windows, or the strongest it may choose on every
instant): the candidate whose synthetic-trained pipeline gives the k real training slides'
letters the highest mean log-probability), whose read-out's
standardisation is re-estimated on the k real training slides' windows (labels unused), which
is scored on the other real slides (synthetic only) and then fine-tuned on the k real slides
(pretrained + fine-tuned: the read-out re-fitted with a prior centred on the pretrained
weights, once on the labels and once on each window's share of the letter as the fitted model
places it, the two read-outs averaged into one), next to the same pipeline trained on the k
real slides alone (real only: the chosen encoder, the capacity the read-out's
cross-validation chooses on those real windows). No test slide is seen by the fit, the choice
of encoder and capacity, the re-estimate, the training or the fine-tune (no early
stopping); `tests/bench/test_sim2real.py` checks the split through every call.
"""


def _cell(values: list[float], scale: float = 100.0, sign: str = "") -> str:
    v = scale * np.asarray(values, np.float64)
    if v.size < 2:
        return f"{v.mean():{sign}.1f}"
    lo, hi = ci95_t(v)
    if not sign:  # an accuracy's interval ends at 0 and 100 %
        lo, hi = max(lo, 0.0), min(hi, scale)
    return f"{v.mean():{sign}.1f} ({lo:{sign}.1f} to {hi:{sign}.1f})"


def ci95_t(v: np.ndarray) -> tuple[float, float]:
    """The 95 % interval of a mean over draws (Student's t)."""
    from scipy import stats

    half = stats.t.ppf(0.975, v.size - 1) * v.std(ddof=1) / np.sqrt(v.size)
    return float(v.mean() - half), float(v.mean() + half)


def _references_section(refs: list[dict], cal: list[dict]) -> list[str]:
    """Per slide (%), means over draws: each non-spiking reference trained on the synthetic
    slides and on the k real ones, next to the spike pipeline on the same seeds."""
    ks = sorted({x["k"] for x in refs})
    first = {(x["k"], x["draw"]): x for x in cal if x["seed"] == x["draw"]}

    def cells(get) -> str:
        per_k = [[get(x) for x in refs if x["k"] == k] for k in ks]
        every = [v for vs in per_k for v in vs]
        return " | ".join(f"{100 * np.mean(v):.1f}" for v in [*per_k, every])

    lines = ["", "## Non-spiking references on the identical draws", "",
             "Per slide (%), means over the draws: the waveform references of `bench real` "
             "trained on each draw's synthetic slides (its first training seed's, render seed = "
             "the draw) or on its k real slides, scored on the same test slides, next to the "
             "spike pipeline of the same seed; `rf_spike_traces`: a forest on that pipeline's own "
             "read-out features (`spike_trace_forest`), where the run has it.", "",
             "| trained on | classifier | " + " | ".join(f"k = {k}" for k in ks) + " | all |",
             "|---|---|" + "---|" * (len(ks) + 1)]  # fmt: skip
    arms = [("synthetic", "synthetic_only_per_slide", "synthetic slides, labels alone"),
            ("synthetic_confidence", "synthetic_only_per_slide",
             "synthetic slides, the pipeline's soft targets"),
            ("real", "real_only_per_slide", "k real slides")]  # fmt: skip
    for arm, own, label in arms:
        if not all(arm in x for x in refs):
            continue
        for name in [n for n in refs[0][arm] if all(n in x[arm] for x in refs)]:
            lines.append(
                f"| {label} | {name} | " + cells(lambda x, a=arm, n=name: x[a][n][1]) + " |"
            )
        if arm == "synthetic" and "synthetic_confidence" in refs[0]:
            continue  # the spike pipeline trained on the soft targets: shown with that arm
        lines.append(f"| {label} | **spike pipeline** | "
                     + cells(lambda x, o=own: first[(x["k"], x["draw"])][o]) + " |")  # fmt: skip
    return lines


def _fabric_section(fab: dict) -> list[str]:
    sh = fab["spectrum_shape_bands_hz"]
    return ["", "## A second sensor: FabricSlide against the `texture` task's capacitive stack", "",
            "`tactilesnn calibrate --statistics-only --task texture --data "
            "../shared/data/fabric_slide/fabric --out docs/sim2real_fabric.json --plot "
            "docs/sim2real_fabric.png` (15 s): the CPM-Finger's recordings "
            f"({fab['recordings']} windows) next to the stack model at its defaults "
            f"({fab['model_samples']} windows). There is nothing to fit: "
            + "; ".join(fab["cannot_express"]) + ". What compares is unit-free: the spectra's "
            f"shapes over the bands both resolve ({sh[0][0]:g}-{sh[-1][1]:g} Hz) are "
            f"{fab['spectrum_shape_rms_decades']:.2f} decades apart (rms; the fabric's power "
            "falls off with frequency, "
            + ", ".join(f"{v:.2f}" for v in fab["spectrum_shape_real"])
            + " log10 shares per octave band, the model's is flatter: "
            + ", ".join(f"{v:.2f}" for v in fab["spectrum_shape_model"])
            + "), and the mean cross-channel correlation is "
            f"{fab['mean_cross_channel_correlation']['real']:.2f} (recordings) against "
            f"{fab['mean_cross_channel_correlation']['model']:.2f} (the model's two channels). A "
            "calibration of this sensor needs a finger model with 16 taxels and a fabric scene "
            "(the fingertip model reads dots, not weaves).", "",
            "![FabricSlide against the texture task's stack](sim2real_fabric.png)"]  # fmt: skip


def chosen_counts(rows: list[dict]) -> str:
    """The pretraining candidates the rows chose, with how often: ``lif / strongest x 7, ...``
    (rows before the capacities: the encoder alone)."""
    from collections import Counter

    keys = Counter(x["encoder"] + (f" / {x['pretraining_capacity']}"
                                   if x.get("pretraining_capacity") else "") for x in rows)  # fmt: skip
    return ", ".join(
        f"{key} x {n}" for key, n in sorted(keys.items(), key=lambda kv: (-kv[1], kv[0]))
    )


def _by_run_table(cal: list[dict], ks: list[int]) -> list[str]:
    """The page's table of each arm per window by recording run (rows with ``by_run``)."""
    if not all("by_run" in x for x in cal):
        return []
    lines = ["", "By recording run (per window, %; a run: five consecutive slides of one "
             "letter, `RUN_SLIDES`): on the test slides of the runs the k training slides come "
             "from (seen) and of the other runs (unseen); the last column pretrained minus real "
             "only on the unseen runs (points).", "",
             "| k | test windows in seen runs | real only: seen / unseen | synthetic only | "
             "pretrained (the mean) | labels' fine-tune | letter's share's | pretrained minus "
             "real only, unseen runs |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for k in ks:
        sel = [x for x in cal if x["k"] == k]
        b = by_run_summary(sel)

        def pair(arm: str, b: dict = b) -> str:
            return " / ".join("-" if b[f"{arm}_{p}"] is None else f"{100 * b[f'{arm}_{p}']:.1f}"
                              for p in ("seen", "unseen"))  # fmt: skip

        gain = [v for v in draw_means(sel, fn=lambda x: x["by_run"]["pretrained"][1]
                                      - x["by_run"]["real_only"][1]) if np.isfinite(v)]  # fmt: skip
        lines.append(f"| {k} | {100 * b['seen_fraction']:.0f} % | {pair('real_only')} | "
                     f"{pair('synthetic_only')} | {pair('pretrained')} | "
                     f"{pair('pretrained_labels')} | {pair('pretrained_letter')} | "
                     + (_cell(gain, sign="+") if gain else "-") + " |")  # fmt: skip
    return lines


def _by_letter_table(cal: list[dict], ks: list[int]) -> list[str]:
    """The page's table of each arm per window on the test windows that hold the letter and on
    the others (rows with ``by_letter``), and on those of unseen recording runs."""
    if not all("by_letter" in x for x in cal):
        return []
    runs = all("letter_unseen" in x["by_letter"]["pretrained"] for x in cal)
    lines = ["", "By where the letter is (per window, %): on the test windows in which the fitted "
             f"model places at least {100 * LETTER_SHARE:.0f} % of the letter's signal (`letter`) and on "
             "the others (`none`: the slide before and after the letter, where only a rest level "
             "tells the letters apart)" + (", over all test windows and on the unseen runs" if runs
                                           else "") + ".", "",
             "| k | test windows with the letter | real only: letter / none | synthetic only | "
             "pretrained | " + ("unseen runs: real only | unseen runs: pretrained |" if runs
                                else ""),
             "|---|---|---|---|---|" + ("---|---|" if runs else "")]  # fmt: skip

    def pair(b: dict, arm: str, suffix: str = "") -> str:
        return " / ".join("-" if b[arm][f"{p}{suffix}"] is None
                          else f"{100 * b[arm][f'{p}{suffix}']:.1f}" for p in ("letter", "none"))  # fmt: skip

    for k in ks:
        b = by_letter_summary([x for x in cal if x["k"] == k])
        cells = [str(k), f"{100 * b['letter_fraction']:.0f} %", pair(b, "real_only"),
                 pair(b, "synthetic_only"), pair(b, "pretrained")]  # fmt: skip
        if runs:
            cells += [pair(b, "real_only", "_unseen"), pair(b, "pretrained", "_unseen")]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _models_section(r: dict, cal: list[dict]) -> list[str]:
    """The page's comparison of the pipelines' model: this page's rows (``r["model"]``, default
    ``readout``) next to each run in ``r["other_models"]`` (``{model: {"command", "calibrated"}}``:
    the same fits, draws and training seeds), per window / per slide (%), means over draws."""
    others = r.get("other_models") or {}
    if not others or not cal:
        return []
    runs = {r.get("model", "readout"): cal, **{m: o["calibrated"] for m, o in others.items()}}
    ks = sorted({x["k"] for x in cal})
    lines = ["", "## Which read-out: the linear one or a forest", "",
             "The same fits, draws and training seeds, each pipeline with the named model "
             "(`bench sim2real --model M`; `forest`: a random forest on the same leaky-integrator "
             "traces, its fine-tune a re-estimate of its leaves' class distributions). Per "
             "window / per slide (%), means over draws with 95 % intervals; the gain is "
             "pretrained minus real only per window (points), over all test windows and on the "
             "unseen recording runs.", "",
             "| k | model | synthetic only | real only | pretrained + fine-tuned | gain per "
             "window | gain, unseen runs |", "|---|---|---|---|---|---|---|"]  # fmt: skip
    for k in ks:
        for model, rows in runs.items():
            sel = [x for x in rows if x["k"] == k]
            if not sel:
                continue

            def pair(key: str, sel: list[dict] = sel) -> str:
                return (f"{_cell(draw_means(sel, key))} / "
                        f"{_cell(draw_means(sel, key + '_per_slide'))}")  # fmt: skip

            gain = draw_means(sel, fn=lambda x: x["pretrained"] - x["real_only"])
            unseen = [v for v in draw_means(sel, fn=lambda x: x["by_run"]["pretrained"][1]
                                            - x["by_run"]["real_only"][1]) if np.isfinite(v)
                      ] if all("by_run" in x for x in sel) else []  # fmt: skip
            lines.append(f"| {k} | {model} | {pair('synthetic_only')} | {pair('real_only')} | "
                         f"{pair('pretrained')} | {_cell(gain, sign='+')} | "
                         + (_cell(unseen, sign="+") if unseen else "-") + " |")  # fmt: skip
    for model, rows in runs.items():
        summary = summarise_calibrated(rows)
        lines.append(
            f"\n`{model}`: synthetic only {100 * summary['synthetic_only_per_slide']:.1f} "
            "% per slide over every k"
            + (f" (`{others[model]['command']}`)" if model in others else "")
            + "."
        )
    return lines


def page(r: dict, fits: dict[str, dict], command: str, fabric: dict | None = None) -> str:
    """The docs page of a run (:data:`PAGE_HEAD`, the before / after tables, the fitted values,
    ``fabric``: the second sensor's statistics-only comparison)."""
    lines = [PAGE_HEAD, f"Command: `{command}` ({r['seconds'] / 60:.0f} min, "
             f"{r.get('machine', 'this machine')}). Chance is 33.3 %; means over draws with 95 % "
             "intervals (t, over draws; a calibrated draw's figure is the mean over its training "
             "seeds, the fit shared).", ""]  # fmt: skip
    cal = r.get("calibrated") or []
    ks = sorted({x["k"] for x in cal})
    lines += ["![the statistics of the real slides against the model before (defaults) and after "
              "the fit](sim2real_fit.png)", "",
              "## Before and after (per window / per slide, %)", "",
              "| k real per class | draws | trained on | uncalibrated model (before) | calibrated "
              "model (after) |", "|---|---|---|---|---|"]  # fmt: skip
    synth_before = [x for x in r.get("synthetic_only", []) if x["taxels"] == "file order"]
    for k in ks:
        sel = [x for x in cal if x["k"] == k]
        before = [x for x in r.get("few_shot", []) if x["k"] == k]
        rb = [x for x in before if x["arm"] == "real only"]
        jb = [x for x in before if x["arm"] == "synthetic + real"]
        sb = ("-" if not synth_before else
              f"{_cell([x['accuracy'] for x in synth_before])} / "
              f"{_cell([x['per_slide'] for x in synth_before])} (all 45)")  # fmt: skip
        nd = count_draws(sel)
        n = f"{nd} x {len(sel) // nd} seeds" if len(sel) > nd else f"{nd}"
        lines += [
            f"| {k} | {n} | synthetic only | {sb} | "
            f"{_cell(draw_means(sel, 'synthetic_only'))} / "
            f"{_cell(draw_means(sel, 'synthetic_only_per_slide'))} |",
            *([f"| {k} | {n} | synthetic only, the read-out's standardisation not re-estimated "
               f"on the k slides | - | {_cell(draw_means(sel, 'synthetic_only_unadapted'))} / "
               f"{_cell(draw_means(sel, 'synthetic_only_unadapted_per_slide'))} |"]
              if all("synthetic_only_unadapted" in x for x in sel) else []),
            f"| {k} | {n} | real only | "
            + (f"{_cell([x['accuracy'] for x in rb])} / {_cell([x['per_slide'] for x in rb])}"
               if rb else "-") + f" | {_cell(draw_means(sel, 'real_only'))} / "
            f"{_cell(draw_means(sel, 'real_only_per_slide'))} |",
            f"| {k} | {n} | synthetic + real: joint (before), pretrained + fine-tuned "
            + ("(after: the mean of the labels' and the letter's share's read-outs) | "
               if all("pretrained_labels" in x for x in sel) else "(after) | ")
            + (f"{_cell([x['accuracy'] for x in jb])} / {_cell([x['per_slide'] for x in jb])}"
               if jb else "-") + f" | {_cell(draw_means(sel, 'pretrained'))} / "
            f"{_cell(draw_means(sel, 'pretrained_per_slide'))} |",
            *([f"| {k} | {n} | pretrained + fine-tuned on the labels alone | - | "
               f"{_cell(draw_means(sel, 'pretrained_labels'))} / "
               f"{_cell(draw_means(sel, 'pretrained_labels_per_slide'))} |"]
              if all("pretrained_labels" in x for x in sel) else []),
            *([f"| {k} | {n} | pretrained + fine-tuned, each real window weighted by its share "
               "of the letter in the fitted model | - | "
               f"{_cell(draw_means(sel, 'pretrained_letter'))} / "
               f"{_cell(draw_means(sel, 'pretrained_letter_per_slide'))} |"]
              if all("pretrained_letter" in x for x in sel) else []),
        ]  # fmt: skip
    if cal:
        letter = all("pretrained_letter" in x for x in cal)
        lines += ["", "| k | pretrained + fine-tuned minus real only, per window (points) | "
                  + ("the same, fine-tuned on the letter's share: per window / per slide "
                     "(points) | " if letter else "")
                  + "encoders (and capacities) chosen, of draws x seeds | "
                  "calibration s (median) | objective (median) |",
                  "|---|---|---|---|---|" + ("---|" if letter else "")]  # fmt: skip
        for k in ks:
            sel = [x for x in cal if x["k"] == k]
            gain = draw_means(sel, fn=lambda x: x["pretrained"] - x["real_only"])
            enc = chosen_counts(sel)
            soft = ""
            if letter:
                gw = draw_means(sel, fn=lambda x: x["pretrained_letter"] - x["real_only"])
                gs = draw_means(sel, fn=lambda x: x["pretrained_letter_per_slide"]
                                - x["real_only_per_slide"])  # fmt: skip
                soft = f"{_cell(gw, sign='+')} / {_cell(gs, sign='+')} | "
            lines.append(f"| {k} | {_cell(gain, sign='+')} | {soft}{enc} | "
                         f"{np.median([x['calibration_s'] for x in sel]):.0f} | "
                         f"{np.median([x['objective'] for x in sel]):.3f} |")  # fmt: skip
        lines += _by_run_table(cal, ks)
        lines += _by_letter_table(cal, ks)
        summary = summarise_calibrated(cal)
        lines += ["", "In `sim2real.json`: `synthetic_only_per_slide` "
                  f"{summary['synthetic_only_per_slide']:.3f}; `shots`: "
                  + ", ".join(f"k = {k}: real only {v['real_only_per_window']:.3f}, pretrained "
                              f"{v['pretrained_per_window']:.3f}"
                              for k, v in summary["shots"].items()) + " (per window)."]  # fmt: skip
    opt = r.get("optimisers") or []
    if opt:
        lines += ["", "## Which optimiser", "",
                  "The objective (lower is better) each reaches in the same "
                  f"{int(np.median([x['evaluations'] for x in opt]))} evaluations on the "
                  "training slides of each k's first draw (seeds 0, 1; the same start):", "",
                  "| k | optimiser | objective per seed | seconds (median) |",
                  "|---|---|---|---|"]  # fmt: skip
        for k in sorted({x["k"] for x in opt}):
            for name in dict.fromkeys(x["optimiser"] for x in opt):
                sel = [x for x in opt if x["k"] == k and x["optimiser"] == name]
                if sel:
                    lines.append(f"| {k} | {name} | " + ", ".join(f"{x['objective']:.3f}" for x in sel)
                                 + f" | {np.median([x['seconds'] for x in sel]):.0f} |")  # fmt: skip
    if fits:
        merged = [{**f.get("params", {}), **f.get("scene", {}), **f.get("randomisation", {})}
                  for f in fits.values()]  # fmt: skip
        names = [n for n in FIT_UNITS if any(n in m for m in merged)]
        lines += ["", "## The fitted values", "",
                  "| value | unit | " + " | ".join(fits) + " |",
                  "|---|---|" + "---|" * len(fits)]  # fmt: skip
        for n in names:
            cells = []
            for f in fits.values():
                v = {**f.get("params", {}), **f.get("scene", {}), **f.get("randomisation", {})}.get(
                    n
                )
                cells.append("-" if v is None else f"{v:.3g}")
            lines.append(f"| `{n}` | {FIT_UNITS[n]} | " + " | ".join(cells) + " |")
    if cal:
        lines += ["", "## Which statistic still differs", "",
                  "Distances between the k training slides and the fitted model's mean "
                  "responses at the end of each fit (medians over draws; 0 = equal; "
                  "`calibration.statistic_distances`):", "",
                  "| k | mean response (share of variance unexplained) | what tells the "
                  "letters apart (share unexplained) | correlation (mean abs difference) | rest "
                  "(share of the largest range) | range |",
                  "|---|---|---|---|---|---|"]  # fmt: skip
        for k in ks:
            d = [x["distances"] for x in cal if x["k"] == k and "distances" in x]
            if d:
                lines.append(f"| {k} | " + " | ".join(
                    f"{np.median([x[key] for x in d]):.3f}" if all(key in x for x in d) else "-"
                    for key in ("mean_response", "class_difference", "correlation", "rest",
                                "range")) + " |")  # fmt: skip
    lines += _models_section(r, cal)
    if r.get("cross_run"):
        lines += _cross_run_section(r["cross_run"], r)
    if r.get("references"):
        lines += _references_section(r["references"], cal)
    if fabric:
        lines += _fabric_section(fabric)
    if r.get("tail"):
        lines += ["", r["tail"]]
    return "\n".join(lines) + "\n"


def write_page(result: dict, out_dir: Path | None, docs: Path, command: str) -> None:
    """``docs`` (the page) and its JSON beside it; the fits of the run's first draws (when
    ``out_dir`` holds them) as the fitted-values table."""
    from . import write_result

    fits = {}
    if out_dir is not None:
        for k in sorted({x["k"] for x in result.get("calibrated", [])}):
            f = Path(out_dir) / "fits" / f"k{k}_d0.json"
            if f.is_file():
                fits[f"k = {k}, draw 0"] = json.loads(f.read_text())
    result = {**result, "fits_first_draw": fits}
    write_result(docs.parent, docs.with_suffix(".json").name, result)
    docs.write_text(page(result, fits, command, _fabric(docs)))


def _fabric(docs: Path) -> dict | None:
    f = Path(docs).parent / "sim2real_fabric.json"
    return json.loads(f.read_text()) if f.is_file() else None


def main(out: Path | None, options: argparse.Namespace) -> int:
    from . import require_out

    if options.cross_runs_from:
        cross_runs(Path(options.cross_runs_from), load_real(data_root(options, "sim2real")))
        return 0
    if options.references_from:
        add_references(Path(options.references_from), load_real(data_root(options, "sim2real")),
                       options.calibrated_synthetic)  # fmt: skip
        return 0
    if options.from_json:
        result = json.loads(Path(options.from_json).read_text())
        if not options.docs:
            raise ValueError("--from-json only rewrites the page: pass --docs")
        docs = Path(options.docs)
        fits = result.get("fits_first_draw") or {}
        docs.write_text(
            page(result, fits, result.get("command", "tactilesnn bench sim2real"), _fabric(docs))
        )
        return 0
    command = (
        f"tactilesnn bench sim2real --out DIR --synthetic {options.synthetic} --seeds "
        f"{options.seeds} --draws {options.draws} --shots {' '.join(map(str, options.shots))} "
        f"--knobs {' '.join(options.knobs)} --calibrated-draws {options.calibrated_draws} "
        f"--calibrated-synthetic {options.calibrated_synthetic} --calibrated-seeds "
        f"{options.calibrated_seeds}"
        + (f" --optimisers {' '.join(options.optimisers)}" if options.optimisers else "")
        + (f" --model {options.model}" if options.model != "readout" else "")
    ).replace("--knobs  ", "--knobs ")
    result = run(Path(require_out(out, "sim2real")), data_root=data_root(options, "sim2real"),
        synthetic=options.synthetic, seeds=options.seeds, shots=tuple(options.shots),
        draws=options.draws, knobs=tuple(options.knobs), knob_synthetic=options.knob_synthetic,
        epochs=options.epochs, level_neurons=options.level_neurons,
        progress=not options.quiet, calibrated_draws=options.calibrated_draws,
        calibration_budget_s=options.calibration_budget_s,
        calibrated_synthetic=options.calibrated_synthetic,
        optimisers=tuple(options.optimisers), calibrated_seeds=options.calibrated_seeds,
        reuse_fits=Path(options.reuse_fits) if options.reuse_fits else None,
        model=options.model)  # fmt: skip
    import os

    result["command"] = command
    result["machine"] = f"{os.cpu_count()} CPUs, {time.strftime('%Y-%m-%d')}"
    if options.docs:
        write_page(result, Path(out), Path(options.docs), command)
    return 0
