"""Leaky-integrator readout: traces against a float64 loop, many classes, export parity."""

import numpy as np
import pytest
import torch

from tactilesnn.app.run import load_run
from tactilesnn.config import PipelineConfig
from tactilesnn.models import ReadoutConfig, build_model
from tactilesnn.models.li_readout import trace_features
from tactilesnn.trainer import Trainer
from tests.helpers import run_task


def test_traces_match_a_float64_loop():
    rng = np.random.default_rng(0)
    spikes = rng.uniform(0, 100, (3, 4, 5))
    spikes[rng.random(spikes.shape) < 0.3] = np.inf
    times = np.array([10.0, 50.0, 100.0])
    want = np.zeros((3, 4, 3))
    for b, a, k, j in np.ndindex(3, 4, 5, 3):
        if spikes[b, a, k] <= times[j]:
            want[b, a, j] += np.exp(-(times[j] - spikes[b, a, k]) / 20.0)
    got = trace_features(torch.from_numpy(spikes), torch.from_numpy(times), 20.0)
    np.testing.assert_allclose(got.numpy(), want, rtol=1e-12)


def test_a_spike_on_an_instant_counts_alike_a_float32_rounding_either_side():
    """Frame-clocked codes put spikes exactly on read-out instants; torch and the exported
    graph round such a time to either side of it. Within the slack (1e-6 of the window) both
    count the spike as on the instant; beyond it, after the instant, it does not count."""
    from tactilesnn.models.li_readout import INSTANT_SLACK

    model = build_model(ReadoutConfig(n_times=4), 1, 1, 2, 925.827)
    t = float(model.times_ms[1])
    ulp = float(np.spacing(np.float32(t)))
    spikes = torch.tensor([[[t]], [[t + 2 * ulp]], [[t - 2 * ulp]], [[t + 1e-3 * 925.827]]],
                          dtype=torch.float32)  # fmt: skip
    f = model.traces(spikes)
    torch.testing.assert_close(f[1], f[0])
    torch.testing.assert_close(f[2], f[0], rtol=1e-5, atol=0)
    assert f[0].view(4)[1] > 0 and f[3].view(4)[1] == 0  # 1e-3 of the window late: not counted
    assert 2 * ulp < INSTANT_SLACK * 925.827


@pytest.mark.slow
def test_trains_thirty_classes_from_spike_timing():
    # class c: afferents fire at class-specific times (a pattern a count code cannot see)
    rng = np.random.default_rng(1)
    n_cls, a, per = 30, 40, 20
    proto = rng.uniform(0, 500, (n_cls, a, 1))
    y = np.repeat(np.arange(n_cls), per)
    spikes = proto[y] + rng.normal(0, 15, (y.size, a, 1))
    spikes = torch.from_numpy(np.clip(spikes, 0, 500)).float()
    model = build_model(ReadoutConfig(), a, 1, n_cls, 500.0)
    from tactilesnn.config import TrainConfig

    Trainer(model, TrainConfig(epochs=30, batch_size=32)).fit(spikes[::2], y[::2])
    with torch.no_grad():
        acc = float((model.scores(spikes[1::2]).argmax(1).numpy() == y[1::2]).mean())
    assert acc > 0.9


@pytest.mark.slow
def test_readout_exports_through_the_registry_only(tmp_path):
    small = {"seed": 0, "n_planar": 10, "n_concave": 5, "n_convex": 5, "n_test": 4}
    cfg = PipelineConfig.from_flat(model="readout", epochs=5)
    run, m = run_task("hook_loop", small, cfg, tmp_path / "r", progress=False, export=True)
    assert m["onnx"]["max_score_diff"] <= 1e-4 and m["test_accuracy"] > 0.8
    pipe, _ = load_run(run)
    assert pipe.config.model_type == "readout"


