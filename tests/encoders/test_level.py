"""The calibrated level code against float64 NumPy, in a pipeline, exported and reloaded."""

import math

import numpy as np
import pytest
import torch

from tactilesnn.app.run import load_run
from tactilesnn.config import PipelineConfig
from tactilesnn.encoders.level import SILENT_BELOW, LevelCode
from tactilesnn.export import export_pipeline
from tactilesnn.pipeline import SpikePipeline
from tactilesnn.service.runtime import PipelineSession
from tests.helpers import run_task


def _windows(n=300, c=3, w=50, seed=0):
    rng = np.random.default_rng(seed)
    level = rng.normal(0, 1, (n, c, 1)) * np.array([1.0, 100.0, 1e-3])[:c, None] + 20000.0
    return (level + rng.normal(0, 1, (n, c, w)) * rng.uniform(0.1, 10, (n, c, 1))).astype(
        np.float32
    )


def _reference(code: LevelCode, X: np.ndarray, train: np.ndarray) -> np.ndarray:
    """float64 NumPy: empirical CDF by np.interp over the training quantiles, then the fields."""
    x = np.asarray(X, np.float64)
    tr = np.asarray(train, np.float64)
    floor = code.sd_floor.double().numpy()
    stats = lambda a: np.stack([a.mean(-1), np.log(a.std(-1) + floor)], -1)  # noqa: E731
    # (the mean's offset does not change ranks: the reference keeps the raw level)
    knots = np.quantile(stats(tr), np.linspace(0, 1, code.knots.shape[-1]), axis=0)  # [K+1, C, 2]
    v = stats(x)
    u = np.empty_like(v)
    for c in range(v.shape[1]):
        for s in range(2):
            u[:, c, s] = np.interp(v[:, c, s], knots[:, c, s], np.linspace(0, 1, knots.shape[0]))
    D, fields = code.duration_ms, code.neurons - 2
    pair = np.stack([D * (1 - u), D * u], -1)
    centres = np.linspace(0, 1, fields)
    r = np.exp(-0.5 * ((u[..., None] - centres) * (fields - 1)) ** 2)
    t = np.concatenate([pair, np.where(r < SILENT_BELOW, np.inf, D * (1 - r))], -1)
    return t.reshape(len(x), -1)


def test_level_code_matches_a_float64_reference():
    train, test = _windows(seed=0), _windows(n=80, seed=1)
    code = LevelCode(3, 5, 250.0).fit(train)
    got = code(torch.from_numpy(test)).numpy()
    ref = _reference(code, test, train)
    assert got.shape == (80, 3 * 2 * 5) and got.dtype == np.float32  # ON, OFF and 3 fields
    both = np.isfinite(ref) & np.isfinite(got)
    # silence may differ only at the threshold; times agree within float32 rounding of a rank
    assert (np.isfinite(ref) != np.isfinite(got)).mean() < 0.01
    assert np.abs(got[both] - ref[both]).max() < 0.05  # ms of a 250 ms window


def test_on_off_pair_orders_latencies_by_rank_and_fields_fire_near_the_value():
    train = _windows(seed=0)
    code = LevelCode(3, 10, 100.0).fit(train)  # the pair and 8 fields
    t = code(torch.from_numpy(train)).numpy().reshape(len(train), 3, 2, 10)
    assert np.isfinite(t[..., :2]).all()  # the pair always fires
    fired = np.isfinite(t[..., 2:]).sum(-1)
    assert fired.min() >= 3 and fired.max() <= 5  # fields within 2.1 spacings of the value
    # channel 1: the highest mean fires ON first and OFF last, the lowest the reverse
    lo, hi = train[:, 1].mean(-1).argmin(), train[:, 1].mean(-1).argmax()
    assert t[hi, 1, 0, 0] == pytest.approx(0.0, abs=1e-3) and t[hi, 1, 0, 1] == pytest.approx(100.0)
    assert t[lo, 1, 0, 1] == pytest.approx(0.0, abs=1e-3) and t[lo, 1, 0, 2] == pytest.approx(
        0.0, abs=1e-3
    )
    order = np.argsort(train[:, 1].mean(-1))
    assert (np.diff(t[order, 1, 0, 0]) <= 1e-3).all()  # ON: later for lower levels


