"""The export check's score tolerance: absolute for small scores, relative for large sums."""

from __future__ import annotations

import numpy as np

from tactilesnn.export.onnx import SCORE_ATOL, SCORE_RTOL, score_tolerance


def test_tolerance_is_absolute_for_small_scores_and_relative_for_large_ones():
    ref = np.array([[0.5, -1.0, 2.0], [150.0, -40.0, 3.0]], dtype=np.float32)
    tol = score_tolerance(ref)
    assert tol[0] == SCORE_ATOL
    assert tol[1] == np.float32(150.0) * SCORE_RTOL  # 3e-3: float32 sums of thousands of terms
    assert 4.2e-4 < tol[1] < 1e-2  # the localise readout's float32 rounding passes; 1 % would not
    assert score_tolerance(np.zeros((0, 3))).shape == (0,)
