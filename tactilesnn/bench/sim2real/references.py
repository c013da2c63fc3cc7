"""The non-spiking references on a draw's split, and what real slides reach on recording runs they
never saw (:func:`cross_runs`).
"""

from __future__ import annotations

import json
import logging
from dataclasses import replace
from pathlib import Path

import numpy as np

from ...core.data import WindowDataset
from .data import render_synthetic
from .protocol import (
    _accuracy,
    cut,
    few_shot_split,
    has_letter_runs,
    letter_parts,
    pretraining_candidates,
    recording_run,
    slides,
    with_seed,
)

log = logging.getLogger("tactilesnn")


def reference_scores(synth_w: WindowDataset, train_w: WindowDataset, test_w: WindowDataset,
                     seed: int) -> dict[str, dict[str, list]]:  # fmt: skip
    """The non-spiking references of ``bench real`` (:func:`.real.references`, the waveform
    ones: no spikes) trained on a draw's synthetic windows and, apart, on its real training
    windows; each scored on the draw's test windows -> ``{"synthetic" | "real": {name: [per
    window, per slide]}}``; where the synthetic windows carry confidences, also
    ``"synthetic_confidence"``: the references trained on the same soft targets as the spike
    pipeline (``"synthetic"``: on the labels alone)."""
    from ..real import references

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

    from ..real import FOREST_TREES, fit_and_score

    forest = RandomForestClassifier(n_estimators=FOREST_TREES, min_samples_leaf=2,
                                    random_state=seed, n_jobs=-1)  # fmt: skip
    per_window, per_slide = fit_and_score(forest, synth_feats, synth_w, test_feats, test_w)
    return [per_window, per_window if per_slide is None else float(per_slide)]


def add_references(run_dir: Path, real: WindowDataset, synthetic: int = 200) -> list[dict]:
    """The non-spiking references for an earlier run's calibrated draws (``run_dir/fits/
    k{k}_d{d}.json``; each fit's own training slides, the draw's split recomputed and checked),
    on its first training seed's synthetic slides (render seed = the draw): one row per draw,
    also written into ``run_dir/sim2real.json`` as ``references``."""
    from ...core.files import write_json_atomic
    from ...datasets_synth.calibration import SensorFit

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
            from ...models.base import seeded
            from ...training import adapt_pipeline, fit_pipeline
            from ..real import default_config

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

    from ...core.files import write_json_atomic
    from ...data_policy import DATA_ENCODER_CANDIDATES
    from ...models.base import seeded
    from ...recordings import expected_class_signal
    from ...selection import candidate_configs
    from ...training import fit_pipeline
    from ..real import default_config

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
