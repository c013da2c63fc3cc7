"""Capacitive-piezoelectric stack against seed 001's measured figures (SPEC 2.1)."""

import numpy as np
import pytest

from tactilesnn.datasets_synth.sensors.capacitive_piezo import (
    CapacitivePiezoParams,
    CapacitivePiezoStack,
)


@pytest.fixture(scope="session")
def stack():
    return CapacitivePiezoStack()


def test_capacitive_relative_sensitivity_matches_seed_001(stack):
    # seed 001: 0.25 kPa^-1 below 100 Pa, falling to 0.002 kPa^-1 near 2.5 kPa
    low = stack.relative_sensitivity_per_kPa(np.linspace(0, 100, 21))
    assert 0.2 <= low.mean() <= 0.3
    assert stack.relative_sensitivity_per_kPa(0.0) == pytest.approx(0.25, rel=0.05)
    assert stack.relative_sensitivity_per_kPa(2500.0) == pytest.approx(0.002, rel=0.1)
    # monotone fall: the low-modulus layer saturates
    s = stack.relative_sensitivity_per_kPa(np.linspace(0, 3000, 61))
    assert np.all(np.diff(s) < 0)


def test_series_capacitance_formula_closed_form(stack):
    p = stack.params
    eps0 = 8.8541878128e-12
    c_l = eps0 * p.lme_eps_r * p.area_m2 / (2 * p.lme_thickness_m)
    c_h = eps0 * p.hme_eps_r * p.area_m2 / (2 * p.hme_thickness_m)
    # 1/C_SG = 2 (1/C_LME + 1/C_HME) at zero pressure
    assert stack.capacitance_F(0.0) == pytest.approx(1 / (2 * (1 / c_l + 1 / c_h)), rel=1e-12)


def test_ctmu_readout_inverts_and_fits_adc(stack):
    c = stack.capacitance_F(np.array([0.0, 500.0, 2500.0]))
    code = stack.ctmu_code(c)
    assert np.all((code > 0) & (code < 1023)), "C_SG must sit inside the CTMU's 10-bit range"
    back = stack.capacitance_from_code(code)
    # 10-bit quantisation of dV = I dt / C: relative error below one LSB over dV
    assert np.all(np.abs(back - c) / c < 1.5 / code)


def test_piezo_step_peak_is_2_28_per_kPa(stack):
    fs = 2000.0
    t = np.arange(0, 1, 1 / fs)
    for dp in (10.0, 100.0):
        v = stack.piezo_relative(np.where(t > 0.5, dp, 0.0), fs)
        assert v.max() == pytest.approx(2.28 * dp / 1000, rel=1e-9)
        assert abs(v[-1]) < 0.01 * v.max(), "the piezo channel responds only to change"


def test_mosfet_compresses_only_negative_half(stack):
    x = np.linspace(-1, 1, 201)
    y = stack.mosfet_amplifier(x)
    np.testing.assert_array_equal(y[x >= 0], x[x >= 0])
    assert np.all(np.abs(y[x < 0]) < np.abs(x[x < 0]))


def test_read_contract_baseline_and_rectification(stack):
    fs = 2000.0
    t = np.arange(0, 4, 1 / fs)
    p = np.where(t > 2.5, 1000.0, 0.0) + 20 * np.sin(2 * np.pi * 30 * t) * (t > 3)
    out = stack.read(p, fs, np.random.default_rng(0))
    assert out.shape == (2, 800) and out.dtype == np.float32
    assert abs(out[0, :300].mean()) < 1e-3, "static channel is baseline-corrected"
    assert np.all(out[1] >= 0), "dynamic channel is rectified"
    # static step settles ~300 ms after onset (95 % of final within 3 tau)
    final = out[0, 590:600].mean()
    assert out[0, 500 + 60] > 0.9 * final


def test_read_refuses_bad_input(stack):
    with pytest.raises(ValueError, match="non-finite"):
        stack.read(np.r_[np.zeros(5000), np.nan], 2000.0)
    with pytest.raises(ValueError, match="integer multiple"):
        stack.read(np.zeros(5000), 1234.0)
    with pytest.raises(ValueError, match="too short"):
        stack.read(np.zeros(100), 2000.0)
    with pytest.raises(ValueError, match="dimensions"):
        stack.read(np.zeros((2, 5000)), 2000.0)
    with pytest.raises(ValueError, match="lme_max_strain"):
        CapacitivePiezoParams(lme_max_strain=1.5)