def test_two_neurons_are_the_pair_alone():
    code = LevelCode(3, 2, 50.0).fit(_windows(seed=0))
    t = code(torch.from_numpy(_windows(n=20, seed=3))).numpy().reshape(20, 3, 2, 2)
    np.testing.assert_allclose(t.sum(-1), 50.0, atol=1e-4)  # ON + OFF = the window


def test_outside_the_training_range_clamps_and_nothing_is_nan():
    train = _windows(seed=0)
    code = LevelCode(3, 4, 100.0).fit(train)
    extreme = np.stack([np.full((3, 50), v, np.float32) for v in (-1e30, 0.0, 1e-30, 3e30)])
    t = code(torch.from_numpy(extreme)).numpy()
    assert not np.isnan(t).any() and np.isfinite(t).any(1).all()
    # a flat window (sd 0) has a finite log sd: the floor
    assert np.isfinite(code.ranks(torch.from_numpy(extreme)).numpy()).all()


def test_a_constant_training_channel_gives_a_step_not_nan():
    train = _windows(seed=0)
    train[:, 0] = 7.0
    code = LevelCode(3, 4, 100.0).fit(train)
    u = code.ranks(torch.from_numpy(train)).numpy()
    assert np.isfinite(u).all() and ((u >= 0) & (u <= 1)).all()


@pytest.mark.parametrize("bad", [1, -1, 65])
def test_level_neurons_out_of_range_is_refused(bad):
    with pytest.raises(ValueError, match="level_neurons"):
        PipelineConfig(level_neurons=bad)


def test_pipeline_appends_the_level_afferents_between_encoder_and_clock():
    cfg = PipelineConfig.from_flat(
        encoder="lif", model="readout", channels=("all",), level_neurons=3
    )
    pipe = SpikePipeline(cfg, 200.0, 50, ("a", "b", "c"), ("x", "y"))
    X = _windows(n=40)
    pipe.calibrate(X)
    s = pipe.encode(X).numpy()
    enc = pipe.encoder.n_afferents
    assert pipe.n_afferents == enc + 3 * 2 * 3 + cfg.clock_afferents
    level = s[:, enc : enc + 18]
    assert np.isinf(level[:, :, 1:]).all()  # one slot each
    assert np.allclose(level[:, :, 0], pipe.level(torch.from_numpy(X)).numpy())


@pytest.mark.parametrize("encoder", ["gwt", "lif"])  # traced and scripted encoder graphs
def test_level_code_is_saved_with_the_run_and_exported(tmp_path, encoder):
    params = {"seed": 0, "n_planar": 8, "n_concave": 4, "n_convex": 4, "n_test": 3}
    cfg = PipelineConfig.from_flat(encoder=encoder, model="readout", level_neurons=4, epochs=2)
    run, _ = run_task("hook_loop", params, cfg, tmp_path / "r", progress=False)
    pipe, _ = load_run(run)
    assert pipe.level is not None and float(pipe.level.knots.abs().sum()) > 0
    from tactilesnn.datasets_synth import HookLoopTask

    X = HookLoopTask(**params).build()[1].X
    export_pipeline(pipe, tmp_path / "m.onnx", X[:4])
    sess = PipelineSession(str(tmp_path / "m.onnx"))
    got = sess.run(sess.validate(X))
    ref = pipe.scores(pipe.encode(X)).numpy()
    assert np.array_equal(got.argmax(1), ref.argmax(1)) and np.abs(got - ref).max() <= 1e-4
    assert math.isclose(float(pipe.level.duration_ms), pipe.duration_ms)
