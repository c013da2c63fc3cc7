"""Encoder selection on held-out training recordings (for a user's file, when the settings
name no encoder): each candidate with its defaults for the data's rate, window and spectrum."""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from .config import PipelineConfig
from .core.data import WindowDataset, evenly_spaced
from .core.memory import release_memory
from .core.settings import while_selecting
from .encoders import ENCODERS
from .models.base import to_tensor_labels
from .pipeline import SpikePipeline
from .trainer import TRAIN_ERROR_WINDOWS
from .training import fit_and_evaluate, split_validation

log = logging.getLogger("tactilesnn")


def median_power_frequency(X: np.ndarray, fs_hz: float, n_max: int = 256) -> float:
    """Frequency (Hz) below which half the power of (up to ``n_max``) windows lies, each
    channel's mean removed, summed over channels and windows; one window at a time in float64
    (a copy of the sample would double a file that fills the memory budget)."""
    idx = evenly_spaced(len(X), n_max)
    power = np.zeros(np.shape(X)[-1] // 2 + 1)
    for i in idx:
        x = np.asarray(X[i], dtype=np.float64)
        x = x - x.mean(-1, keepdims=True)
        power += (np.abs(np.fft.rfft(x, axis=-1)) ** 2).sum(axis=0)
    cum = np.cumsum(power)
    if not cum[-1] > 0:
        return float(fs_hz) / 4
    k = int(np.searchsorted(cum, 0.5 * cum[-1]))
    return float(np.fft.rfftfreq(np.shape(X)[-1], 1.0 / fs_hz)[k])


#: windows the candidates are fitted on at least (small files: all of them); beyond, a share of the
#: training windows that keeps the whole selection near one final training's cost
SELECT_MIN_WINDOWS = 1500


def selection_subset(data: WindowDataset, cap: int, seed: int) -> WindowDataset:
    """Whole recordings of ``data`` (classes in turn, each class's in random order) up to ``cap``
    windows; all of ``data`` when it fits."""
    if data.y.size <= cap:
        return data
    rng = np.random.default_rng([seed, 104729])
    groups, first, sizes = np.unique(data.scan, return_index=True, return_counts=True)
    queues = [list(rng.permutation(np.flatnonzero(data.y[first] == c))) for c in np.unique(data.y)]
    keep, total = [], 0
    while any(queues):
        for q in queues:
            if q and total + sizes[q[0]] <= cap:
                total += sizes[q[0]]
                keep.append(groups[q.pop(0)])
            elif q:
                q.clear()
    return data.subset(np.isin(data.scan, keep))


#: a candidate further below the round's best than HOPELESS_POINTS, or three standard errors of
#: the difference if that is more, stops after the first round whatever the halving keeps
HOPELESS_POINTS = 0.05
#: rounds fit at least this many windows (smaller data: all of them, in one round)
FIRST_ROUND_MIN_WINDOWS = 300
#: each round keeps the better 1 / RUNG_FACTOR of the candidates and fits them on RUNG_FACTOR
#: times the windows (successive halving, as scikit-learn's HalvingGridSearchCV with factor 2)
RUNG_FACTOR = 2
#: the selection's share of the whole run (selection, final fit, export), at most
SELECTION_SHARE = 0.25
#: windows each candidate encodes to measure its speed (and four times as many: :func:`probe`)
PROBE_WINDOWS = 24
#: a fit's seconds per window over its encoding's, before a round has measured it (the level
#: code, the readout's solve, scoring; measured on the visible sets: 1.5-3)
FIT_OVERHEAD = 2.0


def hopeless(acc: float, best: float, n: int) -> bool:
    """Whether held-out accuracy ``acc`` is too far below ``best`` (same windows, from ``n``
    recordings) to win with more training windows (see :data:`HOPELESS_POINTS`). The standard
    error counts recordings, not windows: a recording's windows err together."""
    se = np.sqrt((acc * (1 - acc) + best * (1 - best)) / max(n, 1))
    return best - acc > max(HOPELESS_POINTS, 3 * se)


def candidate_configs(
    config: PipelineConfig,
    train: WindowDataset,
    candidates: tuple[str, ...],
    shift: bool = False,
) -> dict[str, PipelineConfig]:
    """``config`` with each candidate encoder at its defaults for the data's rate, window and
    spectrum (``data_defaults`` of its config); with ``shift`` (test conditions unseen in
    training) each also as ``<name>+shift`` (:func:`shift_variant`). A candidate that would not
    fit in memory for these windows is left out (:func:`_that_fit`)."""
    median = median_power_frequency(train.X, train.fs_hz)
    out = {name: fit_encoder_to_data(config.replace(encoder=ENCODERS.config_class(name)()),
                                     train, median_hz=median) for name in candidates}  # fmt: skip
    if shift:
        out |= {f"{name}{SHIFT_SUFFIX}": shift_variant(cfg) for name, cfg in list(out.items())}
    return _that_fit(out, train)


#: the name a candidate's variant for unseen conditions carries (``cgwt+shift``)
SHIFT_SUFFIX = "+shift"


def shift_variant(config: PipelineConfig) -> PipelineConfig:
    """What a candidate also tries where the test conditions are unseen (``--hold-out``): codes
    whose values move with a harder press by shifting, not by leaving the training range.

    * ``gain_norm``: each window divided by its level (the pattern, not the force);
    * the level code, where there is one, on the ``"wide"`` scale (the training range widened
      by its span each side: a level beyond every training one still codes, where ranks clamp);
    * the scalogram codes' band means only (``stats = ("mean",)``: the fluctuation statistic
      followed the force the training windows had);
    * the read-out's traces read at the window's end only (``n_times = 1``): each is then a
      smooth, monotone function of its spike's time, where a trace read at an instant the spike
      had never preceded in training switches on from a constant 0 (standardised by a ~0 spread).

    FabricSlide, trained at F120-F150 and tested at F180-F250, cgwt + readout, seed 0, per window
    / per recording: as coded 59.2 / 54.5 %; gain-normalised without the level code (this
    variant until 2026-12-08) 70.7 / 72.8; gain + wide level 73.9 / 76.2; + the window's end
    only 89.8 / 91.6; + band means only 93.3 / 93.3 (stft: 93.1 / 96.1); without gain_norm
    86.7 / 86.3; with the rank level code 82.5 / 84.5 (the amplitude-only baseline 88.7 / 91.4,
    logistic regression on log band powers 95.8 / 98.9). The selection then compares it with
    the candidate as it is, leaving whole condition values out."""
    changes: dict[str, Any] = {"gain_norm": True}
    if config.level_neurons:
        changes["level_scale"] = "wide"
    enc, model = config.encoder, config.model
    if "mean" in getattr(enc, "stats", ()):
        changes["encoder"] = replace(enc, stats=("mean",))
    if hasattr(model, "n_times"):
        changes["model"] = replace(model, n_times=1)
    return config.replace(**changes)


def resolved_config(
    res: Any, train: WindowDataset, leave_out: str | None = None
) -> tuple[PipelineConfig, dict[str, Any] | None]:
    """A :class:`~tactilesnn.resolve.Resolution` made concrete on the training windows, as
    ``train --data`` does it: the encoder chosen among ``res.select`` (:func:`select_encoder`,
    its report second; ``leave_out``: a condition held out by whole values, or the hold-out
    spec that names it: :func:`condition_groups`), else fitted to the
    data except the user's fields ``res.keep``, else ``res.config`` as it is."""
    if res.select:
        return select_encoder(res.config, train, res.select, leave_out=leave_out)
    if res.keep is not None:
        return fit_encoder_to_data(res.config, train, keep=res.keep), None
    return res.config, None


def fit_encoder_to_data(config: PipelineConfig, train: WindowDataset, keep: Iterable[str] = (),
                        median_hz: float | None = None) -> PipelineConfig:  # fmt: skip
    """``config`` with its encoder's settings that follow the data (``data_defaults`` of its
    config: bands that reach 0.45 fs and down to the spectrum's median, the dynamic range) taken
    from ``train``'s rate, window and spectrum, except the fields in ``keep`` (the user's). The
    one place a data file's facts set an encoder: ``tactilesnn train --data``, the encoder
    selection and :class:`~tactilesnn.estimator.SpikeClassifier` all come here."""
    cls = type(config.encoder)
    if not cls.follows_data or train.X.ndim != 3:
        return config
    if median_hz is None:
        median_hz = median_power_frequency(train.X, train.fs_hz)
    fitted = cls.data_defaults(train.fs_hz, train.X.shape[-1], median_hz)
    fields = {f.name: getattr(config.encoder, f.name) for f in dataclasses.fields(config.encoder)}
    kept = {k: fields[k] for k in keep if k in fields}
    return config.replace(encoder=cls(**{**fields, **fitted, **kept}))


@dataclass(frozen=True)
class Probe:
    """A pipeline's measured encoding speed (seconds per window), whether its encoder also codes
    windows with their past (the final fit encodes those too), whether its model solves in one
    go (a fit is then a few passes), and for a model trained over epochs the seconds one
    training step takes per window (``step_seconds_per_window``) and its epochs."""

    seconds_per_window: float
    codes_with_past: bool
    solves: bool
    step_seconds_per_window: float | None = None
    epochs: int = 0

    def fit_seconds(
        self, n_train: int, n_test: int, overhead: float = FIT_OVERHEAD
    ) -> float | None:
        """Estimated seconds to fit on ``n_train`` windows and score ``n_test``: the encoding
        (times ``overhead``), and for a model trained over epochs its epochs' steps plus each
        epoch's scoring of up to :data:`~tactilesnn.trainer.TRAIN_ERROR_WINDOWS` training
        windows (a forward pass: a third of a step)."""
        n = n_train * (2 if self.codes_with_past else 1) + n_test
        if self.solves:
            return overhead * self.seconds_per_window * n
        if self.step_seconds_per_window is None:
            return None
        scored = min(n_train, TRAIN_ERROR_WINDOWS) + n_test / max(1, self.epochs)
        per_epoch = self.step_seconds_per_window * (n_train + scored / 3)
        return self.seconds_per_window * n + self.epochs * per_epoch


def probe(config: PipelineConfig, data: WindowDataset, n: int = PROBE_WINDOWS) -> Probe:
    """:class:`Probe` of ``config`` on ``data``'s windows: the encoding timed on ``n`` and on
    ``4 n`` windows (after a first pass that pays for caches), the seconds per window from the
    difference (a call's fixed cost is not a window's: timed on 24 windows alone, cgwt on 1 x
    3,300 samples read 4x its batch rate)."""
    big = data.subset(evenly_spaced(data.y.size, 4 * n))
    small = big.subset(np.arange(big.y.size) < min(n, big.y.size // 2 or 1))
    pipe = SpikePipeline(config, data.fs_hz, data.X.shape[-1], data.channel_names,
                         data.class_names)  # fmt: skip
    pipe.calibrate(big.X)
    spikes = pipe.encode(small.X)
    timed = []
    for part in (small, big):
        t0 = time.perf_counter()
        pipe.encode(part.X)
        timed.append(time.perf_counter() - t0)
    extra = big.y.size - small.y.size
    rate = (timed[1] - timed[0]) / extra if extra > 0 else 0.0
    if rate <= 0:  # too fast or too noisy to tell apart: the larger pass per window
        rate = timed[1] / max(1, big.y.size)
    solves = type(pipe.model).solves_in_one_go(config.model)
    step = None if solves else _step_seconds(pipe.model, spikes, small.y, config.train.batch_size)
    return Probe(rate, pipe.streams_recordings, solves, step, config.train.epochs)


def _step_seconds(model, spikes: torch.Tensor, y: np.ndarray, batch: int) -> float:
    """Seconds per window of one training step of ``model`` (the median of three mini-batches
    of up to ``batch`` windows, after one that pays for caches), on a throw-away model with the
    global random state kept."""
    reps = -(-min(batch, 64) // spikes.shape[0])
    xb = spikes.repeat(reps, 1, 1)[: min(batch, 64)]
    yb = to_tensor_labels(np.resize(y, xb.shape[0]), model.n_classes, xb.shape[0])
    times = []
    with torch.random.fork_rng():
        model.prepare(xb)
        opt = None if model.learns_by_rule else torch.optim.Adam(model.parameters(), lr=1e-6)
        for _ in range(4):
            t0 = time.perf_counter()
            if opt is None:
                model.rule_update(xb, yb, 0)
            else:
                opt.zero_grad()
                model.loss(xb, yb).backward()
                opt.step()
            times.append(time.perf_counter() - t0)
    return float(np.median(times[1:])) / xb.shape[0]


@dataclass
class SelectionBudget:
    """What the selection may spend, from the candidates' measured encoding speed: ``rate``
    (seconds per window, per candidate), ``overhead`` (a fit's seconds over its encoding's) and
    the seconds the rest of the run is expected to take (``rest_s``: final fit and export);
    the selection's windows are cut so that it stays within :data:`SELECTION_SHARE` of it all."""

    rate: dict[str, float]
    rest_s: float
    overhead: float = FIT_OVERHEAD

    @property
    def seconds(self) -> float:
        """The selection's allowance: ``SHARE / (1 - SHARE)`` of the rest of the run."""
        return SELECTION_SHARE / (1.0 - SELECTION_SHARE) * self.rest_s

    def measured_overhead(self, report: dict[str, Any]) -> float:
        """The fit's seconds over its encoding's, as the selection's rounds measured it (the
        estimate :data:`FIT_OVERHEAD` where nothing was measured)."""
        encoding = sum(self.rate[c] * (r["fit_windows"] + r["val_windows"])
                       for r in report.get("rounds", ()) for c in r["candidates"])  # fmt: skip
        taken = sum(r["seconds"] for r in report.get("rounds", ()))
        # (never below the prior: the final fit's readout also cross-validates its penalty)
        return max(self.overhead, taken / encoding) if encoding > 0 else self.overhead

    def cost(self, rounds: list[tuple[int, int]], val_share: float) -> float:
        """Estimated seconds of ``rounds`` ``(candidates, fit windows)``, each fit also scoring
        ``val_share`` times its windows held out."""
        mean = float(np.mean(list(self.rate.values())))
        return sum(k * n * (1.0 + val_share) * mean * self.overhead for k, n in rounds)


def rounds_for(n_candidates: int, last: int) -> list[tuple[int, int]]:
    """Successive halving: ``(candidates, fit windows)`` per round, the candidates halved
    (rounded up) and the windows multiplied by :data:`RUNG_FACTOR` from one round to the next,
    the last round two candidates on ``last`` windows (one round when there are two or fewer).
    Three candidates: ``[(3, last / 2), (2, last)]``."""
    counts = [n_candidates]
    while counts[-1] > 2:
        counts.append(-(-counts[-1] // RUNG_FACTOR))
    return [(k, last // RUNG_FACTOR ** (len(counts) - 1 - i)) for i, k in enumerate(counts)]


def planned_rounds(
    n_candidates: int, n_fit: int, val_share: float, budget: SelectionBudget | None
) -> list[tuple[int, int]]:
    """The selection's rounds ``(candidates, fit windows)`` (:func:`rounds_for`) on ``n_fit``
    windows, the last round cut where ``budget`` says they would take more than their share of
    the run, but never below ``SELECT_MIN_WINDOWS`` (fewer windows ranked the encoders
    differently from the full data on the visible sets: FabricSlide on 356 windows of ~15
    recordings put LIF last where 2,182 put it first by 2.6 points); one round where the first
    would fit fewer than :data:`FIRST_ROUND_MIN_WINDOWS`."""
    last, floor = n_fit, min(n_fit, SELECT_MIN_WINDOWS)
    if budget is not None:
        while (
            last > floor and budget.cost(rounds_for(n_candidates, last), val_share) > budget.seconds
        ):
            last = max(floor, int(last * 0.8))
    rounds = rounds_for(n_candidates, last)
    if rounds[0][1] < FIRST_ROUND_MIN_WINDOWS:
        rounds = [(n_candidates, last)]
    return rounds


def selection_seconds(
    n_train: int, n_candidates: int, budget: SelectionBudget, fraction: float = 0.25
) -> float:
    """Estimated seconds of :func:`select_encoder` on ``n_train`` training windows (its split
    and caps as it makes them, from window counts)."""
    cap = max(SELECT_MIN_WINDOWS, n_train // max(1, n_candidates))
    n_fit = min(round((1 - fraction) * n_train), cap)
    val_share = min(round(fraction * n_train), cap) / max(1, n_fit)
    return budget.cost(planned_rounds(n_candidates, n_fit, val_share, budget), val_share)


def select_encoder(
    config: PipelineConfig,
    train: WindowDataset,
    candidates: tuple[str, ...],
    fraction: float = 0.25,
    budget: SelectionBudget | None = None,
    configs: dict[str, PipelineConfig] | None = None,
    leave_out: str | None = None,
) -> tuple[PipelineConfig, dict[str, Any]]:
    """The candidate encoder (each with its default settings for the data's rate and window:
    :func:`candidate_configs`; the rest of ``config`` unchanged) that scores best on
    ``fraction`` of the training recordings held out (whole recordings).

    Ranked by held-out accuracy per window, ties by per recording, then the earlier candidate
    (per window: many more samples than the quarter of the recordings held out, where one
    recording is several points). Successive halving over recordings: every candidate is fitted
    on a share of the windows, the better half (and none :func:`hopeless`) on twice as many, up
    to ``max(SELECT_MIN_WINDOWS, training windows / candidates)`` windows of whole recordings in
    the last round, or fewer where ``budget`` says the rounds would take more than
    :data:`SELECTION_SHARE` of the run. Windows are coded alone here (an encoder that also codes
    windows with their recording's past gets those in the final fit only). Returns the chosen
    config and a report (``scores`` per candidate with ``rounds`` and ``stopped_after``,
    ``ranked_by``, windows per round, ``seconds``, ``validation``). ``leave_out``: a condition
    of the data held out by whole values (:func:`condition_groups`; each encoder then also as
    its :func:`shift_variant`), so what transfers to an unseen condition is chosen."""
    if not candidates:
        raise ValueError("encoder selection needs at least one candidate encoder")
    t0 = time.perf_counter()
    by, validation, side = condition_groups(train, leave_out)
    configs = configs or candidate_configs(config, train, candidates, shift=by is not None)
    configs, validation = _for_the_trend(configs, by, side, validation)
    fit_set, val_set = split_validation(train, fraction, config.seed + 1, by=by, side=side)
    assert val_set is not None
    cap = max(SELECT_MIN_WINDOWS, train.y.size // max(1, len(candidates)))  # (per encoder)
    candidates = tuple(configs)  # the encoders and, for unseen conditions, their variants
    fit_set = selection_subset(fit_set, cap, config.seed)
    val_set = selection_subset(val_set, cap, config.seed + 1)
    val_share = val_set.y.size / max(1, fit_set.y.size)
    rounds = planned_rounds(len(candidates), fit_set.y.size, val_share, budget)
    scores: dict[str, dict[str, Any]] = {name: {"rounds": []} for name in candidates}
    keys: dict[str, tuple[float, float]] = {}
    report_rounds = []
    alive = list(candidates)
    for r, (keep, n_fit) in enumerate(rounds):
        for name in alive[keep:]:  # ranked by the round before: the better ones go on
            scores[name]["stopped_after"] = r
        alive = alive[:keep]
        fit = selection_subset(fit_set, n_fit, config.seed + 2 * r)
        share = fit.y.size / max(1, fit_set.y.size)
        val = selection_subset(
            val_set, max(1, int(share * val_set.y.size)), config.seed + 2 * r + 1
        )
        t_round = time.perf_counter()
        for name in alive:
            acc, per_rec = _scored(name, configs[name], fit, val)
            scores[name]["rounds"].append(acc)
            scores[name]["per_window"] = acc
            if per_rec is not None:
                scores[name]["per_recording"] = per_rec
            keys[name] = (acc, acc if per_rec is None else per_rec)
        report_rounds.append({"candidates": list(alive), "fit_windows": int(fit.y.size),
                              "val_windows": int(val.y.size),
                              "seconds": time.perf_counter() - t_round})  # fmt: skip
        alive.sort(key=lambda n: (-keys[n][0], -keys[n][1], candidates.index(n)))
        if r + 1 < len(rounds):
            alive = _drop_hopeless(alive, keys, scores, np.unique(val.scan).size, r + 1)
        if len(alive) == 1:
            break
    best = alive[0]
    seconds = time.perf_counter() - t0
    log.info("encoder selection: %s (%.0f s; held out: %s)", best, seconds, validation)
    report = {"chosen": best, "ranked_by": "per window, then per recording",
              "validation": validation,
              "scores": scores, "rounds": report_rounds,
              "fit_windows": report_rounds[-1]["fit_windows"],
              "val_windows": report_rounds[-1]["val_windows"], "seconds": seconds}  # fmt: skip
    return configs[best], report


def _beyond(spec_values: str, train_values: np.ndarray) -> str | None:
    """``"high"`` / ``"low"`` where every value of a hold-out list (``"100,120"``) is a number
    above / below every training value of its condition, else None."""
    try:
        held = np.array([float(v) for v in spec_values.split(",")])
        seen = np.asarray(train_values, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if seen.size == 0 or not np.isfinite(held).all():
        return None
    return "high" if held.min() > seen.max() else "low" if held.max() < seen.min() else None


#: training values of a held-out condition below which leaving one out cannot rank a code that
#: extrapolates against one calibrated to the training range: where the test lies beyond them,
#: only the variants for unseen conditions (:func:`shift_variant`) are compared (still by
#: leaving the nearest value out). FabricSlide trained at F120 and F150: a logistic regression
#: on log band powers fitted at F120 scores 50.5 % at F150, fitted at both 95.8 % at F180-F250;
#: leaving F150 out ranked cgwt (64.5 %) over cgwt+shift (43.6 %), which then scored 59.2 %
#: against the variant's 93.3 % on the test forces; among the variants it ranked cgwt+shift
#: (57.1 %) > stft+shift (52.3) > lif+shift (32.5), as the test forces do (93.3 / 93.1 / 67.1)
TREND_VALUES = 3


def _for_the_trend(configs: dict[str, PipelineConfig], by: np.ndarray | None, side: str | None,
                   validation: str) -> tuple[dict[str, PipelineConfig], str]:  # fmt: skip
    """The candidates and the validation's description where the test lies beyond fewer than
    :data:`TREND_VALUES` training values (``side`` set): only the variants for unseen
    conditions (all candidates where there are none), and why; else both as they are."""
    n = 0 if by is None else np.unique(by).size
    variants = {k: c for k, c in configs.items() if k.endswith(SHIFT_SUFFIX)}
    if side is None or n >= TREND_VALUES or not variants:
        return configs, validation
    return variants, (f"{validation}; among the variants for unseen conditions only: the test "
                      f"lies beyond {n} training values, too few for a held-out one to measure "
                      "extrapolation")  # fmt: skip


def condition_groups(
    train: WindowDataset, leave_out: str | None
) -> tuple[np.ndarray | None, str, str | None]:
    """The groups the selection holds out whole (each window's value of the condition
    ``leave_out`` names, or None: recordings), how it says so in the log and report, and which
    end of the values it holds out: ``leave_out`` is a condition name or the run's hold-out spec
    (``F>=180``); a bound (``>``, ``>=``; ``<``, ``<=``) holds out the training values nearest
    the test's (``"high"``, ``"low"``: trained below, validated above, as the test is), a list
    of values (``run=2,5``) values drawn at random (None)."""
    from .recordings import HOLD_OUT

    if leave_out is None:
        return None, "recordings", None
    m = HOLD_OUT.match(leave_out)
    name, op = (m.group("name"), m.group("op")) if m else (leave_out, "=")
    values = train.condition(name)
    side = "high" if op.startswith(">") else "low" if op.startswith("<") else None
    if m and op == "=":  # numbers all beyond the training values are a bound too
        side = _beyond(m.group("values"), values)
    if np.unique(values).size < 2:
        log.info("encoder selection: the training recordings hold one value of %s: held-out "
                 "recordings instead", name)  # fmt: skip
        return None, "recordings", None
    where = {
        "high": "; its highest held out, as the test's lie above",
        "low": "; its lowest held out, as the test's lie below",
        None: "",
    }[side]
    return values, f"whole values of condition {name} (unseen as the test's are{where})", side


def _that_fit(configs: dict[str, PipelineConfig], train: WindowDataset
              ) -> dict[str, PipelineConfig]:  # fmt: skip
    """The candidates whose pipeline can be built for ``train``'s windows and fits in memory
    (each checked before any is fitted: one that cannot is left out, said in the log, rather
    than failing the run after the others' fits); none: the first one's error."""
    kept, refused = {}, {}
    for name, cfg in configs.items():
        try:
            SpikePipeline(cfg, train.fs_hz, train.X.shape[-1], train.channel_names,
                          train.class_names)  # fmt: skip
        except ValueError as e:  # too large, or not for windows like these (too short...)
            refused[name] = str(e)
            log.info("encoder selection: %s left out: %s", name, e)
            continue
        kept[name] = cfg
    if not kept:
        raise ValueError(next(iter(refused.values())))
    return kept


def _scored(name: str, config: PipelineConfig, fit: WindowDataset,
            val: WindowDataset) -> tuple[float, float | None]:  # fmt: skip
    """Candidate ``name`` fitted on ``fit`` and scored on ``val``: ``(per window, per recording
    or None)``. Its model as the component asks to be fitted while encoders are compared (e.g.
    without its own cross-validation); the chosen config keeps the model as configured."""
    config = config.replace(model=replace(config.model, **while_selecting(type(config.model))))
    m = fit_and_evaluate(config, fit, val, progress=False, with_past=False).metrics
    release_memory()  # a candidate's arrays are not the next one's resident memory
    per_rec = m.get("test_accuracy_per_recording")
    log.info("encoder selection: %s scores %.2f %% per window%s on %d held-out windows "
             "(fitted on %d, %.1f s)", name, 100 * m["test_accuracy"],
             f", {100 * per_rec:.2f} % per recording" if per_rec is not None else "",
             val.y.size, fit.y.size, m["encode_seconds"] + m["fit_seconds"])  # fmt: skip
    return float(m["test_accuracy"]), None if per_rec is None else float(per_rec)


def _drop_hopeless(alive: list[str], keys: dict[str, tuple[float, float]],
                   scores: dict[str, dict[str, Any]], n_rec: int, after: int) -> list[str]:  # fmt: skip
    """``alive`` (ranked) without the candidates :func:`hopeless` against the leader, each
    dropped one marked ``stopped_after`` round ``after``."""
    top = keys[alive[0]][0]
    for name in alive[1:]:
        if hopeless(keys[name][0], top, n_rec):
            scores[name]["stopped_after"] = after
            log.info("encoder selection: %s stops after round %d (%.2f %% against "
                     "%.2f %%)", name, after, 100 * keys[name][0], 100 * top)  # fmt: skip
    return [n for n in alive if not hopeless(keys[n][0], top, n_rec)]
