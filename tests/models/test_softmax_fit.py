"""The readout's exact solver against scikit-learn, and the cross-validated penalty choice."""

import numpy as np
import pytest
import torch
from sklearn.linear_model import LogisticRegression

from tactilesnn.models.softmax_fit import (
    choose_penalty,
    fit_softmax,
    group_folds,
    orthogonal_basis,
)


def _problem(n: int, d: int, k: int, seed: int = 0, noise: float = 2.0):
    rng = np.random.default_rng(seed)
    proto = rng.normal(0, 1, (k, d))
    y = rng.integers(0, k, n)
    x = proto[y] + rng.normal(0, noise, (n, d))
    x = (x - x.mean(0)) / x.std(0)
    return torch.from_numpy(x), torch.from_numpy(y).long()


@pytest.mark.parametrize("n, d", [(120, 15), (60, 200)])  # more windows than features, and fewer
def test_the_exact_fit_is_scikit_learns_multinomial_optimum(n, d):
    x, y = _problem(n, d, 4)
    lam = 0.05
    g, v = orthogonal_basis(x)
    np.testing.assert_allclose((g @ v.T).numpy(), x.numpy(), atol=1e-9)  # F = G V^T
    np.testing.assert_allclose((v.T @ v).numpy(), np.eye(v.shape[1]), atol=1e-9)
    gram = (g.T @ g).numpy()
    np.testing.assert_allclose(gram - np.diag(np.diag(gram)), 0.0, atol=1e-8)  # orthogonal
    z, b, _ = fit_softmax(g, y, 4, lam, tol=1e-9)
    w = (v @ z).T.numpy()
    # sklearn minimises 0.5 |W|^2 + C sum CE, i.e. mean CE + |W|^2 / (2 C N)
    ref = LogisticRegression(C=1.0 / (2 * lam * n), tol=1e-12, max_iter=10_000).fit(x.numpy(), y)
    np.testing.assert_allclose(w, ref.coef_, atol=1e-4 * np.abs(ref.coef_).max())
    np.testing.assert_allclose(b.numpy(), ref.intercept_, atol=1e-4)

    def objective(w, b):
        logits = torch.from_numpy(x.numpy() @ w.T + b)
        return float(torch.nn.functional.cross_entropy(logits, y)) + lam * float((w * w).sum())

    # not worse than the reference's optimum (the two stop at slightly different points)
    assert objective(w, b.numpy()) <= objective(ref.coef_, ref.intercept_) + 1e-9


def test_a_warm_start_reaches_the_same_optimum():
    x, y = _problem(100, 10, 3, seed=1)
    g, _ = orthogonal_basis(x)
    cold = fit_softmax(g, y, 3, 0.01, tol=1e-9)
    warm = fit_softmax(g, y, 3, 0.01, init=fit_softmax(g, y, 3, 0.1)[:2], tol=1e-9)
    np.testing.assert_allclose(warm[0].numpy(), cold[0].numpy(), atol=1e-5)


def test_folds_hold_whole_recordings_and_balance_windows():
    groups = np.repeat(np.arange(9), [5, 5, 5, 4, 4, 4, 3, 3, 3])
    masks = group_folds(groups)
    assert len(masks) == 3
    assert np.array_equal(np.sum(masks, axis=0), np.ones(groups.size))  # each window once
    for m in masks:
        for gr in np.unique(groups):
            assert m[groups == gr].all() or not m[groups == gr].any()  # whole recordings
    assert sorted(int(m.sum()) for m in masks) == [12, 12, 12]
    assert group_folds(np.zeros(10)) == []  # one recording: nothing to cross-validate on


def test_the_chosen_penalty_is_the_best_cross_validated_one():
    # few noisy windows and many features: a heavier penalty than the lightest should win
    x, y = _problem(90, 300, 3, seed=2, noise=6.0)
    groups = np.arange(90) // 3
    g, _ = orthogonal_basis(x)
    pens = [1e-4, 1e-3, 1e-2, 1e-1, 1.0]
    best, table = choose_penalty(g, y, groups, 3, pens)
    assert [r["penalty"] for r in table] == pens
    accs = [r["cv_accuracy"] for r in table]
    assert best in pens and table[pens.index(best)]["cv_accuracy"] == max(accs)
    assert table[0]["cv_log_loss"] > min(r["cv_log_loss"] for r in table)  # overfit is seen
    # ties in accuracy go to the lower held-out cross-entropy
    tied = [r for r in table if r["cv_accuracy"] == max(accs)]
    assert best == min(tied, key=lambda r: r["cv_log_loss"])["penalty"]
    assert all(0.0 <= a <= 1.0 for a in accs)
