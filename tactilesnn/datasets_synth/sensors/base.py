"""The sensor-model contract and registry.

A sensor model turns a scene's physical input (one of :mod:`..scenes.inputs`, with units in its
field names) into the raw stream a real sensor of its kind would deliver:
:meth:`SensorModel.read_scene` ``(scene, rng) -> [channels, samples]`` at
:meth:`SensorModel.output_rate_hz` samples/s, in :attr:`SensorModel.units`. Every sensor also
keeps its own explicit ``read(...)`` (keyword form of the same computation, used by its tests
and benchmarks). Tasks build the scene and ask the sensor; no sensor reaches into a task.

Adding one: a module in ``sensors/`` with a class satisfying :class:`SensorModel`, decorated
``@register_sensor("name")``, imported in ``sensors/__init__.py``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from ...core.registry import Registry

SENSORS: Registry = Registry("sensor")


def register_sensor(name: str) -> Callable[[type], type]:
    """Class decorator: register a sensor model under ``name``."""
    return SENSORS.register(name)


@runtime_checkable
class SensorModel(Protocol):
    """What tasks, generation and calibration use of a sensor model."""

    #: the output's units (e.g. ``"pC"``, ``"V"``, ``"CDC counts"``)
    units: ClassVar[str]
    #: the :mod:`..scenes.inputs` class :meth:`read_scene` takes
    scene_type: ClassVar[type]

    @property
    def channel_names(self) -> tuple[str, ...]: ...

    def output_rate_hz(self, scene: Any) -> float:
        """Samples per second of :meth:`read_scene`'s output for ``scene``."""
        ...

    def read_scene(self, scene: Any, rng: np.random.Generator | None = None) -> np.ndarray:
        """``scene`` -> ``[len(channel_names), samples]`` in :attr:`units` at
        :meth:`output_rate_hz`; ``rng`` draws the noise (None: noise-free)."""
        ...


class SensorParams:
    """Base of a sensor's parameter dataclass: the fields that are electronic noise."""

    #: the fields :func:`noise_scaled` multiplies (none: a noise-free model)
    NOISE_FIELDS: ClassVar[tuple[str, ...]] = ()


def noise_scaled(params: Any, scale: float) -> Any:
    """Sensor parameters with every electronic-noise field (:attr:`SensorParams.NOISE_FIELDS`)
    multiplied by ``scale``: the one way tasks turn ``difficulty`` into noise."""
    if not np.isfinite(scale) or scale < 0:
        raise ValueError(f"noise scale must be a finite number >= 0, got {scale}")
    if not isinstance(params, SensorParams) or not params.NOISE_FIELDS:
        raise TypeError(f"{type(params).__name__} declares no NOISE_FIELDS")
    fields = params.NOISE_FIELDS
    return dataclasses.replace(params, **{f: getattr(params, f) * scale for f in fields})


def check_scene(sensor: SensorModel, scene: Any) -> None:
    """TypeError unless ``scene`` is the sensor's scene type."""
    if not isinstance(scene, sensor.scene_type):
        raise TypeError(f"{type(sensor).__name__} reads a {sensor.scene_type.__name__}, got "
                        f"{type(scene).__name__}")  # fmt: skip
