"""Capacitive triangle module against seed 003 (SPEC 2.4) and closed forms."""

import numpy as np
import pytest

from tactilesnn.datasets_synth.sensors.capacitive_triangle import (
    CapacitiveTriangle,
    CapacitiveTriangleParams,
    ellipse_axes,
    macro_groups,
    pressure_centroid,
    second_moment,
)
from tactilesnn.datasets_synth.sensors.pvdf import EPS0


def test_parallel_plate_and_cdc_range():
    s = CapacitiveTriangle()
    p = s.params
    c0 = p.eps_r * EPS0 * s.pad_area_mm2 * 1e-6 / (p.gap_um * 1e-6) * 1e12 + p.parasitic_pF
    assert s.capacitance_pF(np.zeros(1))[0] == pytest.approx(c0, rel=1e-12)
    full = s.capacitance_pF(np.array([p.strain_max]))[0]
    assert 4.0 < c0 < full < 30.0  # rest and full compression inside the CDC's linear range
    assert s.cdc_code(np.array([3.0, 4.0, 17.0, 30.0, 40.0])).tolist() == [
        0, 0, round(13 / 26 * 65535), 65535, 65535,
    ]  # fmt: skip
    codes = np.arange(0, 65536, 4096)
    assert np.array_equal(s.cdc_code(s.code_to_pF(codes)), codes)


def test_frame_times_of_the_three_modes():
    # seed 003: 12 taxels 9.2 / 18.4 / 36.8 ms, 3 macro-areas 2.3 / 4.6 / 9.2 ms
    for stage, (t12, t3) in enumerate([(9.2, 2.3), (18.4, 4.6), (36.8, 9.2)]):
        prm = CapacitiveTriangleParams(stage=stage)
        assert CapacitiveTriangle(prm, "12").frame_ms == pytest.approx(t12, abs=0.1)
        assert CapacitiveTriangle(prm, "3").frame_ms == pytest.approx(t3, abs=0.1)
        assert CapacitiveTriangle(prm, "1").frame_ms < t3
    assert sorted(np.concatenate(macro_groups("3")).tolist()) == list(range(12))
    assert all(len(g) == 4 for g in macro_groups("3"))


def test_centre_probe_3_high_6_medium_3_small():
    s = CapacitiveTriangle()
    fs = 5000.0
    f = np.r_[np.zeros(250), np.linspace(0, 4, 500), np.full(1000, 4.0)]
    _, code = s.read(f, (0.0, 0.0), 12.0, fs)
    last = code[:, -1]
    high, mid, low = np.sort(last[:3]), np.sort(last[3:9]), np.sort(last[9:])
    assert low.max() < mid.min() and mid.max() < high.min()
    assert np.ptp(high) <= 1 and np.ptp(mid) <= 1 and np.ptp(low) <= 1  # 3-fold symmetry


def test_macro_area_is_sum_of_its_pads_and_hysteresis():
    s12, s3 = CapacitiveTriangle(mode="12"), CapacitiveTriangle(mode="3")
    pr = s12.taxel_pressure_Pa(np.array([3.0]), (2.0, 1.0), 8.0)
    c = s12.capacitance_pF(s12.strain(pr))[:, 0]
    g = macro_groups("3")[0]
    area = c[g].sum() - 3 * s12.params.parasitic_pF
    assert s3.cdc_code(np.array([area]))[0] == s3.cdc_code(np.array([area]))[0]
    # loading and unloading through the same pressure give different strains (play operator)
    p = np.r_[np.linspace(0, 60e3, 50), np.linspace(60e3, 0, 50)][None, :]
    st = s12.strain(p)[0]
    assert st[24] < st[75]
    assert np.max(np.abs(st[24] - st[75])) <= s12.params.hysteresis + 1e-12


def test_centroid_and_ellipse_closed_forms():
    pos = np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    v = np.array([1.0, 1.0, 2.0])
    assert np.allclose(pressure_centroid(v, pos), [0.0, 1.0])
    E = second_moment(v, pos)
    ref = np.cov(pos.T, aweights=v, bias=True)
    assert np.allclose(E, ref)
    axes, ang = ellipse_axes(np.diag([4.0, 1.0]))
    assert np.allclose(axes, [2.0, 1.0]) and abs(np.sin(ang)) < 1e-12
    frames = np.stack([v, 2 * v, np.zeros(3)], 1)  # [channels, frames]
    c = pressure_centroid(frames, pos)
    assert np.allclose(c[:2], [0.0, 1.0]) and np.isnan(c[2]).all()


