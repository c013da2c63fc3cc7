"""The run plan's arithmetic: a fit's estimate from the measured encoding and training steps."""

from __future__ import annotations

import numpy as np
import pytest

from tactilesnn.config import PipelineConfig
from tactilesnn.core.data import WindowDataset
from tactilesnn.selection import Probe, probe
from tactilesnn.trainer import TRAIN_ERROR_WINDOWS


def test_a_model_solved_in_one_go_costs_its_encoding_times_the_overhead():
    p = Probe(0.01, codes_with_past=True, solves=True)
    assert p.fit_seconds(100, 50, overhead=2.0) == pytest.approx(2.0 * 0.01 * (2 * 100 + 50))


def test_a_model_trained_over_epochs_costs_its_steps_and_its_scoring():
    p = Probe(0.001, False, False, step_seconds_per_window=0.002, epochs=12)
    n_tr, n_te = 5000, 1000
    scored = min(n_tr, TRAIN_ERROR_WINDOWS) + n_te / 12
    want = 0.001 * (n_tr + n_te) + 12 * 0.002 * (n_tr + scored / 3)
    assert p.fit_seconds(n_tr, n_te) == pytest.approx(want)
    assert Probe(0.001, False, False).fit_seconds(10, 10) is None  # not measured: no estimate


def test_the_probe_measures_a_training_step_and_keeps_the_random_state():
    import torch

    rng = np.random.default_rng(0)
    X = rng.poisson(0.3, (40, 2 * 16, 20)).astype(np.float32)
    data = WindowDataset(X, np.arange(40) % 2, np.arange(40), 1000.0, ("a", "b"),
                         tuple(f"t{i}" for i in range(32)))  # fmt: skip
    cfg = PipelineConfig.from_flat(encoder="events", model="csnn", channels=("all",),
                                   csnn_grid="4x4", clock_afferents=0, epochs=3)  # fmt: skip
    torch.manual_seed(5)
    before = torch.get_rng_state()
    p = probe(cfg, data)
    assert torch.equal(torch.get_rng_state(), before)
    assert not p.solves and p.epochs == 3 and p.step_seconds_per_window > 0
    assert p.fit_seconds(40, 10) > 3 * p.step_seconds_per_window * 40
