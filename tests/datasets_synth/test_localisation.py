"""Localisation task on the piezoresistive array: labels match the continuous truth, the seed's
least-squares inverse finds the contact, errors and knobs."""

import numpy as np
import pytest

from tactilesnn.bench import localise
from tactilesnn.datasets_synth import get_task


def test_position_labels_are_the_cell_holding_the_contact():
    t = get_task("localise", seed=2, n_samples=36, cells=3)
    assert len(t.class_names) == 9 and t.fs_hz == 60.0 and t.window == 60
    size = 2 * t.extent_mm / 3
    for i in range(18):
        x, y, info = t.sample(i)
        assert x.shape == (100, 60) and np.isfinite(x).all()
        assert np.all(np.abs(np.array(info["center_mm"]) - t.cell_center_mm(y)) <= size / 2 + 1e-9)


def test_direction_labels_are_the_sector_of_the_tangential_force():
    t = get_task("localise", seed=2, n_samples=16, target="direction")
    assert t.class_names[0] == "E" and len(t.class_names) == 8
    for i in range(16):
        _, y, info = t.sample(i)
        assert localise._angle_error(45.0 * y, info["angle_deg"]) <= 22.5 + 1e-9
        ang = np.degrees(np.arctan2(info["shear_N"][1], info["shear_N"][0]))
        assert localise._angle_error(ang, info["angle_deg"]) < 1e-6


def test_least_squares_finds_the_contact_on_quiet_strong_presses():
    t = get_task("localise", seed=0, n_samples=27, difficulty=0.0, force_lo_N=12.0, force_hi_N=12.0,
                 friction_lo=0.5, friction_hi=0.5)  # fmt: skip
    X = np.stack([t.sample(i)[0] for i in range(27)])
    info = [t.sample(i)[2] for i in range(27)]
    centres, angles = localise.least_squares(X, t.depth_mm)
    err_mm = np.linalg.norm(centres - np.array([i["center_mm"] for i in info]), axis=1)
    err_deg = localise._angle_error(angles, [i["angle_deg"] for i in info])
    # the 12-bit ADC (6.5 kPa per LSB at gain 100) leaves the far chips a few LSB: ~2 mm, ~13 deg
    assert np.median(err_mm) < 3.0 and np.median(err_deg) < 20


def test_bad_settings_are_refused():
    for bad in ({"target": "force"}, {"cells": 1}, {"cells": 9}, {"extent_mm": 30.0},
                {"force_lo_N": 5.0, "force_hi_N": 1.0},
                {"target": "direction", "friction_lo": 0.0}):  # fmt: skip
        with pytest.raises(ValueError):
            get_task("localise", **bad)


@pytest.mark.slow
def test_bench_localise_rows(tmp_path):
    rows = localise.run(tmp_path, n_samples=120, epochs=3, progress=False)
    assert {r["target"] for r in rows} == {"position", "direction"}
    floor = next(r for r in rows if r["target"] == "position" and r["method"].startswith("floor"))
    assert floor["accuracy"] == 1.0 and floor["mean"] < 2 * localise_cell_half_diagonal()
    assert (tmp_path / "localise.md").read_text().count("| position |") == 5
    amp = next(r for r in rows if r["target"] == "position" and "amplitude" in r["method"])
    assert 0 <= amp["accuracy"] <= 1 and amp["median"] >= 0


def localise_cell_half_diagonal():
    t = get_task("localise")
    return np.sqrt(2) * t.extent_mm / t.cells
