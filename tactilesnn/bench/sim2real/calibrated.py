"""One calibrated draw: the sensor model fitted to the k training slides, pretrained on its slides,
transferred to the real ones (:func:`~tactilesnn.training.transfer_pipeline`), scored beside
real only.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ...core.data import WindowDataset
from .data import render_synthetic
from .protocol import (
    _accuracy,
    cut,
    has_letter_runs,
    in_seen_runs,
    letter_parts,
    pretraining_candidates,
    recording_run,
    slides,
)
from .references import read_out_features, reference_scores, spike_trace_forest

log = logging.getLogger("tactilesnn")


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
    from ...core.data import confidence_summary

    if np.intersect1d(train_idx, test_idx).size:
        raise ValueError("a slide is in both the training and the test draw")
    train_real = slides(real, train_idx)
    test_real = slides(real, test_idx)
    fit, t_cal = _fit(real, train_real, train_idx, budget_s, seed, reuse, known)
    seed = seed if train_seed is None else int(train_seed)  # from here on: the training's
    synth, letter = _render(real, train_real, fit, synthetic, seed, fit_path, plot_path)
    # the synthetic windows' confidence: their share of the letter's own signal (the renderer
    # knows it): windows before and after the letter are trained to say nothing, not to read
    # a rest level the robot's letters do not own
    synth_w, train_w, test_w = cut(synth, letter), cut(train_real), cut(test_real)
    pre, chosen, capacity, cfg, scores = _pretrain(synth_w, train_w, model, seed, epochs)
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
    # the read-out's features on the synthetic windows, before the re-estimate (the references'
    # forest on the spike pipeline's own features)
    synth_feats = read_out_features(pre, synth_w) if references else None
    test_feats = _transfer_and_score(row, real, pre, cfg, (train_real, test_real, train_w, test_w),
                                     (train_idx, test_idx), synth, letter, seed,
                                     features=references)  # fmt: skip
    if references:
        row["references"] = reference_scores(synth_w, train_w, test_w, seed)
        if test_feats is not None and "synthetic_confidence" in row["references"]:
            row["references"]["synthetic_confidence"]["rf_spike_traces"] = spike_trace_forest(
                synth_feats, synth_w, test_feats, test_w, seed
            )
    return row


def _fit(real: WindowDataset, train_real: WindowDataset, train_idx: np.ndarray, budget_s: float,
         seed: int, reuse: Path | None, known: dict[str, float] | None) -> tuple:  # fmt: skip
    """``(sensor fit, seconds)``: the braille model calibrated to the draw's training slides
    only, or ``reuse``'s fit file (checked to be of these slides)."""
    from ...datasets_synth.tasks.braille import BrailleTask

    t0 = time.perf_counter()
    if reuse is not None:
        from ...datasets_synth.calibration import SensorFit

        fit = SensorFit.load(reuse)
        if fit.fitted_on.get("train_slides") not in (None, train_idx.tolist()) or (
            fit.fitted_on.get("recordings") != train_idx.size
        ):
            raise ValueError(f"{reuse} was fitted to other slides than this draw's")
        return fit, float(fit.objective.get("seconds", float("nan")))
    fit = BrailleTask.calibrate(np.asarray(train_real.X, np.float64), train_real.y,
                                real.fs_hz, real.class_names, budget_s=budget_s, seed=seed,
                                known=known)  # fmt: skip
    fit.fitted_on["train_slides"] = train_idx.tolist()
    return fit, time.perf_counter() - t0


