"""Braille task and the iCub capacitive fingertip: geometry, force balance against closed form,
readout, timing of a dot's passage, knobs and errors."""

import numpy as np
import pytest

from tactilesnn.datasets_synth import get_task
from tactilesnn.datasets_synth.scenes.braille_cell import (
    BRAILLE_DOTS,
    DOT_DIAMETER_MM,
    DOT_HEIGHT_MM,
    cell_dots_mm,
    scaled_dot_diameter_mm,
)
from tactilesnn.datasets_synth.sensors.capacitive_fingertip import (
    CapacitiveFingertip,
    FingertipParams,
    icub_fingertip_layout,
)


def test_cell_geometry():
    assert len(BRAILLE_DOTS) == 26
    a, b, c = (cell_dots_mm(x) for x in "abc")
    assert a.shape == (1, 2)
    # b: dots 1 and 2, one column, 2.34 mm apart across the slide; c: dots 1 and 4, along it
    assert np.allclose(b[0, 0], b[1, 0]) and np.isclose(abs(b[0, 1] - b[1, 1]), 2.34)
    assert np.allclose(c[0, 1], c[1, 1]) and np.isclose(abs(c[0, 0] - c[1, 0]), 2.34)
    full = cell_dots_mm("y")  # 1 3 4 5 6
    assert full.shape == (5, 2) and np.allclose(np.abs(full).max(0), [1.17, 2.34])
    with pytest.raises(ValueError, match="unknown Braille letter"):
        cell_dots_mm("!")
    # a printed cell: its own pitch between columns (along the slide) and between rows
    wide = cell_dots_mm("y", 4.4, 2.6)
    assert np.allclose(wide, full * [4.4 / 2.34, 2.6 / 2.34])
    assert np.isclose(scaled_dot_diameter_mm(2.34), DOT_DIAMETER_MM)
    assert np.isclose(scaled_dot_diameter_mm(4.68, 4.68), 2 * DOT_DIAMETER_MM)


def test_layout():
    xy = icub_fingertip_layout(3.5)
    assert xy.shape == (12, 2) and np.allclose(xy.mean(0), 0)
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1) + 1e9 * np.eye(12)
    assert np.isclose(d.min(), 3.5)  # pads at the pitch, none closer


def _flat(n):
    return np.full((n, 1, 2), 1e3)  # one dot far away: a flat surface


def test_force_balance_matches_the_paraboloid_closed_form():
    """Linear foam (small strain): p = (p_half / s_max) s, so F = k V with V the volume of a
    paraboloid cap below the approach, pi d^2 sqrt(Rx Ry), and k = p_half / (s_max foam)."""
    prm = FingertipParams(grid_mm=0.05)
    tip = CapacitiveFingertip(prm)
    force = np.array([1e-4, 3e-4])  # N: strain << s_max
    grid = tip.contact_grid(np.zeros(2), 0.0)
    relief = tip.relief_mm(grid, _flat(2), DOT_HEIGHT_MM, DOT_DIAMETER_MM)
    delta = tip.approach_mm(force, grid, tip.height_mm(grid, np.zeros(2)), relief)
    k = prm.p_half_Pa / (prm.strain_max * prm.foam_mm * 1e-3)  # Pa per m of compression
    expect = np.sqrt(
        force / (k * np.pi * np.sqrt(prm.radius_along_mm * prm.radius_across_mm) * 1e-3)
    )
    assert np.allclose(delta * 1e-3, expect, rtol=0.03)


def test_force_balance_holds_at_full_force():
    tip = CapacitiveFingertip()
    grid = tip.contact_grid(np.zeros(2), DOT_HEIGHT_MM)
    bumps = np.array([[[0.3, 0.2]]])
    relief = tip.relief_mm(grid, bumps, DOT_HEIGHT_MM, DOT_DIAMETER_MM)
    h = tip.height_mm(grid, np.zeros(2))
    delta = tip.approach_mm(np.array([1.8]), grid, h, relief)
    p = tip.pressure_Pa(tip._strain(delta, h, relief))
    assert np.isclose(p.sum() * (tip.params.grid_mm * 1e-3) ** 2, 1.8, rtol=1e-4)
    assert 0.95 * DOT_HEIGHT_MM < relief.max() <= DOT_HEIGHT_MM
    # the grid reaches past the contact: its rim carries no load
    r = np.linalg.norm(grid / [np.ptp(grid[:, 0]), np.ptp(grid[:, 1])], axis=1)
    assert np.all(p[0, r > 0.9 * r.max()] == 0)


