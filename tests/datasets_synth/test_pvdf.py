"""PVDF triangle against seed 004 / SPEC 2.5: film, Boussinesq, charge amplifier, 5 decades."""

import numpy as np
import pytest

from tactilesnn.datasets_synth.sensors.pvdf import (
    PVDFParams,
    PVDFTriangle,
    boussinesq_t3,
    reconstruct_forces,
)

FS_SIM = 40_000.0


@pytest.fixture(scope="session")
def sensor():
    return PVDFTriangle()


def test_film_capacitance_and_amplifier_corner_match_seed_004(sensor):
    p = sensor.params
    assert p.capacitance_pF == pytest.approx(24.0, rel=0.02)  # seed 004 table 3
    assert p.highpass_hz == pytest.approx(1 / (2 * np.pi * 100e6 * 100e-12), rel=1e-12)


def test_boussinesq_closed_forms():
    h = 2.5
    # peak stress under a point force: 3 F / (2 pi h^2)
    assert boussinesq_t3(1.0, 0.0, h) == pytest.approx(-3 / (2 * np.pi * (h * 1e-3) ** 2))
    # vertical equilibrium: the stress integrates to -F over the sensor plane
    r = np.linspace(0, 400, 400_001)  # mm
    integral = np.trapezoid(boussinesq_t3(1.0, r, h) * 2 * np.pi * r * 1e-3, r * 1e-3)
    assert integral == pytest.approx(-1.0, rel=1e-4)


def test_influence_is_the_quadrature_of_boussinesq(sensor):
    """The in-place influence matrix against the closed form evaluated point by point: each
    taxel's charge per newton is d33 x the mean of T3 over its quadrature x its area."""
    p = sensor.params
    pts = np.random.default_rng(0).uniform(-5, 25, (40, 2))  # mm, over and around the pad
    got = sensor.influence(pts)
    want = np.zeros((12, len(pts)))
    for t, centre in enumerate(sensor.taxels_mm):
        for off in sensor._quad:
            r = np.hypot(*(centre + off - pts).T)
            want[t] += boussinesq_t3(1.0, r, p.cover_mm) * sensor._cell_m2
    np.testing.assert_allclose(got, p.d33_pC_per_N * want, rtol=1e-12, atol=0)


def test_charge_is_d33_times_the_stress_on_the_taxel(sensor):
    # a point force over a taxel centre puts most of its stress on that taxel; all taxels
    # together with the plane outside them share d33 * F
    per_newton = sensor.influence(sensor.taxels_mm[:1])[:, 0]
    assert np.argmax(per_newton) == 0
    assert 0.5 * 20 < per_newton[0] < 20.0  # |d33| = 20 pC/N bounds the charge of one taxel
    assert np.all(per_newton > 0)  # compressive stress, negative d33: positive charge


def test_charge_amplifier_step_response(sensor):
    fs = FS_SIM
    q = np.where(np.arange(4000) >= 1000, 500.0, 0.0)[None]  # 500 pC step (seed: 25 N * 20 pC/N)
    v = sensor.amplify(q, fs, 100.0)[0]
    assert v.min() == pytest.approx(-5.0, rel=0.02)  # V = -q / C_f: the seed's 5 V saturation
    tau = 100e6 * 100e-12
    k = 1000 + int(0.5 * tau * fs)
    assert v[k] == pytest.approx(-5.0 * np.exp(-0.5), rel=0.03)  # R_f C_f decay (high-pass)


def test_five_decades_without_overflow_or_loss_of_the_small_end(sensor):
    t = np.arange(int(0.3 * FS_SIM)) / FS_SIM
    press = (t > 0.1) & (t < 0.2)
    rng = np.random.default_rng(0)
    caress = sensor.read(np.where(press, 0.2, 0.0), sensor.taxels_mm[4], 70.0, FS_SIM, rng)
    noise = sensor.read(np.zeros_like(t), sensor.taxels_mm[4], 70.0, FS_SIM, rng)
    assert np.abs(caress).max() > 5 * noise.std()  # ~50 Pa still stands out of the noise
    peaks = []
    for force in (20.0, 130.0):  # hard pokes up to 5.6 MPa on 5.45 mm
        out = sensor.read(np.where(press, force, 0.0), sensor.taxels_mm[4], 5.45, FS_SIM)
        assert np.isfinite(out).all()
        peaks.append(np.abs(out).max())
    assert peaks[1] / peaks[0] == pytest.approx(130 / 20, rel=0.01)  # still linear: no clipping
    assert peaks[1] > 1000.0  # ~1 nC at the top of the range (SPEC 2.5)


def test_pseudo_inverse_force_reconstruction(sensor):
    c = sensor.influence(sensor.taxels_mm)
    x = np.zeros(12)
    x[[2, 7]] = [1.5, 0.4]
    np.testing.assert_allclose(reconstruct_forces(sensor, c @ x), x, atol=1e-9)
    off_grid = sensor.influence(sensor.taxels_mm[5:6] + np.array([1.0, 0.8]))[:, 0] * 3.0
    est = reconstruct_forces(sensor, off_grid)
    assert np.all(est >= 0) and est.sum() == pytest.approx(3.0, rel=0.15)


def test_refuses_bad_input(sensor):
    with pytest.raises(ValueError, match="non-finite"):
        sensor.read(np.array([0.0, np.nan]), [0, 0], 4.0, FS_SIM)
    with pytest.raises(ValueError, match="integer multiple"):
        sensor.read(np.zeros(10), [0, 0], 4.0, 1000.0)
    with pytest.raises(ValueError, match="lowpass"):
        PVDFParams(fs_hz=1500.0)
