"""Leaky-integrator readout: exact membrane traces at fixed times -> linear softmax: ``readout``.

Each afferent drives a leaky integrator (time constant ``tau_ms``; 0, the default, takes the
window's duration) that jumps by 1 at each of its spikes; its membrane ``m_a(t) = sum_k
exp(-(t - t_ak) / tau) H(t - t_ak)`` is read, in closed form, at ``n_times`` instants
``t_j = (j + 1) D / n_times`` across the window. The class scores are a linear map of ``log1p`` of
those ``afferents x n_times`` traces, each standardised by its mean and standard deviation over
the training set (fitted by :meth:`LIReadout.prepare`, kept as buffers, so saved and exported).
The loss is cross-entropy plus a penalty on the squared weights: ``weight_decay`` at
:data:`PRIOR_WINDOWS` training windows, scaled by ``PRIOR_WINDOWS / N`` for ``N`` (a fixed prior
against a data term that grows with the data, as in a MAP estimate; sklearn's ``C`` works alike).
A constant penalty underfit large files: FabricSlide (5,238 training windows) LIF + readout, seed 0,
98.40 % per window at 0.03, 99.30 % at 0.003, 99.41 % at 0.0003, while iCub Braille (190) was
tuned at 0.03. Cost per
window is ``O(afferents x spikes x n_times x classes)``: linear in the inputs (the exact
tempotron's ``V_max`` holds pairwise lags, quadratic in them), and the softmax trains 20-50
classes as easily as 2.

The loss is convex, so by default (``solver = "exact"``) it is minimised to its optimum
(:mod:`.softmax_fit`: full-batch L-BFGS in the features' row space) rather than by epochs of
Adam, and (``choose``) its capacity follows the data: the penalty (1/3 to 30 times the prior
above) and the read-out instants used (all ``n_times``, or only the window's end, where the
traces' time course adds more variance than information) are chosen by 3-fold cross-validation
over recordings on the training windows (the folds stratified by class); ``metrics.json``
``model_fit`` reports every candidate.
40 epochs of Adam stopped short of the optimum and a fixed capacity overfit synthetic texture
(1,488 features for 1,920 windows): seed 0, 65.2 % (Adam) -> 67.9 % (exact, same penalty) ->
72.1 % (chosen: the last instant, penalty x 1/3).

Why these defaults (measured with ``tactilesnn bench real``): without standardisation the few
afferents that carry a class (a rarely reached band) have small traces and the L2 penalty
silences them; a trace that outlasts the window keeps each spike's time in a slowly varying
value instead of a 100 ms pulse. With the ``--data`` defaults, seed 0: synthetic material
82.8 -> 91.1 %, texture 57.7 -> 67.7 %, iCub Braille 94.7 -> 97.4 % per window (seeds 0-2).
Runs written before keep their settings and score as before.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import replace
from typing import ClassVar

import numpy as np
import torch
from torch import Tensor, nn

from ..core.device import seeded_normal
from ..core.memory import release_memory
from ..schema.models import ReadoutConfig
from .base import SpikeModel, register_model, seeded
from .softmax_fit import (
    CV_WINDOWS,
    PENALTY_FACTORS,
    choose_penalty,
    fit_features,
    fit_softmax,
    row_space,
    soft_targets,
    whole_groups,
)

log = logging.getLogger("tactilesnn")

#: training windows at which the penalty is ``weight_decay`` (see the module docstring)
PRIOR_WINDOWS = 256
#: the strongest penalty factor the cross-validation may choose (a pretraining's candidate)
STRONGEST_FACTOR = max(PENALTY_FACTORS)
#: the exact solver's float32 feature matrix may take this much (its working set adds the
#: float64 ``N x N`` Gram matrix where features outnumber windows, the features then let go);
#: above it, the exact fit on the windows it holds (:data:`EXACT_MIN_SHARE`) or Adam's epochs
EXACT_BUDGET_BYTES = 256 << 20
#: over the budget, the exact fit still runs on the whole recordings the budget holds when they
#: are at least this share of the training windows (else Adam trains on all of them). The
#: 22-channel electrode stand-in (``bench fit``; 5,600 windows x 19,088 features): Adam's
#: epochs on every window 60 s, 35.93 % per window / 53.5 % per recording, 1.20 GB peak; the
#: exact fit on the 63 % a 256 MiB budget holds: 37.14 / 56.0 %, 1.3-1.4 GB (on 78 % at 320 MiB:
#: 38.93 / 56.0 %, but 1.4-1.7 GB, over the 1.5 GB a file of 100 MB may take)
EXACT_MIN_SHARE = 0.6


#: a feature varies when its standard deviation exceeds this share of its magnitude (and
#: :data:`MIN_FEATURE_SD`): below, it is a constant that float32 rounding perturbs (~100 ulps)
FEATURE_REL_SD = 1e-5
MIN_FEATURE_SD = 1e-6


def varies(mean: Tensor, sd: Tensor) -> Tensor:
    """Which features vary beyond arithmetic rounding (bool, the shape of ``sd``); the others
    are standardised by 1, not by their spread. A channel at +30,000 through the LIF code
    gave a trace feature of standard deviation 1.007e-6 at a magnitude of ~5 (2 float32 ulps):
    divided by it, the summation order's rounding moved the exported graph's scores 0.07 from
    torch's, and the export was refused (``tests/encoders/test_degenerate_windows.py``)."""
    return sd > torch.clamp(FEATURE_REL_SD * mean.abs(), min=MIN_FEATURE_SD)