def test_readout_counts():
    tip = CapacitiveFingertip()
    n = 5
    flat = _flat(n)
    args = (DOT_HEIGHT_MM, DOT_DIAMETER_MM, np.zeros(2))
    lo = tip.read(np.full(n, 0.5), flat, *args, np.ones(12), np.zeros(12))
    hi = tip.read(np.full(n, 2.0), flat, *args, np.ones(12), np.zeros(12))
    assert lo.shape == (12, n) and np.all(hi >= lo) and hi.max() > lo.max() > 0
    assert set(np.unique(lo)) <= set(range(256))
    # pads far from the contact read the calibrated rest, 0; an offset lifts them, gain scales
    far = np.linalg.norm(tip.taxels_mm, axis=1) > 5
    assert np.all(lo[far] == 0)
    assert np.all(tip.read(np.full(n, 0.5), flat, *args, np.ones(12), np.full(12, 7.0))[far] == 7)
    g2 = tip.read(np.full(n, 0.5), flat, *args, np.full(12, 2.0), np.zeros(12))
    assert np.all(np.abs(g2 - 2 * lo) <= 1)
    assert np.all(tip.read(np.full(n, 50.0), flat, *args, np.full(12, 9.0), np.zeros(12)) <= 255)
    with pytest.raises(ValueError, match="force_N"):
        tip.read(np.zeros(n), flat, *args, np.ones(12), np.zeros(12))
    with pytest.raises(ValueError, match="bumps_mm"):
        tip.read(np.ones(n), flat[:2], *args, np.ones(12), np.zeros(12))
    with pytest.raises(ValueError, match="gain"):
        tip.read(np.ones(n), flat, *args, np.ones(11), np.zeros(12))


def test_a_dot_peaks_under_the_pad_it_crosses():
    """A dot sliding along x through a pad's row peaks that pad's counts when it is nearest."""
    tip = CapacitiveFingertip()
    pad = 5  # the middle row's pad nearest the contact point
    y = tip.taxels_mm[pad, 1]
    x = np.linspace(-6, 6, 241)
    bumps = np.stack([x, np.full_like(x, y)], 1)[:, None, :]
    c = tip.read(np.full(x.size, 1.8), bumps, DOT_HEIGHT_MM, DOT_DIAMETER_MM, np.zeros(2),
                 np.ones(12), np.zeros(12))  # fmt: skip
    rise = c[pad] - c[pad, 0]
    assert rise.max() >= 10
    peak = x[rise == rise.max()]
    assert abs(peak.mean() - tip.taxels_mm[pad, 0]) < 0.6


@pytest.mark.slow
def test_task_knobs_and_errors():
    t = get_task("braille", seed=1, n_samples=6)
    assert t.class_names == ("a", "b", "c") and t.window == 350 and t.fs_hz == pytest.approx(93.3)
    x, y, info = t.sample(4)
    assert x.shape == (12, 350) and y == 1 and info["class"] == "b"
    assert 0 <= x.min() and x.max() <= 255 and np.array_equal(x, np.round(x))
    # all knobs off: the same letter renders the same every time (no noise, no spread)
    ideal = get_task("braille", seed=1, n_samples=6, difficulty=0.0)
    assert np.array_equal(ideal.sample(0)[0], ideal.sample(3)[0])
    assert not np.array_equal(ideal.sample(0)[0], ideal.sample(1)[0])  # a differs from b
    assert not np.array_equal(t.sample(0)[0], t.sample(3)[0])
    z = get_task("braille", letters="xyz", n_samples=6)
    assert z.class_names == ("x", "y", "z")
    for bad in ({"letters": "a"}, {"letters": "aa"}, {"letters": "a!"}, {"gain_spread": -1},
                {"force_spread": 1.0}, {"force_N": 0.0}):  # fmt: skip
        with pytest.raises(ValueError):
            get_task("braille", **bad)


