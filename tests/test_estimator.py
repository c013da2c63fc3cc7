"""The scikit-learn estimator: clone, cross-validation, grid search, pipelines, probabilities,
and the datasets / encoders as torch-style datasets and transforms."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from sklearn.base import clone
from sklearn.model_selection import GridSearchCV, GroupKFold, cross_val_score
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import FunctionTransformer

from tactilesnn import SpikeClassifier
from tactilesnn.datasets_synth import HookLoopTask, get_task

SMALL = {"seed": 0, "n_planar": 8, "n_concave": 4, "n_convex": 4, "n_test": 4}


@pytest.fixture(scope="session")
def default_task():
    """The default task's windows (hook vs loop, 2 channels at 200 Hz) and their scans."""
    train, test = HookLoopTask(**SMALL).build()
    return train, test


def fast(**kw) -> SpikeClassifier:
    return SpikeClassifier(**{"encoder": "gwt", "model": "readout", "epochs": 4, "fs_hz": 200.0,
                              **kw})  # fmt: skip


@pytest.mark.slow
def test_fit_predict_proba_score_on_the_default_task(default_task):
    train, test = default_task
    clf = fast().fit(train.X, np.asarray(train.class_names)[train.y])
    assert list(clf.classes_) == sorted(train.class_names)
    assert clf.channel_names_ == ("ch0", "ch1") and clf.fs_hz_ == 200.0
    labels = np.asarray(train.class_names)[test.y]
    p = clf.predict_proba(test.X)
    assert p.shape == (len(test.y), 2) and np.allclose(p.sum(1), 1.0)
    np.testing.assert_array_equal(clf.classes_[p.argmax(1)], clf.predict(test.X))
    acc = clf.score(test.X, labels)
    # the pipeline's own scores: the estimator adds nothing of its own to the model
    ref = clf.pipeline_.scores(clf.pipeline_.encode(test.X)).numpy().argmax(1)
    np.testing.assert_array_equal(clf.predict(test.X), clf.classes_[ref])
    assert acc > 0.6, acc  # well above chance (0.5) after 4 epochs of the readout
    assert 0 < clf.temperature_ < np.inf
    # calibration: the mean predicted probability of the predicted class tracks its accuracy
    conf = p.max(1).mean()
    assert abs(conf - acc) < 0.35


def test_clone_params_and_no_fitted_state_in_init():
    clf = fast(model_params={"tau_ms": 50.0})
    c = clone(clf)
    assert c.get_params() == clf.get_params() and c is not clf
    assert c.model_params == {"tau_ms": 50.0} and c.model_params is not clf.model_params
    c.set_params(epochs=2, encoder="stft")
    assert c.epochs == 2 and clf.epochs == 4
    assert not hasattr(c, "classes_")


@pytest.mark.slow
def test_cross_val_score_and_grid_search_on_the_default_task(default_task):
    train, _ = default_task
    # whole scans per fold: windows of one scan never straddle a split
    scores = cross_val_score(fast(), train.X, train.y, groups=train.scan, cv=GroupKFold(3))
    assert scores.shape == (3,) and (scores > 0.5).all(), scores
    search = GridSearchCV(fast(), {"encoder": ["gwt", "stft"]}, cv=GroupKFold(2))
    search.fit(train.X, train.y, groups=train.scan)
    assert search.best_params_["encoder"] in ("gwt", "stft")
    assert search.best_estimator_.pipeline_.config.encoder_type == search.best_params_["encoder"]


@pytest.mark.slow
def test_in_a_sklearn_pipeline_and_with_fit_params(default_task):
    train, test = default_task
    pipe = make_pipeline(FunctionTransformer(lambda x: 1e3 * x), SpikeClassifier(
        encoder="stft", epochs=3))  # fmt: skip
    pipe.fit(train.X, train.y, spikeclassifier__fs_hz=200.0)
    assert pipe.score(test.X, test.y) > 0.5


