"""The run folder's pictures hold for any class count, and a readout run's training picture
shows what its solve did."""

from __future__ import annotations

import numpy as np
import pytest

from tactilesnn.app.plots import MAX_WINDOW_COLUMNS, classes_drawn, plot_training


@pytest.mark.parametrize("n_classes", [2, 4, 7, 8])
def test_every_class_is_drawn_up_to_the_column_limit(n_classes):
    y = np.repeat(np.arange(n_classes), 3)
    shown, present = classes_drawn(y, n_classes)
    assert shown == present == list(range(n_classes))


@pytest.mark.parametrize("n_classes", [9, 20, 36])
def test_more_classes_are_spread_over_the_columns(n_classes):
    y = np.repeat(np.arange(n_classes), 2)
    shown, present = classes_drawn(y, n_classes)
    assert len(shown) == MAX_WINDOW_COLUMNS and shown[0] == 0 and shown[-1] == n_classes - 1
    assert len(set(shown)) == len(shown) and len(present) == n_classes


def test_classes_missing_from_the_test_split_are_not_drawn():
    assert classes_drawn(np.array([0, 0, 2]), 3) == ([0, 2], [0, 2])


@pytest.mark.slow
def test_a_readout_solve_is_drawn_as_its_cross_validation(tmp_path):
    table = [{"instants": k, "penalty": p, "cv_accuracy": a, "cv_log_loss": 0.1}
             for k in (4, 2) for p, a in ((1e-4, 0.8), (1e-3, 0.9), (1e-2, 0.85))]  # fmt: skip
    solve = {"penalty": 1e-3, "instants": 4, "solver": "exact", "cross_validation": table}
    plot_training([0.05], [0.88], tmp_path / "solve.png", solve)
    plot_training([0.5, 0.3, 0.2], [0.6, 0.7, 0.8], tmp_path / "epochs.png")
    import matplotlib.image

    a = matplotlib.image.imread(tmp_path / "solve.png")
    b = matplotlib.image.imread(tmp_path / "epochs.png")
    assert a.shape == b.shape and not np.array_equal(a, b)
    # the solve's picture draws lines, not one dot: many more non-white pixels than a dot
    assert (a[..., :3] < 0.9).any(axis=-1).sum() > 3000
