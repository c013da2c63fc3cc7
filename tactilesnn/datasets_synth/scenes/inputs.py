"""A scene's physical input to a sensor model: what :meth:`SensorModel.read_scene` takes.

Each is a plain record of arrays with units in the field names; the scenes (sliding scans,
indentations, presses) compute them, the sensor models read them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PressureSeries:
    """Contact pressure on one taxel over time: ``pressure_Pa [samples]`` at ``fs_in_hz``."""

    pressure_Pa: np.ndarray
    fs_in_hz: float


@dataclass(frozen=True)
class ContactSeries:
    """A round contact over time: normal force ``force_N [samples]``, centre ``center_mm [2]``
    or ``[samples, 2]`` (mm, sensor frame), diameter ``diameter_mm``, at ``fs_in_hz``."""

    force_N: np.ndarray
    center_mm: np.ndarray
    diameter_mm: float
    fs_in_hz: float


@dataclass(frozen=True)
class StressSeries:
    """In-plane stress at every chip over time: ``sigma_Pa`` and ``lambda_rad`` ``[samples,
    chips]`` (magnitude and direction of the in-plane stress) at ``fs_in_hz``."""

    sigma_Pa: np.ndarray
    lambda_rad: np.ndarray
    fs_in_hz: float


@dataclass(frozen=True)
class GapSeries:
    """An approaching object: ``gap_mm [channels, samples]`` or ``[channels, points, samples]``
    (mm, at the sensor's rate), its ``material``, the charging ``contacts`` before, and the
    share of the pad the skin covers (``skin_share``)."""

    gap_mm: np.ndarray
    material: str
    contacts: int = 0
    skin_share: np.ndarray | float = 1.0


@dataclass(frozen=True)
class FingertipPress:
    """A relief pressed against a fingertip, frame by frame (``fs_frames_hz``): ``force_N
    [frames]``, the bumps' centres ``bumps_mm [frames, k, 2]`` (mm, fingertip frame), their
    height and base diameter (mm), the contact point ``contact_mm [2]``, each taxel's ``gain``
    and ``offset_counts [12]``, and whether the finger is held in position (``position_control``)
    or free to comply."""

    force_N: np.ndarray
    bumps_mm: np.ndarray
    bump_height_mm: float
    bump_diameter_mm: float
    contact_mm: np.ndarray
    gain: np.ndarray
    offset_counts: np.ndarray
    fs_frames_hz: float
    position_control: bool = True
