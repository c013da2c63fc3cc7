"""Exact fits of an L2-penalised softmax (multinomial logistic) regression, and the choice of
its penalty by cross-validation over recordings.

The readout's loss ``mean CE(F W^T + b, y) + lam ||W||^2`` is convex in ``(W, b)``: it has one
minimum, which full-batch L-BFGS reaches (the same problem scikit-learn's
``LogisticRegression(C=1 / (2 lam N))`` solves; tested against it).

**Preconditioning by one Cholesky factor.** The loss's curvature is bounded by
``M = G^T G / 4N + 2 lam I`` (the softmax's Hessian is at most a quarter per class), so L-BFGS
runs in ``U = L^T W`` with ``M = L L^T``: tens to hundreds of steps where raw coordinates (singular
values spread over decades) need thousands. One Cholesky of the ``r x r`` matrix replaces the
eigendecomposition used before (FabricSlide, 5,840 trace features: ``eigh`` 50-100 s, Cholesky
1.5-2.3 s, on 2 cores), with the same iterates: in an orthogonal basis ``M`` is diagonal and the
old diagonal scaling was exactly this preconditioner.

**Fewer features than windows or more.** With ``d <= N`` the features ``F [N, d]`` are fitted as
they are (``G = F``). With ``d > N`` the optimum lies in the row space of ``F`` (the representer
argument): with ``K = F F^T = L_K L_K^T``, ``V = F^T L_K^{-T}`` is an orthonormal basis of it and
``F V = L_K``, so the problem is one of ``N`` features ``G = L_K`` with ``W = V Z`` and ``|W| =
|Z|`` (:func:`row_space`). A tiny ridge on ``K`` (``RIDGE`` of its mean diagonal) keeps the
factorisation defined where ``F`` is rank-deficient; it moves ``|W|`` by the same fraction in the
directions the data hardly spans.

**Precision.** The data matmuls (``N x r x classes``, nearly all the work) are float32; the
parameters, the loss, the line search and the factor are float64. On FabricSlide's 6,548 windows
x 5,840 features the float32 fit's weights are within 1e-3 (relative) of the float64 one's and
its test predictions agree (see ``tests/models/test_softmax_fit.py`` for the same check against
scikit-learn's float64 optimum).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

#: the penalties tried, as multiples of the configured one (a decade and a half either way of it)
PENALTY_FACTORS = (1 / 3, 1.0, 3.0, 10.0, 30.0)
#: folds of the cross-validation (by recording: a recording's windows never straddle folds)
FOLDS = 3
#: windows the cross-validation uses at most (whole recordings, evenly spaced)
CV_WINDOWS = 2000
#: the ridge added to ``F F^T`` (times its mean diagonal) before its Cholesky factorisation
RIDGE = 1e-7
#: largest gradient entry at which the final fit stops (the loss is a mean, O(1)): FabricSlide
#: (6,548 windows x 5,840 features) 921 function evaluations at 1e-6, 337 at 1e-5, 65 at 1e-4;
#: test accuracy 99.73 / 99.73 / 99.68 %
TOL = 1e-5
#: the cross-validation's fits rank penalties, and stop at this gradient: FabricSlide's 2,000
#: cross-validation windows (LIF + readout, seed 0) 41 s at 1e-5, 5 s at 1e-4, the same penalty
#: and instants chosen (every candidate's accuracy within 0.8 points)
CV_TOL = 1e-4


def row_space(features: Tensor) -> tuple[Tensor, Tensor | None]:
    """``F [N, d]`` -> ``(G, L_K)``: ``(F, None)`` when ``d <= N`` (fitted as it is), else
    ``G = L_K`` ``[N, N]`` in ``F``'s dtype, the Cholesky factor of ``F F^T`` (+ :data:`RIDGE`),
    with which :func:`from_row_space` maps a solution back to ``d`` features. ``F F^T`` is
    summed in float64 over blocks of columns (no float64 copy of ``F``) and factored in place:
    one ``N x N`` float64 matrix at a time, the factor then kept in ``F``'s dtype."""
    n, d = features.shape
    if d <= n:
        return features, None
    ridge = RIDGE
    while True:
        k = _row_gram(features)
        k.diagonal().add_(ridge * float(k.diagonal().mean()) + 1e-20)  # (1e-20: a float32 root)
        _, info = torch.linalg.cholesky_ex(k, out=(k, torch.empty((), dtype=torch.int32)))
        if int(info) == 0 or ridge >= 1e-2:  # rounding made it indefinite: a larger ridge
            break
        ridge *= 10
    lk = k.tril_().to(features.dtype)
    del k
    return lk, lk


