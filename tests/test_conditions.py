"""Conditions in the data (recording run, day, force, speed...): read from ``group_<name>``
arrays or file names, listed by ``convert --dry-run``, held out by ``train --hold-out``, scored
per value, and left out whole by the encoder selection so that it never sees a test condition."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tactilesnn.readers import conditions_from_names
from tactilesnn.recordings import datasets_from_arrays, hold_out_mask


def _arrays(n_rec: int = 12, per: int = 2, seed: int = 0) -> dict[str, np.ndarray]:
    """``n_rec`` recordings of ``per`` windows; class = level pattern; force 1..3 scales it."""
    rng = np.random.default_rng(seed)
    rec = np.repeat(np.arange(n_rec), per)
    y = rec % 2
    force = (rec // 2) % 3 + 1
    X = (np.array([[3.0, 1.0], [1.0, 3.0]])[y] * force[:, None])[:, :, None]
    X = X + rng.normal(0, 0.3, (rec.size, 2, 64))
    return {"X": X.astype(np.float32), "y": y, "fs": np.asarray(100.0), "recording": rec,
            "class_names": np.array(["a", "b"]), "group_force": force,
            "group_day": np.array(["mon", "tue"])[rec % 2 * 0 + (rec >= n_rec // 2)]}  # fmt: skip


def test_conditions_come_from_the_fields_every_file_name_states(tmp_path):
    names = ["Denim_F120_V-10mmps_0.csv", "Denim_F150_V20mmps_1.csv", "Silk_F120_V20mmps_2.csv",
             "Silk_F150_V-10mmps_3.csv"]  # fmt: skip
    files = [tmp_path / n for n in names]
    got = conditions_from_names(files, tmp_path)
    assert sorted(got) == ["F", "V"]
    assert got["F"].tolist() == [120, 150, 120, 150] and got["V"].tolist() == [-10, 20, 20, -10]
    some = conditions_from_names([*files, tmp_path / "Silk_F150_3.csv"], tmp_path)
    assert sorted(some) == ["F"]  # a field only some files state is none
    sub = [tmp_path / "Denim" / "day1" / "r0.csv", tmp_path / "Silk" / "day2" / "r1.csv"]
    assert conditions_from_names(sub, tmp_path)["level1"].tolist() == ["day1", "day2"]


def test_hold_out_tests_on_the_named_conditions_only():
    arrays = _arrays()
    train, test = datasets_from_arrays(arrays, "f.npz", 0, hold_out="force>=3")
    assert set(test.condition("force")) == {3} and set(train.condition("force")) == {1, 2}
    assert not set(train.scan) & set(test.scan)
    _, test2 = datasets_from_arrays(arrays, "f.npz", 0, hold_out="day=tue")
    assert set(test2.condition("day")) == {"tue"}
    _, test3 = datasets_from_arrays(arrays, "f.npz", 0, hold_out="force=1,2")
    assert set(test3.condition("force")) == {1, 2}


@pytest.mark.parametrize(
    ("spec", "change", "message"),
    [
        ("speed>=3", {}, "states no condition 'speed'"),
        ("day>=3", {}, "holds names, not numbers"),
        ("force=7", {}, "no recording has force = 7"),
        ("force>=9", {}, "leaves no test recording"),
        ("force>=0", {}, "leaves no training recording"),
        ("force", {}, "expected NAME=V1,V2"),
        ("force>=3", {"split": "both"}, "gives its own split"),
        ("force>=3", {"group_force": "two per recording"}, "two values"),
    ],
)
def test_a_hold_out_that_cannot_be_made_is_refused_by_name(spec, change, message):
    arrays = _arrays()
    if change.get("split"):
        arrays["split"] = (arrays["recording"] >= 6).astype(np.int64)
    if change.get("group_force"):
        arrays["group_force"] = np.arange(arrays["y"].size)
    with pytest.raises(ValueError, match=message):
        datasets_from_arrays(arrays, "f.npz", 0, hold_out=spec)


def test_the_mask_reads_numbers_and_names_alike():
    groups = np.array([0, 1, 2])
    table = {"F": {0: 120.0, 1: 150.0, 2: 180.0}}
    assert hold_out_mask("F=150", table, groups, "x").tolist() == [False, True, False]
    assert hold_out_mask("F > 120", table, groups, "x").tolist() == [False, True, True]


def _file(path: Path, **extra) -> Path:
    arrays = {**_arrays(n_rec=24, per=2), **extra}
    np.savez(path, **arrays)
    return path


@pytest.mark.slow
def test_a_held_out_run_reports_unseen_conditions_and_the_selection_never_sees_them(
    tmp_path, monkeypatch, capsys
):
    import tactilesnn.app.run as app_run
    from tactilesnn.cli import main

    seen = []
    select = app_run.select_encoder

    def spy(config, train, *a, **kw):
        seen.append((set(train.condition("force")), kw.get("leave_out")))
        return select(config, train, *a, **kw)

    monkeypatch.setattr(app_run, "select_encoder", spy)
    path = _file(tmp_path / "f.npz")
    out = tmp_path / "run"
    assert main(["train", "--data", str(path), "--hold-out", "force>=3", "--out", str(out),
                 "--quiet", "--no-export"]) == 0  # fmt: skip
    assert seen == [({1, 2}, "force>=3")]
    import json

    m = json.loads((out / "metrics.json").read_text())
    assert set(m["by_condition"]["force"]) == {"3"}
    assert m["encoder_selection"]["validation"].startswith("whole values of condition force")
    text = capsys.readouterr().out
    assert "on the held-out conditions (force>=3, none trained on): force=3:" in text
    assert json.loads((out / "config.json").read_text())["data_hold_out"] == "force>=3"
    assert main(["evaluate", str(out), "--quiet"]) == 0  # the run's own split again


@pytest.mark.slow
def test_a_file_without_conditions_runs_as_before(tmp_path, monkeypatch):
    import tactilesnn.app.run as app_run
    from tactilesnn.app.defaults import run_spec

    arrays = _arrays(n_rec=24, per=2)
    for k in ("group_force", "group_day"):
        arrays.pop(k)
    path = tmp_path / "plain.npz"
    np.savez(path, **arrays)
    spec = run_spec({"data": str(path), "epochs": 1}, tmp_path / "r", progress=False)
    assert spec.source.hold_out is None and spec.source.condition_left_out is None
    res = app_run.train_run(spec)
    assert "by_condition" not in res.metrics and "unseen_conditions" not in res.metrics
    assert res.metrics["encoder_selection"]["validation"] == "recordings"


@pytest.mark.slow
def test_a_file_with_conditions_and_no_flag_reports_unseen_condition_accuracy(
    tmp_path, monkeypatch, capsys
):
    """No ``--hold-out``: the run still says how an unseen condition value would go, each value
    left out of a re-fitted read-out in turn, never fitted on the windows it scores."""
    import json

    import tactilesnn.training as training
    from tactilesnn.cli import main

    calls = []
    real = training._left_out_scores

    def spy(model, spikes, y, groups, held):
        calls.append((held.copy(), np.unique(groups[~held]), np.unique(groups[held])))
        return real(model, spikes, y, groups, held)

    monkeypatch.setattr(training, "_left_out_scores", spy)
    path = _file(tmp_path / "f.npz")
    out = tmp_path / "run"
    assert main(["train", "--data", str(path), "--out", str(out), "--quiet",
                 "--no-export"]) == 0  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    un = m["unseen_conditions"]
    assert set(un) == {"day", "force"} and set(un["force"]["per_value"]) == {"1", "2", "3"}
    assert len(calls) == 2 + 3  # day: mon, tue; force: 1, 2, 3 (up to 3 folds of values)
    for held, fitted_on, scored in calls:  # whole recordings: none both fitted on and scored
        assert held.any() and (~held).any() and not set(fitted_on) & set(scored)
    text = capsys.readouterr().out
    assert (
        "unseen values of force (training windows, each scored by a read-out re-fitted "
        f"without its value): {100 * un['force']['accuracy']:.1f} %"
    ) in text


def test_convert_dry_run_lists_the_conditions_and_needs_no_class_names(tmp_path):
    """``convert --dry-run`` names each condition with its recordings per value; a file with
    ``X`` / ``y`` / ``fs`` and no ``class_names`` is described, not a KeyError."""
    from tactilesnn.app.convert import convert

    arrays = _arrays()
    arrays.pop("class_names")
    path = tmp_path / "c.npz"
    np.savez(path, **arrays)
    lines = convert(path, None, dry_run=True).lines()
    assert "  condition force (recordings): 1 (4), 2 (4), 3 (4)" in lines
    assert "  condition day (recordings): mon (6), tue (6)" in lines
    assert any("--hold-out" in line for line in lines)


def test_gain_normalised_windows_against_a_float64_reference():
    from tactilesnn.pipeline import gain_normalised

    rng = np.random.default_rng(3)
    x = rng.normal(0, 1, (4, 3, 50)).astype(np.float32) * np.array([1e-3, 1.0, 1e4, 0.0],
                                                                  np.float32)[:, None, None]  # fmt: skip
    got = gain_normalised(x)
    ref = x.astype(np.float64) / np.abs(x.astype(np.float64)).mean(axis=(1, 2), keepdims=True)
    np.testing.assert_allclose(got[:3], ref[:3], rtol=1e-5)
    assert np.all(got[3] == 0) and np.isfinite(got).all()  # a silent window stays silent
    np.testing.assert_allclose(gain_normalised(7.0 * x[:3]), got[:3], rtol=1e-5)  # scale-free


@pytest.mark.slow
def test_gain_norm_exports_in_the_window_graph_and_is_refused_by_the_stream_graph(tmp_path):
    """``gain_norm`` is a stage of the exported window graph (verified against torch, as every
    stage), also on windows louder than any training one; the stream graph refuses it."""
    import onnxruntime as ort

    from tactilesnn.config import PipelineConfig
    from tactilesnn.export import export_pipeline
    from tactilesnn.export.stream_graph import StreamEncoderGraph
    from tactilesnn.recordings import datasets_from_arrays
    from tactilesnn.training import fit_pipeline

    train, test = datasets_from_arrays(_arrays(n_rec=24, per=2), "f.npz", 0, hold_out="force>=3")
    cfg = PipelineConfig.from_flat(encoder="cgwt", model="readout", channels=("all",),
                                   gain_norm=True, level_neurons=0)  # fmt: skip
    pipe = fit_pipeline(cfg, train, with_past=False).pipeline
    louder = np.concatenate([test.X, 40.0 * test.X])
    report = export_pipeline(pipe, tmp_path / "g.onnx", louder)
    assert report["prediction_agreement"] == 1.0
    got = ort.InferenceSession(str(tmp_path / "g.onnx")).run(["scores"], {"window": louder})[0]
    want = pipe.scores(pipe.encode(louder)).numpy()
    np.testing.assert_allclose(got, want, atol=1e-3, rtol=1e-3)
    np.testing.assert_allclose(want[: len(test.X)], want[len(test.X) :], atol=1e-3)  # scale-free
    with pytest.raises(ValueError, match="gain_norm"):
        StreamEncoderGraph(pipe)


def test_the_selection_tries_each_encoder_for_unseen_conditions_too():
    from tactilesnn.config import PipelineConfig
    from tactilesnn.selection import candidate_configs

    train, _ = datasets_from_arrays(_arrays(), "f.npz", 0, hold_out="force>=3")
    base = PipelineConfig.from_flat(model="readout", channels=("all",), level_neurons=2)
    plain = candidate_configs(base, train, ("cgwt", "lif"))
    shifted = candidate_configs(base, train, ("cgwt", "lif"), shift=True)
    assert list(plain) == ["cgwt", "lif"]
    assert list(shifted) == ["cgwt", "lif", "cgwt+shift", "lif+shift"]
    cg, lif = shifted["cgwt+shift"], shifted["lif+shift"]
    assert cg == plain["cgwt"].replace(gain_norm=True, level_scale="wide",
                                       encoder=replace(plain["cgwt"].encoder, stats=("mean",)),
                                       model=replace(plain["cgwt"].model, n_times=1))  # fmt: skip
    assert lif.encoder == plain["lif"].encoder and lif.gain_norm and lif.model.n_times == 1


def test_the_gain_level_is_the_same_whatever_sums_it():
    """The level is summed in float64 and rounded once, so numpy's order and the graph's (torch
    here, onnxruntime there) give the same float32 windows bit for bit: a last-bit difference
    moved a latency spike by 1.6 ms on FabricSlide's harder presses and failed the export."""
    import torch

    from tactilesnn.pipeline import gain_normalised

    rng = np.random.default_rng(5)
    x = rng.standard_normal((64, 18, 141)) * 10.0 ** rng.uniform(-3, 4, (64, 1, 1))
    x = x.astype(np.float32)
    t = torch.from_numpy(x)
    level = t.double().abs().mean(dim=[1, 2], keepdim=True).float()
    graph = (t / torch.clamp(level, min=float(np.finfo(np.float32).tiny))).numpy()
    np.testing.assert_array_equal(gain_normalised(x), graph)
    shuffled = x[:, :, rng.permutation(x.shape[-1])]  # another summation order, same level
    np.testing.assert_array_equal(
        np.sort(gain_normalised(shuffled), axis=-1), np.sort(gain_normalised(x), axis=-1)
    )