def test_prepare_standardises_the_traces_against_a_float64_reference():
    rng = np.random.default_rng(2)
    spikes = rng.uniform(0, 400, (50, 6, 2))
    spikes[rng.random(spikes.shape) < 0.4] = np.inf
    spikes[:, 5] = np.inf  # a silent afferent: constant features keep scale 1
    model = build_model(ReadoutConfig(n_times=4), 6, 2, 3, 400.0)
    assert model.tau_ms == 400.0  # tau_ms = 0: the window's duration
    t = torch.from_numpy(spikes).float()
    model.prepare(t)
    times = (np.arange(4) + 1) * 100.0
    raw = np.zeros((50, 6, 4))
    for b, a, k, j in np.ndindex(50, 6, 2, 4):
        if spikes[b, a, k] <= times[j]:
            raw[b, a, j] += np.exp(-(times[j] - spikes[b, a, k]) / 400.0)
    feats = np.log1p(raw).reshape(50, -1)
    sd = feats.std(0)
    np.testing.assert_allclose(model.feat_mean.numpy(), feats.mean(0), atol=1e-6)
    np.testing.assert_allclose(model.feat_scale.numpy(), np.where(sd > 1e-6, sd, 1.0), rtol=1e-4)
    z = model.features(t).detach().numpy()
    live = sd > 1e-6
    np.testing.assert_allclose(z[:, live].mean(0), 0.0, atol=1e-5)
    np.testing.assert_allclose(z[:, live].std(0), 1.0, rtol=1e-4)
    assert np.all(z[:, ~live] == 0.0)


def test_weights_without_the_scaler_load_as_identity():
    """Runs written before the scaler existed keep their scores (their buffers are optional)."""
    from tactilesnn.pipeline import SpikePipeline

    cfg = PipelineConfig.from_flat(model="readout", readout_tau_ms=100.0, readout_times=8)
    pipe = SpikePipeline(cfg, 200.0, 100, ("static", "dynamic"), ("hook", "loop"))
    old = {k: v for k, v in pipe.weights().items() if "feat_" not in k}
    fresh = SpikePipeline(cfg, 200.0, 100, ("static", "dynamic"), ("hook", "loop"))
    fresh.load_weights(old)
    assert torch.all(fresh.model.feat_mean == 0) and torch.all(fresh.model.feat_scale == 1)
    spikes = torch.rand(4, fresh.model.n_afferents, 1) * 500
    np.testing.assert_array_equal(fresh.model.features(spikes).numpy(),
                                  fresh.model.traces(spikes).numpy())  # fmt: skip


def _timing_problem(seed: int = 3):
    rng = np.random.default_rng(seed)
    proto = rng.uniform(0, 400, (3, 8, 1))
    y = np.repeat(np.arange(3), 30)
    spikes = np.clip(proto[y] + rng.normal(0, 40, (y.size, 8, 1)), 0, 400)
    return torch.from_numpy(spikes).float(), y


def test_the_exact_solver_finds_scikit_learns_optimum_on_the_readouts_features():
    from sklearn.linear_model import LogisticRegression

    from tactilesnn.config import TrainConfig

    spikes, y = _timing_problem()
    model = build_model(ReadoutConfig(n_times=4, choose=False), 8, 1, 3, 400.0)
    trainer = Trainer(model, TrainConfig(epochs=7, batch_size=16))
    history = trainer.fit(spikes, y)
    assert len(history) == 1 and trainer.history["epoch"] == 7  # solved: no epochs to run
    info = trainer.history["solved"]
    assert info["instants"] == 4 and info["penalty"] == pytest.approx(0.03 * 256 / 90)
    feats = model.features(spikes).detach().double().numpy()
    ref = LogisticRegression(C=1.0 / (2 * info["penalty"] * 90), tol=1e-10, max_iter=10_000)
    ref.fit(feats, y)
    w = model.linear.weight.detach().numpy()
    np.testing.assert_allclose(w, ref.coef_, atol=1e-3 * np.abs(ref.coef_).max())


