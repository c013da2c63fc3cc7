"""The readout's exact solver against scikit-learn, and the cross-validated penalty choice."""

import numpy as np
import pytest
import torch
from sklearn.linear_model import LogisticRegression

from tactilesnn.models.softmax_fit import (
    choose_penalty,
    fit_features,
    fit_softmax,
    from_row_space,
    group_folds,
    row_space,
    soft_targets,
    whole_groups,
)


def _problem(n: int, d: int, k: int, seed: int = 0, noise: float = 2.0):
    rng = np.random.default_rng(seed)
    proto = rng.normal(0, 1, (k, d))
    y = rng.integers(0, k, n)
    x = proto[y] + rng.normal(0, noise, (n, d))
    x = (x - x.mean(0)) / x.std(0)
    return torch.from_numpy(x), torch.from_numpy(y).long()


@pytest.mark.parametrize("n, d", [(120, 15), (60, 200)])  # more windows than features, and fewer
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_the_exact_fit_is_scikit_learns_multinomial_optimum(n, d, dtype):
    x, y = _problem(n, d, 4)
    lam = 0.05
    w, b, _ = fit_features(x.to(dtype), y, 4, lam, tol=1e-9 if dtype == torch.float64 else 1e-6)
    w = w.T.numpy()
    # sklearn minimises 0.5 |W|^2 + C sum CE, i.e. mean CE + |W|^2 / (2 C N)
    ref = LogisticRegression(C=1.0 / (2 * lam * n), tol=1e-12, max_iter=10_000).fit(x.numpy(), y)
    rel = 1e-4 if dtype == torch.float64 else 2e-3  # float32 data: its rounding, not the solver's
    np.testing.assert_allclose(w, ref.coef_, atol=rel * np.abs(ref.coef_).max())
    np.testing.assert_allclose(b.numpy(), ref.intercept_, atol=rel * 10)

    def objective(w, b):
        logits = torch.from_numpy(x.numpy() @ w.T + b)
        return float(torch.nn.functional.cross_entropy(logits, y)) + lam * float((w * w).sum())

    # not worse than the reference's optimum (the two stop at slightly different points)
    slack = 1e-9 if dtype == torch.float64 else 1e-6
    assert objective(w, b.numpy()) <= objective(ref.coef_, ref.intercept_) + slack


def test_the_row_space_of_wide_features_is_exact():
    # d > N: G = L_K with F F^T = L_K L_K^T; W = F^T L_K^-T Z maps back with |W| = |Z|
    x = _problem(40, 300, 3, seed=3)[0] + 0.5  # (centred columns would make F F^T singular)
    g, lk = row_space(x)
    assert lk is not None and g.shape == (40, 40)
    np.testing.assert_allclose((g @ g.T).numpy(), (x @ x.T).numpy(), rtol=1e-5, atol=1e-5)
    z = torch.randn(40, 3, dtype=torch.float64)
    w = from_row_space(x, lk, z)
    fz = (g @ z).numpy()  # equal but for the ridge that keeps the factorisation defined
    np.testing.assert_allclose((x @ w).numpy(), fz, atol=1e-4 * np.abs(fz).max())
    np.testing.assert_allclose(float(w.norm()), float(z.norm()), rtol=1e-4)
    assert row_space(x[:, :20])[1] is None  # d <= N: fitted as it is


def test_a_warm_start_reaches_the_same_optimum():
    x, y = _problem(100, 10, 3, seed=1)
    cold = fit_softmax(x, y, 3, 0.01, tol=1e-9)
    warm = fit_softmax(x, y, 3, 0.01, init=fit_softmax(x, y, 3, 0.1)[:2], tol=1e-9)
    np.testing.assert_allclose(warm[0].numpy(), cold[0].numpy(), atol=1e-5)
    assert warm[2] < cold[2]  # fewer evaluations from nearby


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


