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
import torch
from torch import Tensor

from ..core.checks import as_float_array, check_choice, check_finite, check_positive

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


def lif_hold_substep(v: Tensor, v_inf: Tensor, rem: Tensor, tau_ms: float, theta: float):
    """Advance LIF neurons inside a sample held at ``v_inf`` with ``rem`` ms of it left.

    Returns ``(fires, s, relaxed)``: ``fires`` marks neurons that reach ``theta`` within ``rem``
    (at once if already there), ``s`` the exact time to that crossing (ms; ``inf`` where none),
    ``relaxed`` the potential at the end of the sample for neurons that do not fire. The one
    definition of the converter's arithmetic (used by :func:`lif_convert`, the LIF-population
    encoder and its exported graph).
    """
    above = v >= theta
    ratio = (v - v_inf) / (theta - v_inf)
    s = torch.where(above, torch.zeros_like(v), tau_ms * torch.log(ratio.clamp_min(1e-30)))
    fires = (above | (v_inf > theta)) & (s <= rem) & (rem > 0)
    relaxed = v_inf + (v - v_inf) * torch.exp(-rem / tau_ms)
    return fires, torch.where(fires, s, torch.full_like(s, math.inf)), relaxed


def hold_constants(v_inf: Tensor, tau_ms: float) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """What :func:`lif_hold_sample` needs of a held drive ``v_inf`` alone, not of the potential:
    ``(above, safe, safe_m1, isi)``: whether it exceeds threshold 1, the drive where it does (2
    where not: a finite stand-in), ``safe - 1`` and the interval between its periodic spikes
    (ms). Separate so that a graph computes them for every sample at once, outside its loop."""
    above = v_inf > 1.0
    safe = torch.where(above, v_inf, torch.full_like(v_inf, 2.0))
    safe_m1 = safe - 1.0
    return above, safe, safe_m1, tau_ms * torch.log1p(1.0 / safe_m1)


def lif_hold_sample(v: Tensor, v_inf: Tensor, dt_ms: float, tau_ms: float):
    """Every crossing of threshold 1 in one sample held at ``v_inf``, for converters that reset
    by subtraction from ``v < 1``, in closed form: a held drive above threshold fires
    periodically after the first crossing.

    Returns ``(n, s1, isi, v_end)``: spikes in the sample (float, whole numbers), the first at
    ``s1`` ms into it, then one every ``isi`` ms (``tau ln(v_inf / (v_inf - 1))``, since the
    subtraction at threshold restarts from 0); ``v_end`` the potential at the sample's end.
    Same crossings as :func:`lif_hold_substep` repeated, without a loop per crossing.
    """
    consts = hold_constants(v_inf, tau_ms)
    n, s1, v_end = lif_hold_from(v, v_inf, *consts, dt_ms, tau_ms)
    return n, s1, consts[3], v_end


def lif_hold_from(
    v: Tensor, v_inf: Tensor, above: Tensor, safe: Tensor, safe_m1: Tensor, isi: Tensor,
    dt_ms: float, tau_ms: float,
) -> tuple[Tensor, Tensor, Tensor]:  # fmt: skip
    """:func:`lif_hold_sample` given the drive's :func:`hold_constants`: ``(n, s1, v_end)``,
    the only part that depends on the potential ``v`` (a graph's loop body)."""
    s1 = tau_ms * torch.log((safe - v) / safe_m1)
    fires = above & (s1 <= dt_ms)
    # (a scalar fill, a swapped difference and the whole intervals reused where they fire,
    # rather than zeros_like, a negation and n - 1: the same values, three nodes fewer per
    # sample in the exported loops; t_last is only read where the converter fires)
    whole = torch.floor((dt_ms - s1) / isi)  # periodic spikes after the first
    n = torch.where(fires, whole + 1.0, 0.0)
    t_last = s1 + whole * isi
    v_fired = safe * (1.0 - torch.exp((t_last - dt_ms) / tau_ms))  # no expm1 in ONNX
    v_quiet = v_inf + (v - v_inf) * math.exp(-dt_ms / tau_ms)
    return n, s1, torch.where(fires, v_fired, v_quiet)