def test_a_pretraining_tries_the_chosen_capacity_and_the_strongest_on_every_instant():
    """The readout's capacities for a pretraining: its cross-validation's choice, and the
    strongest penalty that choice may take on all instants, solved as that very candidate;
    a fixed capacity (or Adam) is kept as configured, as by every other model."""
    from tactilesnn.models.base import MODELS
    from tactilesnn.models.forest_readout import ForestConfig

    cls = MODELS.component_for(ReadoutConfig())
    caps = cls.pretraining_capacities(ReadoutConfig(n_times=4))
    assert list(caps) == ["chosen", "strongest"] and caps["chosen"] == ReadoutConfig(n_times=4)
    strong = caps["strongest"]
    assert not strong.choose and strong.n_times == 4
    assert strong.weight_decay == pytest.approx(0.03 * 30)
    assert (
        cls.pretraining_capacities(ReadoutConfig(weight_decay=0.5))["strongest"].weight_decay == 1.0
    )
    for fixed in (ReadoutConfig(choose=False), ReadoutConfig(solver="adam")):
        assert cls.pretraining_capacities(fixed) == {"configured": fixed}
    forest = ForestConfig()
    assert MODELS.component_for(forest).pretraining_capacities(forest) == {"configured": forest}
    spikes, y = _timing_problem(4)
    model = build_model(strong, 8, 1, 3, 400.0)
    model.prepare(spikes)
    info = model.solve(spikes, torch.from_numpy(y), np.arange(90) // 3)
    assert info["instants"] == 4 and info["penalty"] == pytest.approx(0.03 * 30 * 256 / 90)


@pytest.mark.slow
def test_cross_validation_reports_every_candidate_and_zeroes_unused_instants():
    spikes, y = _timing_problem(4)
    groups = np.arange(90) // 3
    model = build_model(ReadoutConfig(n_times=4), 8, 1, 3, 400.0)
    model.prepare(spikes)
    info = model.solve(spikes, torch.from_numpy(y), groups)
    assert {(r["instants"], r["penalty"]) for r in info["cross_validation"]} == {
        (m, model.config.weight_decay * 256 / 90 * f) for m in (4, 1)
        for f in (1 / 3, 1.0, 3.0, 10.0, 30.0)
    }  # fmt: skip
    best = max(r["cv_accuracy"] for r in info["cross_validation"])
    chosen = [r for r in info["cross_validation"]
              if r["instants"] == info["instants"] and r["penalty"] == info["penalty"]]  # fmt: skip
    assert chosen[0]["cv_accuracy"] == best
    w = model.linear.weight.detach().numpy().reshape(3, 8, 4)
    if info["instants"] == 1:
        assert np.all(w[..., :3] == 0) and np.any(w[..., 3] != 0)


def test_adam_and_saved_runs_keep_the_epochs():
    from tactilesnn.app.run import saved_pipeline_config

    spikes, y = _timing_problem()
    model = build_model(ReadoutConfig(solver="adam"), 8, 1, 3, 400.0)
    model.prepare(spikes)
    assert model.solve(spikes, torch.from_numpy(y)) is None
    saved = PipelineConfig.from_flat(model="readout").to_dict()
    del saved["model"]["solver"], saved["model"]["choose"]  # written before the exact solver
    cfg = saved_pipeline_config(saved)
    assert (cfg.model.solver, cfg.model.choose) == ("adam", False)
    assert PipelineConfig.from_dict(saved).model.solver == "exact"  # a user's file: today's
    with pytest.raises(ValueError, match="solver"):
        ReadoutConfig(solver="sgd")


def test_over_the_budget_the_choice_is_kept_and_the_epochs_train(monkeypatch):
    """Features too large for the exact fit: the penalty and instants are chosen on whole
    recordings within the budget, then Adam trains only the chosen instants."""
    from tactilesnn.config import TrainConfig
    from tactilesnn.models import li_readout

    spikes, y = _timing_problem(5)
    # float32 features: 45 windows of the last instant's 8 (11 of every instant's 32) of 90,
    # under EXACT_MIN_SHARE of them: Adam's epochs on all
    monkeypatch.setattr(li_readout, "EXACT_BUDGET_BYTES", 4 * 8 * 45)
    monkeypatch.setattr(li_readout, "instant_subsets", lambda n: [[n - 1]])  # the last only
    model = build_model(ReadoutConfig(n_times=4), 8, 1, 3, 400.0)
    trainer = Trainer(model, TrainConfig(epochs=5, batch_size=16))
    history = trainer.fit(spikes, y, groups=np.arange(90) // 3)
    info = trainer.history["solved"]
    assert info["train_epochs"] and info["cv_windows"] <= 15 and len(history) == 5
    assert info["instants"] == 1
    w = model.linear.weight.detach().numpy().reshape(3, 8, 4)
    assert np.all(w[..., :3] == 0) and np.all(w[..., 3] != 0)  # Adam kept the others at zero
    assert "instant_mask" not in model.state_dict()  # not saved: the zero weights are


def test_chosen_instants_within_the_budget_get_the_exact_fit(monkeypatch):
    """Every instant's features exceed the budget, the chosen instant's fit it: the choice is
    made on the windows the budget allows, the exact fit on every window of that instant."""
    from tactilesnn.config import TrainConfig
    from tactilesnn.models import li_readout

    spikes, y = _timing_problem(5)
    monkeypatch.setattr(li_readout, "EXACT_BUDGET_BYTES", 4 * 32 * 60)  # 60 of 90 windows
    monkeypatch.setattr(li_readout, "instant_subsets", lambda n: [[n - 1]])
    model = build_model(ReadoutConfig(n_times=4), 8, 1, 3, 400.0)
    trainer = Trainer(model, TrainConfig(epochs=5, batch_size=16))
    history = trainer.fit(spikes, y, groups=np.arange(90) // 3)
    info = trainer.history["solved"]
    assert not info.get("train_epochs") and info["cv_windows"] <= 60 and len(history) == 1
    assert info["solver"].startswith("exact") and info["instants"] == 1
    w = model.linear.weight.detach().numpy().reshape(3, 8, 4)
    assert np.all(w[..., :3] == 0) and np.any(w[..., 3] != 0)
    # the training error it reports is the fitted model's
    err = float((model.batched_scores(spikes).argmax(1).numpy() != y).mean())
    assert info["train_error"] == pytest.approx(err, abs=1.5 / 90)


@pytest.mark.parametrize("n_times", [4, 16])  # fewer features than windows, and more
def test_silent_inputs_give_finite_zero_weights(n_times):
    spikes = torch.full((20, 8, 1), float("inf"))  # no afferent ever spikes: constant features
    y = np.arange(20) % 2
    model = build_model(ReadoutConfig(n_times=n_times, weight_decay=0.0), 8, 1, 2, 400.0)
    model.prepare(spikes)
    info = model.solve(spikes, torch.from_numpy(y), np.arange(20) // 2)
    w = model.linear.weight.detach()
    assert info is not None and torch.isfinite(w).all() and torch.all(w == 0)
    assert torch.isfinite(model.scores(spikes)).all()


def test_a_little_over_the_budget_the_exact_fit_takes_the_recordings_that_fit(monkeypatch):
    """Every instant's features over the budget by a little: the exact fit runs on the whole
    recordings the budget holds (here 81 of 90 windows), not Adam's epochs on all."""
    from tactilesnn.config import TrainConfig
    from tactilesnn.models import li_readout
    from tactilesnn.models.softmax_fit import fit_features, whole_groups

    spikes, y = _timing_problem(5)
    groups = np.arange(90) // 3
    monkeypatch.setattr(li_readout, "EXACT_BUDGET_BYTES", 4 * 32 * 82)  # 82 windows of 90
    monkeypatch.setattr(li_readout, "instant_subsets", lambda n: [list(range(n))])
    model = build_model(ReadoutConfig(n_times=4), 8, 1, 3, 400.0)
    trainer = Trainer(model, TrainConfig(epochs=5, batch_size=16))
    history = trainer.fit(spikes, y, groups=groups)
    info = trainer.history["solved"]
    rows = whole_groups(groups, 82, y)
    assert len(rows) == 81 and info["fit_windows"] == 81 and len(history) == 1
    assert not info.get("train_epochs") and "81 of 90 windows" in info["solver"]
    # the weights are the exact fit on those windows' features
    feats = model.features(spikes[torch.from_numpy(rows)])  # standardised as the solve's
    w, b, _ = fit_features(feats, torch.from_numpy(y[rows]), 3, info["penalty"])
    np.testing.assert_allclose(model.linear.weight.detach().numpy(), w.T.numpy(), atol=1e-5)
    np.testing.assert_allclose(model.linear.bias.detach().numpy(), b.numpy(), atol=1e-5)


def _domain(rng, proto, per):
    y = np.repeat(np.arange(proto.shape[0]), per)
    s = proto[y] + rng.normal(0, 10, (y.size, proto.shape[1], 1))
    return torch.from_numpy(np.clip(s, 0, 500)).float(), y


def _pretrained(rng):
    """A readout trained on one domain of three classes' spike times, and its prototypes."""
    from tactilesnn.config import TrainConfig

    proto = rng.uniform(50, 450, (3, 12, 1))
    src, ys = _domain(rng, proto, 40)
    model = build_model(ReadoutConfig(), 12, 1, 3, 500.0)
    Trainer(model, TrainConfig(epochs=1)).fit(src, ys)
    return model, proto


def test_finetune_adapts_near_the_pretrained_weights():
    """Pretrain on one domain, fine-tune on a few windows of a shifted one: the fine-tuned
    readout classifies the shifted domain better than the pretrained one, and a strong prior
    keeps it at the pretrained weights (the penalty pulls towards them, not towards zero)."""
    model, proto = _pretrained(np.random.default_rng(4))
    rng = np.random.default_rng(40)
    # the new domain: classes 0 and 1 swap their timing on two thirds of the afferents
    new = proto.copy()
    new[0, :8], new[1, :8] = proto[1, :8], proto[0, :8]
    few, yf = _domain(rng, new, 2)
    test, yt = _domain(rng, new, 30)
    before = float((model.scores(test).argmax(1).numpy() == yt).mean())
    w0 = model.linear.weight.detach().clone()
    report = model.finetune(few, torch.from_numpy(yf))
    after = float((model.scores(test).argmax(1).numpy() == yt).mean())
    assert report["windows"] == 6 and report["loss_after"] < report["loss_before"]
    assert after > before
    moved = float((model.linear.weight - w0).norm())
    assert moved > 0
    # a prior 1e6 times stronger: the weights stay where pretraining left them
    model.linear.weight.data.copy_(w0)
    model.finetune_penalty = lambda n: 1e6  # type: ignore[method-assign]
    model.finetune(few, torch.from_numpy(yf))
    assert float((model.linear.weight - w0).norm()) < 1e-3 * moved
    with pytest.raises(ValueError, match="one label each"):
        model.finetune(few, torch.from_numpy(yf[:-1]))


def test_finetune_on_confidences_takes_soft_targets():
    """Fine-tuning on window confidences: all 1 is the labels' fine-tune (to float32 rounding:
    the two data terms are summed differently); all
    0 fits the uniform target (the windows' scores move towards equal, not towards the
    labels); a model that cannot train on confidences, or confidences of the wrong length, are
    refused."""
    from tactilesnn.models.softmax_fit import soft_targets

    model, proto = _pretrained(np.random.default_rng(8))
    few, yf = _domain(np.random.default_rng(80), proto, 3)
    y = torch.from_numpy(yf)
    state = {k: v.clone() for k, v in model.state_dict().items()}

    def finetuned(conf):
        model.load_state_dict(state)
        report = model.finetune(few, y, confidence=conf)
        return report, torch.softmax(model.scores(few).double(), 1)

    hard, p_hard = finetuned(None)
    ones, p_ones = finetuned(torch.ones(yf.size))
    torch.testing.assert_close(p_ones, p_hard, atol=1e-4, rtol=0)
    assert ones["loss_after"] == pytest.approx(hard["loss_after"], rel=1e-4)
    zeros, p_zero = finetuned(torch.zeros(yf.size))
    uniform = torch.full_like(p_zero, 1 / 3)
    assert (p_zero - uniform).abs().max() < (p_hard - uniform).abs().max()
    # the data term is the soft targets' cross-entropy (float64 reference)
    q = soft_targets(y, 3, torch.zeros(yf.size))
    assert zeros["loss_after"] == pytest.approx(float(-(q * p_zero.log()).sum(1).mean()), rel=1e-4)
    with pytest.raises(ValueError, match="confidence must be"):
        model.finetune(few, y, confidence=torch.ones(yf.size + 1))
    model.trains_on_confidence = False  # as a model without soft targets declares
    with pytest.raises(ValueError, match="does not train on window confidences"):
        model.finetune(few, y, confidence=torch.ones(yf.size))


def test_blended_finetunes_score_with_the_mean_of_their_logits():
    """Two copies of one pretrained pipeline fine-tuned on different targets, blended: one
    read-out whose scores are the mean of theirs (float64 reference); the features' scaling
    (not fine-tuned) untouched; a pipeline of another shape refused."""
    import copy

    from tactilesnn.training import blend_finetuned

    model, proto = _pretrained(np.random.default_rng(9))
    few, yf = _domain(np.random.default_rng(90), proto, 3)
    y = torch.from_numpy(yf)

    class Pipe:  # the part of a pipeline blend_finetuned reads
        def __init__(self, m):
            self.model = m

    a, b = Pipe(copy.deepcopy(model)), Pipe(copy.deepcopy(model))
    a.model.finetune(few, y)
    b.model.finetune(few, y, confidence=torch.zeros(yf.size))
    want = (a.model.scores(few).double() + b.model.scores(few).double()) / 2
    scale = a.model.feat_scale.clone()
    blend_finetuned(a, b)
    torch.testing.assert_close(a.model.scores(few).double(), want, atol=1e-5, rtol=0)
    torch.testing.assert_close(a.model.feat_scale, scale)
    other = Pipe(build_model(ReadoutConfig(), 6, 1, 3, 500.0))
    with pytest.raises(ValueError, match="shapes differ"):
        blend_finetuned(a, other)


def test_finetune_chooses_its_prior_by_leaving_recordings_out():
    model, proto = _pretrained(np.random.default_rng(5))
    few, yf = _domain(np.random.default_rng(50), proto, 4)
    groups = np.arange(yf.size) // 2  # two windows per recording
    report = model.finetune(few, torch.from_numpy(yf), groups, factors=(0.3, 3.0, 30.0))
    assert [r["factor"] for r in report["cross_validation"]] == [0.3, 3.0, 30.0]
    best = min(r["held_out_loss"] for r in report["cross_validation"])
    chosen = next(r for r in report["cross_validation"] if r["factor"] == report["factor"])
    assert chosen["held_out_loss"] == best
    assert np.isclose(report["penalty"], model.finetune_penalty(yf.size) * report["factor"])
    # one recording: nothing to leave out, the prior's own strength
    solo = model.finetune(few, torch.from_numpy(yf), np.zeros(yf.size, np.int64))
    assert solo["factor"] == 1.0 and solo["cross_validation"] == []


def test_adapt_restandardises_on_the_new_domain_against_a_float64_reference():
    """``adapt`` re-estimates the features' mean and standard deviation on a new domain's
    unlabelled spikes (float64 reference), keeps the weights, keeps the trained scale of a
    feature constant there; a readout trained on one domain then classifies a delayed copy of it
    (every spike 150 ms later) that it misreads before (below chance, then 77 %)."""
    from tactilesnn.config import TrainConfig
    from tactilesnn.models.base import build_model as build

    rng = np.random.default_rng(6)
    proto = rng.uniform(50, 300, (3, 12, 1))
    src, ys = _domain(rng, proto, 40)
    model = build_model(ReadoutConfig(), 12, 1, 3, 500.0)
    Trainer(model, TrainConfig(epochs=1)).fit(src, ys)
    new, yn = _domain(rng, proto + 150.0, 30)
    new[:, 11] = float("inf")  # an afferent silent in the new domain
    before = float((model.scores(new).argmax(1).numpy() == yn).mean())
    w0, scale0 = model.linear.weight.detach().clone(), model.feat_scale.clone()
    report = model.adapt(new)
    after = float((model.scores(new).argmax(1).numpy() == yn).mean())
    times = (np.arange(model.config.n_times) + 1) * 500.0 / model.config.n_times
    s = new.double().numpy()
    raw = np.where(s <= times, np.exp(-(times - np.minimum(s, times)) / 500.0), 0.0)
    feats = np.log1p(raw).reshape(len(s), -1)
    sd, live = feats.std(0), feats.std(0) > 1e-6
    np.testing.assert_allclose(model.feat_mean.numpy(), feats.mean(0), atol=1e-6)
    np.testing.assert_allclose(model.feat_scale.numpy()[live], sd[live], rtol=1e-4)
    assert torch.equal(model.feat_scale[~torch.from_numpy(live)], scale0[~torch.from_numpy(live)])
    assert torch.equal(model.linear.weight, w0)
    assert report["windows"] == len(s) and report["features_rescaled"] == int(live.sum())
    assert before < 1 / 3 and after > 0.7, (before, after)  # 0.02 -> 0.77 when written
    with pytest.raises(ValueError, match="two windows or more"):
        model.adapt(new[:1])
    tempotron = build(PipelineConfig.from_flat(model="tempotron").model, 12, 1, 3, 500.0)
    with pytest.raises(NotImplementedError, match="no input statistics"):
        tempotron.adapt(new)


def test_a_feature_varying_by_rounding_alone_is_standardised_by_one():
    """Spread at float32 rounding of the feature's magnitude: a constant, scale 1 (dividing by
    it amplifies the summation order's rounding); a spread of 1e-3 of it is kept."""
    from tactilesnn.models.li_readout import varies

    mean = torch.tensor([5.0, 5.0, 5.0, 0.0, 0.0], dtype=torch.float64)
    sd = torch.tensor([1.007e-6, 5e-3, 0.0, 2e-6, 5e-7], dtype=torch.float64)
    assert varies(mean, sd).tolist() == [False, True, False, True, False]
