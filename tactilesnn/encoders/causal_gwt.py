"""Causal Gabor scalogram -> latency code as an encoder component: ``cgwt``.

The ``gwt`` encoder's code (one latency spike per channel, statistic and band; the same afferent
layout, band range, statistics, activity gate and band restriction) on the causal recursive
Gabor bank of :mod:`.causal_gabor` instead of the windowed FFT scalogram. Each window is
transformed from the zero state (its first sample as the constant past); a stream carries the
state instead (:class:`~.causal_gabor.CausalGaborStream`), so every input sample is transformed
once. Exported as the bank's own exact form: one strided convolution (the polyphase FIR of every
band) and the frame recursion as block MatMuls, then the code.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import ClassVar

import numpy as np
import torch
from torch import Tensor, nn

from ..core.checks import check_allocation
from ..core.data import evenly_spaced
from ..schema.encoders import CausalGWTConfig
from .base import check_recordings_and_starts, register_encoder
from .causal_gabor import CausalGaborScalogram
from .latency import LatencyCode
from .scalogram_latency import (
    ScalogramLatencyEncoder,
    level_off,
    unit_peak,
)


def auto_hop(fs_hz: float, f_hi_hz: float, window: int) -> int:
    """Frames every ``hop`` samples, fast enough for the highest band's envelope: its magnitude
    varies within ``+- 2 sigma_f`` (``sigma_f`` = 0.184 f_hi), so a frame rate of ``4 sigma_f``
    samples it at twice that; at most an eighth of the window. The largest such hop that divides
    half an even window (a stream step, half a window, is then whole frames: the stream graph
    needs it) unless that is under half the bound (3,250-sample windows would get hop 1 instead of
    3: three times the frames), then the bound."""
    sigma_f = f_hi_hz / (math.pi * math.sqrt(3.0))  # cmor1.5-1.0: f / (pi C sqrt(2 B))
    bound = int(max(1, min(math.floor(fs_hz / (4.0 * sigma_f)), int(window) // 8)))
    if window % 2:
        return bound
    best = max(d for d in range(1, bound + 1) if (window // 2) % d == 0)
    return best if 2 * best >= bound else bound


@register_encoder("cgwt", CausalGWTConfig)
class CausalGWTLatencyEncoder(ScalogramLatencyEncoder):
    """Causal (streamable) Gabor bank -> latency code."""

    #: runs saved before the stream's input gain load with gain 1 (as they were exported)
    optional_state: ClassVar[tuple[str, ...]] = ("gate_rms", "stream_gain")
    has_stream_form: ClassVar[bool] = True

    def __init__(self, config, fs_hz: float, window: int, n_channels: int) -> None:
        super().__init__(config, fs_hz, window, n_channels)
        # per channel a power of two whose square brings the training windows' typical range
        # near 1 (:func:`stream_gains`): the stream graph's recursion then runs on normal
        # float32 numbers whatever the sensor's units (data near 1e-40 was subnormal there, and
        # rounded unlike the float64 reference); exact, and the code is scale-free
        self.register_buffer("stream_gain", torch.ones(n_channels))

    def fit(self, X: np.ndarray) -> CausalGWTLatencyEncoder:
        super().fit(X)
        self.stream_gain.copy_(torch.from_numpy(stream_gains(X)))
        return self

    def scaled(self, x: Tensor) -> Tensor:
        """:func:`level_off`: the bank's output is that of the window (scaled), computed
        without the window's level (see there); a run saved before that: :func:`unit_peak`."""
        return level_off(x) if self.config.level_off else unit_peak(x)

    @property
    def codes_with_past(self) -> bool:
        """Whether :meth:`encode_recording` codes windows as the stream graph serves them (not
        with the activity gate, which skips samples, nor for a run saved before the level
        was taken off)."""
        return self.config.gate <= 0 and self.config.level_off

    def _check_level_off(self, what: str) -> None:
        if not self.config.level_off:
            raise ValueError(f"this run was trained before the cgwt encoder took each window's "
                             f"level off, which {what} needs: train it again (its window graph "
                             "still exports)")  # fmt: skip

    def make_scalogram(self, freqs_hz: np.ndarray) -> nn.Module:
        hop = self.config.hop or auto_hop(self.fs_hz, float(np.max(self.freqs_hz)), self.window)
        if hop > self.window:
            raise ValueError(f"cgwt hop ({hop}) exceeds the window ({self.window})")
        return CausalGaborScalogram(self.fs_hz, freqs_hz, hop=hop, order=self.config.order)

    @property
    def hop(self) -> int:
        return self.scalogram.hop

    def bytes_per_window(self) -> int:
        # the strided FIR's output and the recursion's blocks: a few complex values per frame
        nb, f = self.config.n_bands, self.window // self.hop
        return 8 * self.n_channels * (self.window + 8 * nb * f)

    def onnx_module(self) -> nn.Module:
        return self._gated(_ScalogramCode(self.scalogram, self.code))

    def stream_module(self, step: int | None = None) -> CausalStreamCode:
        """The encoder's stream step (``step`` samples per call, default half a window), for the
        stream graph."""
        self._check_level_off("the stream graph")
        return CausalStreamCode(self, self.window // 2 if step is None else step)

    @torch.no_grad()
    def encode_recording(self, x: np.ndarray, starts: Sequence[int]) -> Tensor:
        """Spike times ``[len(starts), afferents, 1]`` of the windows of one recording ``x
        [channels, samples]`` that start at ``starts`` (samples), each with the recording's
        past, as the stream graph codes them: the bank run once over the recording (its first
        sample the constant past, its level off; once per phase of the starts modulo the hop,
        so that every window's frames fall on its grid), each window's frames coded as
        :func:`in_range_units` gives them. A window starting at 0 is :meth:`encode_batch`'s (up
        to float rounding); a later one differs where the bank still rings with what came
        before it."""
        return self.encode_recordings([x], [starts])[0]

    def encode_recordings(
        self, recs: Sequence[np.ndarray], starts: Sequence[Sequence[int]],
        budget_bytes: int = 1 << 26,
    ) -> list[Tensor]:  # fmt: skip
        """:meth:`encode_recording` of each ``(recs[i], starts[i])``, the recordings run through
        the bank together: in order of length, in batches of at most ``budget_bytes`` of
        frames, each padded to its batch's longest with its first sample (the bank is causal
        and blind to a constant, so no frame of the recording changes). One recording at a
        time made every block of the bank a matrix-vector product that read the block's whole
        matrix for one row: 5x slower on 1,000 recordings of 13,000 samples."""
        check_recordings_and_starts(recs, starts)
        arrays = [np.asarray(r) for r in recs]
        for r in arrays:
            if r.ndim != 2 or r.shape[0] != self.n_channels:
                raise ValueError(f"expected a recording [{self.n_channels} channels, samples], "
                                 f"got shape {r.shape}")  # fmt: skip
        per_sample = 16 * self.n_channels * self.scalogram.n_bands / self.hop
        out: list[Tensor] = [torch.zeros(0)] * len(arrays)
        order = sorted(range(len(arrays)), key=lambda i: arrays[i].shape[-1])
        batches: list[list[int]] = [[]]
        for i in order:  # the longest so far sets the batch's padded length
            if (
                batches[-1]
                and (len(batches[-1]) + 1) * arrays[i].shape[-1] * per_sample > budget_bytes
            ):
                batches.append([])
            batches[-1].append(i)
        for batch in batches:
            if batch:
                codes = self._encode_batch_of_recordings([arrays[j] for j in batch],
                                                         [starts[j] for j in batch])  # fmt: skip
                for j, c in zip(batch, codes, strict=True):
                    out[j] = c
        return out

    @torch.no_grad()
    def _encode_batch_of_recordings(
        self, recs: list[np.ndarray], starts: Sequence[Sequence[int]]
    ) -> list[Tensor]:
        """:meth:`encode_recordings` of one batch: the recordings padded to the longest with
        their first sample, the level off, the bank run once per phase of the starts over the
        recordings that have a window of that phase, as far as the last of them."""
        self.check_fitted()
        self._check_level_off("coding a window with its past")
        if self.config.gate > 0:
            raise ValueError("a recording's windows with their past need every sample: the "
                             "activity gate skips quiet ones (train without --gate)")  # fmt: skip
        hop, frames, window = self.hop, self.window // self.hop, self.window
        n = max(r.shape[-1] for r in recs)
        check_allocation(4 * len(recs) * self.n_channels * self.scalogram.n_bands
                         * (n // hop + 1), "the causal bank's frames of the recordings")  # fmt: skip
        padded = np.empty((len(recs), self.n_channels, n), np.float32)
        wins: dict[int, list[tuple[int, int, int]]] = {}  # phase -> (recording, window, start)
        for r, (x, st) in enumerate(zip(recs, starts, strict=True)):
            padded[r, :, : x.shape[-1]] = x
            padded[r, :, x.shape[-1] :] = x[:, :1]
            for w, s in enumerate(int(v) for v in st):
                if s < 0 or s + window > x.shape[-1]:
                    raise ValueError(f"the windows starting at {list(st)} do not all lie in the "
                                     f"recording's {x.shape[-1]} samples")  # fmt: skip
                wins.setdefault(s % hop, []).append((r, w, s))
        rec = level_off(torch.from_numpy(padded))  # scaled by each recording's peak, level off
        out = [torch.full((len(st), self.n_afferents, 1), math.inf) for st in starts]
        for ph, items in wins.items():
            rows = sorted({r for r, _, _ in items})
            at = {r: k for k, r in enumerate(rows)}
            end = max(s for _, _, s in items) + window  # the bank only as far as the last window
            mag = self.scalogram(rec[rows, :, ph:end])  # [rows, C, bands, frames]
            win = torch.stack([mag[at[r], ..., (s - ph) // hop : (s - ph) // hop + frames]
                               for r, _, s in items])  # fmt: skip
            rng = torch.stack([_window_range(rec[r : r + 1, :, s : s + window])[0]
                               for r, _, s in items])  # fmt: skip
            t = self.code(in_range_units(win, rng))
            t = (self.band_scatter(t) if self.restricted else t).float()
            for k, (r, w, _) in enumerate(items):
                out[r][w, :, 0] = t[k]
        return out

    def stream_reference(self, x: Tensor, step: int) -> Tensor:
        """What the stream step must give on a whole stream ``x [1, channels, samples]`` (float64
        for a reference): the bank run once over it, each complete window's frames (a window
        ending every ``step`` samples) coded -> spike times ``[windows, afferents, 1]``."""
        mag = self.scalogram(x - x[..., :1])  # [1, C, bands, frames]: the stream's level off
        fs, frames = step // self.hop, self.window // self.hop
        n = x.shape[-1] // step - self.window // step + 1
        t = torch.cat([self.code(in_range_units(
            mag[..., j * fs : j * fs + frames],
            _window_range(x[..., j * step : j * step + self.window])).float())
            for j in range(n)])  # fmt: skip
        return (self.band_scatter(t) if self.restricted else t).unsqueeze(-1)


class _ScalogramCode(nn.Module):
    """Window ``[B, C, W]`` -> the bank's magnitudes -> the latency code ``[B, C * stats * bands]``
    (the bank traced as it runs: a strided Conv and block MatMuls)."""

    def __init__(self, scalogram: CausalGaborScalogram, code: LatencyCode) -> None:
        super().__init__()
        self.scalogram, self.code = scalogram, code

    def forward(self, x: Tensor) -> Tensor:
        return self.code(self.scalogram(x))  # (the window comes level_off: _WithSlot)


def stream_gains(X: np.ndarray, n_max: int = 4096) -> np.ndarray:
    """Per channel ``g = 2 ** (-round(log2(r) / 2))``, ``r`` the median range (max - min, input
    units) of up to ``n_max`` evenly spaced windows ``X [N, C, W]`` (1 where that is 0 or not
    finite): the samples times ``g`` twice have a range near 1 (within a factor 2). Applied
    twice because the gain data near 1e-40 needs, 2 ** 133, is beyond float32's largest value;
    each factor a power of two, so both products are exact."""
    arr = np.asarray(X)
    # one window at a time (a float64 copy of thousands of long windows would not fit); the
    # extremes are exact in the input's type, so the ranges are those of a float64 copy
    ranges = [np.asarray(arr[i].max(-1), np.float64) - np.asarray(arr[i].min(-1), np.float64)
              for i in evenly_spaced(len(arr), n_max)]  # fmt: skip
    r = np.median(np.stack(ranges), axis=0)  # [C]
    ok = np.isfinite(r) & (r > 0)
    e = np.where(ok, -np.round(np.log2(np.where(ok, r, 1.0)) / 2), 0.0)
    return np.exp2(np.clip(e, -126, 126)).astype(np.float32)


def in_range_units(mag: Tensor, rng: Tensor) -> Tensor:
    """A stream window's magnitudes ``mag [B, C, bands, F]`` as the code takes them: in units
    of their largest (the code is scale-free; this keeps its float32 squares in range whatever
    the sensor's units), and zeros where the window's range ``rng [B, C, 1, 1]`` is zero: a
    window whose samples are all equal is silent, whatever its bank still rings with from the
    past (it has no signal of its own), as the window graph codes a constant window."""
    top = mag.amax((-2, -1), keepdim=True).clamp_min(torch.finfo(mag.dtype).tiny)
    return mag * ((rng > 0).to(mag.dtype) / top)


def _window_range(x: Tensor) -> Tensor:
    """``x [B, C, samples]`` -> its range ``[B, C, 1, 1]``."""
    return (x.amax(-1) - x.amin(-1))[..., None, None]


def _modulus(re: Tensor, im: Tensor) -> Tensor:
    """``|re + i im|`` without squaring a large or tiny value (float32 squares overflow above
    ~1.8e19 and lose precision below ~1e-19): ``m sqrt(1 + (n / m)^2)``, ``m`` the larger part."""
    a, b = re.abs(), im.abs()
    m, n = torch.maximum(a, b), torch.minimum(a, b)
    r = n / m.clamp_min(torch.finfo(m.dtype).tiny)
    return m * torch.sqrt(1.0 + r * r)


class CausalStreamCode(nn.Module):
    """One stream step of the ``cgwt`` encoder: the next ``step`` samples ``chunk [B, C, step]``
    and the encoder's state -> the spike times of the window that ends with them ``[B,
    afferents, 1]`` and the new state. Every sample is transformed once: the bank continues
    from its state, and the window's frames are the earlier ones (kept as state) then the
    chunk's. ``step`` (a whole number of hops dividing the window, at most half of it) sets the
    latency: a sample's frame, and the spikes of the window it ends, exist after the call that
    takes it (one hop: one frame).

    State (``[B, units]`` each, :attr:`state_names`): ``cgwt_tail`` the last ``taps - 1``
    samples less the stream's level, times the channel's fitted ``stream_gain`` squared (a fresh
    stream: zeros, the bank's constant past; the bank runs on the samples less the level, see
    :func:`level_off`), ``cgwt_rec`` the frame
    recursion's values (zeros), ``cgwt_frames`` the window's magnitudes before the chunk's, and
    ``cgwt_extent`` per channel the stream's level (its first sample) then the largest and the
    negated smallest sample of each of those frames (a window whose range is zero is silent, as
    the window graph codes a constant window; a fresh stream: its first sample repeated);
    ``stream_prev``, the window's samples before the chunk, only where the pipeline's level
    code reads the window.
    """

    def __init__(self, encoder: CausalGWTLatencyEncoder, step: int) -> None:
        super().__init__()
        if encoder.config.gate > 0:
            raise ValueError(
                "the activity gate skips a window's quiet channels, but a stream's recursion "
                "needs every sample: export the stream graph of a run trained without --gate"
            )
        bank: CausalGaborScalogram = encoder.scalogram
        check_stream_step(step, encoder.window, bank.hop)
        self.bank, self.code = bank, encoder.code
        self.register_buffer("gain", encoder.stream_gain.detach().clone().view(1, -1, 1))
        self.scatter = encoder.band_scatter if encoder.restricted else None
        self.step, self.channels = int(step), encoder.n_channels
        self.f_step = self.step // bank.hop
        self.f_kept = (encoder.window - self.step) // bank.hop  # the window's earlier frames
        nb, k, c = bank.n_bands, bank.order, self.channels
        self.state_names = [("cgwt_tail", c * (bank.n_taps - 1)), ("cgwt_rec", c * nb * 2 * k),
                            ("cgwt_frames", c * nb * self.f_kept),
                            ("cgwt_extent", c * (1 + 2 * self.f_kept))]  # fmt: skip
        #: a fresh stream's extent is its first sample repeated (the runtime's rule: its level,
        #: and the extent of the constant past); the others zeros
        self.state_init = {"cgwt_extent": "repeat_first"}

    def initial_state(self, first: np.ndarray) -> dict[str, np.ndarray]:
        """The state of a fresh stream whose first samples are ``first [B, C]`` (float32)."""
        b = first.shape[0]
        ext = np.repeat(first.astype(np.float32)[:, :, None], 1 + 2 * self.f_kept, axis=2)
        return {**{n: np.zeros((b, u), np.float32) for n, u in self.state_names[:-1]},
                "cgwt_extent": ext.reshape(b, -1)}  # fmt: skip

    def forward(
        self, chunk: Tensor, tail: Tensor, rec: Tensor, frames: Tensor, extent: Tensor
    ) -> tuple[Tensor, ...]:
        b, c, n = chunk.shape
        nb, k, nt, fk = self.bank.n_bands, self.bank.order, self.bank.n_taps, self.f_kept
        level, extent = extent.reshape(b, c, -1).split([1, 2 * fk], -1)
        # the stream's level off (exact: the bank has no DC gain), times the fitted gain twice
        # (powers of two: exact; scaled before the difference, which then cannot overflow)
        g = self.gain
        xs = (chunk * g) * g - (level * g) * g
        buf = torch.cat([tail.reshape(b * c, 1, nt - 1), xs.reshape(b * c, 1, n)], -1)
        re, im, state = self.bank.frames_from(buf, rec.reshape(b * c, nb, 2 * k))
        mag = _modulus(re, im).reshape(b, c, nb, self.f_step)  # [B, C, bands, F step]
        window = torch.cat([frames.reshape(b, c, nb, fk), mag], -1)
        # each frame's largest sample and negated smallest: the window's range is the sum of
        # their maxima (zero: a constant window, silent as in the window graph)
        hops = chunk.reshape(b, c, self.f_step, 1, -1)
        ext = torch.cat(
            [extent.reshape(b, c, fk, 2), torch.cat([hops, -hops], -2).amax(-1)], 2
        )  # [B, C, F, 2]
        rng = ext.amax(2, keepdim=True).sum(-1, keepdim=True)  # [B, C, 1, 1]
        t = self.code(in_range_units(window, rng))
        if self.scatter is not None:
            t = self.scatter(t)
        fs = self.f_step
        new_extent = torch.cat([level, ext[:, :, fs:].reshape(b, c, -1)], -1).reshape(b, -1)
        return (t.unsqueeze(-1), buf[..., -(nt - 1) :].reshape(b, -1), state.reshape(b, -1),
                window[..., fs:].reshape(b, -1), new_extent)  # fmt: skip


def check_stream_step(step: int, window: int, hop: int) -> int:
    """``step``: samples per stream call, a whole number of hops (frames) that divides the
    window and is at most half of it (windows overlap; the window's earlier frames are state)."""
    step = int(step)
    if step < 1 or step % hop or window % step or 2 * step > window:
        fits = [s for s in range(hop, window // 2 + 1, hop) if window % s == 0]
        raise ValueError(
            f"a stream step of {step} samples does not fit: it must be a whole number of hops "
            f"({hop}) that divides the window ({window} samples) and is at most half of it"
            + (f" (these fit: {_some(fits)})" if fits else "")
        )
    return step


def _some(values: list[int]) -> str:
    """A list short enough for a message: its first four and last two beyond eight values."""
    if len(values) <= 8:
        return ", ".join(map(str, values))
    return ", ".join(map(str, values[:4])) + ", ..., " + ", ".join(map(str, values[-2:]))
