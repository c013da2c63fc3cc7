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


def test_a_candidate_that_would_not_fit_in_memory_is_left_out_before_any_fit(monkeypatch):
    """Long windows: the STFT candidate's one window would exceed the budget, the others fit;
    it is left out of the candidates (said in the log) instead of failing the run after the
    others' fits; none fitting is the first refusal."""
    import numpy as np

    from tactilesnn.config import PipelineConfig
    from tactilesnn.core import checks
    from tactilesnn.core.data import WindowDataset
    from tactilesnn.selection import candidate_configs

    X = np.random.default_rng(0).normal(size=(8, 2, 20000)).astype(np.float32)
    ds = WindowDataset(X, np.arange(8) % 2, np.arange(8), 1000.0, ("a", "b"), ("c0", "c1"))
    base = PipelineConfig.from_flat(model="readout", channels=("all",))
    monkeypatch.setattr(checks, "memory_limit_bytes", lambda: 200 << 20)  # budget 100 MiB
    assert list(candidate_configs(base, ds, ("cgwt", "stft", "lif"))) == ["cgwt", "lif"]
    monkeypatch.setattr(checks, "memory_limit_bytes", lambda: 200 << 10)
    with pytest.raises(ValueError, match="would need"):
        candidate_configs(base, ds, ("cgwt", "stft"))
