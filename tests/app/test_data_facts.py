"""A data file's facts (events, grid, auto window) are read once per run, before the run spec
is built, and nothing else in the application layer opens the file for them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import tactilesnn.app.defaults as defaults
import tactilesnn.recordings as recordings
from tactilesnn.app.defaults import run_spec


def _events_file(path: Path) -> Path:
    rng = np.random.default_rng(0)
    X = rng.poisson(0.2, (24, 16, 2, 30)).astype(np.uint8)
    np.savez(path, X=X, y=np.arange(24) % 2, class_names=np.array(["a", "b"]))
    return path


def _analog_file(path: Path) -> Path:
    rng = np.random.default_rng(0)
    np.savez(path, X=rng.standard_normal((8, 3, 4000)).astype(np.float32), y=np.arange(8) % 2,
             fs=np.asarray(100.0))  # fmt: skip
    return path


@pytest.mark.parametrize("make", [_events_file, _analog_file])
def test_the_facts_are_read_once_per_run_spec(tmp_path, monkeypatch, make):
    path = make(tmp_path / "d.npz")
    calls = []
    real = recordings.data_facts

    def counted(p):
        calls.append(p)
        return real(p)

    monkeypatch.setattr(defaults, "data_facts", counted)
    spec = run_spec({"data": str(path)}, tmp_path / "out")
    assert len(calls) == 1
    facts = real(path)
    if facts.events:  # a 4 x 4 grid of taxels: the conv model, its time scale from the window
        assert spec.config.model_type == "csnn" and facts.grid == "4x4"
        assert spec.config.model.dt_ms == 0.0 and not spec.select_encoders
    else:  # 40 s recordings: cut into windows, the encoder chosen among candidates
        assert facts.auto_cut is not None and spec.source.window_s == facts.auto_cut[0]
        assert spec.select_encoders


def test_a_file_the_loader_refuses_has_no_facts_but_no_traceback(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    facts = recordings.data_facts(bad)
    assert not facts.events and facts.auto_cut is None


def test_a_task_is_built_once_and_its_parameters_resolved_once(monkeypatch):
    built, resolved = [], []
    real_get, real_params = defaults.get_task, defaults.task_params

    def get(name, **kw):
        built.append(name)
        return real_get(name, **kw)

    def params(name, settings):
        resolved.append(name)
        return real_params(name, settings)

    monkeypatch.setattr(defaults, "get_task", get)
    monkeypatch.setattr(defaults, "task_params", params)
    spec = run_spec({"task": "localise"}, None)
    assert built == ["localise"] and resolved == ["localise"]
    assert spec.select_encoders  # the wide task's decision, taken once where it was made