def instant_subsets(n_times: int) -> list[list[int]]:
    """The read-out instants the exact solver may use: every one, or the last only (where the
    trace's time course adds more variance than information: synthetic texture 65.2 -> 72.1 %,
    seed 0; intermediate resolutions never ranked first on the visible sets)."""
    out = [list(range(n_times))]
    if n_times > 1:
        out.append([n_times - 1])
    return out


def trace_features(spikes: Tensor, times_ms: Tensor, tau_ms: float,
                   slack_ms: float = 0.0) -> Tensor:  # fmt: skip
    """Spike times ``[B, A, k]`` (ms, inf = none) -> traces ``[B, A, n_times]`` at ``times_ms``.
    A spike up to ``slack_ms`` after an instant counts at it as if on it (see
    :data:`INSTANT_SLACK`)."""
    lag = times_ms.view(1, 1, 1, -1) - spikes.unsqueeze(-1)  # [B, A, k, T]; inf spikes -> -inf
    live = lag >= -slack_ms
    kern = torch.exp(-torch.where(live, lag.clamp_min(0.0), torch.zeros_like(lag)) / tau_ms)
    return torch.where(live, kern, torch.zeros_like(kern)).sum(2)


#: a spike this share of the window after a read-out instant counts at it. Frame-clocked codes
#: (STFT) put spikes exactly on instants (7 % of them on synthetic iCub Braille slides): there
#: torch and the exported graph, each rounding the spike time in float32 (~1e-7 relative), fell
#: on either side and scored a window differently (0.025, 3 of 420 windows, export refused); the
#: slack, a tenth of the export's spike-time tolerance above float32 rounding, counts both alike
INSTANT_SLACK = 1e-6