@pytest.mark.slow
def test_a_window_dataset_fits_directly_and_auto_chooses_an_encoder(default_task):
    train, test = default_task
    clf = SpikeClassifier(epochs=2).fit(train)  # rate, channel and class names from the data
    assert clf.channel_names_ == train.channel_names and set(clf.classes_) == {"hook", "loop"}
    assert set(clf.encoder_selection_["scores"]) == {"cgwt", "stft", "lif"}
    assert clf.predict(test).shape == (len(test),)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda c, X, y: c.fit(X, y), "sampling rate is unknown"),
        (lambda c, X, y: c.fit(X, y[:-1], fs_hz=200), "labels"),
        (lambda c, X, y: c.fit(X, np.zeros_like(y), fs_hz=200), "at least two"),
        (lambda c, X, y: c.fit(X[..., :1], y, fs_hz=200), "at least 2 samples"),
        (lambda c, X, y: c.fit(X[:0], y[:0], fs_hz=200), "0 sample"),
        (lambda c, X, y: c.fit(X, y, fs_hz=float("nan")), "positive finite"),
        (lambda c, X, y: c.fit(np.where(X > 0, np.nan, X), y, fs_hz=200), "contains NaN"),
    ],
)
def test_bad_input_gets_specific_errors(default_task, call, match):
    train, _ = default_task
    with pytest.raises((ValueError, TypeError), match=match):
        call(SpikeClassifier(encoder="gwt", epochs=1), train.X, train.y)


@pytest.mark.slow
def test_predict_checks_shape_and_fit(default_task):
    from sklearn.exceptions import NotFittedError

    train, test = default_task
    with pytest.raises(NotFittedError):
        fast().predict(test.X)
    clf = fast(epochs=1).fit(train.X, train.y)
    with pytest.raises(ValueError, match="2 channels of 100 samples"):
        clf.predict(test.X[:, :1])


@pytest.mark.slow
def test_window_dataset_is_a_torch_dataset_and_encoders_are_transforms(default_task):
    train, _ = default_task
    assert len(train) == len(train.y)
    x, y = train[3]
    assert x.shape == train.X.shape[1:] and y == int(train.y[3])
    clf = fast(epochs=1).fit(train.X, train.y)
    enc = clf.pipeline_.encoder
    ds = train.with_transform(enc.transform)
    spikes, label = ds[3]
    assert label == int(train.y[3])
    np.testing.assert_array_equal(spikes.numpy(), enc.encode(train.X[3:4])[0].numpy())
    loader = torch.utils.data.DataLoader(ds, batch_size=5)
    xb, yb = next(iter(loader))
    assert xb.shape == (5, enc.n_afferents, enc.max_spikes) and yb.tolist() == train.y[:5].tolist()


def test_building_a_model_leaves_the_global_generator_alone():
    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    task = get_task("hook_loop", **SMALL)
    from tactilesnn.config import PipelineConfig
    from tactilesnn.models import MODELS, build_model
    from tactilesnn.pipeline import SpikePipeline

    for model in ("snn", "readout", "tempotron"):
        cfg = PipelineConfig.from_flat(model=model, channels=("all",))
        SpikePipeline(cfg, task.fs_hz, task.window, task.channel_names, ("a", "b"))
    build_model(MODELS.config_class("csnn")(grid="4x4"), 32, 1, 2, 100.0, seed=3)
    assert torch.equal(torch.rand(3), expected)


@pytest.mark.slow
def test_sklearn_check_estimator():
    """scikit-learn's own estimator checks (its 2-D feature tables are one-channel windows of
    their columns). One check is expected to fail, with the reason below; the checks that need
    pandas or the array API are skipped by sklearn itself when those are not installed."""
    from sklearn.utils.estimator_checks import check_estimator

    expected = {
        # float32 scores: a batched BLAS product may differ by one unit in the last place
        # (~1e-7) between batch sizes; predictions are the same
        "check_methods_subset_invariance": "float32 scores differ by 1 ulp between batch sizes",
    }
    # one exact read-out fit per call (choose off): the checks fit ~50 times, and the capacity's
    # cross-validation (15 L-BFGS fits each; tests/models/test_li_readout.py) took 19 of 27 s
    results = check_estimator(
        SpikeClassifier(
            encoder="lif", epochs=15, fs_hz=100.0, clock_afferents=0, model_params={"choose": False}
        ),
        on_fail=None,
        expected_failed_checks=expected,
    )
    failed = {r["check_name"]: str(r["exception"])[:300] for r in results
              if r["status"] == "failed"}  # fmt: skip
    assert not failed, failed
    passed = {r["check_name"] for r in results if r["status"] == "passed"}
    assert len(passed) >= 45 and "check_classifiers_train" in passed


