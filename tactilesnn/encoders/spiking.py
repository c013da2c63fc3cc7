"""Direct analog-to-spike converters and spike-train utilities (SPEC 2.2, 3).

Array contract: input ``[batch, channels, samples]`` float at ``fs_hz`` (in the sensor's units);
output :class:`SpikeEvents` (batch, neuron, time in ms, polarity), convertible to a dense
``[batch, neurons, steps]`` raster. Neuron ``c`` is input channel ``c`` for the LIF converter; the
delta / sigma-delta codes have two neurons per channel: ``2c`` (up) and ``2c + 1`` (down).

LIF converter (seed 000's analog-to-spike circuit): ``tau dV/dt = -(V - V_rest) + R I(t)`` with the
input held constant over each sample (zero-order hold, as an ADC delivers it), integrated exactly:
``V(t + s) = V_inf + (V(t) - V_inf) exp(-s / tau)``, ``V_inf = V_rest + R I``. A threshold crossing
inside a sample is located exactly, ``s* = tau ln((V - V_inf) / (theta - V_inf))``, so spike times
are not quantised to the sample grid; after a spike V resets to rest or by subtraction of
``theta - V_rest``, optionally held for a refractory time; several spikes per sample are allowed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._checks import as_float_array, check_choice, check_finite, check_positive

RESETS = ("rest", "subtract")


@dataclass(frozen=True)
class SpikeEvents:
    """Spike events: parallel arrays, times in ms from the start of the input."""

    batch: np.ndarray  # int64 [E]
    neuron: np.ndarray  # int64 [E]
    time_ms: np.ndarray  # float64 [E]
    polarity: np.ndarray  # int8 [E], +1 / -1 (LIF: +1)
    shape: tuple[int, int]  # (batch, neurons)
    duration_ms: float

    def __len__(self) -> int:
        return int(self.time_ms.size)

    def to_dense(self, dt_ms: float) -> np.ndarray:
        """Dense spike counts ``[batch, neurons, steps]`` float32, step = floor(t / dt)."""
        dt = check_positive(dt_ms, "dt_ms")
        steps = max(1, math.ceil(self.duration_ms / dt))
        out = np.zeros((*self.shape, steps), dtype=np.float32)
        idx = np.minimum((self.time_ms / dt).astype(np.int64), steps - 1)
        np.add.at(out, (self.batch, self.neuron, idx), 1.0)
        return out

    def times(self, b: int, n: int) -> np.ndarray:
        """Sorted spike times (ms) of neuron ``n`` in batch item ``b``."""
        m = (self.batch == b) & (self.neuron == n)
        return np.sort(self.time_ms[m])


def _validate(x: np.ndarray, fs_hz: float) -> tuple[np.ndarray, float]:
    arr = as_float_array(x, "x", ndim=3).astype(np.float64)
    check_finite(arr, "x")
    return arr, check_positive(fs_hz, "fs_hz")


def lif_convert(
    x: np.ndarray,
    fs_hz: float,
    tau_ms: float = 10.0,
    threshold: float = 1.0,
    gain: float = 1.0,
    v_rest: float = 0.0,
    reset: str = "rest",
    refractory_ms: float = 0.0,
) -> SpikeEvents:
    """LIF analog-to-spike conversion, exact for piecewise-constant input (see module doc).

    ``gain`` is R (input units -> volts); ``threshold`` and ``v_rest`` in volts.
    """
    arr, fs = _validate(x, fs_hz)
    tau = check_positive(tau_ms, "tau_ms")
    check_choice(reset, "reset", RESETS)
    if threshold <= v_rest:
        raise ValueError(f"threshold ({threshold}) must be above v_rest ({v_rest})")
    if refractory_ms < 0:
        raise ValueError(f"refractory_ms must be >= 0, got {refractory_ms}")
    b, c, n = arr.shape
    dt = 1000.0 / fs
    drive = v_rest + gain * arr.reshape(b * c, n)  # V_inf per sample
    v = np.full(b * c, v_rest)
    refr = np.zeros(b * c)  # refractory time left, ms
    jump = threshold - v_rest if reset == "subtract" else None
    ev_n: list[np.ndarray] = []
    ev_t: list[np.ndarray] = []
    for i in range(n):
        v_inf = drive[:, i]
        rem = np.full(b * c, dt)
        while True:
            # refractory neurons stay at reset for the time they have left
            hold = np.minimum(refr, rem)
            refr -= hold
            rem -= hold
            live = rem > 0
            if not live.any():
                break
            vi, vl = v_inf[live], v[live]
            with np.errstate(divide="ignore", invalid="ignore"):
                s_star = tau * np.log((vl - vi) / (threshold - vi))
            s_star = np.where(vl >= threshold, 0.0, s_star)
            fires = (vi > threshold) | (vl >= threshold)
            fires &= s_star <= rem[live]
            idx = np.flatnonzero(live)
            # neurons that do not fire integrate to the end of the sample
            quiet = idx[~fires]
            v[quiet] = v_inf[quiet] + (v[quiet] - v_inf[quiet]) * np.exp(-rem[quiet] / tau)
            rem[quiet] = 0.0
            spk = idx[fires]
            if spk.size == 0:
                break
            s = s_star[fires]
            ev_n.append(spk)
            ev_t.append(i * dt + (dt - rem[spk]) + s)
            rem[spk] -= s
            if jump is None:
                v[spk] = v_rest
            else:  # by subtraction from the potential at the crossing (theta, or above at s = 0)
                v[spk] = np.maximum(v[spk], threshold) - jump
            refr[spk] = refractory_ms
    neuron = np.concatenate(ev_n) if ev_n else np.zeros(0, np.int64)
    times = np.concatenate(ev_t) if ev_t else np.zeros(0)
    order = np.lexsort((times, neuron))
    neuron, times = neuron[order], times[order]
    return SpikeEvents(
        batch=(neuron // c).astype(np.int64),
        neuron=(neuron % c).astype(np.int64),
        time_ms=times,
        polarity=np.ones(times.size, np.int8),
        shape=(b, c),
        duration_ms=n * dt,
    )


def _updown(arr: np.ndarray, fs: float, step, kind: str) -> SpikeEvents:
    b, c, n = arr.shape
    dt = 1000.0 / fs
    flat = arr.reshape(b * c, n)
    ref = flat[:, 0].copy() if kind == "delta" else np.zeros(b * c)
    rows, times, pol = [], [], []
    for i in range(n):
        if kind == "delta":
            diff = flat[:, i] - ref
        else:  # sigma-delta: integrate the input, emit a quantum of +-step
            ref += flat[:, i]
            diff = ref
        k = np.trunc(diff / step).astype(np.int64)  # whole quanta crossed this sample
        nz = np.flatnonzero(k)
        if nz.size:
            cnt = np.abs(k[nz])
            rows.append(np.repeat(nz, cnt))
            pol.append(np.repeat(np.sign(k[nz]), cnt).astype(np.int8))
            times.append(np.full(cnt.sum(), i * dt))
            if kind == "delta":
                ref[nz] += k[nz] * step
            else:
                ref[nz] -= k[nz] * step
    row = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    p = np.concatenate(pol) if pol else np.zeros(0, np.int8)
    t = np.concatenate(times) if times else np.zeros(0)
    return SpikeEvents(
        batch=row // c,
        neuron=2 * (row % c) + (p < 0),
        time_ms=t,
        polarity=p,
        shape=(b, 2 * c),
        duration_ms=n * dt,
    )


def delta_encode(x: np.ndarray, fs_hz: float, step: float) -> SpikeEvents:
    """Send-on-delta: an up (down) spike each time the input rises (falls) by ``step`` since the
    last spike. ``x[0] + step * (ups - downs)`` tracks the input within ``step``."""
    arr, fs = _validate(x, fs_hz)
    return _updown(arr, fs, check_positive(step, "step"), "delta")


def sigma_delta_encode(x: np.ndarray, fs_hz: float, step: float) -> SpikeEvents:
    """First-order sigma-delta: integrate the input, emit +-``step`` quanta. ``step * (ups -
    downs)`` up to sample n tracks ``sum(x[:n+1])`` within ``step``."""
    arr, fs = _validate(x, fs_hz)
    return _updown(arr, fs, check_positive(step, "step"), "sigma")


def spike_rate(events: SpikeEvents, bin_ms: float, step_ms: float) -> tuple[np.ndarray, np.ndarray]:
    """Sliding-bin firing rate (SPEC 2.2): counts in ``[t - bin, t)`` / bin, in Hz.

    Returns ``(t_ms [T], rate_hz [batch, neurons, T])`` with ``t`` from ``bin_ms`` to the end.
    """
    bin_ = check_positive(bin_ms, "bin_ms")
    step = check_positive(step_ms, "step_ms")
    t = np.arange(bin_, events.duration_ms + 1e-9, step)
    out = np.zeros((*events.shape, t.size))
    for (b, nrn), times in _group(events).items():
        hi = np.searchsorted(times, t, side="left")
        lo = np.searchsorted(times, t - bin_, side="left")
        out[b, nrn] = (hi - lo) / (bin_ / 1000.0)
    return t, out


def _group(events: SpikeEvents) -> dict[tuple[int, int], np.ndarray]:
    order = np.lexsort((events.time_ms, events.neuron, events.batch))
    b, n, t = events.batch[order], events.neuron[order], events.time_ms[order]
    keys = b * events.shape[1] + n
    groups = {}
    if keys.size:
        splits = np.flatnonzero(np.diff(keys)) + 1
        for chunk_k, chunk_t in zip(np.split(keys, splits), np.split(t, splits), strict=True):
            k = int(chunk_k[0])
            groups[(k // events.shape[1], k % events.shape[1])] = chunk_t
    return groups


def contact_onset(x: np.ndarray, fs_hz: float, smooth_ms: float = 5.0) -> np.ndarray:
    """Contact onset per channel (SPEC 2.2): time (ms) of the peak of the first derivative of the
    signal smoothed by a Gaussian of sd ``smooth_ms``. ``x`` ``[batch, channels, samples]`` ->
    ``[batch, channels]``."""
    from scipy.ndimage import gaussian_filter1d

    arr, fs = _validate(x, fs_hz)
    sigma = check_positive(smooth_ms, "smooth_ms") * fs / 1000.0
    deriv = gaussian_filter1d(arr, sigma, axis=-1, order=1, mode="nearest")
    return deriv.argmax(axis=-1) * 1000.0 / fs
