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


@pytest.mark.parametrize(
    "encoder, scale, share",
    [("gwt", "rank", False), ("lif", "rank", False), ("gwt", "rank+linear", True),
     ("cgwt", "wide", False)],
)  # traced and scripted encoder graphs; the data defaults' pairs and share; unseen conditions'  # fmt: skip
@pytest.mark.slow
def test_level_code_is_saved_with_the_run_and_exported(tmp_path, encoder, scale, share):
    params = {"seed": 0, "n_planar": 8, "n_concave": 4, "n_convex": 4, "n_test": 3}
    cfg = PipelineConfig.from_flat(encoder=encoder, model="readout", level_neurons=4, epochs=2,
                                   level_scale=scale, level_share=share)  # fmt: skip
    run, _ = run_task("hook_loop", params, cfg, tmp_path / "r", progress=False)
    pipe, _ = load_run(run)
    assert pipe.level is not None and float(pipe.level.knots.abs().sum()) > 0
    assert (pipe.level.scale, pipe.level.share) == (scale, share)
    from tactilesnn.datasets_synth import HookLoopTask

    X = HookLoopTask(**params).build()[1].X
    export_pipeline(pipe, tmp_path / "m.onnx", X[:4])
    sess = PipelineSession(str(tmp_path / "m.onnx"))
    got = sess.run(sess.validate(X))
    ref = pipe.scores(pipe.encode(X)).numpy()
    assert np.array_equal(got.argmax(1), ref.argmax(1)) and np.abs(got - ref).max() <= 1e-4
    assert math.isclose(float(pipe.level.duration_ms), pipe.duration_ms)


def _reference_linear_and_share(code: LevelCode, X: np.ndarray, train: np.ndarray) -> np.ndarray:
    """float64 NumPy: the rank pair, the linear pair (position between the training minimum and
    maximum) of mean, log sd and share (the channel's deviation over the window's total)."""
    x, tr = np.asarray(X, np.float64), np.asarray(train, np.float64)
    centre = np.median(tr.mean(-1), axis=0)
    floor = code.sd_floor.double().numpy()
    typical = (np.median(tr.std(-1), 0) + np.median(np.abs(tr.mean(-1) - centre), 0)).sum()

    def stats(a):
        dev = a.mean(-1) - centre
        share = dev / (np.abs(dev).sum(1, keepdims=True) + typical)
        return np.stack([dev, np.log(a.std(-1) + floor), share], -1)

    s_tr, v = stats(tr), stats(x)
    knots = np.quantile(s_tr, np.linspace(0, 1, code.knots.shape[-1]), axis=0)
    rank = np.empty_like(v)
    for c in range(v.shape[1]):
        for k in range(3):
            rank[:, c, k] = np.interp(v[:, c, k], knots[:, c, k], np.linspace(0, 1, len(knots)))
    lin = np.clip((v - s_tr.min(0)) / (s_tr.max(0) - s_tr.min(0)), 0, 1)
    D = code.duration_ms
    t = np.stack([D * (1 - rank), D * rank, D * (1 - lin), D * lin], -1)
    return t.reshape(len(x), -1)


def test_linear_pair_and_share_match_a_float64_reference():
    train, test = _windows(seed=0), _windows(n=80, seed=1)
    code = LevelCode(3, 2, 250.0, scale="rank+linear", share=True).fit(train)
    assert code.n_afferents == 3 * 3 * 4  # channels x (mean, log sd, share) x two pairs
    got = code(torch.from_numpy(test)).numpy()
    ref = _reference_linear_and_share(code, test, train)
    assert got.shape == ref.shape and np.abs(got - ref).max() < 0.05  # ms of 250
    # the linear pair is proportional to the level: equal steps in level, equal steps in time
    x = np.repeat(train[:1], 5, 0) + np.linspace(-1, 1, 5, dtype=np.float32)[:, None, None] * 20
    t = code(torch.from_numpy(x)).numpy().reshape(5, 3, 3, 4)[:, 1, 0, 2]  # channel 1, mean, ON
    np.testing.assert_allclose(np.diff(t), np.diff(t)[0], rtol=1e-3)  # float32 input at 2e4
    only = LevelCode(3, 3, 250.0, scale="linear").fit(train)  # the pair and one field, linear
    u = only.position_of(only.stats_of(torch.from_numpy(test).double())).numpy()
    t = only(torch.from_numpy(test)).numpy().reshape(80, 3, 2, 3)
    np.testing.assert_allclose(t[..., 1], 250.0 * u, atol=1e-3)


