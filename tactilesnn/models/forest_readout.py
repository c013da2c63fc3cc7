"""Random-forest read-out of leaky-integrator traces: ``forest``.

The features are the ``readout`` model's (:mod:`.li_readout`): each afferent's leaky-integrator
membrane read at ``n_times`` instants, ``log1p``, standardised by their mean and standard
deviation over the training windows (buffers: saved, exported, re-estimated by :meth:`adapt`).
The class probabilities are a random forest's on them (scikit-learn's
``RandomForestClassifier``, fitted in one go by :meth:`ForestReadout.solve`; soft targets as
weighted rows), its trees kept as tensors (each node's feature, threshold and children, each
leaf's class distribution) and walked in torch: as many steps of gathers from the root as the
deepest leaf is deep, leaves pointing at themselves, so the exported graph is the same
arithmetic with no tree operator. Scores: ``ln(p + PROB_FLOOR)`` of the mean leaf distribution over trees.

Why a forest: it does not extrapolate. A linear read-out trained on one domain (synthetic
slides of a calibrated sensor model) and read on another (the real sensor) carries every
feature's excess past the training range into the scores; a tree reads a threshold and stops
there. iCub Braille, the calibrated model's synthetic slides alone, scored on the real slides
(``bench sim2real --model forest``; docs/sim2real.md has the measured table).

Fine-tuning (:meth:`finetune`) re-estimates the leaves' class distributions, not the splits:
each leaf's distribution is a posterior mean with the pretrained distribution as a Dirichlet
prior worth ``prior`` windows, updated with the new windows (soft targets) that land in it;
``prior`` is chosen by leave-one-recording-out cross-validation (held-out cross-entropy).
"""

from __future__ import annotations

import logging
import time

import numpy as np
import torch
from torch import Tensor, nn

from ..schema.models import ForestConfig
from .base import register_model
from .li_readout import TraceFeatures
from .softmax_fit import soft_targets

log = logging.getLogger("tactilesnn")

#: the probability floor of the scores' logarithm (a leaf distribution may hold exact zeros)
PROB_FLOOR = 1e-3
#: the float32 feature matrix the fit may take; over it, the fit takes a random share of the
#: windows that fits (reported)
FIT_BUDGET_BYTES = 256 << 20
#: the fine-tune's candidate prior strengths (pretrained windows per leaf)
PRIOR_WINDOWS = (0.3, 1.0, 3.0, 10.0, 30.0)
#: the prior's strength without recordings to choose it on
DEFAULT_PRIOR_WINDOWS = 3.0