class TraceFeatures(SpikeModel):
    """The trace read-outs' features (``readout``, ``forest``): each afferent's leaky-integrator
    trace at ``config.n_times`` instants, ``log1p``, standardised by buffers ``feat_mean`` /
    ``feat_scale`` that :meth:`fit_standardisation` fits on the training spikes and
    :meth:`adapt` re-estimates on a new domain's. The base of the models that read them."""

    def _init_trace_features(self, config: object, n_afferents: int, duration_ms: float) -> int:
        """Registers the read-out instants and the scaler's buffers; returns the feature count."""
        n_times = int(config.n_times)
        # n_times values, made on the host even when the model is built on meta to be counted
        # (an arange there would import torch._dynamo: core.device.seeded_normal)
        times = (torch.arange(n_times, dtype=torch.float32, device="cpu") + 1) * (
            duration_ms / n_times
        )
        self.register_buffer("times_ms", times)
        self.tau_ms = float(config.tau_ms) or float(duration_ms)
        n_in = n_afferents * n_times
        # feature scaling, fitted on the training spikes by fit_standardisation()
        self.register_buffer("feat_mean", torch.zeros(n_in))
        self.register_buffer("feat_scale", torch.ones(n_in))
        return n_in

    def traces(self, spikes: Tensor) -> Tensor:
        """``log1p`` of the LI traces, ``[B, afferents * n_times]`` (before scaling)."""
        slack = INSTANT_SLACK * float(self.duration_ms)
        return torch.log1p(trace_features(spikes, self.times_ms, self.tau_ms, slack)).flatten(1)

    def features(self, spikes: Tensor) -> Tensor:
        return (self.traces(spikes) - self.feat_mean) / self.feat_scale

    def _moments(self, spikes: Tensor, kept: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """float64 mean and (population) standard deviation of every trace feature over
        ``spikes``, in batches bounded by the byte budget; ``kept`` ``[N, d]``, when given,
        receives the float32 traces."""
        total = torch.zeros_like(self.feat_mean, dtype=torch.float64)
        total_sq = torch.zeros_like(total)
        batch, n = self.batch_size(spikes), spikes.shape[0]
        for i in range(0, n, batch):
            t = self.traces(spikes[i : i + batch])
            if kept is not None:
                kept[i : i + batch] = t
            f = t.double()
            total += f.sum(0)
            total_sq += (f * f).sum(0)
        mean = total / n
        return mean, (total_sq / n - mean * mean).clamp_min(0.0).sqrt()

    @torch.no_grad()
    def fit_standardisation(self, spikes: Tensor, kept: Tensor | None = None) -> None:
        """Mean and standard deviation of every trace feature over the training spikes (float64
        sums over batches bounded by the byte budget); constant features (:func:`varies`) keep
        scale 1."""
        mean, sd = self._moments(spikes, kept)
        self.feat_mean.copy_(mean.float())
        self.feat_scale.copy_(torch.where(varies(mean, sd), sd, torch.ones_like(sd)).float())

    @torch.no_grad()
    def adapt(self, spikes: Tensor) -> dict:
        """The feature standardisation (mean and standard deviation of every trace feature)
        re-estimated on a new domain's unlabelled spikes ``[N, A, k]``, N >= 2, what was learnt
        kept: the read-out then sees the new domain's features on the scale it was trained on
        (as AdaBN re-estimates batch statistics). A feature constant over the new windows keeps
        its trained scale. iCub Braille, the calibrated model's synthetic slides, re-estimated
        on the k real training slides (``docs/sim2real.md``, nine draws x three seeds, the
        linear read-out): synthetic only 59.1 -> 63.1 % per slide, 48.1 -> 50.2 % per window.
        Returns the windows used, the features rescaled and the median shift of the means
        (trained standard deviations)."""
        n = int(spikes.shape[0])
        if n < 2:
            raise ValueError(f"adapting the standardisation needs two windows or more, got {n}")
        mean, sd = self._moments(spikes)
        live = varies(mean, sd)
        shift = ((mean - self.feat_mean.double()).abs() / self.feat_scale.double()).median()
        self.feat_mean.copy_(mean.float())
        self.feat_scale.copy_(torch.where(live, sd, self.feat_scale.double()).float())
        return {"windows": n, "features_rescaled": int(live.sum()),
                "features": int(live.numel()), "median_mean_shift_sd": float(shift)}  # fmt: skip


@register_model("readout", ReadoutConfig)
class LIReadout(TraceFeatures):
    """Leaky-integrator traces at fixed times -> linear class scores; see the module docstring."""

    score_units = "logits of a softmax over classes"
    trains_on_confidence = True
    #: the feature scaler's buffers: runs written before it load them as identity
    optional_state: ClassVar[tuple[str, ...]] = ("feat_mean", "feat_scale")

    def __init__(self, config: ReadoutConfig, n_afferents: int, max_spikes: int, n_classes: int,
                 duration_ms: float, seed: int = 0) -> None:  # fmt: skip
        super().__init__(config, n_afferents, max_spikes, n_classes, duration_ms, seed)
        g = torch.Generator().manual_seed(int(seed))
        n_in = n_afferents * config.n_times
        with seeded(seed):  # (its own initial draws are replaced below)
            self.linear = nn.Linear(n_in, n_classes)
        with torch.no_grad():
            self.linear.weight.copy_(seeded_normal(n_classes, n_in, g).div_(math.sqrt(n_in)))
            self.linear.bias.zero_()
        self._init_trace_features(config, n_afferents, duration_ms)
        self.penalty = float(config.weight_decay)  # set from the training set's size by prepare()
        # which features train (solve() may leave instants out); not saved: zero weights are
        self.register_buffer("instant_mask", torch.ones(n_in), persistent=False)
        self._prepared: tuple[Tensor, Tensor] | None = None  # prepare()'s traces, for solve()
        #: ``(instants, penalty factor)`` a solve takes instead of cross-validating (None: it
        #: chooses as configured); :attr:`chosen_capacity` is what the last solve used
        self.refit_capacity: tuple[list[int], float] | None = None
        self.chosen_capacity: tuple[list[int], float] | None = None

    @classmethod
    def solves_in_one_go(cls, config: object) -> bool:
        return isinstance(config, ReadoutConfig) and config.solver == "exact"

    @classmethod
    def pretraining_capacities(cls, config: object) -> dict[str, object]:
        """With ``choose``: the capacity the cross-validation chooses on the pretraining
        windows, and the strongest penalty it may choose (x :data:`STRONGEST_FACTOR`) on every
        instant. The synthetic windows' own folds pick the capacity that separates synthetic
        letters best; a real sensor reads the broader, smoother map of the strongest prior
        better: ``bench sim2real`` (docs/sim2real.md) took it in 24 of 27 draws x seeds, synthetic
        only 65.9 -> 70.6 % per slide on the iCub file's other slides."""
        if not (isinstance(config, ReadoutConfig) and config.choose and config.solver == "exact"):
            return {"configured": config}
        strongest = min(1.0, config.weight_decay * STRONGEST_FACTOR)
        return {"chosen": config,
                "strongest": replace(config, choose=False, weight_decay=strongest)}  # fmt: skip

    @torch.no_grad()
    def prepare(self, spikes: Tensor) -> None:
        """Mean and standard deviation of every trace feature over the training spikes
        (float64 sums over batches bounded by the byte budget); constant features keep scale 1.
        Where the float32 traces fit :data:`EXACT_BUDGET_BYTES` they are kept for
        :meth:`solve` on the same spikes (computed once, not once per use)."""
        n = spikes.shape[0]
        self._prepared = None
        if n == 0:
            return
        self.penalty = self.config.weight_decay * PRIOR_WINDOWS / n
        keep = (
            self.config.solver == "exact" and 4 * n * self.linear.in_features <= EXACT_BUDGET_BYTES
        )
        kept = torch.empty(n, self.linear.in_features) if keep else None  # filled, not joined
        self.fit_standardisation(spikes, kept)
        if kept is not None:
            self._prepared = (spikes, kept)

    def scores(self, spikes: Tensor) -> Tensor:
        return self.linear(self.features(spikes))

    def _training_features(
        self, spikes: Tensor, idx: np.ndarray | None, cols: Tensor | None = None
    ) -> Tensor:
        """Standardised float32 features ``[len(idx), len(cols)]`` of ``spikes[idx]`` (all rows:
        ``idx`` None; all columns: ``cols`` None), from :meth:`prepare`'s traces when it kept
        those of these spikes (then released: they are used once)."""
        kept, self._prepared = self._prepared, None
        if kept is not None and kept[0] is spikes:
            f = kept[1] if idx is None else kept[1][torch.from_numpy(idx)]
            f = f.sub_(self.feat_mean).div_(self.feat_scale)
            return f if cols is None else f[:, cols]
        sub = spikes if idx is None else spikes[torch.from_numpy(idx)]
        step = self.batch_size(sub)
        width = self.linear.in_features if cols is None else len(cols)
        out = torch.empty(len(sub), width, dtype=torch.float32)  # filled: no second copy
        for i in range(0, len(sub), step):
            f = self.features(sub[i : i + step])
            out[i : i + step] = f if cols is None else f[:, cols]
        return out

    def _exact(self, held: list[Tensor], spikes: Tensor, rows: np.ndarray | None,
               cols: Tensor | None, y: Tensor, lam: float,
               confidence: Tensor | None = None) -> tuple[Tensor, Tensor, int, Tensor]:  # fmt: skip
        """The exact fit on the features ``held.pop()`` (of ``spikes[rows]``, columns ``cols``;
        handed over in a list so that this frame holds their last reference):
        ``(W [d, classes] float64, b, function evaluations, training logits)``. With more
        features than windows the fit runs in their row space (:func:`row_space`), and the
        features are let go during it: the weights are then summed from blocks of them computed
        again (``W = F^T a``), so only one ``N x d`` matrix is ever held."""
        part = held.pop()
        g, lk = row_space(part)
        if lk is None:
            w, b, evals = fit_features(part, y, self.n_classes, lam, confidence=confidence)
            return w, b, evals, part @ w.float() + b.float()
        del part  # the features freed: the row space is all the fit needs
        z, b, evals = fit_softmax(g, y, self.n_classes, lam, confidence=confidence)
        logits = (g @ z.to(g.dtype)).double() + b  # F W = L_K L_K^T L_K^-T z = G z
        a = torch.linalg.solve_triangular(g.T.double(), z, upper=True)  # [N, classes]
        del g, lk
        n = len(y)
        width = self.linear.in_features if cols is None else len(cols)
        w = torch.zeros(width, self.n_classes, dtype=torch.float64)
        step = max(1, (64 << 20) // (4 * width))  # 64 MiB of features at a time
        idx = np.arange(len(spikes)) if rows is None else rows
        for i in range(0, n, step):
            f = self._training_features(spikes, idx[i : i + step], cols)
            w.addmm_(f.T.double(), a[i : i + step])
        return w, b, evals, logits

    @torch.no_grad()
    def solve(self, spikes: Tensor, y: Tensor, groups: np.ndarray | None = None,
              confidence: Tensor | None = None) -> dict | None:  # fmt: skip
        """The exact solver (``solver = "exact"``; None otherwise): after :meth:`prepare`, the
        penalised cross-entropy minimised to its optimum (:func:`~.softmax_fit.fit_features`),
        with ``choose`` the penalty and the read-out instants used (the others get zero weight)
        chosen by cross-validation over ``groups`` (recording ids ``[N]``; each window its own
        without) on at most ``CV_WINDOWS`` windows; ``confidence`` ``[N]``: soft targets
        (:func:`~.softmax_fit.soft_targets`) in the fit and the cross-validation. Returns what
        was chosen, with the cross-validated accuracy of every candidate and the training error
        of the fit.

        Bounded: the cross-validation featurises at most :data:`EXACT_BUDGET_BYTES` of float32
        (whole recordings), the final fit every window's features of the chosen instants where
        they fit it; where even those do not, the weights are trained by the trainer's epochs
        with the chosen penalty and instants (``"train_epochs": True`` in the report)."""
        cfg = self.config
        n, d = spikes.shape[0], self.linear.in_features
        if cfg.solver != "exact" or n == 0 or (4 * n * d > EXACT_BUDGET_BYTES and not cfg.choose):
            self._prepared = None
            return None
        t0 = time.perf_counter()
        groups = np.arange(n) if groups is None else np.asarray(groups)
        cols = torch.arange(d).view(-1, cfg.n_times)  # [afferents, instants]
        whole = 4 * n * d <= EXACT_BUDGET_BYTES
        feats = self._training_features(spikes, None) if whole else None
        if self.refit_capacity is None:
            subset, lam, table, cv = self._cross_validate(spikes, y, groups, confidence, feats,
                                                          cols)  # fmt: skip
        else:  # a refit at a capacity chosen before (training.unseen_condition_accuracy)
            subset, factor = self.refit_capacity
            lam, table, cv = factor * self.penalty, [], np.arange(0)
        #: the instants and the penalty as a factor of the prior, for a refit on other windows
        self.chosen_capacity = (list(subset), float(lam / self.penalty) if self.penalty else 1.0)
        used = cols[:, subset].reshape(-1)
        weight = torch.zeros(self.n_classes, d, dtype=torch.float64)
        report = {"penalty": lam, "instants": len(subset),
                  "instants_ms": [float(self.times_ms[j]) for j in subset],
                  "cross_validation": table, "cv_windows": len(cv)}  # fmt: skip
        fit_n = min(n, EXACT_BUDGET_BYTES // (4 * len(used)))
        if fit_n >= EXACT_MIN_SHARE * n:
            every = len(subset) == cfg.n_times
            # over the budget by a little: the exact fit on the most whole recordings it allows
            rows = None if fit_n == n else whole_groups(groups, fit_n, y.numpy())
            if feats is not None:
                part = feats if every else feats[:, used]
            else:
                part = self._training_features(spikes, rows, None if every else used)
            del feats
            fit_y = y if rows is None else y[torch.from_numpy(rows)]
            fit_c = confidence if rows is None or confidence is None else confidence[
                torch.from_numpy(rows)]  # fmt: skip
            cols_used = None if every else used
            held = [part]  # handed over: _exact holds the features' last reference
            del part
            w, b, evals, logits = self._exact(held, spikes, rows, cols_used, fit_y, lam, fit_c)
            weight[:, used] = w.T
            self.linear.bias.copy_(b.float())
            report.update(solver="exact (L-BFGS, float32 data)", function_evaluations=evals,
                          train_error=float((logits.argmax(1) != fit_y).float().mean()))  # fmt: skip
            if rows is not None:
                report.update(fit_windows=len(rows), solver="exact (L-BFGS, float32 data) on "
                              f"{len(rows)} of {n} windows (whole recordings; the byte budget)")  # fmt: skip
        else:  # the trainer's epochs, on the chosen instants only (see loss())
            weight[:, used] = self.linear.weight.double()[:, used]
            self.instant_mask.zero_()
            self.instant_mask[used] = 1.0
            report.update(solver="adam (features over the exact fit's budget)", train_epochs=True)
        self.linear.weight.copy_(weight.float())
        report["seconds"] = time.perf_counter() - t0
        log.info("readout: %s, penalty %.3g (%.3g x the prior), %d read-out instant(s)%s "
                 "(%.1f s)", report["solver"], lam, lam / self.penalty if self.penalty else 1.0,
                 len(subset),
                 " refitted at the capacity chosen before" if self.refit_capacity is not None
                 else " chosen by cross-validation over recordings" if cfg.choose else "",
                 report["seconds"])  # fmt: skip
        self.penalty = lam
        return report

    def _cross_validate(self, spikes: Tensor, y: Tensor, groups: np.ndarray,
                        confidence: Tensor | None, feats: Tensor | None,
                        cols: Tensor) -> tuple[list[int], float, list[dict], np.ndarray]:  # fmt: skip
        """:meth:`solve`'s choice of read-out instants and penalty by cross-validation over
        ``groups`` on at most ``CV_WINDOWS`` windows (``feats``: every window's features, or
        None where they are over the budget: then only the cross-validation's are made).
        Returns ``(instants, penalty, the table of every candidate, the windows used)``."""
        cfg = self.config
        n, d = spikes.shape[0], self.linear.in_features
        subsets = instant_subsets(cfg.n_times) if cfg.choose else [list(range(cfg.n_times))]
        factors = PENALTY_FACTORS if cfg.choose else (1.0,)
        best: tuple = ()
        table = []
        cv = whole_groups(groups, min(CV_WINDOWS, EXACT_BUDGET_BYTES // (4 * d)), y.numpy())
        if feats is None:  # over the budget: only the cross-validation's windows featurised
            cv_feats = self._training_features(spikes, cv)
        else:
            cv_feats = feats if len(cv) == n else feats[torch.from_numpy(cv)]
        for subset in subsets:
            part = (
                cv_feats if len(subset) == cfg.n_times else cv_feats[:, cols[:, subset].reshape(-1)]
            )
            lam, rows = choose_penalty(part, y[torch.from_numpy(cv)], groups[cv], self.n_classes,
                                       [self.penalty * f for f in factors],
                                       confidence=None if confidence is None else
                                       confidence[torch.from_numpy(cv)])  # fmt: skip
            del part
            acc = max((r["cv_accuracy"] for r in rows), default=0.0)
            table += [{"instants": len(subset), **r} for r in rows]
            if not best or acc > best[0]:  # ties: the candidate tried first (more instants)
                best = (acc, subset, lam)
        del cv_feats
        release_memory()  # the cross-validation's features handed back before the final fit
        _, subset, lam = best
        return subset, lam, table, cv

    def bytes_per_sample(self, afferents: int, k: int) -> int:
        return 4 * 4 * afferents * k * self.config.n_times

    def loss(self, spikes: Tensor, y: Tensor, confidence: Tensor | None = None) -> Tensor:
        # instants left out by solve() have zero weight and, masked here, zero gradient: Adam
        # keeps them at exactly zero, so the unmasked scores() equal the masked ones
        w = self.linear.weight * self.instant_mask
        target = y if confidence is None else soft_targets(y, self.n_classes, confidence).float()
        ce = nn.functional.cross_entropy(nn.functional.linear(self.features(spikes), w,
                                                              self.linear.bias), target)  # fmt: skip
        return ce + self.penalty * w.pow(2).sum()

    def finetune_parameters(self) -> list[nn.Parameter]:
        return [self.linear.weight, self.linear.bias]

    def finetune_penalty(self, n: int) -> float:
        # the same prior as training's (weight_decay at PRIOR_WINDOWS windows), centred on the
        # pretrained weights
        return self.config.weight_decay * PRIOR_WINDOWS / max(n, 1)

    def finetune_loss(self, spikes: Tensor, y: Tensor, confidence: Tensor | None = None) -> Tensor:
        w = self.linear.weight * self.instant_mask
        target = y if confidence is None else soft_targets(y, self.n_classes, confidence).float()
        return nn.functional.cross_entropy(nn.functional.linear(self.features(spikes), w,
                                                                self.linear.bias), target)  # fmt: skip

    def learning_rate(self) -> float:
        return self.config.lr

    def onnx_module(self) -> nn.Module:
        return self