def _render(real: WindowDataset, train_real: WindowDataset, fit, synthetic: int, seed: int,
            fit_path: Path | None, plot_path: Path | None) -> tuple:  # fmt: skip
    """``(synthetic slides, each slide's letter signal)`` of the fitted model (saved to
    ``fit_path`` where given; its statistics against the training slides' at ``plot_path``)."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(fit_path) if fit_path is not None else Path(tmp) / "fit.json"
        fit.save(path, overwrite=True)
        synth, _, letter = render_synthetic(real, synthetic, seed, False, class_signal=True,
                                            calibration=str(path))  # fmt: skip
    if plot_path is not None:
        from ...datasets_synth.calibration import plot_statistics, slide_statistics

        n_cls = len(real.class_names)
        st_real = slide_statistics(train_real.X, train_real.y, real.fs_hz, n_cls)
        st_syn = slide_statistics(synth.X, synth.y, real.fs_hz, n_cls)
        plot_statistics(st_real, {"calibrated": st_syn}, real.class_names, real.fs_hz,
                        plot_path, title=f"fitted to {train_real.y.size} real slides")  # fmt: skip
    return synth, letter


def _pretrain(synth_w: WindowDataset, train_w: WindowDataset, model: str, seed: int,
              epochs: int | None) -> tuple:  # fmt: skip
    """``(pretrained pipeline, encoder, capacity, the real-only arm's config, every candidate's
    scores)``. The encoder: the candidate whose synthetic-trained pipeline gives the k real
    training slides' letters the highest mean log-probability (what transfers; the training
    slides only, never the test ones). Not their accuracy: on 21-105 windows, of which the
    windows without the letter are now near-uniform coin flips, it picked the Gabor or STFT
    code on 7 of 27 draws x seeds, which lost 6-15 points there (docs/sim2real.md). The
    pretraining's capacity likewise (:func:`pretraining_candidates`), chosen with the encoder
    by the same criterion."""
    from ...models.base import seeded
    from ...training import fit_pipeline
    from ..real import default_config

    base = default_config(False, None, model, seed)
    if epochs is not None:
        base = base.replace(train=replace(base.train, epochs=epochs))
    scores, fitted = {}, {}
    candidates = pretraining_candidates(base, synth_w, seed)
    for key, (_, _, pre_cfg, _) in candidates.items():
        with seeded(seed):
            fitted[key] = fit_pipeline(pre_cfg, synth_w, with_past=False).pipeline
        scores[key] = list(_accuracy(fitted[key], train_w, log_likelihood=True))
    best = max(scores, key=lambda n: scores[n][2])  # ties: the earlier candidate
    chosen, capacity, _, cfg = candidates[best]
    return fitted[best], chosen, capacity, cfg, scores


#: :func:`~tactilesnn.training.transfer_pipeline`'s stages -> the arms they score
ARM_OF_STAGE = {"adapted": "synthetic_only", "class_share": "pretrained_letter",
                "labels": "pretrained_labels", "blend": "pretrained"}  # fmt: skip


def _transfer_and_score(row: dict, real: WindowDataset, pre, cfg, windows: tuple, idx: tuple,
                        synth: WindowDataset, letter: np.ndarray, seed: int,
                        features: bool = False) -> np.ndarray | None:  # fmt: skip
    """Every arm of the draw scored into ``row``: ``pre`` transferred to the training slides
    (:func:`~tactilesnn.training.transfer_pipeline`: the read-out's standardisation re-estimated,
    labels unused, scored as synthetic only; fine-tuned on the labels and, apart, on each
    window's share of the letter; their blend is the pretrained arm) and real only. Returns the
    adapted read-out's features of the test windows where ``features`` (else None)."""
    from ...models.base import seeded
    from ...recordings import expected_class_signal
    from ...training import fit_pipeline, transfer_pipeline

    train_real, test_real, train_w, test_w = windows
    train_idx, test_idx = idx
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
    out: dict = {}

    def score(stage: str, pipe) -> None:
        arm = ARM_OF_STAGE.get(stage, stage)
        got = _accuracy(pipe, test_w, runs_of=runs_of, parts=parts)
        row[arm], row[f"{arm}_per_slide"] = got[:2]
        if runs_of is not None:
            by_run[arm] = got[2]
        by_letter[arm] = got[-1]
        if stage == "adapted" and features:
            out["test_feats"] = read_out_features(pipe, test_w)

    # the letter's share: each real training window weighted by its share of the letter as the
    # fitted model renders it at that place in the slide (the class's mean synthetic signal;
    # the fit matched the letter's timing to these slides), as the synthetic windows were
    lettered = cut(train_real, expected_class_signal(letter, synth.y, train_real.y))
    report = transfer_pipeline(pre, train_w, lettered, seed=seed, on_arm=score)
    row["adapt"] = report["adapt"]
    row["finetune_letter"] = report["finetune_class_share"]
    row["finetune"] = report["finetune"]
    with seeded(seed):
        alone = fit_pipeline(cfg, train_w, with_past=False).pipeline
    score("real_only", alone)
    if runs_of is not None:
        row["by_run"] = by_run
    row["by_letter"] = by_letter
    return out.get("test_feats")
