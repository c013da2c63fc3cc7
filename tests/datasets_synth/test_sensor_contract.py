"""Every registered sensor model satisfies the SensorModel contract: a typed scene in, a raw
stream [channels, samples] in its units at its stated rate out, the same as its explicit read."""

from __future__ import annotations

import numpy as np
import pytest

from tactilesnn.datasets_synth.scenes import inputs
from tactilesnn.datasets_synth.sensors import SENSORS, SensorModel, SensorParams, noise_scaled
from tactilesnn.datasets_synth.sensors.teng import layout

FS_IN = 8000.0


def _scenes(sensor) -> object:
    t = np.arange(int(2.0 * FS_IN)) / FS_IN  # (the piezo stack's baseline takes 1.5 s)
    force = 1.0 * np.sin(np.pi * t / t[-1]) ** 2
    name = sensor.registry_name
    if name == "capacitive_piezo":
        return inputs.PressureSeries(2e4 * force, FS_IN)
    if name in ("pvdf", "capacitive_triangle"):
        return inputs.ContactSeries(force, np.zeros(2), 4.0, FS_IN)
    if name == "piezoresistive":
        sig = 1e5 * force[:, None] * np.ones((1, 25))
        return inputs.StressSeries(sig, np.zeros_like(sig), FS_IN)
    if name == "teng":
        gap = 2.0 - 2.5 * force[None, :: int(FS_IN // sensor.fs_hz)]
        return inputs.GapSeries(np.repeat(gap, len(sensor.channel_names), 0), "kapton")
    if name == "capacitive_fingertip":
        frames = 50
        bumps = np.zeros((frames, 1, 2))
        return inputs.FingertipPress(np.linspace(0.1, 1.0, frames), bumps, 0.6, 1.4, np.zeros(2),
                                     np.ones(12), np.zeros((12, frames)), 93.3)  # fmt: skip
    raise AssertionError(f"a sensor without a test scene: {name}")


def _sensor(name: str):
    cls = SENSORS.get(name)
    return cls(layout("finger8")) if name == "teng" else cls()


@pytest.mark.parametrize("name", SENSORS.names())
def test_a_sensor_reads_its_scene_into_a_stream(name):
    sensor = _sensor(name)
    assert isinstance(sensor, SensorModel) and sensor.units
    scene = _scenes(sensor)
    out = sensor.read_scene(scene, np.random.default_rng(0))
    assert out.ndim == 2 and out.shape[0] == len(sensor.channel_names)
    assert np.isfinite(out).all() and out.shape[1] >= 1
    assert sensor.output_rate_hz(scene) > 0
    again = sensor.read_scene(scene, np.random.default_rng(0))
    np.testing.assert_array_equal(out, again)  # the noise comes from the rng alone


@pytest.mark.parametrize("name", SENSORS.names())
def test_a_sensor_refuses_another_sensor_s_scene(name):
    sensor = _sensor(name)
    wrong = next(t for t in (inputs.PressureSeries, inputs.GapSeries) if t is not sensor.scene_type)
    with pytest.raises(TypeError, match=sensor.scene_type.__name__):
        sensor.read_scene(object.__new__(wrong))


def test_the_scene_form_is_the_explicit_read():
    sensor = _sensor("capacitive_triangle")
    scene = _scenes(sensor)
    _, codes = sensor.read(scene.force_N, scene.center_mm, scene.diameter_mm, FS_IN,
                           np.random.default_rng(1))  # fmt: skip
    np.testing.assert_array_equal(sensor.read_scene(scene, np.random.default_rng(1)), codes)
    assert sensor.output_rate_hz(scene) == pytest.approx(1000.0 / sensor.frame_ms)


def test_noise_scaled_needs_declared_noise_fields():
    from tactilesnn.datasets_synth.sensors.pvdf import PVDFParams

    assert isinstance(PVDFParams(), SensorParams)
    assert noise_scaled(PVDFParams(), 2.0).noise_uV == 2.0 * PVDFParams().noise_uV
    with pytest.raises(TypeError, match="NOISE_FIELDS"):
        noise_scaled(object(), 1.0)