@register_model("forest", ForestConfig)
class ForestReadout(TraceFeatures):
    """Leaky-integrator traces -> a random forest's class log-probabilities; see the module
    docstring."""

    score_units = f"ln(class probability + {PROB_FLOOR:g}) of a random forest"
    trains_on_confidence = True

    def __init__(self, config: ForestConfig, n_afferents: int, max_spikes: int, n_classes: int,
                 duration_ms: float, seed: int = 0) -> None:  # fmt: skip
        super().__init__(config, n_afferents, max_spikes, n_classes, duration_ms, seed)
        self.seed = int(seed)
        self._init_trace_features(config, n_afferents, duration_ms)
        t, m = config.trees, 2 * config.leaves - 1
        # an unfitted forest: every tree a single leaf of the uniform distribution
        self.register_buffer("node_feature", torch.zeros(t, m, dtype=torch.int64))
        self.register_buffer("node_threshold", torch.zeros(t, m))
        self.register_buffer("node_left", torch.zeros(t, m, dtype=torch.int64))
        self.register_buffer("node_right", torch.zeros(t, m, dtype=torch.int64))
        # the leaves' class distributions: what fine-tuning re-estimates (no gradient)
        self.leaf_value = nn.Parameter(torch.full((t, m, n_classes), 1.0 / n_classes),
                                       requires_grad=False)  # fmt: skip
        # the walk's steps: the deepest leaf's depth (set from the node tensors whenever they
        # change; a Python int, so the exported graph unrolls exactly that many)
        self.walk_steps = 0

    def _set_walk_steps(self) -> None:
        """:attr:`walk_steps` from the node tensors: the depth of the deepest leaf."""
        left, right = self.node_left.numpy(), self.node_right.numpy()
        t, m = left.shape
        inner = left != np.arange(m)  # [T, M]: split nodes (a leaf points at itself)
        level = np.zeros((t, m), bool)
        level[:, 0] = True  # the roots
        steps, rows = 0, np.arange(t)[:, None].repeat(m, 1)
        while (level & inner).any():  # one level down: the split nodes' children
            split = level & inner
            level = np.zeros((t, m), bool)
            level[rows[split], left[split]] = True
            level[rows[split], right[split]] = True
            steps += 1
        self.walk_steps = steps

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        out = super().load_state_dict(state_dict, strict=strict, assign=assign)
        self._set_walk_steps()
        return out

    @classmethod
    def solves_in_one_go(cls, config: object) -> bool:
        return isinstance(config, ForestConfig)

    def bytes_per_sample(self, afferents: int, k: int) -> int:
        return 4 * 4 * afferents * k * self.config.n_times + 24 * self.config.trees

    @torch.no_grad()
    def prepare(self, spikes: Tensor) -> None:
        """The trace features' mean and standard deviation over the training spikes (constant
        features keep scale 1)."""
        if spikes.shape[0]:
            self.fit_standardisation(spikes)

    def _features_of(self, spikes: Tensor) -> Tensor:
        batch = self.batch_size(spikes)
        with torch.no_grad():
            return torch.cat([self.features(spikes[i : i + batch])
                              for i in range(0, spikes.shape[0], batch)])  # fmt: skip

    # ------------------------------------------------------------------ the trees
    def leaves_of(self, feats: Tensor) -> Tensor:
        """Standardised features ``[B, d]`` -> the leaf each tree sends each window to
        ``[B, trees]`` (int64): :attr:`walk_steps` steps from the root, the deepest leaf's depth
        (a leaf points at itself, so a shallower one is kept)."""
        b, t = feats.shape[0], self.node_feature.shape[0]
        node = torch.zeros(t, b, dtype=torch.int64)
        for _ in range(self.walk_steps):
            f = torch.gather(self.node_feature, 1, node)  # [T, B]
            x = torch.gather(feats, 1, f.t()).t()
            thr = torch.gather(self.node_threshold, 1, node)
            node = torch.where(x <= thr, torch.gather(self.node_left, 1, node),
                               torch.gather(self.node_right, 1, node))  # fmt: skip
        return node.t()

    def mean_leaf(self, leaf: Tensor, values: Tensor | None = None) -> Tensor:
        """Leaves ``[B, trees]`` -> the mean of their class distributions ``[B, classes]``
        (``values`` ``[trees, nodes, classes]``; default: the model's)."""
        values = self.leaf_value if values is None else values
        t, m, c = values.shape
        flat = leaf + torch.arange(t, dtype=torch.int64).view(1, -1) * m
        return values.reshape(t * m, c)[flat.reshape(-1)].reshape(leaf.shape[0], t, c).mean(1)

    def probabilities(self, spikes: Tensor) -> Tensor:
        """Class probabilities ``[B, classes]``: the mean of the trees' leaf distributions."""
        return self.mean_leaf(self.leaves_of(self.features(spikes)))

    def scores(self, spikes: Tensor) -> Tensor:
        return torch.log(self.probabilities(spikes) + PROB_FLOOR)

    @torch.no_grad()
    def solve(self, spikes: Tensor, y: Tensor, groups: np.ndarray | None = None,
              confidence: Tensor | None = None) -> dict:  # fmt: skip
        """The forest fitted on the standardised features (after :meth:`prepare`), each window
        once per class with its soft target's weight where ``confidence`` is given; over
        :data:`FIT_BUDGET_BYTES` of features, on a random share of the windows. Returns the
        fit's report."""
        from sklearn.ensemble import RandomForestClassifier

        cfg, t0 = self.config, time.perf_counter()
        n, d = int(spikes.shape[0]), int(self.feat_mean.numel())
        keep = min(n, max(1, FIT_BUDGET_BYTES // (4 * d)))
        rng = np.random.default_rng(self.seed)
        rows = np.arange(n) if keep == n else np.sort(rng.choice(n, keep, replace=False))
        feats = self._features_of(spikes[torch.from_numpy(rows)]).numpy()
        labels = y.numpy()[rows]
        if confidence is None:  # unit weights: scikit-learn's bootstrap draws differ without
            fx, fy, fw = feats, labels, np.ones(len(labels))
        else:
            q = soft_targets(torch.as_tensor(labels), self.n_classes,
                             torch.as_tensor(confidence.numpy()[rows], dtype=torch.float64))  # fmt: skip
            r, c = np.nonzero(q.numpy() > 0)
            fx, fy, fw = feats[r], c, q.numpy()[r, c]
        forest = RandomForestClassifier(n_estimators=cfg.trees, max_leaf_nodes=cfg.leaves,
                                        min_samples_leaf=cfg.min_leaf, random_state=self.seed,
                                        n_jobs=-1)  # fmt: skip
        forest.fit(fx, fy, sample_weight=fw)
        self._load_forest(forest)
        train_error = float((self.leaves_to_proba(feats).argmax(1) != labels).mean())
        report = {"solver": "random forest (scikit-learn)", "trees": cfg.trees,
                  "fit_windows": int(keep), "features": d, "train_error": train_error,
                  "max_depth": int(max(e.tree_.max_depth for e in forest.estimators_)),
                  "seconds": time.perf_counter() - t0}  # fmt: skip
        log.info("forest: %d trees of up to %d leaves on %d windows x %d features (%.1f s)",
                 cfg.trees, cfg.leaves, keep, d, report["seconds"])  # fmt: skip
        return report

    def leaves_to_proba(self, feats: np.ndarray) -> np.ndarray:
        """Class probabilities of standardised features given as an array (numpy in and out)."""
        with torch.no_grad():
            leaf = self.leaves_of(torch.from_numpy(np.asarray(feats, np.float32)))
            return self.mean_leaf(leaf).numpy()

    @torch.no_grad()
    def _load_forest(self, forest) -> None:
        """scikit-learn's trees into the node tensors. Thresholds rounded down to float32: for a
        float32 feature ``x <= float64 threshold`` exactly when ``x <=`` the largest float32 not
        above it, so the walk takes scikit-learn's branches."""
        t, m = self.node_feature.shape
        feature = np.zeros((t, m), np.int64)
        threshold = np.zeros((t, m), np.float32)
        left = np.tile(np.arange(m), (t, 1))
        right = left.copy()
        value = np.full((t, m, self.n_classes), 1.0 / self.n_classes, np.float32)
        for i, est in enumerate(forest.estimators_):
            tree = est.tree_
            c = tree.node_count
            inner = tree.children_left[:c] >= 0
            feature[i, :c] = np.where(inner, tree.feature[:c], 0)
            thr = tree.threshold[:c].astype(np.float32)
            thr = np.where(thr.astype(np.float64) > tree.threshold[:c],
                           np.nextafter(thr, np.float32(-np.inf)), thr)  # fmt: skip
            threshold[i, :c] = np.where(inner, thr, 0.0)
            idx = np.arange(c)
            left[i, :c] = np.where(inner, tree.children_left[:c], idx)
            right[i, :c] = np.where(inner, tree.children_right[:c], idx)
            v = np.zeros((c, self.n_classes))
            v[:, forest.classes_.astype(np.int64)] = tree.value[:c, 0, :]
            total = v.sum(1, keepdims=True)
            value[i, :c] = np.where(total > 0, v / np.where(total > 0, total, 1.0),
                                    1.0 / self.n_classes)  # fmt: skip
        self.node_feature.copy_(torch.from_numpy(feature))
        self.node_threshold.copy_(torch.from_numpy(threshold))
        self.node_left.copy_(torch.from_numpy(left))
        self.node_right.copy_(torch.from_numpy(right))
        self.leaf_value.copy_(torch.from_numpy(value))
        self._set_walk_steps()

    # ------------------------------------------------------------------ fine-tuning
    def finetune_parameters(self) -> list[nn.Parameter]:
        return [self.leaf_value]

    @torch.no_grad()
    def finetune(self, spikes: Tensor, y: Tensor, groups: np.ndarray | None = None,
                 factors: tuple[float, ...] = PRIOR_WINDOWS, max_iter: int = 0,
                 confidence: Tensor | None = None) -> dict:  # fmt: skip
        """The leaves' class distributions re-estimated on a few windows of a new domain (see
        the module docstring): spikes ``[N, A, k]``, labels ``y [N]``, ``confidence`` ``[N]``
        soft targets; the prior's strength (windows per leaf): the one of ``factors`` where it
        names one, else chosen among them by leave-one-recording-out cross-validation over
        ``groups`` where there are two recordings or more, else :data:`DEFAULT_PRIOR_WINDOWS`.
        ``max_iter`` is unused (the update is closed-form). Returns the prior, the
        cross-validation's table and the data term (cross-entropy) before and after."""
        n, conf = self.check_finetune_inputs(spikes, y, groups, confidence)
        q = soft_targets(y, self.n_classes, torch.ones(n, dtype=torch.float64) if conf is None
                         else conf.double()).double()  # fmt: skip
        leaf = self.leaves_of(self._features_of(spikes))  # [N, T]
        prior = self.leaf_value.double().clone()
        t, m, c = prior.shape

        def posterior(rows: np.ndarray, strength: float) -> Tensor:
            counts = torch.zeros(t * m, c, dtype=torch.float64)
            flat = (leaf[rows] + torch.arange(t).view(1, -1) * m).reshape(-1)
            counts.index_add_(0, flat, q[rows].repeat_interleave(t, 0))
            counts = counts.view(t, m, c)
            return (strength * prior + counts) / (strength + counts.sum(-1, keepdim=True))

        def cross_entropy(values: Tensor, rows: np.ndarray) -> float:
            p = self.mean_leaf(leaf[rows], values)
            return float(-(q[rows] * torch.log(p + PROB_FLOOR)).sum(1).mean())

        every = np.arange(n)
        before = cross_entropy(prior, every)
        table = []
        ids = np.unique(groups) if groups is not None else np.array([])
        if len(factors) == 1:
            strength = float(factors[0])
        elif ids.size >= 2:
            for s in factors:
                losses = [cross_entropy(posterior(np.flatnonzero(groups != g), s),
                                        np.flatnonzero(groups == g)) for g in ids]  # fmt: skip
                table.append({"prior_windows": s, "cv_loss": float(np.mean(losses))})
            strength = min(table, key=lambda r: (r["cv_loss"], -r["prior_windows"]))[
                "prior_windows"]  # fmt: skip
        else:
            strength = DEFAULT_PRIOR_WINDOWS
        values = posterior(every, strength)
        self.leaf_value.copy_(values.float())
        return {"windows": n, "prior_windows": strength, "cross_validation": table,
                "loss_before": before, "loss_after": cross_entropy(values, every)}  # fmt: skip

    def learning_rate(self) -> float:
        # the trainer builds its optimiser before solve(); the forest takes no gradient step
        return 1e-3

    def loss(self, spikes: Tensor, y: Tensor, confidence: Tensor | None = None) -> Tensor:
        raise NotImplementedError("the forest fits in one go (solve), not by gradient")

    def onnx_module(self) -> nn.Module:
        return self