def test_folds_and_subsets_of_recordings_stored_in_a_cycle_of_the_classes_hold_every_class():
    """A synthetic dataset stores recording i as class i % classes: with as many folds as
    classes, unstratified folds put each class in a fold of its own (every held-out window of
    a class the fold never trained on), and evenly spaced recordings are all one class."""
    groups = np.repeat(np.arange(30), 7)  # 30 recordings of 7 windows
    y = groups % 3
    plain = group_folds(groups)
    assert all(np.unique(y[m]).size == 1 for m in plain)  # the failure the labels prevent
    masks = group_folds(groups, y=y)
    assert np.array_equal(np.sum(masks, axis=0), np.ones(groups.size))
    for m in masks:
        # each class's 10 recordings spread 4 / 3 / 3 over the folds
        assert set(np.bincount(y[m], minlength=3).tolist()) <= {21, 28}
        for gr in np.unique(groups):
            assert m[groups == gr].all() or not m[groups == gr].any()
    assert np.unique(y[whole_groups(groups, 70)]).size == 1  # unstratified: one class
    keep = whole_groups(groups, 70, y)
    assert keep.size <= 70 and np.bincount(y[keep], minlength=3).min() >= 21
    kept = np.unique(groups[keep])
    assert np.isin(np.flatnonzero(np.isin(groups, kept)), keep).all()


def test_the_chosen_penalty_is_the_best_cross_validated_one():
    # few noisy windows and many features: a heavier penalty than the lightest should win
    x, y = _problem(90, 300, 3, seed=2, noise=6.0)
    groups = np.arange(90) // 3
    pens = [1e-4, 1e-3, 1e-2, 1e-1, 1.0]
    best, table = choose_penalty(x, y, groups, 3, pens)
    assert [r["penalty"] for r in table] == pens
    accs = [r["cv_accuracy"] for r in table]
    assert best in pens and table[pens.index(best)]["cv_accuracy"] == max(accs)
    assert table[0]["cv_log_loss"] > min(r["cv_log_loss"] for r in table)  # overfit is seen
    # ties in accuracy go to the lower held-out cross-entropy
    tied = [r for r in table if r["cv_accuracy"] == max(accs)]
    assert best == min(tied, key=lambda r: r["cv_log_loss"])["penalty"]
    assert all(0.0 <= a <= 1.0 for a in accs)


@pytest.mark.parametrize("n, d", [(90, 12), (40, 120)])
def test_soft_targets_are_the_optimum_of_the_windows_weighted_by_class(n, d):
    # mean over windows of -(q . log p) with q = c one-hot + (1 - c) / K is scikit-learn's
    # weighted fit of every window repeated once per class, weighted by q
    k, lam = 3, 0.05
    x, y = _problem(n, d, k, seed=4)
    conf = torch.from_numpy(np.random.default_rng(5).uniform(0, 1, n))
    conf[:10] = 0.0  # windows with none of their class's signal
    w, _, _ = fit_features(x, y, k, lam, tol=1e-10, confidence=conf)
    q = soft_targets(y, k, conf).numpy()
    np.testing.assert_allclose(q.sum(1), 1.0)
    np.testing.assert_allclose(q[:10], 1.0 / k)
    xr = np.repeat(x.numpy(), k, axis=0)
    yr = np.tile(np.arange(k), n)
    ref = LogisticRegression(C=1.0 / (2 * lam * n), tol=1e-12, max_iter=20_000).fit(
        xr, yr, sample_weight=q.reshape(-1)
    )
    np.testing.assert_allclose(w.T.numpy(), ref.coef_, atol=1e-4 * np.abs(ref.coef_).max())


def test_full_confidence_is_the_hard_label_fit_and_bad_confidence_is_refused():
    x, y = _problem(80, 10, 3, seed=6)
    hard = fit_features(x, y, 3, 0.02, tol=1e-9)
    full = fit_features(x, y, 3, 0.02, tol=1e-9, confidence=torch.ones(80, dtype=torch.float64))
    np.testing.assert_allclose(full[0].numpy(), hard[0].numpy(), atol=1e-8)
    groups = np.arange(80) // 4
    lam_h, t_h = choose_penalty(x, y, groups, 3, [0.01, 0.1, 1.0])
    lam_f, t_f = choose_penalty(x, y, groups, 3, [0.01, 0.1, 1.0], confidence=torch.ones(80))
    assert lam_h == lam_f
    np.testing.assert_allclose([r["cv_accuracy"] for r in t_f], [r["cv_accuracy"] for r in t_h])
    # windows with no signal count 1 / classes in the cross-validated accuracy, whatever is said
    _, t0 = choose_penalty(x, y, groups, 3, [0.01, 0.1], confidence=torch.zeros(80))
    np.testing.assert_allclose([r["cv_accuracy"] for r in t0], 1.0 / 3)
    for bad in (torch.full((80,), 1.5), torch.ones(79)):
        with pytest.raises(ValueError, match="confidence"):
            soft_targets(y, 3, bad)
