"""The training loop's bookkeeping: progress lines in a log, a bounded training-error sample, the
csnn's time-held dropout mask."""

import logging

import numpy as np
import pytest
import torch

from tactilesnn import trainer as trainer_mod
from tactilesnn.config import TrainConfig
from tactilesnn.models import ConvSNNConfig, build_model


def _data(n=40, seed=0):
    rng = np.random.default_rng(seed)
    spikes = torch.full((n, 2 * 16, 2), float("inf"))
    y = np.arange(n) % 2
    for i in range(n):  # class 0 fires early on the left half, class 1 on the right
        cols = np.arange(16) if y[i] == 0 else np.arange(16, 32)
        spikes[i, cols, 0] = torch.from_numpy(rng.uniform(0, 20, 16).astype(np.float32))
    return spikes, y


def test_a_training_without_a_terminal_logs_its_epochs(monkeypatch, caplog):
    monkeypatch.setattr(trainer_mod, "LOG_EVERY_S", 0.0)
    model = build_model(ConvSNNConfig(grid="4x4", channels=2), 32, 2, 2, 50.0, seed=0)
    spikes, y = _data()
    with caplog.at_level(logging.INFO, logger="tactilesnn"):
        trainer_mod.Trainer(model, TrainConfig(epochs=3, batch_size=8), progress=True).fit(
            spikes, y
        )
    lines = [r.getMessage() for r in caplog.records if "epoch" in r.getMessage()]
    assert [ln.split("epoch ")[1].split(",")[0] for ln in lines] == ["1/3", "2/3", "3/3"]
    assert all("s left" in ln for ln in lines)


def test_without_progress_there_are_no_epoch_lines(caplog):
    model = build_model(ConvSNNConfig(grid="4x4", channels=2), 32, 2, 2, 50.0, seed=0)
    spikes, y = _data()
    with caplog.at_level(logging.INFO, logger="tactilesnn"):
        trainer_mod.Trainer(model, TrainConfig(epochs=2, batch_size=8)).fit(spikes, y)
    assert not [r for r in caplog.records if "epoch" in r.getMessage()]


def test_the_training_error_is_measured_on_a_bounded_even_sample(monkeypatch):
    """Above TRAIN_ERROR_WINDOWS windows the recorded error is that of an evenly spaced sample
    (first and last included); below it, of every window (as before)."""
    monkeypatch.setattr(trainer_mod, "TRAIN_ERROR_WINDOWS", 10)
    seen = []

    class Probe:
        n_classes = 2

        def batched_scores(self, s):
            seen.append(s.shape[0])
            return torch.zeros(s.shape[0], 2)

    st = {"history": [], "val_history": []}
    spikes, y = _data(40)
    trainer_mod._record(st, Probe(), spikes, torch.from_numpy(y), None)
    assert seen == [10] and abs(st["history"][0] - 0.5) < 0.11
    spikes, y = _data(8)
    trainer_mod._record(st, Probe(), spikes, torch.from_numpy(y), None)
    assert seen[-1] == 8


def test_the_csnn_dropout_mask_is_held_over_time(monkeypatch):
    """One draw per sample and neuron (shape [1, B, n2], broadcast over the time steps): a
    neuron dropped in a window is silent at every step of it; the kept spikes scaled by
    1/(1-p)."""
    cfg = ConvSNNConfig(grid="4x4", channels=2, dropout=0.5)
    model = build_model(cfg, 32, 2, 2, 50.0, seed=0)
    shapes, real_rand = [], torch.rand

    def spy(*size, **kw):
        shapes.append(tuple(size))
        return real_rand(*size, **kw)

    captured = {}
    h = model.core.out.register_forward_hook(lambda m, a, o: captured.update(x=a[0]))
    monkeypatch.setattr(torch, "rand", spy)
    spikes, _ = _data(6)
    model.scores(spikes, training=True)
    h.remove()
    assert shapes == [(1, 6, model.core.n2)]
    s2 = captured["x"][..., : model.core.n2]  # [steps, B, n2]: 0 or 1 / (1 - p)
    assert set(torch.unique(s2).tolist()) <= {0.0, 2.0}


