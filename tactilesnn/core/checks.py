"""Input validation shared by every stage: clear, specific errors instead of silent wrong answers."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def as_float_array(x: object, name: str, ndim: int | Sequence[int] | None = None) -> np.ndarray:
    """Return ``x`` as a float ndarray (float32/float64 kept, other real types -> float64).

    Raises TypeError for non-numeric data and ValueError for a wrong number of dimensions.
    """
    arr = np.asarray(x)
    if arr.dtype.kind not in "fiub":
        raise TypeError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if arr.dtype not in (np.float32, np.float64):
        arr = arr.astype(np.float64)
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if arr.ndim not in allowed:
            raise ValueError(
                f"{name} must have {' or '.join(map(str, allowed))} dimensions, "
                f"got shape {arr.shape}"
            )
    return arr


def check_finite(x: np.ndarray, name: str) -> None:
    """Refuse NaN/Inf, naming the index (for ``[..., channels, samples]``: channel and sample)."""
    finite = np.isfinite(x)
    if finite.all():
        return
    idx = tuple(int(i) for i in np.argwhere(~finite)[0])
    value = x[idx]
    if x.ndim >= 2:
        where = f"channel {idx[-2]}, sample {idx[-1]}"
        if x.ndim > 2:
            where = f"batch index {idx[:-2]}, " + where
    else:
        where = f"sample {idx[-1]}"
    raise ValueError(f"{name} contains a non-finite value ({value}) at {where}")


FLOAT32_MAX = float(np.finfo(np.float32).max)


def check_float32_range(x: np.ndarray, name: str) -> None:
    """Refuse values that are finite here but overflow float32 (the precision the encoders and
    the exported graph compute in): ``|x| <= 3.4e38``; rescale such data (other units)."""
    if x.dtype.itemsize <= 4 or x.size == 0:
        return
    big = np.abs(x) > FLOAT32_MAX
    if big.any():
        idx = tuple(int(i) for i in np.argwhere(big)[0])
        raise ValueError(
            f"{name} holds {x[idx]:.3g} at index {idx}, beyond the float32 range "
            f"(|x| <= {FLOAT32_MAX:.3g}) the encoders compute in: express the data in other units"
        )


def memory_limit_bytes() -> int:
    """Physical memory, or the process's address-space limit if that is lower."""
    import os
    import resource

    phys = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    soft = resource.getrlimit(resource.RLIMIT_AS)[0]
    return min(phys, soft) if soft != resource.RLIM_INFINITY else phys


def check_allocation(nbytes: int, what: str, fraction: float = 0.5) -> None:
    """Refuse, before any work, an array that would take more than ``fraction`` of the memory
    this process may use (a clear error instead of an out-of-memory kill halfway through)."""
    limit = fraction * memory_limit_bytes()
    if nbytes > limit:
        raise ValueError(
            f"{what} would need {nbytes / 2**30:.2f} GiB, more than {limit / 2**30:.2f} GiB "
            f"({fraction:.0%} of the memory available); use fewer windows, channels or bands"
        )


#: sampling rates taken (Hz): one sample in ~17 minutes up to 1 GHz; beyond, the timestamps are in
#: other units than they say, or corrupt (steps of 1e300 s gave a rate of 1e-300 Hz)
MIN_RATE_HZ, MAX_RATE_HZ = 1e-3, 1e9


def check_rate(fs_hz: float, where: str) -> float:
    """``fs_hz`` as a float within [:data:`MIN_RATE_HZ`, :data:`MAX_RATE_HZ`], else a
    ValueError naming ``where`` (a file, a flag) and the rate."""
    fs = float(fs_hz)
    if not (math.isfinite(fs) and MIN_RATE_HZ <= fs <= MAX_RATE_HZ):
        raise ValueError(f"{where}: a sampling rate of {fs:g} Hz is outside {MIN_RATE_HZ:g} .. "
                         f"{MAX_RATE_HZ:g} Hz (timestamps in other units than they say?)")  # fmt: skip
    return fs


def check_positive(value: float, name: str) -> float:
    """Return ``value`` as float, or raise ValueError if it is not a finite positive number."""
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")
    return v


def check_choice(value: str, name: str, choices: Sequence[str]) -> str:
    """Raise ValueError listing the valid choices when ``value`` is not one of them."""
    if value not in choices:
        raise ValueError(f"unknown {name} {value!r}; choose one of: {', '.join(choices)}")
    return value


def check_decimation(fs_in_hz: float, fs_out_hz: float) -> int:
    """Integer factor from a simulation rate down to a readout rate, or a ValueError."""
    fs_in = check_positive(fs_in_hz, "fs_in_hz")
    ratio = fs_in / fs_out_hz
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise ValueError(
            f"fs_in_hz ({fs_in_hz}) must be an integer multiple of the readout rate ({fs_out_hz})"
        )
    return round(ratio)


def check_int(value: object, name: str, minimum: int = 1) -> int:
    """Return ``value`` as int if it is an integer >= ``minimum`` (1.7 and True are refused)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value}")
    return int(value)


def check_range(value: object, name: str, lo: float, hi: float) -> float:
    """Return ``value`` as float if finite and in ``[lo, hi]``."""
    if isinstance(value, bool):
        raise ValueError(f"{name} must be a number, got {value!r}")
    v = float(value)  # type: ignore[arg-type]
    if not (np.isfinite(v) and lo <= v <= hi):
        raise ValueError(f"{name} must be a finite number in [{lo}, {hi}], got {value!r}")
    return v


class ExportError(RuntimeError):
    """The exported graph does not reproduce the torch pipeline (nothing is written). Here, not
    in :mod:`tactilesnn.export`, so that the CLI catches it without importing onnx."""


#: the devices :mod:`tactilesnn.core.device` resolves (and ``cuda:N``)
DEVICES = ("auto", "cpu", "cuda")


def check_device_name(name: str) -> str:
    """``name`` if it names a device this module resolves (ValueError otherwise)."""
    base, _, index = str(name).partition(":")
    if base not in DEVICES or (index and (base != "cuda" or not index.isdigit())):
        raise ValueError(f"device must be auto, cpu, cuda or cuda:N, got {name!r}")
    return str(name)
