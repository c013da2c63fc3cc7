"""The few-shot protocol's pieces: windows cut from slides, the draws, recording runs and where the
letter is, and each arm's accuracy.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

import numpy as np

from ...core.data import WindowDataset

log = logging.getLogger("tactilesnn")


# ---------------------------------------------------------------- fits
def slides(real: WindowDataset, idx: np.ndarray) -> WindowDataset:
    """The slides ``idx`` (indices into the file's slides) of ``real``, in file order."""
    return real.subset(np.isin(np.arange(real.y.size), idx))


def cut(ds: WindowDataset, class_signal: np.ndarray | None = None) -> WindowDataset:
    """Windows as ``train --data`` cuts the real file (:func:`~tactilesnn.recordings.auto_cut`);
    with the slides' ``class_signal`` ``[N, samples]``, each window's confidence from it."""
    from ...recordings import auto_cut, cut_windows

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
    from ...training import fit_and_evaluate

    m = fit_and_evaluate(cfg, train, test, progress=progress).metrics
    return float(m["test_accuracy"]), float(
        m.get("test_accuracy_per_recording") or m["test_accuracy"]
    )


def base_config(synth_windows: WindowDataset, seed: int, epochs: int | None,
                model: str = "readout"):  # fmt: skip
    """The ``train --data`` defaults (with ``model``), the encoder chosen on the synthetic
    training windows."""
    from ...data_policy import DATA_ENCODER_CANDIDATES
    from ...selection import select_encoder
    from ..real import default_config

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

    from ...pipeline import recording_accuracy

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


def pretraining_candidates(base, synth_w: WindowDataset, seed: int) -> dict[str, tuple]:
    """The pipelines a calibrated draw pretrains on the synthetic windows, by key: every
    encoder candidate of a data file (:data:`~tactilesnn.data_policy.DATA_ENCODER_CANDIDATES`)
    times every capacity its model offers a pretraining
    (:meth:`~tactilesnn.models.base.SpikeModel.pretraining_capacities`; the readout: its
    cross-validation's choice and the strongest penalty). Each value: ``(encoder, capacity
    or None where the model offers one, the pretraining's config, the encoder's config as the
    model configures itself)`` (the last trains the real-only arm: on the real windows the
    model's own choice of capacity stands). Keys: ``encoder`` or ``encoder/capacity``."""
    from ...data_policy import DATA_ENCODER_CANDIDATES
    from ...models.base import MODELS
    from ...selection import candidate_configs

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