@pytest.mark.slow
def test_letters_are_separable_without_noise():
    """Idealised slides: each letter's mean over taxels differs from the others (a sanity check
    that the dots reach the pads at the default force)."""
    t = get_task("braille", seed=0, n_samples=6, difficulty=0.0)
    xs = [t.sample(i)[0] for i in range(3)]
    for i in range(3):
        for j in range(i + 1, 3):
            assert np.abs(xs[i] - xs[j]).max() >= 5


def test_position_control_raises_the_force_over_a_dot_force_control_holds_it():
    tip = CapacitiveFingertip()
    x = np.linspace(-10, 10, 81)
    bumps = np.stack([x, np.zeros_like(x)], 1)[:, None, :]
    args = (np.full(x.size, 1.5), bumps, DOT_HEIGHT_MM, DOT_DIAMETER_MM, np.zeros(2),
            np.ones(12), np.zeros(12))  # fmt: skip
    held = tip.read(*args, position_control=True)
    rise = tip.last_force_N
    assert np.isclose(rise[0], 1.5, rtol=1e-3) and rise.max() > 1.6  # the dot adds load
    free = tip.read(*args, position_control=False)
    assert np.allclose(tip.last_force_N, 1.5, rtol=1e-3)
    pad = 5
    assert held[pad].max() > free[pad].max()  # at a set height the dot presses harder


@pytest.mark.parametrize("spread", [0.0, 1.0, 3.3])
def test_relief_is_the_dots_shape_at_every_frame_and_point(spread):
    """The relief evaluated only where a dot is within reach equals the shape evaluated at
    every frame and point (a spherical cap, or the cover's raised-cosine drape; the higher of
    overlapping dots), bit for bit."""
    tip = CapacitiveFingertip(FingertipParams(cover_spread_mm=spread))
    rng = np.random.default_rng(1)
    pts = rng.uniform(-6, 6, (200, 2))
    track = np.stack([np.linspace(-30, 30, 300), rng.normal(0, 1, 300)], 1)
    bumps = track[:, None] + rng.uniform(-3, 3, (1, 4, 2))
    h, a = DOT_HEIGHT_MM, DOT_DIAMETER_MM / 2
    r = np.sqrt(((pts[None, None] - bumps[:, :, None]) ** 2).sum(-1))  # [frames, k, P]
    if spread > 0:
        z = h * np.cos(0.5 * np.pi * np.minimum(r / (a + spread), 1.0)) ** 2
    else:
        radius = (a * a + h * h) / (2 * h)
        z = np.maximum(np.sqrt(np.maximum(radius**2 - r**2, 0.0)) - (radius - h), 0.0)
    want = np.maximum(z.max(1), 0.0)
    got = tip.relief_mm(pts, bumps, h, 2 * a)
    assert got.shape == want.shape and np.allclose(got, want, rtol=0, atol=1e-15)
    assert (got > 1e-9).any(1).sum() < 0.5 * len(track)  # most frames: no dot within reach


def check_class_signal(task) -> None:
    """The letter's own signal: zero where the cell is out of reach, and the slide unchanged."""
    for i in range(3):
        x, _, info = task.sample(i)
        x2, _, info2 = task.sample(i, class_signal=True)
        np.testing.assert_array_equal(x, x2)  # the draw is not disturbed
        assert "class_signal" not in info
        sig = info2["class_signal"]
        assert sig.shape == (x.shape[-1],) and sig.dtype == np.float32 and (sig >= 0).all()
        n = sig.size
        # the cell passes the fingertip mid-slide: nothing at the ends, most in the middle half
        assert sig[: n // 10].max() == 0 and sig[-(n // 10) :].max() == 0
        assert sig[n // 4 : 3 * n // 4].sum() > 0.8 * sig.sum() > 0


def test_the_class_signal_is_the_letters_response_and_leaves_the_slide_as_it_was():
    check_class_signal(get_task("braille", seed=2, n_samples=6))