def test_bad_input():
    with pytest.raises(ValueError, match="unknown mode"):
        CapacitiveTriangle(mode="6")
    with pytest.raises(ValueError, match="too coarse"):
        CapacitiveTriangle().read(np.ones(10), (0, 0), 5.0, 100.0)
    with pytest.raises(ValueError, match="stage"):
        CapacitiveTriangleParams(stage=3)


def test_noise_grows_with_modules_and_falls_with_conversion_time():
    f = np.zeros(20000)

    def noise(**kw):
        s = CapacitiveTriangle(CapacitiveTriangleParams(**kw))
        return s.read(f, (0, 0), 5.0, 10000.0, np.random.default_rng(0))[1].std()

    base = noise()
    assert noise(modules=16) == pytest.approx(4 * base, rel=0.15)
    assert noise(stage=2) == pytest.approx(base / 2, rel=0.15)


def test_hysteresis_steps_only_where_strain_changes_and_equals_every_sample():
    """Time before contact, after release and steady holds are skipped (the play operator is
    idempotent over constant input): bit-identical to stepping every sample, with hysteresis
    memory kept across the skipped spans."""
    sensor = CapacitiveTriangle()
    f = np.zeros(30_000)
    f[2000:12000] = 5 * np.sin(np.linspace(0, np.pi, 10_000))
    f[14000:16000] = 2.0  # a hold
    f[20000:22000] = np.linspace(0, 1, 2000)  # a ramp that stops mid-way, then release
    p = sensor.taxel_pressure_Pa(f, np.array([1.0, -2.0]), 12.0)
    np.testing.assert_array_equal(sensor.strain(p), sensor.strain_every_sample(p))


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["12", "3", "1"])
def test_pads_a_contact_cannot_reach_are_skipped_with_identical_codes(mode):
    """A small probe on one pad leaves the far pads at their rest code (the spread's bound is
    exact through the monotone strain, capacitance and CDC): skipping them changes no code."""
    sensor = CapacitiveTriangle(mode=mode)
    fs = 5000.0
    f = np.zeros(4000)
    f[500:2500] = 3.0 * np.sin(np.linspace(0, np.pi, 2000))
    scenes = [
        (f, sensor.taxels_mm[7] + 0.3, 3.0),  # one corner pad
        (f, np.linspace(sensor.taxels_mm[0], sensor.taxels_mm[4], f.size), 4.0),  # a slide
        (10 * f, np.zeros(2), 24.0),  # a wide, hard press reaches everything
        (np.zeros(4000), np.zeros(2), 5.0),  # no contact: nothing to simulate
    ]
    skipped = []
    for force, centre, diam in scenes:
        got = sensor.read(force, centre, diam, fs, rng=np.random.default_rng(3))
        n_skip = sensor.last_skipped_channels
        ref = sensor.read(force, centre, diam, fs, rng=np.random.default_rng(3), skip=False)
        np.testing.assert_array_equal(got[1], ref[1])
        skipped.append(n_skip)
    assert skipped[2] <= skipped[0] and skipped[3] == sensor.n_channels
    # light touch: far pads stay within one rounding of rest; with a tolerance of 1 LSB more are
    # left out and every code stays within 1 LSB of the full simulation (noise: 4 LSB rms)
    light = 0.1 * f
    exact = sensor.read(light, sensor.taxels_mm[7] + 0.3, 3.0, fs)[1]
    n_exact = sensor.last_skipped_channels
    tol = sensor.read(light, sensor.taxels_mm[7] + 0.3, 3.0, fs, skip_tol_lsb=1.0)[1]
    n_tol = sensor.last_skipped_channels
    full = sensor.read(light, sensor.taxels_mm[7] + 0.3, 3.0, fs, skip=False)[1]
    np.testing.assert_array_equal(exact, full)
    assert np.abs(tol - full).max() <= 1
    if mode == "12":
        assert n_exact >= 1 and n_tol >= n_exact + 3
    with pytest.raises(ValueError, match="skip_tol_lsb"):
        sensor.read(light, np.zeros(2), 3.0, fs, skip_tol_lsb=-1.0)