@pytest.mark.slow
def test_windows_that_say_their_rate_and_channels_are_checked_at_predict():
    """A WindowDataset at another rate is refused; its channels in another order are put back
    in the fitted order by name; numpy scalars are rates like any number."""
    from dataclasses import replace

    import pytest

    from tactilesnn import SpikeClassifier
    from tactilesnn.core.data import WindowDataset

    rng = np.random.default_rng(0)
    y = np.arange(24) % 2
    t = np.arange(100) / 100.0
    X = np.stack([np.stack([np.sin(2 * np.pi * (3 + 4 * c) * t + rng.uniform(0, 6)),
                            (1 + c) * np.ones(100)]) for c in y]).astype(np.float32)  # fmt: skip
    data = WindowDataset(X, y, np.arange(24), 100.0, ("a", "b"), ("ch0", "ch1"))
    clf = SpikeClassifier(encoder="lif", model="readout", epochs=2)
    clf.fit(X, y, fs_hz=np.float32(100), channel_names=("ch0", "ch1"))
    assert clf.fs_hz_ == 100.0 and isinstance(clf.fs_hz_, float)
    want = clf.predict(data)
    swapped = replace(data, X=X[:, ::-1].copy(), channel_names=("ch1", "ch0"))
    assert np.array_equal(clf.predict(swapped), want)
    assert clf.score(swapped) == clf.score(data)
    with pytest.raises(ValueError, match="200 Hz, the model at 100 Hz"):
        clf.predict(replace(data, fs_hz=200.0))
    with pytest.raises(ValueError, match="not the model's"):
        clf.predict(replace(data, channel_names=("ch0", "other")))
    # plain arrays say it by keyword: the same checks
    assert np.array_equal(clf.predict(X[:, ::-1], channel_names=["ch1", "ch0"]), want)
    np.testing.assert_allclose(clf.predict_proba(X[:, ::-1], channel_names=["ch1", "ch0"]),
                               clf.predict_proba(X))  # fmt: skip
    assert np.array_equal(clf.predict(X, fs_hz=np.float32(100)), want)
    with pytest.raises(ValueError, match="200 Hz, the model at 100 Hz"):
        clf.predict(X, fs_hz=200)
    with pytest.raises(ValueError, match="not the model's"):
        clf.predict(X, channel_names=["ch0", "other"])


@pytest.mark.slow
@pytest.mark.parametrize("encoder", ["lif", "cgwt"])
def test_the_cli_and_the_estimator_fit_the_same_weights(tmp_path, encoder):
    """One fit path: ``tactilesnn train --data F --encoder E`` and ``SpikeClassifier(encoder=E)``
    on the same training split learn the same weights (cgwt: both also learn every window coded
    with its recording's past)."""
    from tactilesnn.cli import main
    from tactilesnn.recordings import load_data_file

    rng = np.random.default_rng(0)
    n, fs, s = 24, 200.0, 800
    y = np.arange(n) % 2
    t = np.arange(s) / fs
    X = np.sin(
        2 * np.pi * np.where(y == 0, 4.0, 11.0)[:, None, None] * t + rng.uniform(0, 6, (n, 3, 1))
    )
    X = (X + 0.2 * rng.normal(size=(n, 3, s))).astype(np.float32)
    path = tmp_path / "d.npz"
    np.savez(path, X=X, y=y, fs=fs, class_names=np.array(["slow", "fast"]))
    out = tmp_path / "run"
    argv = ["train", "--data", str(path), "--encoder", encoder, "--model", "readout", "--no-export",
            "--quiet", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    cli = dict(np.load(out / "weights.npz", allow_pickle=False))
    train, _ = load_data_file(path)  # the split train --data made (seed 0), cut the same way
    from tactilesnn.recordings import auto_window, cut_windows

    cut = auto_window(path)
    if cut is not None:
        train = cut_windows(train, *cut)
    clf = SpikeClassifier(encoder=encoder, model="readout").fit(train)
    est = clf.pipeline_.weights()
    assert set(cli) == set(est)
    for key in cli:
        np.testing.assert_array_equal(cli[key], est[key], err_msg=key)
