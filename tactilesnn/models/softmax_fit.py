"""Exact fits of an L2-penalised softmax (multinomial logistic) regression, and the choice of
its penalty by cross-validation over recordings.

The readout's loss ``mean CE(F W^T + b, y) + lam ||W||^2`` is convex in ``(W, b)``: it has one
minimum, which full-batch L-BFGS reaches (the same problem scikit-learn's
``LogisticRegression(C=1 / (2 lam N))`` solves; tested against it). By the representer argument
the penalised optimum lies in the row space of the features, so ``F = U S V^T`` (thin SVD) turns
a ``d``-feature problem into one of ``rank <= min(N, d)`` orthogonal features ``G = U S`` with
``W = Z^T V^T``: the same optimum, synthetic material's 9,296 trace features for 720 windows
cost as 720 (the decomposition once, every fit and fold after it), and orthogonal columns make
the coordinate scaling of :func:`fit_softmax` a good preconditioner. Fits are float64.
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


def orthogonal_basis(features: Tensor, rtol: float = 1e-6) -> tuple[Tensor, Tensor]:
    """``F [N, d]`` -> ``(G [N, r], V [d, r])`` with ``F = G V^T``, ``V`` orthonormal, the
    columns of ``G`` orthogonal (``G = U S`` of the thin SVD) and ``r`` the numerical rank
    (singular values above ``rtol`` times the largest). From the smaller Gram matrix:
    ``F^T F`` (``d <= N``) or ``F F^T``."""
    f = features.double()
    n, d = f.shape
    gram = f.T @ f if d <= n else f @ f.T
    s2, vec = torch.linalg.eigh(gram)  # ascending
    s2, vec = s2.flip(0).clamp_min(0.0), vec.flip(1)
    s = s2.sqrt()
    r = max(1, int((s > rtol * s[0]).sum())) if s[0] > 0 else 1
    s, vec = s[:r], vec[:, :r]
    if d <= n:
        return f @ vec, vec
    return vec * s, (f.T @ vec) / s.clamp_min(1e-300)  # all-zero features: V = 0, weights 0


def fit_softmax(
    g: Tensor,
    y: Tensor,
    n_classes: int,
    penalty: float,
    init: tuple[Tensor, Tensor] | None = None,
    tol: float = 1e-6,
    max_iter: int = 1000,
) -> tuple[Tensor, Tensor, int]:
    """Minimise ``mean CE(g Z + b, y) + penalty ||Z||^2`` (``b`` unpenalised) with full-batch
    L-BFGS (strong Wolfe line search) from ``init`` (warm start) or zeros.

    ``g [N, r]`` float64 (fastest with orthogonal columns, :func:`orthogonal_basis`), ``y [N]``
    int64 in ``[0, n_classes)``. The coordinates are scaled by ``1 / sqrt(|g_j|^2 / 4N +
    2 penalty)``, a bound on each one's curvature (exact for orthogonal columns up to the
    softmax weights): L-BFGS then needs tens of steps where the raw coordinates (singular values
    spread over decades) needed over a thousand. Returns ``(Z [r, classes], b [classes],
    function evaluations)``; stops when the largest gradient entry is below ``tol`` (or after
    ``max_iter`` iterations)."""
    n = g.shape[0]
    # (+ a tiny floor: a zero column with no penalty would scale by infinity)
    scale = 1.0 / torch.sqrt((g * g).sum(0) / (4.0 * n) + 2.0 * penalty + 1e-12)  # [r]
    w = torch.zeros(g.shape[1], n_classes, dtype=torch.float64)
    b = torch.zeros(n_classes, dtype=torch.float64)
    if init is not None:
        w, b = init[0] / scale[:, None], init[1].clone()
    w.requires_grad_(True)
    b.requires_grad_(True)
    opt = torch.optim.LBFGS([w, b], lr=1.0, max_iter=max_iter, history_size=20,
                            tolerance_grad=tol, tolerance_change=1e-12,
                            line_search_fn="strong_wolfe")  # fmt: skip
    evals = 0
    sq = (scale * scale)[:, None]

    def closure() -> Tensor:
        nonlocal evals
        evals += 1
        opt.zero_grad()
        # g (w scaled), not (g scaled) w: no scaled copy of the features
        loss = torch.nn.functional.cross_entropy(g @ (w * scale[:, None]) + b, y)
        loss = loss + penalty * (sq * w * w).sum()
        loss.backward()
        return loss

    with torch.enable_grad():
        opt.step(closure)
    return w.detach() * scale[:, None], b.detach(), evals


def group_folds(groups: np.ndarray, folds: int = FOLDS) -> list[np.ndarray]:
    """Boolean held-out masks of ``folds`` folds, whole groups each, balanced by window count
    (largest groups first onto the lightest fold; deterministic). Fewer folds when there are
    fewer groups; none below two."""
    ids, counts = np.unique(np.asarray(groups), return_counts=True)
    k = min(folds, ids.size)
    if k < 2:
        return []
    load = np.zeros(k)
    fold_of = np.empty(ids.size, dtype=np.int64)
    for i in np.argsort(-counts, kind="stable"):
        fold_of[i] = int(np.argmin(load))
        load[fold_of[i]] += counts[i]
    where = fold_of[np.searchsorted(ids, np.asarray(groups))]
    return [where == f for f in range(k)]


def choose_penalty(
    g: Tensor,
    y: Tensor,
    groups: np.ndarray,
    n_classes: int,
    penalties: list[float],
    max_windows: int = CV_WINDOWS,
) -> tuple[float, list[dict]]:
    """The penalty with the highest cross-validated accuracy over recordings (ties: the lower
    held-out cross-entropy, then the larger penalty), on at most ``max_windows`` windows (whole
    recordings, evenly spaced). Fitted from the largest penalty down, each fit warm-started
    from the last (the well-conditioned end first), to a gradient of 1e-5 (a ranking, not the
    final weights). Returns ``(penalty, [{"penalty", "cv_accuracy", "cv_log_loss"} per
    penalty])``; with one penalty (nothing to choose) or fewer than two recordings, the middle
    penalty and an empty table."""
    if len(penalties) == 1:
        return float(penalties[0]), []
    keep = whole_groups(np.asarray(groups), max_windows)
    if keep.size < len(y):  # the subsample's own basis: fewer, better-conditioned coordinates
        g = orthogonal_basis(g[torch.from_numpy(keep)])[0]
        y, groups = y[torch.from_numpy(keep)], np.asarray(groups)[keep]
    masks = group_folds(groups)
    if not masks:
        return penalties[len(penalties) // 2], []
    order = sorted(range(len(penalties)), key=lambda i: -penalties[i])
    acc = np.zeros(len(penalties))
    ce = np.zeros(len(penalties))
    for held in masks:
        fit, out = torch.from_numpy(~held), torch.from_numpy(held)
        warm = None
        for i in order:
            z, b, _ = fit_softmax(g[fit], y[fit], n_classes, penalties[i], warm, tol=1e-5,
                                  max_iter=300)  # fmt: skip
            warm = (z, b)
            logits = g[out] @ z + b
            acc[i] += float((logits.argmax(1) == y[out]).double().sum())
            ce[i] += float(torch.nn.functional.cross_entropy(logits, y[out], reduction="sum"))
    n = float(len(y))
    table = [{"penalty": float(lam), "cv_accuracy": acc[i] / n, "cv_log_loss": ce[i] / n}
             for i, lam in enumerate(penalties)]  # fmt: skip
    # highest accuracy; then lowest cross-entropy; then the largest penalty (the simplest model)
    best = max(range(len(penalties)), key=lambda i: (round(acc[i]), -ce[i], penalties[i]))
    return float(penalties[best]), table


def whole_groups(groups: np.ndarray, max_windows: int) -> np.ndarray:
    """Indices of whole groups, evenly spaced over the groups, totalling at most
    ``max_windows`` windows (all when they fit; at least one group)."""
    if groups.size <= max_windows:
        return np.arange(groups.size)
    ids, inv, counts = np.unique(groups, return_inverse=True, return_counts=True)
    share = max_windows / groups.size
    picked = np.zeros(ids.size, dtype=bool)
    total = 0
    for j in np.argsort((np.arange(ids.size) * share) % 1.0, kind="stable"):
        if total + counts[j] <= max_windows:
            picked[j] = True
            total += counts[j]
    if not picked.any():
        picked[0] = True
    return np.flatnonzero(picked[inv])
