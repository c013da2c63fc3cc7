"""Settings are resolved once, the same way from every entry point: ``tactilesnn train --data``
(:func:`~tactilesnn.app.defaults.run_spec`), ``SpikeClassifier`` and ``bench real`` give the
identical pipeline configuration, encoder candidates and fitted-field set for each kind of data,
and one run reads the data's facts once and calls the data policy once."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import tactilesnn.resolve as resolve_module
from tactilesnn import SpikeClassifier
from tactilesnn.app.defaults import run_spec
from tactilesnn.bench.real import default_config
from tactilesnn.core.data import DataFacts
from tactilesnn.datasets_synth import get_task
from tactilesnn.recordings import load_data_file
from tactilesnn.resolve import resolve


def _analog(path: Path) -> Path:
    rng = np.random.default_rng(0)
    np.savez(path, X=rng.standard_normal((12, 3, 300)).astype(np.float32), y=np.arange(12) % 2,
             fs=np.asarray(100.0), class_names=np.array(["a", "b"]))  # fmt: skip
    return path


def _csv_folder(path: Path) -> Path:
    rng = np.random.default_rng(1)
    for c in ("press", "slide"):
        (path / c).mkdir(parents=True)
        for r in range(4):
            t = np.arange(200) * 5.0
            rows = np.column_stack([t, rng.standard_normal((200, 2))])
            np.savetxt(path / c / f"r{r}.csv", rows, delimiter=",", header="time_ms,a,b",
                       comments="")  # fmt: skip
    return path


def _events(path: Path, taxels: int) -> Path:
    rng = np.random.default_rng(2)
    X = rng.poisson(0.3, (16, taxels, 2, 25)).astype(np.uint8)
    np.savez(path, X=X, y=np.arange(16) % 2, bin_ms=np.asarray(2.0),
             class_names=np.array(["a", "b"]))  # fmt: skip
    return path


def _task_file(path: Path) -> Path:
    """A synthetic task's windows as a file (the task's own rate, channels and classes)."""
    train, _ = get_task("hook_loop", n_planar=6, n_test=3, seed=0).build()
    np.savez(path, X=train.X, y=train.y, fs=np.asarray(train.fs_hz),
             class_names=np.array(train.class_names),
             channel_names=np.array(train.channel_names))  # fmt: skip
    return path


KINDS = {
    "npz analog": lambda d: _analog(d / "a.npz"),
    "CSV folder": lambda d: _csv_folder(d / "slides"),
    "events on a grid": lambda d: _events(d / "g.npz", 16),
    "events without a grid": lambda d: _events(d / "l.npz", 7),
    "a synthetic task": lambda d: _task_file(d / "t.npz"),
}


@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("model", [None, "readout"])
def test_every_entry_point_resolves_the_same_run(tmp_path, kind, model):
    path = KINDS[kind](tmp_path)
    settings = {"data": str(path), **({"model": model} if model else {})}
    spec = run_spec(settings, tmp_path / "out")
    train, _ = load_data_file(path, window_s=spec.source.window_s, hop_s=spec.source.hop_s,
                              fs_hz=spec.source.fs_hz)  # fmt: skip
    clf = SpikeClassifier(**({"model": model} if model else {}))
    got = clf._config(train)
    assert (got.config, got.select, got.keep) == (
        spec.config,
        spec.select_encoders,
        spec.fit_encoder_keep,
    )
    if model:  # bench real's pipelines name their model
        events = spec.config.encoder_type == "events"
        assert default_config(events, None, model, 0, facts=train.facts) == spec.config


def test_event_counts_given_to_the_estimator_resolve_as_the_file_does(tmp_path):
    """``SpikeClassifier().fit`` on ``[N, taxels, polarity, bins]`` counts codes them with the
    ``events`` encoder and, on a square of taxels, the conv model, as ``train --data`` does."""
    path = _events(tmp_path / "g.npz", 16)
    spec = run_spec({"data": str(path)}, tmp_path / "out")
    f = np.load(path)
    clf = SpikeClassifier(fs_hz=500.0)
    data, _ = clf._dataset(f["X"], f["y"], None, None, None)
    assert clf._config(data).config == spec.config
    assert spec.config.encoder_type == "events" and spec.config.model_type == "csnn"


def test_a_default_belongs_to_its_component():
    """The csnn's epochs and schedule on a grid file go with the csnn only: another model on
    the same file keeps its own (the flat dict once kept them for ``--model snn``)."""
    grid = DataFacts(True, "4x4")
    csnn = resolve({}, facts=grid).config
    assert csnn.model_type == "csnn" and csnn.train.epochs == 12
    assert csnn.train.lr_schedule == "cosine" and csnn.level_neurons == 0
    snn = resolve({"model": "snn"}, facts=grid).config
    assert snn.train.epochs == 40 and snn.train.lr_schedule == "constant"
    assert snn.level_neurons == 2
    assert resolve({"model": "csnn", "epochs": 3}, facts=grid).config.train.epochs == 3
    toml = resolve({}, {"train": {"epochs": 5}}, facts=grid).config  # a file's [train] wins
    assert toml.train.epochs == 5


def test_one_run_reads_the_facts_once_and_calls_the_policy_once(tmp_path, monkeypatch):
    import tactilesnn.app.defaults as defaults
    import tactilesnn.recordings as recordings

    path = _events(tmp_path / "g.npz", 16)
    calls = {"facts": 0, "policy": 0, "component": 0}
    real_facts = recordings.data_facts
    real_policy, real_component = resolve_module.data_file_defaults, resolve_module.model_defaults

    def facts(p):
        calls["facts"] += 1
        return real_facts(p)

    def policy(f):
        calls["policy"] += 1
        return real_policy(f)

    def component(f, m):
        calls["component"] += 1
        return real_component(f, m)

    monkeypatch.setattr(defaults, "data_facts", facts)
    monkeypatch.setattr(resolve_module, "data_file_defaults", policy)
    monkeypatch.setattr(resolve_module, "model_defaults", component)
    run_spec({"data": str(path), "epochs": 2}, tmp_path / "out")
    assert calls == {"facts": 1, "policy": 1, "component": 1}


def test_a_flag_that_needs_no_data_is_refused_before_the_file_is_opened(tmp_path, monkeypatch):
    import tactilesnn.app.defaults as defaults

    def never(p):
        raise AssertionError("the file was opened")

    monkeypatch.setattr(defaults, "data_facts", never)
    with pytest.raises(ValueError, match="--data-hop-s needs a window length"):
        run_spec({"data": str(tmp_path / "x.npz"), "data_window_s": 0, "data_hop_s": 1.0}, None)


def test_component_settings_by_field_name_are_checked():
    with pytest.raises(ValueError, match="has no setting"):
        resolve({"encoder": "lif"}, facts=DataFacts(False), fields={"encoder": {"nope": 1}})
    res = resolve({"encoder": "lif"}, facts=DataFacts(False), fields={"encoder": {"neurons": 4}})
    assert res.config.encoder.neurons == 4 and res.keep == ("neurons",) and not res.select