def first_spikes_start(
    drive: Tensor, k: int, every: Tensor | None, gain: Tensor | None
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """The converters' start for :func:`lif_first_spikes` on ``drive [N, C, samples]``: ``(gain
    [P] (ones(1) when None), potential [N, A], counts [N, A], kept times [N, A, k] (inf),
    wanted [1, A, k])`` with ``A = C * P``; slot ``j`` keeps the converter's spike number
    ``(j + 1) every[a]``."""
    dev = drive.device
    g = (torch.ones(1, dtype=drive.dtype, device=dev) if gain is None
         else gain.to(device=dev, dtype=drive.dtype))  # fmt: skip
    n, a = drive.shape[0], drive.shape[1] * g.shape[0]
    m = (torch.ones(1, a, dtype=drive.dtype, device=dev) if every is None
         else every.to(device=dev, dtype=drive.dtype).view(1, a))  # fmt: skip
    wanted = (torch.arange(k, dtype=drive.dtype, device=dev).view(1, 1, -1) + 1.0) * m.unsqueeze(-1)
    v = torch.zeros(n, a, dtype=drive.dtype, device=dev)
    count = torch.zeros(n, a, dtype=drive.dtype, device=dev)
    times = torch.full((n, a, k), math.inf, dtype=drive.dtype, device=dev)
    return g, v, count, times, wanted


def lif_first_spikes(
    drive: Tensor,
    dt_ms: float,
    tau_ms: float,
    k: int,
    every: Tensor | None = None,
    gain: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """Spike times ``[N, A, k]`` (ms; inf = none) and spike counts ``[N, A]`` of LIF
    converters (threshold 1, rest 0, reset by subtraction) driven by ``drive [N, A, samples]``
    held over each sample (:func:`lif_hold_sample`: every crossing counted exactly, so the
    cost per sample does not grow with the firing rate).

    ``every`` ``[A]`` (whole numbers >= 1, default 1): converter ``a`` keeps every
    ``every[a]``-th spike (the ``every``-th, ``2 every``-th, ...), a prescaler, so ``k`` slots
    cover a long window instead of its first spikes.

    ``gain`` ``[P]``: ``drive`` is ``[N, C, samples]`` and feeds ``P`` converters per channel,
    afferent ``c * P + j`` seeing ``drive[:, c] * gain[j]`` (``A = C * P``); the product is formed
    one sample at a time, so memory stays that of the channels, not of the afferents.
    """
    g, v, count, times, wanted = first_spikes_start(drive, k, every, gain)
    w = drive.shape[2]
    for i in range(w):
        v, count, times = first_spikes_step(
            v, count, times, drive[:, :, i], i * dt_ms, g, wanted, dt_ms, tau_ms
        )
    return times, count


def lif_first_spikes_sparse(
    drive: Tensor,
    dt_ms: float,
    tau_ms: float,
    k: int,
    every: Tensor | None = None,
    gain: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """:func:`lif_first_spikes` with the kept spike times (:func:`kept_spike_times`) updated
    only for the converters that fire in each sample: a few in a hundred, where the ``[N, A,
    k]`` slot arithmetic of every converter at every sample was most of the encoder's time. The
    same arithmetic element by element, so the same times and counts bit for bit; eager only
    (its row selection has no graph form: the exported graphs run :func:`first_spikes_step`)."""
    g, v, count, times, wanted = first_spikes_start(drive, k, every, gain)
    w = drive.shape[2]
    n, a = v.shape
    flat_times, flat_wanted = times.view(n * a, k), wanted.expand(n, a, k).reshape(n * a, k)
    for i in range(w):
        fired, s1, isi, v = lif_hold_sample(v, _drive_of(drive[:, :, i], g), dt_ms, tau_ms)
        at = torch.nonzero(fired.view(-1)).squeeze(1)
        if at.numel():
            flat_times[at] = kept_spike_times(
                flat_times[at], count.view(-1)[at], fired.view(-1)[at], s1.view(-1)[at],
                isi.view(-1)[at], flat_wanted[at], i * dt_ms,
            )  # fmt: skip
        count = count + fired
    return times, count


def _drive_of(drive_i: Tensor, gain: Tensor) -> Tensor:
    """The converters' drive ``[N, C * P]`` from the channels' ``drive_i [N, C]``."""
    return (drive_i.unsqueeze(-1) * gain).flatten(1)


def kept_spike_times(
    times: Tensor, count: Tensor, fired: Tensor, s1: Tensor, isi: Tensor, wanted: Tensor,
    t0_ms: float,
) -> Tensor:  # fmt: skip
    """The kept spike times ``[..., k]`` after a sample from ``t0_ms`` in which converters with
    ``count`` spikes so far fire ``fired`` more, the first at ``s1`` ms, one every ``isi`` ms
    (:func:`lif_hold_sample`): slot ``j`` takes the spike numbered ``wanted[..., j]`` if it falls
    in this sample."""
    j = wanted - count.unsqueeze(-1)  # position of each slot's spike within this sample
    hit = (j >= 1.0) & (j <= fired.unsqueeze(-1))
    t_abs = t0_ms + s1.unsqueeze(-1) + (j - 1.0) * isi.unsqueeze(-1)
    return torch.where(hit, t_abs, times)


def first_spikes_step(
    v: Tensor,
    count: Tensor,
    times: Tensor,
    drive_i: Tensor,
    t0_ms: float,
    gain: Tensor,
    wanted: Tensor,
    dt_ms: float,
    tau_ms: float,
) -> tuple[Tensor, Tensor, Tensor]:
    """One sample of :func:`lif_first_spikes`: ``drive_i [N, C]`` held from ``t0_ms``; returns the
    converters' potential, spike counts and kept spike times after it."""
    fired, s1, isi, v = lif_hold_sample(v, _drive_of(drive_i, gain), dt_ms, tau_ms)
    times = kept_spike_times(times, count, fired, s1, isi, wanted, t0_ms)
    return v, count + fired, times


def lif_first_spikes_op(
    drive: Tensor, dt_ms: float, tau_ms: float, k: int, every: Tensor, gain: Tensor,
    slots_in_loop: bool = False,
) -> tuple[Tensor, Tensor]:  # fmt: skip
    """:func:`lif_first_spikes` with its sample loop as one scan operator (``torch.export``
    writes an ONNX ``Scan``; not scriptable), the same arithmetic bit for bit: the drive's
    :func:`hold_constants` for every sample at once, only :func:`lif_hold_from` (the potential's
    recurrence) in the loop, which hands out each sample's spike count and first spike time,
    and the kept slots read from those afterwards (:func:`slots_from_samples`). Updating the
    ``k`` slots of every converter at every sample inside the loop, as the eager step does, made
    the exported graph 2-3x slower in onnxruntime (docs/benchmarks.md); the price is about 14
    eight-byte values per afferent and sample held at once
    (:meth:`.LIFPopulationEncoder.graph_bytes_per_window`). ``slots_in_loop`` keeps the eager
    step's form (:func:`first_spikes_step`: memory of the slots alone), for windows long enough
    that the samples' values would not fit."""
    from torch._higher_order_ops.scan import scan

    g, v, count, times, wanted = first_spikes_start(drive, k, every, gain)
    if slots_in_loop:
        t0 = torch.arange(drive.shape[2], dtype=drive.dtype, device=drive.device) * dt_ms

        def slot_step(carry, x):
            v, count, times = first_spikes_step(*carry, x[0], x[1], g, wanted, dt_ms, tau_ms)
            return (v, count, times), v.new_zeros(1)  # (a scan must give an output per step)

        (_, count, times), _ = scan(slot_step, (v, count, times), (drive.permute(2, 0, 1), t0))
        return times, count
    v_inf = (drive.permute(2, 0, 1).unsqueeze(-1) * g).flatten(2)  # [W, N, A], as _drive_of
    consts = hold_constants(v_inf, tau_ms)

    def step(v, x):
        n, s1, v = lif_hold_from(v, *x, dt_ms, tau_ms)
        return v, (n, s1)

    _, (n, s1) = scan(step, v, (v_inf, *consts))
    return slots_from_samples(n, s1, consts[3], wanted, dt_ms)


def slots_from_samples(
    n: Tensor, s1: Tensor, isi: Tensor, wanted: Tensor, dt_ms: float
) -> tuple[Tensor, Tensor]:
    """Kept spike times ``[N, A, k]`` and counts ``[N, A]`` from each sample's spike count
    ``n``, first spike time ``s1`` (ms into the sample) and interval ``isi`` (each ``[samples,
    N, A]``, :func:`lif_hold_sample`): slot ``j`` holds spike number ``wanted[..., j] = (j + 1)
    every`` (``[1, A, k]``), which falls in the first sample whose running count reaches it, at
    the time :func:`kept_spike_times` gives it there (the same operations, so the same bits);
    inf where the window ends before it. Which sample fills each slot comes from a histogram of
    the slots filled by each sample's end (a scatter-add and a running sum), so the work is
    ``O(samples + k)`` per converter: a comparison over the samples per slot made ``k = 32``
    slower than the loop it replaced."""
    w, k = n.shape[0], wanted.shape[-1]
    cum = torch.cumsum(n, 0)  # spikes up to and including each sample: whole numbers, exact
    before = cum - n
    filled = torch.floor(cum / wanted[..., 0]).clamp(max=k).to(torch.int64)  # [W, N, A]
    hist = torch.zeros((k + 1, *n.shape[1:]), dtype=torch.int64, device=n.device)
    at = torch.cumsum(hist.scatter_add(0, filled, torch.ones_like(filled)), 0)[:k]  # [k, N, A]
    i = at.clamp(max=w - 1)
    want = wanted.permute(2, 0, 1)  # [k, 1, A]
    t = (at.to(n.dtype) * dt_ms + s1.gather(0, i)
         + (want - before.gather(0, i) - 1.0) * isi.gather(0, i))  # fmt: skip
    return torch.where(at < w, t, math.inf).permute(1, 2, 0), cum[-1]


def lif_rate_bound(
    drive: np.ndarray, dt_ms: float, tau_ms: float, theta: float, refractory_ms: float = 0.0
) -> float:
    """Upper bound on the spikes one LIF converter emits in one sample for ``drive`` (volts
    above rest, held ``dt_ms``): from rest a constant drive ``v > theta`` needs ``tau ln(v /
    (v - theta))`` ms per spike plus the refractory time; a potential carried over adds at
    most one spike."""
    v = float(np.max(drive, initial=-np.inf))
    if not v > theta:
        return 1.0
    return dt_ms / (tau_ms * math.log1p(theta / (v - theta)) + refractory_ms) + 1.0


def _check_rate_bound(drive: np.ndarray, dt: float, tau: float, theta: float,
                      refractory_ms: float, max_spikes_per_sample: int) -> None:  # fmt: skip
    """Refuse (ValueError) a drive (V) that could fire more than ``max_spikes_per_sample``
    times in one ``dt`` ms sample (:func:`lif_rate_bound`), before any work."""
    bound = lif_rate_bound(drive, dt, tau, theta, refractory_ms)
    if bound > max_spikes_per_sample:
        raise ValueError(
            f"this input could make a LIF converter fire {bound:.3g} times in one "
            f"{dt:.3g} ms sample (> max_spikes_per_sample={max_spikes_per_sample}): the drive "
            f"reaches {float(drive.max()):.3g} V against a {theta:.3g} V threshold; "
            "lower the gain, raise the threshold, or raise max_spikes_per_sample"
        )


def lif_convert(
    x: np.ndarray,
    fs_hz: float,
    tau_ms: float = 10.0,
    threshold: float = 1.0,
    gain: float = 1.0,
    v_rest: float = 0.0,
    reset: str = "rest",
    refractory_ms: float = 0.0,
    max_spikes_per_sample: int = 64,
) -> SpikeEvents:
    """LIF analog-to-spike conversion, exact for piecewise-constant input (see module doc).

    ``gain`` is R (input units -> volts); ``threshold`` and ``v_rest`` in volts. Computed in
    float64 with :func:`lif_hold_substep`, one crossing per neuron per step, so the work grows
    with the spikes per sample: an input that could fire more than ``max_spikes_per_sample``
    times in one sample (:func:`lif_rate_bound`) is refused before any work (ValueError)
    instead of running for hours.
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
    # shifted so that rest is 0: threshold theta - v_rest, drive = R I
    theta = float(threshold - v_rest)
    _check_rate_bound(gain * arr, dt, tau, theta, refractory_ms, max_spikes_per_sample)
    drive = torch.from_numpy(gain * arr.reshape(b * c, n))
    v = torch.zeros(b * c, dtype=torch.float64)
    refr = torch.zeros(b * c, dtype=torch.float64)  # refractory time left, ms
    zero = torch.zeros((), dtype=torch.float64)
    ev_n: list[Tensor] = []
    ev_t: list[Tensor] = []
    for i in range(n):
        v_inf = drive[:, i]
        rem = torch.full((b * c,), dt, dtype=torch.float64)
        while True:
            # refractory neurons stay at reset for the time they have left
            hold = torch.minimum(refr, rem)
            refr, rem = refr - hold, rem - hold
            live = rem > 0
            if not bool(live.any()):
                break
            fires, s, relaxed = lif_hold_substep(v, v_inf, rem, tau, theta)
            fires &= live
            quiet = live & ~fires
            v = torch.where(quiet, relaxed, v)
            rem = torch.where(quiet, zero, rem)
            spk = torch.nonzero(fires).flatten()
            if spk.numel() == 0:
                break
            ev_n.append(spk)
            ev_t.append(i * dt + (dt - rem[spk]) + s[spk])
            rem = torch.where(fires, rem - s, rem)
            # reset to rest, or by subtraction from the potential at the crossing
            reset_v = zero if reset == "rest" else torch.clamp(v, min=theta) - theta
            v = torch.where(fires, reset_v, v)
            refr = torch.where(fires, torch.full_like(refr, refractory_ms), refr)
    neuron = torch.cat(ev_n).numpy() if ev_n else np.zeros(0, np.int64)
    times = torch.cat(ev_t).numpy() if ev_t else np.zeros(0)
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
