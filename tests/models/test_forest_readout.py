"""The forest read-out: its tree walk against scikit-learn's, its fine-tune, its export."""

import numpy as np
import pytest
import torch

from tactilesnn.app.run import load_run
from tactilesnn.config import PipelineConfig
from tactilesnn.models import ForestConfig, build_model
from tactilesnn.models.forest_readout import PROB_FLOOR
from tests.helpers import run_task


def _domain(rng, proto, per, sd=60.0):
    y = np.repeat(np.arange(proto.shape[0]), per)
    s = proto[y] + rng.normal(0, sd, (y.size, proto.shape[1], 1))
    return torch.from_numpy(np.clip(s, 0, 500)).float(), y


def _fitted(rng, trees=40, confidence=None):
    proto = rng.uniform(50, 450, (3, 12, 1))
    s, y = _domain(rng, proto, 40)
    model = build_model(ForestConfig(trees=trees, leaves=16), 12, 1, 3, 500.0, seed=3)
    model.prepare(s)
    report = model.solve(s, torch.from_numpy(y), confidence=confidence)
    return model, proto, s, y, report


def test_the_tree_walk_gives_scikit_learns_probabilities():
    """The forest's torch walk (gathers, float32 thresholds rounded down) gives the class
    probabilities scikit-learn's own forest gives on the same features, on windows it did not
    see, to float32 rounding of the leaf distributions; the scores are their floored log."""
    from sklearn.ensemble import RandomForestClassifier

    rng = np.random.default_rng(0)
    model, proto, s, y, report = _fitted(rng)
    assert report["fit_windows"] == len(y) and report["train_error"] < 0.2
    # the walk takes the deepest leaf's depth in steps (fewer than the leaves' bound)
    assert model.walk_steps == report["max_depth"] < 15
    ref = RandomForestClassifier(n_estimators=40, max_leaf_nodes=16, min_samples_leaf=2,
                                 random_state=3).fit(model.features(s).numpy(), y,
                                                     sample_weight=np.ones(len(y)))  # fmt: skip
    new, _ = _domain(rng, proto, 30)
    f = model.features(new)
    np.testing.assert_allclose(model.probabilities(new).numpy(),
                               ref.predict_proba(f.numpy()), atol=1e-6)  # fmt: skip
    # on the split thresholds themselves (the float32 rounding's edge): the same branches
    thr = model.node_threshold[model.node_left != torch.arange(31)].unique()
    cols = model.node_feature[model.node_left != torch.arange(31)].unique()
    edge = f[:1].repeat(len(thr), 1)
    edge[:, cols[0]] = thr
    np.testing.assert_allclose(model.leaves_to_proba(edge.numpy()), ref.predict_proba(edge.numpy()),
                               atol=1e-6)  # fmt: skip
    torch.testing.assert_close(model.scores(new), torch.log(model.probabilities(new) + PROB_FLOOR))


def test_soft_targets_of_full_confidence_are_the_labels():
    a = _fitted(np.random.default_rng(1))[0]
    b = _fitted(np.random.default_rng(1), confidence=torch.ones(120))[0]
    torch.testing.assert_close(a.leaf_value, b.leaf_value)
    assert torch.equal(a.node_threshold, b.node_threshold)


def test_finetune_reestimates_the_leaves_towards_the_new_domain():
    """The leaves' distributions re-estimated on a few windows of a domain whose classes 0 and 1
    swapped: the new domain is read better after, the splits are kept, the prior is chosen by
    leaving recordings out (every candidate reported), a prior of many windows keeps the
    pretrained leaves, and wrong shapes are refused."""
    rng = np.random.default_rng(2)
    model, proto, _, _, _ = _fitted(rng)
    new = proto[[1, 0, 2]]
    few, yf = _domain(rng, new, 6)
    test, yt = _domain(rng, new, 30)
    before = float((model.scores(test).argmax(1).numpy() == yt).mean())
    thr0, v0 = model.node_threshold.clone(), model.leaf_value.clone()
    groups = np.arange(len(yf)) % 6
    report = model.finetune(few, torch.from_numpy(yf), groups)
    after = float((model.scores(test).argmax(1).numpy() == yt).mean())
    assert after > before + 0.3, (before, after)
    assert torch.equal(model.node_threshold, thr0)
    assert len(report["cross_validation"]) == 5 and report["loss_after"] < report["loss_before"]
    model.leaf_value.copy_(v0)
    model.finetune(few, torch.from_numpy(yf), groups, factors=(1e9,))
    torch.testing.assert_close(model.leaf_value, v0, atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="one label each"):
        model.finetune(few, torch.from_numpy(yf[:-1]))
    with pytest.raises(ValueError, match="confidence must be"):
        model.finetune(few, torch.from_numpy(yf), confidence=torch.ones(3))


def test_adapt_restandardises_and_keeps_the_trees():
    rng = np.random.default_rng(4)
    model, proto, _, _, _ = _fitted(rng)
    shifted, _ = _domain(rng, proto + 40.0, 10)
    v0 = model.leaf_value.clone()
    report = model.adapt(shifted)
    f = model.features(shifted).double()
    np.testing.assert_allclose(f.mean(0).numpy()[model.feat_scale.numpy() != 1], 0.0, atol=1e-4)
    assert torch.equal(model.leaf_value, v0) and report["windows"] == len(shifted)
    with pytest.raises(ValueError, match="two windows or more"):
        model.adapt(shifted[:1])


def test_settings_are_checked():
    for bad in ({"trees": 0}, {"leaves": 1}, {"min_leaf": 0}, {"n_times": 0}, {"tau_ms": -1.0}):
        with pytest.raises(ValueError):
            ForestConfig(**bad)


def test_forest_trains_saves_and_exports(tmp_path):
    """Trained as any model through a run: saved, loaded back with the same scores, and its
    exported graph (the walk as gathers) scores as torch does."""
    small = {"seed": 0, "n_planar": 10, "n_concave": 5, "n_convex": 5, "n_test": 4}
    cfg = PipelineConfig.from_flat(model="forest", forest_trees=30)
    run, m = run_task("hook_loop", small, cfg, tmp_path / "r", progress=False, export=True)
    assert m["onnx"]["max_score_diff"] <= 1e-4 and m["test_accuracy"] > 0.6
    pipe, _ = load_run(run)
    assert pipe.config.model_type == "forest"
    assert 0 < pipe.model.walk_steps == m["model_fit"]["max_depth"], m.get("model_fit")
    assert torch.equal(pipe.model.leaf_value, pipe.model.leaf_value.clamp(0, 1))


def test_over_the_byte_budget_the_forest_fits_on_a_share_of_the_windows(monkeypatch):
    """Features over :data:`FIT_BUDGET_BYTES`: the fit takes the windows the budget holds (a
    seeded random share, reported), and the forest still reads every window."""
    from tactilesnn.models import forest_readout

    rng = np.random.default_rng(5)
    proto = rng.uniform(50, 450, (3, 12, 1))
    s, y = _domain(rng, proto, 40)
    model = build_model(ForestConfig(trees=20, leaves=8), 12, 1, 3, 500.0, seed=1)
    d = model.feat_mean.numel()
    monkeypatch.setattr(forest_readout, "FIT_BUDGET_BYTES", 4 * d * 50)
    model.prepare(s)
    report = model.solve(s, torch.from_numpy(y))
    assert report["fit_windows"] == 50
    assert (model.scores(s).argmax(1).numpy() == y).mean() > 0.8