def _row_gram(features: Tensor) -> Tensor:
    """``F F^T`` ``[N, N]`` float64, summed over blocks of 16 MiB of float64 columns."""
    n, d = features.shape
    k = torch.zeros(n, n, dtype=torch.float64)
    step = max(1, (16 << 20) // (8 * n))  # 16 MiB of float64 columns at a time
    for j in range(0, d, step):
        block = features[:, j : j + step].double()
        k.addmm_(block, block.T)
    return k


def from_row_space(features: Tensor, lk: Tensor | None, z: Tensor) -> Tensor:
    """Weights ``[d, classes]`` of the features from a solution ``z`` on :func:`row_space`'s
    ``G``: ``W = F^T L_K^{-T} z`` (``z`` itself when the features were fitted as they are)."""
    if lk is None:
        return z
    a = torch.linalg.solve_triangular(lk.T.double(), z, upper=True)
    return (features.T @ a.to(features.dtype)).double()


def gram(g: Tensor) -> Tensor:
    """``G^T G`` in float64 (from float32 products where ``G`` is float32: a sum of N terms,
    accurate to ~1e-6 relative, which is all a preconditioner needs)."""
    out = g.T @ g
    return out.double()


def curvature_factor(gg: Tensor, n: int, penalty: float, inplace: bool = False) -> Tensor:
    """The Cholesky factor ``L`` of ``G^T G / 4N + 2 penalty I`` (+ a floor for a zero column
    with no penalty); ``inplace``: in ``gg``'s memory (which it then holds)."""
    m = gg.div_(4.0 * n) if inplace else gg.div(4.0 * n)
    m.diagonal().add_(
        2.0 * penalty + 1e-12 * (1.0 + (float(m.diagonal().max()) if m.numel() else 0.0))
    )
    if not inplace:
        return torch.linalg.cholesky(m)
    torch.linalg.cholesky(m, out=m)
    return m.tril_()


def fit_softmax(
    g: Tensor,
    y: Tensor,
    n_classes: int,
    penalty: float,
    init: tuple[Tensor, Tensor] | None = None,
    tol: float = TOL,
    max_iter: int = 1000,
    gg: Tensor | None = None,
    confidence: Tensor | None = None,
) -> tuple[Tensor, Tensor, int]:
    """Minimise ``mean CE(g Z + b, y) + penalty ||Z||^2`` (``b`` unpenalised) with full-batch
    L-BFGS (strong Wolfe line search), preconditioned by :func:`curvature_factor`, from ``init``
    (warm start, ``(Z, b)``) or zeros.

    ``g [N, r]`` (float32 for speed or float64), ``y [N]`` int64 in ``[0, n_classes)``; ``gg``:
    ``g``'s :func:`gram` when the caller has it (the cross-validation reuses one per fold);
    ``confidence``: each window's :func:`soft_targets` weight ``[N]`` (None: hard labels).
    Returns ``(Z [r, classes] float64, b [classes] float64, function evaluations)``; stops when
    the largest gradient entry is below ``tol`` (or after ``max_iter`` iterations)."""
    n, r = g.shape
    dt = g.dtype
    lf = curvature_factor(gram(g), n, penalty, inplace=True) if gg is None else (
        curvature_factor(gg, n, penalty))  # fmt: skip
    onehot = soft_targets(y, n_classes, confidence)
    u = torch.zeros(r, n_classes, dtype=torch.float64)
    b = torch.zeros(n_classes, dtype=torch.float64)
    if init is not None:
        u, b = (lf.T @ init[0].double()).contiguous(), init[1].double().clone()
    u.requires_grad_(True)
    b.requires_grad_(True)
    opt = torch.optim.LBFGS([u, b], lr=1.0, max_iter=max_iter, history_size=20,
                            tolerance_grad=tol, tolerance_change=1e-12,
                            line_search_fn="strong_wolfe")  # fmt: skip
    evals = 0

    @torch.no_grad()
    def closure() -> Tensor:
        # the gradient by hand: two matmuls and two triangular solves, no autograd graph
        nonlocal evals
        evals += 1
        w = torch.linalg.solve_triangular(lf.T, u, upper=True)
        logits = (g @ w.to(dt)).double() + b
        lse = torch.logsumexp(logits, 1, keepdim=True)
        p = torch.exp(logits - lse)
        loss = (lse.squeeze(1) - (logits * onehot).sum(1)).mean() + penalty * (w * w).sum()
        d = (p - onehot) / n
        gw = (g.T @ d.to(dt)).double() + 2.0 * penalty * w
        u.grad = torch.linalg.solve_triangular(lf, gw, upper=False).contiguous()
        b.grad = d.sum(0)
        return loss

    opt.step(closure)
    with torch.no_grad():
        z = torch.linalg.solve_triangular(lf.T, u.detach(), upper=True)
    return z, b.detach(), evals


def soft_targets(y: Tensor, n_classes: int, confidence: Tensor | None = None) -> Tensor:
    """Targets ``[N, classes]`` float64: one-hot ``y``, or with ``confidence`` ``c [N]`` in
    ``[0, 1]`` the mixture ``c * one-hot + (1 - c) / classes``: a window that holds none of its
    class's signal (``c = 0``; a synthetic slide's windows before its letter) is trained to say
    nothing rather than taught a cue its class does not own."""
    q = torch.zeros(len(y), n_classes, dtype=torch.float64)
    q[torch.arange(len(y)), y] = 1.0
    if confidence is None:
        return q
    c = torch.as_tensor(confidence, dtype=torch.float64).reshape(-1, 1)
    if c.shape[0] != len(y) or not bool(((c >= 0) & (c <= 1)).all()):
        raise ValueError(f"confidence must be [N={len(y)}] in [0, 1]")
    return c * q + (1.0 - c) / n_classes


def group_folds(
    groups: np.ndarray, folds: int = FOLDS, y: np.ndarray | None = None
) -> list[np.ndarray]:
    """Boolean held-out masks of ``folds`` folds, whole groups each, balanced by window count
    (largest groups first onto the lightest fold; deterministic). With the windows' labels
    ``y``, stratified too: each group goes to the fold holding the fewest windows of its class
    (then the fewest windows), so recordings stored in a cycle of the classes (a synthetic
    dataset: class ``i % classes``) do not put each class in a fold of its own, where every
    held-out window is one the fold never trained on. Fewer folds when there are fewer groups;
    none below two."""
    groups = np.asarray(groups)
    ids, first, counts = np.unique(groups, return_index=True, return_counts=True)
    k = min(folds, ids.size)
    if k < 2:
        return []
    cls = np.zeros(ids.size, np.int64) if y is None else np.unique(
        np.asarray(y)[first], return_inverse=True)[1]  # fmt: skip
    load = np.zeros((cls.max() + 1, k))
    fold_of = np.empty(ids.size, dtype=np.int64)
    for i in np.argsort(-counts, kind="stable"):
        total = load.sum(0)
        fold_of[i] = int(np.lexsort((total, load[cls[i]]))[0])
        load[cls[i], fold_of[i]] += counts[i]
    where = fold_of[np.searchsorted(ids, groups)]
    return [where == f for f in range(k)]


def choose_penalty(
    features: Tensor,
    y: Tensor,
    groups: np.ndarray,
    n_classes: int,
    penalties: list[float],
    max_windows: int = CV_WINDOWS,
    confidence: Tensor | None = None,
) -> tuple[float, list[dict]]:
    """The penalty with the highest cross-validated accuracy over recordings (ties: the lower
    held-out cross-entropy, then the larger penalty), on at most ``max_windows`` windows (whole
    recordings, evenly spaced). Each fold's features are put in their row space once
    (:func:`row_space`) and fitted from the largest penalty down, each fit warm-started from the
    last (the well-conditioned end first), to a gradient of :data:`CV_TOL` (a ranking, not
    the final weights). Returns ``(penalty, [{"penalty", "cv_accuracy", "cv_log_loss"} per penalty])``;
    with one penalty (nothing to choose) or fewer than two recordings, the middle penalty and an
    empty table. With ``confidence`` (:func:`soft_targets`) the fits take the soft targets and
    a held-out window's accuracy is its target's share on the class predicted (a window with
    none of its class's signal counts 1 / classes whatever the prediction)."""
    if len(penalties) == 1:
        return float(penalties[0]), []
    keep = whole_groups(np.asarray(groups), max_windows, y.numpy())
    if keep.size < len(y):
        at = torch.from_numpy(keep)
        features, y, groups = features[at], y[at], np.asarray(groups)[keep]
        confidence = None if confidence is None else torch.as_tensor(confidence)[at]
    q = None if confidence is None else soft_targets(y, n_classes, confidence)
    masks = group_folds(groups, y=y.numpy())
    if not masks:
        return penalties[len(penalties) // 2], []
    order = sorted(range(len(penalties)), key=lambda i: -penalties[i])
    acc = np.zeros(len(penalties))
    ce = np.zeros(len(penalties))
    for held in masks:
        fit, out = torch.from_numpy(~held), torch.from_numpy(held)
        f_fit = features[fit]
        g, lk = row_space(f_fit)
        gg = gram(g)
        warm = None
        for i in order:
            z, b, _ = fit_softmax(g, y[fit], n_classes, penalties[i], warm, tol=CV_TOL,
                                  max_iter=300, gg=gg,
                                  confidence=None if confidence is None else confidence[fit])  # fmt: skip
            warm = (z, b)
            w = from_row_space(f_fit, lk, z)
            logits = (features[out] @ w.to(features.dtype)).double() + b
            if confidence is None:
                acc[i] += float((logits.argmax(1) == y[out]).double().sum())
                ce[i] += float(torch.nn.functional.cross_entropy(logits, y[out], reduction="sum"))
            else:
                acc[i] += float(q[out].gather(1, logits.argmax(1, keepdim=True)).sum())
                ce[i] += float(-(q[out] * torch.log_softmax(logits, 1)).sum())
    n = float(len(y))
    table = [{"penalty": float(lam), "cv_accuracy": acc[i] / n, "cv_log_loss": ce[i] / n}
             for i, lam in enumerate(penalties)]  # fmt: skip
    # highest accuracy; then lowest cross-entropy; then the largest penalty (the simplest model)
    best = max(range(len(penalties)), key=lambda i: (round(acc[i]), -ce[i], penalties[i]))
    return float(penalties[best]), table


def fit_features(
    features: Tensor,
    y: Tensor,
    n_classes: int,
    penalty: float,
    tol: float = TOL,
    confidence: Tensor | None = None,
) -> tuple[Tensor, Tensor, int]:
    """The exact fit on features ``[N, d]`` (float32 or float64): ``(W [d, classes] float64,
    b [classes], function evaluations)`` through :func:`row_space` and :func:`fit_softmax`
    (``confidence``: soft targets, :func:`soft_targets`)."""
    g, lk = row_space(features)
    z, b, evals = fit_softmax(g, y, n_classes, penalty, tol=tol, confidence=confidence)
    del g
    return from_row_space(features, lk, z), b, evals


def whole_groups(groups: np.ndarray, max_windows: int, y: np.ndarray | None = None) -> np.ndarray:
    """Indices of whole groups, evenly spaced over the groups (with the windows' labels ``y``:
    over each class's groups, so a file stored in a cycle of the classes does not give one
    class), totalling at most ``max_windows`` windows (all when they fit; at least one group)."""
    if groups.size <= max_windows:
        return np.arange(groups.size)
    ids, first, inv, counts = np.unique(groups, return_index=True, return_inverse=True,
                                        return_counts=True)  # fmt: skip
    share = max_windows / groups.size
    cls = np.zeros(ids.size, np.int64) if y is None else np.asarray(y)[first]
    key = np.empty(ids.size)
    for c in np.unique(cls):
        members = np.flatnonzero(cls == c)
        key[members] = (np.arange(members.size) * share) % 1.0
    picked = np.zeros(ids.size, dtype=bool)
    total = 0
    for j in np.argsort(key, kind="stable"):
        if total + counts[j] <= max_windows:
            picked[j] = True
            total += counts[j]
    if not picked.any():
        picked[0] = True
    return np.flatnonzero(picked[inv])