def test_wide_scale_codes_levels_beyond_the_training_range_linearly():
    """``scale="wide"`` (unseen conditions): the position in the training range widened by its
    span each side, against float64 NumPy; a level up to one span above the training maximum
    (a harder press) still moves the spike, where the linear and rank pairs clamp."""
    train = _windows(seed=0)
    wide = LevelCode(3, 2, 300.0, scale="wide").fit(train)
    lin = LevelCode(3, 2, 300.0, scale="linear").fit(train)
    x = np.asarray(train, np.float64)
    mean = x.mean(-1) - np.median(x.mean(-1), axis=0)
    lo, hi = mean.min(0), mean.max(0)
    span = hi - lo
    press = np.repeat(train[:1], 7, 0).astype(np.float64)
    shift = np.linspace(-0.5, 1.5, 7)[:, None] * span[None, :]  # levels from inside to beyond
    press += (shift + hi - press.mean(-1) + np.median(x.mean(-1), axis=0))[..., None]
    level = press.mean(-1) - np.median(x.mean(-1), axis=0)
    want = np.clip((level - (lo - span)) / (3 * span), 0.0, 1.0)
    t = wide(torch.from_numpy(press.astype(np.float32))).numpy().reshape(7, 3, 2, 2)
    # channels 0 and 1 (channel 2's levels differ by thousandths at 20,000: below float32)
    np.testing.assert_allclose(t[:, :2, 0, 1], 300.0 * want[:, :2], atol=0.05)  # OFF = D u, ms
    assert np.all(np.diff(t[:, :2, 0, 1], axis=0)[:5] > 0)  # beyond the maximum: still moving
    clamped = lin(torch.from_numpy(press.astype(np.float32))).numpy().reshape(7, 3, 2, 2)
    assert np.allclose(clamped[2:, :2, 0, 1], 300.0, atol=1e-3)  # the linear pair has clamped


def test_share_is_scale_free_and_finite_at_rest():
    train = _windows(seed=0)
    code = LevelCode(3, 2, 100.0, share=True).fit(train)
    centre = code.centre.numpy()[None, :, None].astype(np.float32)
    press = np.broadcast_to(centre, (3, 3, 50)).astype(np.float64)
    force = np.array([40.0, 400.0, 4000.0])
    press[:, 1] += force[:, None]  # one taxel pressed; the others at their typical level
    v = code.stats_of(torch.from_numpy(press)).numpy()[:, :, 2]
    floor = float(code.share_floor)  # closed form: force / (force + floor), towards 1 at any scale
    np.testing.assert_allclose(v[:, 1], force / (force + floor), atol=1e-5)  # float32 centre
    assert np.abs(v[:, [0, 2]]).max() < 1e-4 and v[2, 1] > 0.95
    rest = np.broadcast_to(centre, (1, 3, 50)).astype(np.float32)
    assert np.isfinite(code(torch.from_numpy(rest)).numpy()).all()


@pytest.mark.parametrize("bad", ["log", "Rank", ""])
def test_unknown_level_scale_is_refused(bad):
    with pytest.raises(ValueError, match="level_scale"):
        PipelineConfig(level_scale=bad)
    with pytest.raises(ValueError, match="level_scale"):
        LevelCode(2, 2, 10.0, scale=bad)


def test_a_run_saved_before_the_linear_pair_and_share_reads_as_it_was_written():
    """Settings and weights without the new fields: the rank pair, no share, neutral floor."""
    d = PipelineConfig.from_flat(encoder="lif", model="readout", level_neurons=2).to_dict()
    for key in ("level_scale", "level_share"):
        del d[key]
    cfg = PipelineConfig.from_dict(d)
    assert (cfg.level_scale, cfg.level_share) == ("rank", False)
    pipe = SpikePipeline(cfg.replace(channels=("all",)), 200.0, 50, ("a", "b", "c"), ("x", "y"))
    X = _windows(n=40)
    pipe.calibrate(X)
    w = {k: v for k, v in pipe.weights().items() if k != "level.share_floor"}
    again = SpikePipeline(cfg.replace(channels=("all",)), 200.0, 50, ("a", "b", "c"), ("x", "y"))
    again.load_weights(w)
    assert torch.equal(again.encode(X), pipe.encode(X))


def test_data_defaults_both_pairs_and_the_share_for_analog_the_rank_pair_for_event_counts():
    from tactilesnn.data_policy import data_file_defaults
    from tactilesnn.recordings import DataFacts

    analog, events = data_file_defaults(DataFacts(False)), data_file_defaults(DataFacts(True))
    assert (analog["level_scale"], analog["level_share"]) == ("rank+linear", True)
    assert (events["level_scale"], events["level_share"]) == ("rank", False)