def test_rest_referenced_windows_against_a_float64_reference():
    from tactilesnn.pipeline import rest_referenced

    rng = np.random.default_rng(3)
    x = (rng.normal(size=(4, 3, 50)) + rng.uniform(-1e3, 1e3, size=(4, 3, 1))).astype(np.float32)
    got = rest_referenced(x, 5)
    ref = x.astype(np.float64) - x[..., :5].astype(np.float64).mean(-1, keepdims=True)
    np.testing.assert_allclose(got, ref, atol=1e-3)
    np.testing.assert_allclose(rest_referenced(x + 250.0, 5), got, atol=1e-3)  # offset-free
    assert got.dtype == np.float32


@pytest.mark.slow
def test_rest_ms_exports_in_the_window_graph_and_is_refused_by_the_stream_graph(tmp_path):
    """``rest_ms`` (each channel less its level over the window's first ms) is a stage of the
    exported window graph, verified against torch, also on windows offset beyond any training
    one (the scores do not move); the stream graph refuses it."""
    import onnxruntime as ort

    from tactilesnn.config import PipelineConfig
    from tactilesnn.export import export_pipeline
    from tactilesnn.export.stream_graph import StreamEncoderGraph
    from tactilesnn.recordings import datasets_from_arrays
    from tactilesnn.training import fit_pipeline

    train, test = datasets_from_arrays(_arrays(n_rec=24, per=2), "f.npz", 0, hold_out="force>=3")
    cfg = PipelineConfig.from_flat(encoder="cgwt", model="readout", channels=("all",),
                                   rest_ms=20.0, level_neurons=0)  # fmt: skip
    pipe = fit_pipeline(cfg, train, with_past=False).pipeline
    assert pipe.rest_samples == round(20.0 * train.fs_hz / 1000)
    offset = np.concatenate([test.X, test.X + 5.0 * np.abs(test.X).max()]).astype(np.float32)
    report = export_pipeline(pipe, tmp_path / "g.onnx", offset)
    assert report["prediction_agreement"] == 1.0
    got = ort.InferenceSession(str(tmp_path / "g.onnx")).run(["scores"], {"window": offset})[0]
    want = pipe.scores(pipe.encode(offset)).numpy()
    np.testing.assert_allclose(got, want, atol=1e-3, rtol=1e-3)
    n = len(test.X)
    # offset-free (up to float32 rounding of the offset windows near a latency threshold)
    assert np.mean(want[:n].argmax(1) == want[n:].argmax(1)) >= 0.95
    with pytest.raises(ValueError, match="rest_ms"):
        StreamEncoderGraph(pipe)
    with pytest.raises(ValueError, match="rest_ms must be"):
        cfg.replace(rest_ms=float("nan"))


