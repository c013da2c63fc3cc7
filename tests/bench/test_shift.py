"""``bench shift``: rows hold out whole conditions; the defaults (their encoder chosen by
leaving conditions out), the references and the amplitude-only baseline on the identical split;
the page is generated from the JSON."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tactilesnn.bench import real as bench_real
from tactilesnn.bench import shift


def _file(path):
    rng = np.random.default_rng(0)
    rec = np.repeat(np.arange(24), 2)
    y = rec % 2
    force = (rec // 2) % 3 + 1
    X = (np.array([[3.0, 1.0], [1.0, 3.0]])[y] * force[:, None])[:, :, None]
    X = (X + rng.normal(0, 0.3, (rec.size, 2, 64))).astype(np.float32)
    np.savez(path, X=X, y=y, fs=np.asarray(100.0), recording=rec,
             class_names=np.array(["a", "b"]), group_force=force)  # fmt: skip


@pytest.mark.slow
def test_a_row_holds_out_conditions_and_scores_every_arm_on_one_split(tmp_path, monkeypatch):
    _file(tmp_path / "toy.npz")
    monkeypatch.setattr(shift, "ROWS", {
        "toy": shift.Shift("toy.npz", lambda a: "force>=3", "pressed harder"),
        "doubled": shift.Shift("toy.npz", lambda a: "twice>=6", "derived",
                               lambda a: {"twice": 2 * a["group_force"]}),
        "absent": shift.Shift("none.npz", lambda a: "x=1", "not here"),
    })  # fmt: skip
    monkeypatch.setattr(bench_real, "FOREST_TREES", 20)
    seen = []
    score = bench_real.references

    def spy(train, test, pipe, seed):
        seen.append((set(train.condition("force")), set(test.condition("force"))))
        return score(train, test, pipe, seed)

    monkeypatch.setattr(bench_real, "references", spy)
    res = shift.run(tmp_path / "out", tmp_path)
    assert [r["row"] for r in res["rows"]] == ["toy", "doubled"]  # the absent file skipped
    assert seen == [({1, 2}, {3}), ({1, 2}, {3})]
    row = res["rows"][0]
    assert row["defaults"]["validation"].startswith("whole values of condition force")
    assert shift.AMPLITUDE in row["references"] and "within" in row
    assert json.loads((tmp_path / "out" / "shift.json").read_text())["rows"][0]["row"] == "toy"
    text = shift.page(res["rows"], "cmd", "2 CPUs")
    assert "| toy | pressed harder | `force>=3` |" in text


def test_the_icub_rows_hold_out_one_run_per_letter():
    a = {"y": np.repeat([0, 1, 2, 0, 1, 2, 0, 1, 2], 5), "recording": np.arange(45)}
    assert shift._last_run_per_class(a) == "run=6,7,8"
    assert shift._icub_runs(a)["run"].tolist()[:6] == [0, 0, 0, 0, 0, 1]


def test_a_synthetic_row_renders_training_and_test_at_other_values():
    """Training at each training value (the condition the selection leaves out), testing at
    the held-out value, the rest of the scene as the task draws it."""
    from pathlib import Path

    row = shift.SynthShift("texture", "speed_mm_s", (40.0, 60.0), 100.0, "faster", n_samples=60)
    train, test, spec = row.load(Path("."), 0)
    assert spec == "speed_mm_s=100"
    speeds = train.condition("speed_mm_s")
    assert sorted(set(speeds.tolist())) == [40.0, 60.0]
    assert np.unique(train.scan).size == train.y.size  # one id space across the two renders
    assert test.fs_hz == train.fs_hz and test.channel_names == train.channel_names
    assert train.facts is not None and not train.facts.events  # read as a file of windows
    from tactilesnn.recordings import HOLD_OUT

    assert HOLD_OUT.match(spec).group("name") == "speed_mm_s"