def test_the_cosine_schedule_runs_from_the_rate_to_zero():
    from tactilesnn.trainer import scheduled_lr

    total = 100
    got = np.array([scheduled_lr(0.01, "cosine", s, total) for s in range(total + 1)])
    want = 0.005 * (1 + np.cos(np.pi * np.arange(total + 1) / total))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
    assert got[0] == 0.01 and got[-1] == 0.0 and np.all(np.diff(got) <= 0)
    assert scheduled_lr(0.01, "constant", 57, total) == 0.01


@pytest.mark.slow
def test_a_resumed_cosine_run_equals_an_uninterrupted_one():
    """The rate is a function of the step alone: 2 epochs, then 2 more from the saved state,
    learn the weights 4 epochs in a row learn."""
    spikes, y = _data()
    cfg = TrainConfig(epochs=4, batch_size=8, lr_schedule="cosine")

    def model():
        return build_model(ConvSNNConfig(grid="4x4", channels=2, dropout=0.0, shift=0), 32, 2, 2,
                           50.0, seed=0)  # fmt: skip

    whole = model()
    trainer_mod.Trainer(whole, cfg).fit(spikes, y)
    states = {}
    first = model()
    trainer_mod.Trainer(first, cfg).fit(
        spikes, y, on_epoch=lambda e, st: states.__setitem__(e, st) if e == 1 else None
    )
    resumed = model()
    trainer_mod.Trainer(resumed, cfg).fit(spikes, y, resume=states[1])
    for (k, a), b in zip(whole.state_dict().items(), resumed.state_dict().values(), strict=True):
        assert torch.equal(a, b), k


@pytest.mark.parametrize("solver", ["exact", "adam"])
def test_windows_without_their_class_signal_train_towards_saying_nothing(solver):
    from tactilesnn.models import ReadoutConfig

    spikes, y = _data(60, seed=3)
    # half the windows carry the wrong half's pattern: with full confidence they pull the
    # read-out; with none, they are trained to the uniform target and leave it alone
    y_noisy = y.copy()
    y_noisy[:30] = 1 - y_noisy[:30]
    conf = np.r_[np.zeros(30), np.ones(30)].astype(np.float32)

    def fitted(confidence):
        model = build_model(ReadoutConfig(solver=solver, choose=False), 32, 2, 2, 50.0, seed=0)
        cfg = TrainConfig(epochs=60 if solver == "adam" else 1, batch_size=16, seed=0)
        trainer_mod.Trainer(model, cfg).fit(spikes, y_noisy, confidence=confidence)
        return torch.softmax(model.scores(spikes), 1).detach()

    p_none, p_full = fitted(conf), fitted(np.ones(60, np.float32))
    hit = lambda p: float((p.argmax(1).numpy() == y).mean())  # noqa: E731
    # (exact: 0.97 against 0.50; Adam's 60 epochs: 0.75+ against 0.50)
    assert hit(p_none) >= 0.7 and hit(p_full) <= 0.6, (hit(p_none), hit(p_full))
    if solver == "exact":  # all 1 is the hard-label fit itself
        model = build_model(ReadoutConfig(choose=False), 32, 2, 2, 50.0, seed=0)
        trainer_mod.Trainer(model, TrainConfig(seed=0)).fit(spikes, y_noisy)
        np.testing.assert_allclose(torch.softmax(model.scores(spikes), 1).detach(), p_full,
                                   atol=1e-5)  # fmt: skip


def test_a_model_that_cannot_take_confidences_says_so():
    model = build_model(ConvSNNConfig(grid="4x4", channels=2), 32, 2, 2, 50.0, seed=0)
    spikes, y = _data()
    with pytest.raises(ValueError, match="does not train on window confidences"):
        trainer_mod.Trainer(model, TrainConfig(epochs=1)).fit(spikes, y, confidence=np.ones(40))
