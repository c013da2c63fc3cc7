"""CMOS piezoresistive chip array against seed 002 / SPEC 2.3."""

import numpy as np
import pytest

from tactilesnn.datasets_synth.piezoresistive import (
    PI11,
    PI12,
    PI44,
    ChipArray,
    ChipArrayParams,
    chip_positions,
    contact_stress,
    locate_contact,
    relative_resistance,
    solve_stress,
)


def test_piezoresistive_equation_special_cases():
    s = 1e6
    # stress along a resistor: pi11; across it: pi12 (seed 002 N-well coefficients)
    assert relative_resistance(s, 0.0, 0.0) == pytest.approx(PI11 * s)
    assert relative_resistance(s, np.pi / 2, 0.0) == pytest.approx(PI12 * s)
    # 45-degree resistor under 45-degree stress: (pi11 + pi12 + pi44) / 2
    got = relative_resistance(s, np.pi / 4, np.pi / 4)
    assert got == pytest.approx((PI11 + PI12 + PI44) / 2 * s)


@pytest.mark.parametrize("sigma", [-50e6, -1e5, 2e5, 80e6])
def test_magnitude_and_direction_are_recovered_within_one_degree(sigma):
    lam = np.deg2rad(np.linspace(-89, 89, 179))
    phis = np.deg2rad([0, 45, 90, 135])
    r = relative_resistance(sigma, lam[:, None], phis[None, :])
    s_hat, l_hat = solve_stress(r)
    np.testing.assert_allclose(s_hat, sigma, rtol=1e-9)
    err = np.rad2deg(np.abs(np.angle(np.exp(2j * (l_hat - lam))) / 2))
    assert err.max() < 1e-6  # noise-free: exact (seed: resolution < 1 degree)


def test_readout_chain_figures():
    p = ChipArrayParams(gain=10.0)
    # ~9 mV/MPa at gain 10 (seed: up to 12 mV/MPa), tens of kPa per LSB (seed: 48 kPa/LSB)
    assert 8.0 < p.sensitivity_mV_per_MPa < 12.0
    assert 40.0 < p.kPa_per_lsb < 80.0
    with pytest.raises(ValueError, match="gain"):
        ChipArrayParams(gain=7.0)


def test_array_geometry_and_one_frame_latency():
    chips = chip_positions()
    assert chips.shape == (25, 2)
    pitch = chips[1, 0] - chips[0, 0]
    assert pitch == pytest.approx(1.46 + 6.0) and 5 * pitch == pytest.approx(37.3)  # seed patch
    arr = ChipArray()
    fs = 600.0
    sig = np.zeros((600, 25))
    sig[300:] = 20e6  # step at 0.5 s
    out = arr.read(sig, np.zeros_like(sig), fs)
    assert out.shape == (25, 4, 60)
    step = np.flatnonzero(out[0, 0] != 0)[0]
    assert step == 31  # sensed in frame 30 (t = 0.5 s), reported one frame later
    s_hat, _ = solve_stress(out[:, :, -1])
    np.testing.assert_allclose(s_hat, 20e6, rtol=0.01)


def test_contact_located_between_four_chips():
    chips = chip_positions()
    center = np.array([3.7, -3.7])  # between four chips, as in seed 002's 8 mm contact test
    sigma, lam = contact_stress(5.0, center, chips)
    r = relative_resistance(sigma[:, None], lam[:, None], np.deg2rad([0, 45, 90, 135])[None])
    s_hat, l_hat = solve_stress(r)
    np.testing.assert_allclose(locate_contact(chips, s_hat, l_hat), center, atol=1e-6)
    # stress falls with distance from the contact
    d = np.linalg.norm(chips - center, axis=1)
    assert sigma[np.argmin(d)] > sigma[np.argmax(d)]


def test_refuses_bad_input():
    arr = ChipArray()
    with pytest.raises(ValueError, match=r"\[samples, 25\]"):
        arr.read(np.zeros((10, 24)), np.zeros((10, 24)), 600.0)
    bad = np.zeros((10, 25))
    bad[3, 7] = np.inf
    with pytest.raises(ValueError, match="non-finite"):
        arr.read(bad, np.zeros((10, 25)), 600.0)
