"""CMOS piezoresistive chip array against seed 002 / SPEC 2.3."""

import numpy as np
import pytest

from tactilesnn.datasets_synth.sensors.piezoresistive import (
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


def _johnson_in_plane(P, Q, d_m, z_m):
    """Johnson (Contact Mechanics eqs 3.20 and 3.22) at nu = 0.5, written out independently:
    Boussinesq sigma_r = -3 P z r^2 / (2 pi rho^5) (sigma_theta = 0) and Cerruti for Q along x:
    sigma_x = -3 Q x^3, sigma_y = -3 Q x y^2, tau_xy = -3 Q x^2 y (each / 2 pi rho^5); a Q at an
    angle is the x-case in rotated coordinates. Returns the in-plane tensors [n, 2, 2] (Pa)."""
    out = []
    qn = np.linalg.norm(Q)
    rot = np.eye(2) if qn == 0 else np.array([[Q[0], -Q[1]], [Q[1], Q[0]]]) / qn
    for x, y in d_m:
        r2 = x * x + y * y
        rho5 = (r2 + z_m * z_m) ** 2.5
        ang = np.arctan2(y, x)
        radial = np.array([[np.cos(ang) ** 2, np.cos(ang) * np.sin(ang)],
                           [np.cos(ang) * np.sin(ang), np.sin(ang) ** 2]])  # fmt: skip
        t = -3 * P * z_m * r2 / (2 * np.pi * rho5) * radial
        xr, yr = rot.T @ np.array([x, y])  # chip in coordinates where Q is along x
        c = (
            -3
            * qn
            / (2 * np.pi * rho5)
            * np.array([[xr**3, xr * xr * yr], [xr * xr * yr, xr * yr * yr]])
        )
        out.append(t + rot @ c @ rot.T)
    return np.array(out)


def test_normal_and_tangential_stress_match_johnson():
    from tactilesnn.datasets_synth.sensors.piezoresistive import contact_stress

    chips = chip_positions()
    center, P, Q = np.array([2.0, -5.0]), 6.0, np.array([1.5, -2.0])
    sigma, lam = contact_stress(P, center, chips, 1.0, Q)
    ref = _johnson_in_plane(P, Q, (chips - center) * 1e-3, 1e-3)
    u = np.stack([np.cos(lam), np.sin(lam)], 1)
    ours = -sigma[:, None, None] * u[:, :, None] * u[:, None, :]  # compression positive
    np.testing.assert_allclose(ours, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())


def test_least_squares_inverse_recovers_position_and_forces():
    from tactilesnn.datasets_synth.sensors.piezoresistive import contact_stress, solve_contact

    chips = chip_positions()
    center, P, Q = np.array([-4.2, 6.1]), 8.0, np.array([-2.0, 1.0])
    sigma, lam = contact_stress(P, center, chips, 1.0, Q)
    r = relative_resistance(sigma[:, None], lam[:, None], np.deg2rad([0, 45, 90, 135])[None])
    s_hat, l_hat = solve_stress(r)
    c_hat, f_hat = solve_contact(chips, s_hat, l_hat, 1.0)
    np.testing.assert_allclose(c_hat, center, atol=1e-6)
    np.testing.assert_allclose(f_hat, [P, *Q], rtol=1e-6)
