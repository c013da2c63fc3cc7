"""Taxel geometry: positions placed on a grid, the csnn on an irregular shuffled layout."""

import json

import numpy as np
import pytest

from tactilesnn.cli import main
from tactilesnn.core.layout import check_taxel_xy, place_on_grid


def test_a_shuffled_subset_of_a_grid_is_placed_back_on_its_cells():
    rng = np.random.default_rng(0)
    keep = rng.choice(100, 40, replace=False)  # 40 of a 10 x 10 array, shuffled, 2.5 mm pitch
    rows, cols = np.divmod(keep, 10)
    xy = np.stack([cols * 2.5, rows * 2.5], 1) + rng.normal(0, 0.2, (40, 2))  # jitter 0.2 mm
    r, c, cells = place_on_grid(xy)
    # the grid spans the kept taxels' rows and columns; each taxel in its own cell of the array
    assert (r, c) == (rows.max() - rows.min() + 1, cols.max() - cols.min() + 1)
    np.testing.assert_array_equal(cells, (rows - rows.min()) * c + (cols - cols.min()))


def test_a_triangle_layout_gets_distinct_cells_that_keep_neighbours_near():
    # a hexagonal patch: rows offset by half a pitch (not a grid)
    pts = [(x + 0.5 * (y % 2), y * np.sqrt(3) / 2) for y in range(4) for x in range(4)]
    xy = np.array(pts) * 4.0
    r, c, cells = place_on_grid(xy)
    assert len(set(cells.tolist())) == 16 and r * c <= 40
    rc = np.stack(np.divmod(cells, c), 1)
    d_mm = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    d_cell = np.abs(rc[:, None] - rc[None]).max(-1)
    assert (d_cell[(d_mm > 0) & (d_mm < 4.1)] <= 2).all()  # touching taxels stay adjacent


@pytest.mark.parametrize("bad, match", [(np.zeros((3, 3)), r"\[3 taxels, 2\]"),
                                        (np.array([[0, 0], [0, 0], [1, 1]]), "share a position"),
                                        (np.array([[0, 0], [np.nan, 0], [1, 1]]), "NaN")])  # fmt: skip
def test_bad_positions_are_refused(bad, match):
    with pytest.raises(ValueError, match=match):
        check_taxel_xy(bad, 3)


def test_positions_in_the_wrong_units_are_refused():
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [1e6, 0.0]])
    with pytest.raises(ValueError, match="positions in mm"):
        place_on_grid(xy)


def _irregular_event_file(path, n=90, seed=0):
    """12 taxels scattered irregularly (shuffled order, positions given); class c touches the
    taxels near corner c of the patch."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 20, (12, 2))
    y = np.arange(n) % 3
    corners = np.array([[0, 0], [20, 0], [10, 20]])
    X = (rng.random((n, 12, 2, 40)) < 0.03).astype(np.uint8)
    for i, c in enumerate(y):
        near = np.argsort(np.linalg.norm(xy - corners[c], axis=1))[:3]
        X[i, near, 0, 5:30:3] = 1
    np.savez(path, X=X, y=y, bin_ms=5.0, class_names=np.array(["a", "b", "c"]), taxel_xy=xy)


@pytest.mark.slow
def test_an_event_file_with_positions_trains_the_conv_model_on_its_placement(tmp_path):
    _irregular_event_file(tmp_path / "ev.npz")
    out = tmp_path / "r"
    assert main(["train", "--data", str(tmp_path / "ev.npz"), "--out", str(out), "--epochs", "15",
                 "--quiet"]) == 0  # fmt: skip
    cfg = json.loads((out / "config.json").read_text())["pipeline"]
    m = json.loads((out / "metrics.json").read_text())
    assert cfg["model"]["type"] == "csnn" and len(cfg["model"]["cells"]) == 12
    assert m["test_accuracy"] >= 0.8 and m["onnx"]["model_max_score_diff"] <= 1e-4


def test_positions_that_do_not_match_the_taxels_are_a_clear_error(tmp_path, capsys):
    _irregular_event_file(tmp_path / "ev.npz")
    z = dict(np.load(tmp_path / "ev.npz"))
    z["taxel_xy"] = z["taxel_xy"][:5]
    np.savez(tmp_path / "bad.npz", **z)
    args = ["train", "--data", str(tmp_path / "bad.npz"), "--out", str(tmp_path / "r"), "--quiet"]
    assert main(args) != 0
    assert "taxel_xy must be [12 taxels, 2]" in capsys.readouterr().err
    assert not (tmp_path / "r").exists() and not (tmp_path / "r.partial").exists()


def test_the_sensor_models_own_layouts_place_on_distinct_cells():
    from tactilesnn.datasets_synth.sensors.capacitive_triangle import CapacitiveTriangle

    xy = CapacitiveTriangle().taxels_mm  # the iCub triangle's 12 pads
    r, c, cells = place_on_grid(xy)
    assert len(set(cells.tolist())) == len(xy) == 12 and r * c < 4 * len(xy)
