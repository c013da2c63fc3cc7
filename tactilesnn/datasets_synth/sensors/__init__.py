"""Sensor models (each registered in :data:`~.base.SENSORS`; the contract: :mod:`.base`)."""

from __future__ import annotations

from . import (  # noqa: F401  (importing a sensor module registers it)
    capacitive_fingertip,
    capacitive_piezo,
    capacitive_triangle,
    piezoresistive,
    pvdf,
    teng,
)
from .base import SENSORS, SensorModel, SensorParams, noise_scaled, register_sensor

__all__ = ["SENSORS", "SensorModel", "SensorParams", "noise_scaled", "register_sensor"]