@pytest.mark.parametrize(
    "spec, side",
    [("force>=3", "high"), ("force>2", "high"), ("force<2", "low"), ("force=4", "high"),
     ("force=0.5,0.7", "low"), ("force=2", None), ("day=tue", None), ("force", None)],
)  # fmt: skip
def test_the_selection_holds_out_the_training_values_nearest_the_test(spec, side):
    """A bound (or a list of numbers all beyond the training values) holds out the training
    values at the same end, so the selection is trained below and validated above as the test
    is; a list of names draws them at random."""
    from tactilesnn.selection import condition_groups
    from tactilesnn.training import split_validation

    arrays = _arrays(n_rec=18)
    train, _ = datasets_from_arrays(arrays, "f.npz", 0)
    name = spec.split("=")[0].split(">")[0].split("<")[0]
    by, validation, got = condition_groups(train, spec)
    assert got == side and np.array_equal(by, train.condition(name))
    fit, val = split_validation(train, 0.25, 0, by=by, side=got)
    if side is not None:
        values = train.condition("force")
        want = values.max() if side == "high" else values.min()
        assert set(val.condition("force")) == {want} and want not in set(fit.condition("force"))
        end = ("highest", "above") if side == "high" else ("lowest", "below")
        assert validation.endswith(f"its {end[0]} held out, as the test's lie {end[1]})")


