"""``bench fit``: stand-ins of the stated shapes, a run timed in its own process with its own
peak memory, the references on the identical split, and the table."""

import json

import numpy as np
import pytest

from tactilesnn.bench import fit, standins


def test_stand_ins_have_the_stated_shapes(tmp_path) -> None:
    ev = np.load(standins.events(tmp_path / "ev.npz", n=40))
    assert ev["X"].shape == (40, 39, 2, 325) and float(ev["bin_ms"]) == 20.0
    assert 0.03 < (ev["X"] > 0).mean() < 0.2  # sparse, as real event files are
    el = np.load(standins.electrode(tmp_path / "el.npz", n=20))
    assert el["X"].shape == (20, 22, 600) and el["X"].dtype == np.float32 and float(el["fs"]) == 100
    vib = np.load(standins.vibration(tmp_path / "vib.npz", n=10))
    assert vib["X"].shape == (10, 1, 13200) and float(vib["fs"]) == 2200
    folder = standins.slide_csv(tmp_path / "slides", n=8)
    files = sorted(folder.glob("*.csv"))
    assert len(files) == 8 and files[0].read_text().startswith("timestamp,ch1,")
    gl = np.load(standins.glove(tmp_path / "gl.npz"))
    assert gl["X"].shape == (560, 5, 50) and float(gl["fs"]) == 10.0
    assert np.unique(gl["y"]).size == 28 and np.bincount(gl["y"]).min() == 20
    assert gl["X"].max() < 10.5 and np.isfinite(gl["X"]).all()  # a resistor saturates below 10
    # deterministic from the seed
    again = np.load(standins.events(tmp_path / "ev2.npz", n=40))
    assert np.array_equal(again["X"], ev["X"])


@pytest.mark.slow
def test_a_run_is_timed_in_its_own_process_against_references(tmp_path) -> None:
    path = standins.events(tmp_path / "ev.npz", n=60)
    quiet = fit.run_train(path, tmp_path / "run")
    assert quiet["returncode"] == 0, quiet["output_tail"]
    m = quiet["metrics"]
    assert m["stage_seconds"]["fit"] > 0 and "export" in m["stage_seconds"]
    assert quiet["peak_rss_bytes"] > 50e6 and quiet["seconds"] > sum(m["stage_seconds"].values())
    log = (tmp_path / "run.log").read_text()
    assert "\r" not in log  # a piped log: stage lines, no bar redraws
    refs = fit.references(path)
    assert set(refs) == {"logreg_logspec", "rf_summary", "rf_time_slices"}
    assert all(0 <= r["accuracy"] <= 1 and r["seconds"] > 0 for r in refs.values())
    r = fit.row("events", quiet, None, refs)
    best = max(refs.values(), key=lambda v: v["accuracy"])
    assert r["reference"]["accuracy"] == best["accuracy"]
    assert r["time_ratio_to_reference"] == quiet["seconds"] / best["seconds"]
    line = fit.table([r]).splitlines()[-1]
    assert line.startswith("| events |") and f"{100 * m['test_accuracy']:.2f} %" in line
    json.dumps(r)  # the row is what fit.json holds


def test_the_docs_page_is_the_table_its_json_gives() -> None:
    from pathlib import Path

    docs = Path(__file__).resolve().parents[2] / "docs"
    result = json.loads((docs / "fit.json").read_text())
    text = (docs / "fit.md").read_text()
    assert text == fit.page(result["rows"], result["command"], result["machine"])
    assert {r["set"] for r in result["rows"]} >= {"fabric_slide", "braille_icub_abc"}