def test_too_few_training_values_to_measure_a_trend_compare_only_the_variants():
    """Trained at two forces and tested beyond both: leaving one out would rank codes
    calibrated to the training range above those that extrapolate (FabricSlide: cgwt 64.5 %
    vs its variant 43.6 % at the held-out force, 59.2 vs 93.3 % at the test forces), so only
    the variants for unseen conditions are compared, and the report says why."""
    from tactilesnn.config import PipelineConfig
    from tactilesnn.selection import select_encoder

    train, _ = datasets_from_arrays(_arrays(n_rec=24), "f.npz", 0, hold_out="force>=3")
    base = PipelineConfig.from_flat(model="readout", channels=("all",), level_neurons=2)
    config, report = select_encoder(base, train, ("cgwt", "stft"), leave_out="force>=3")
    assert set(report["scores"]) == {"cgwt+shift", "stft+shift"}
    assert config.gain_norm and config.level_scale == "wide" and config.model.n_times == 1
    assert "too few for a held-out one to measure extrapolation" in report["validation"]
    # three training values: every candidate and its variant, the highest value held out
    train3, _ = datasets_from_arrays(_arrays(n_rec=24), "f.npz", 0, hold_out="day=tue")
    _, report3 = select_encoder(base, train3, ("cgwt", "stft"), leave_out="force>=4")
    assert set(report3["scores"]) == {"cgwt", "stft", "cgwt+shift", "stft+shift"}
