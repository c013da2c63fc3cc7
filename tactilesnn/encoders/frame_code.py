"""A continuous code: causal band envelopes, LIF-coded frame by frame (``frames``).

The causal Gabor bank (:mod:`.causal_gabor`) turns each channel into ``n_bands`` magnitude
envelopes, one frame every ``hop`` samples (``hop = round(frame_ms * fs / 1000)``, at least 1;
frame ``i`` completes at sample ``(i + 1) hop - 1``). Each envelope row drives ``neurons`` LIF
converters, one step per frame::

    u_j <- beta u_j + (1 - beta) env / (level theta_j)        beta = exp(-1 / tau_frames)
    s_j = [u_j >= 1];  u_j <- u_j - s_j                      (reset by subtraction)

``level``: the row's median RMS envelope over the training windows (fitted, a buffer, floored at
1e-3 of its channel's loudest row); ``theta_j`` graded geometrically from ``lo`` to ``hi``. The
membrane low-passes the envelope in units of ``level theta_j`` and a converter fires at most once
a frame, at a rate that grows with the band's energy: no window reference anywhere, so the code
runs on for ever (:meth:`FrameCodeEncoder.frame_module`: one frame of samples and the state in,
that frame's spikes and the next state out), unlike the latency codes, which rank each band
against its window's peak.

Spike-time contract: afferent ``(channel * n_bands + band) * neurons + j``; its spikes in
ascending slots, a spike of frame ``i`` stamped ``(i + 1/2) frame_ms`` (it is known at the
frame's last sample), ``max_spikes = frames`` per window. A window is coded from rest (the bank
from its first sample held constant before it, converters at zero), as a fresh stream starts;
:meth:`FrameCodeEncoder.encode_recording` codes windows with their recording's past, as the
stream runs. The arithmetic is the functional core's LIF step (:func:`~tactilesnn.models.
functional.lif_step`); the window graph runs the converters as one ONNX ``LSTM`` node.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from typing import ClassVar

import numpy as np
import torch
from torch import Tensor, nn

from ..core.data import evenly_spaced
from ..models.functional import decay_factor, lif_step
from ..models.snn import _LSTMWeights
from ..schema.encoders import FrameCodeConfig
from .base import SpikeEncoder, register_encoder
from .causal_gabor import CausalGaborScalogram
from .gwt import log_bands
from .window_graphs import WindowEncoder

log = logging.getLogger("tactilesnn")
#: a row's level is at least this many float32 units of its channel's largest training value
RESOLUTION_ULPS = 256


def spike_times(spikes: Tensor, frame_ms: float) -> Tensor:
    """Frame spikes ``[frames, B, A]`` (0/1) -> spike times ``[B, A, frames]`` (ms, ascending,
    ``+inf`` after the last): frame ``i``'s spike at ``(i + 1/2) frame_ms``."""
    steps = spikes.shape[0]
    t = (torch.arange(steps, dtype=spikes.dtype, device=spikes.device) + 0.5) * frame_ms
    times = torch.where(spikes > 0, t.view(-1, 1, 1), torch.full_like(spikes, math.inf))
    return torch.sort(times.permute(1, 2, 0), dim=-1).values


class _FrameStep(nn.Module):
    """One frame: ``frame [B, C, hop]`` + state -> that frame's spikes ``[B, afferents]`` +
    the next state (``[B, units]`` each: per channel the bank's input tail and recursion, then
    the converters' membranes). The bank's frame is linear in (tail, recursion, frame): one
    MatMul by :meth:`FrameCodeEncoder.step_matrix`, the map :meth:`CausalGaborScalogram.
    frames_from` computes, with the real and imaginary parts of each band side by side so that
    one L2 norm gives the envelopes; the envelopes times :meth:`FrameCodeEncoder.gain` as one
    MatMul. (Each graph node and each graph input costs onnxruntime ~1.5 us on a 2-core machine,
    more than these products: the form has as few of either as the arithmetic allows.)"""

    def __init__(self, enc: FrameCodeEncoder) -> None:
        super().__init__()
        self.c, self.nb = enc.n_channels, enc.bank.n_bands
        self.per_channel = enc.bank.n_taps - 1 + 2 * enc.bank.order * self.nb
        self.register_buffer("step", enc.step_matrix().float())
        self.register_buffer("expand", enc.gain_matrix())
        self.sus = 2 if enc.n_sustained else 0
        # the rest level of each channel's (ON, OFF) pair: (rest, -rest)
        self.register_buffer("rest2", torch.stack([enc.rest, -enc.rest], 1).reshape(1, -1))
        self.beta = enc.beta
        self.state_names = [("frame_bank", self.c * self.per_channel),
                            ("frame_code", enc.n_afferents)]  # fmt: skip

    def forward(self, frame: Tensor, bank: Tensor, u: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        b = frame.shape[0]
        rows = torch.cat([bank.reshape(b * self.c, self.per_channel),
                          frame.reshape(b * self.c, -1)], 1)  # fmt: skip
        out = (rows @ self.step).split([2 * self.nb, self.sus, self.per_channel], 1)
        env = torch.linalg.vector_norm(out[0].reshape(b, self.c * self.nb, 2), dim=-1)
        if self.sus:  # (ON, OFF) per channel: the frame's mean against the rest, rectified
            env = torch.cat([env, torch.relu(out[1].reshape(b, -1) - self.rest2)], 1)
        s, u_new, _ = lif_step(u, env @ self.expand, self.beta, 1.0, True)
        new_bank = out[2]
        return s, new_bank.reshape(b, -1), u_new


class _FrameCodeGraph(nn.Module):
    """Window ``[B, C, W]`` -> envelopes (the bank's linear map: MatMuls and a modulus) and the
    sustained rows -> converters (one ``LSTM`` node, its independent units in rows of at
    least 16) -> spike times ``[B, afferents, frames]``."""

    def __init__(self, enc: FrameCodeEncoder) -> None:
        super().__init__()
        self.envelopes = WindowEncoder(enc.bank, nn.Identity(), enc.window)  # type: ignore[arg-type]
        self.frames, self.frame_ms, self.hop = enc.frames, enc.frame_ms, enc.hop
        self.register_buffer("gain", enc.gain().clone())
        self.register_buffer("rest", enc.rest.detach().clone().view(1, -1, 1))
        self.sustained = enc.n_sustained > 0
        self.beta, self.a = enc.beta, enc.n_afferents
        self.lstm = _LSTMWeights(self.a, self.beta, 1.0, True)

    def forward(self, x: Tensor) -> Tensor:
        b, c = x.shape[0], x.shape[1]
        # the bank sees differences only (its past: the first sample held), so the window less
        # its first sample has the same envelopes; in float32 a large offset (a pressure
        # sensor's counts at rest) would otherwise swamp the product's small sums
        rel = x - x[..., :1]
        rows = self.envelopes.scalogram(rel)[..., : self.frames].reshape(b, -1, self.frames)
        if self.sustained:
            m = x[..., : self.frames * self.hop].reshape(b, c, self.frames, self.hop).mean(-1)
            d = m - self.rest
            sus = torch.stack([torch.relu(d), torch.relu(-d)], 2).reshape(b, 2 * c, self.frames)
            rows = torch.cat([rows, sus], 1)
        cur = (rows.unsqueeze(2) * self.gain.unsqueeze(-1)).reshape(b, self.a, self.frames)
        cur = cur.permute(2, 0, 1)  # [frames, B, A]
        no_rec = self.lstm.W[:0, :0]
        spikes, _, _ = self.lstm(cur, torch.zeros_like(cur[0]), None, no_rec)
        return spike_times(spikes, self.frame_ms)


@register_encoder("frames", FrameCodeConfig)
class FrameCodeEncoder(SpikeEncoder):
    """Causal band envelopes LIF-coded frame by frame; see the module docstring."""

    needs_fit = True
    has_frame_step: ClassVar[bool] = True

    def __init__(self, config: FrameCodeConfig, fs_hz: float, window: int, n_channels: int):
        super().__init__(config, fs_hz, window, n_channels)
        f_hi = min(config.f_hi_hz, 0.45 * self.fs_hz)
        if not config.f_lo_hz < f_hi:
            raise ValueError(f"frames: f_lo_hz ({config.f_lo_hz}) must lie below 0.45 x the "
                             f"sampling rate ({f_hi:.4g} Hz)")  # fmt: skip
        self.freqs_hz = log_bands(config.f_lo_hz, f_hi, config.n_bands)
        self.hop = max(1, round(config.frame_ms * self.fs_hz / 1000.0))
        self.frames = self.window // self.hop
        if self.frames < 2:
            raise ValueError(f"frames: a {window}-sample window holds {self.frames} frame of "
                             f"{self.hop} samples; use a shorter frame_ms")  # fmt: skip
        self.frame_ms = 1000.0 * self.hop / self.fs_hz
        self.bank = CausalGaborScalogram(self.fs_hz, self.freqs_hz, hop=self.hop)
        self.beta = decay_factor(1.0, config.tau_frames)
        thr = np.geomspace(config.lo, config.hi, config.neurons)
        self.register_buffer("inv_thr", torch.as_tensor(1.0 / thr, dtype=torch.float32))
        self.n_sustained = 2 * self.n_channels if config.sustained else 0
        self.n_rows = self.n_channels * config.n_bands + self.n_sustained
        self.register_buffer("level", torch.ones(self.n_rows))  # per row, input units
        self.register_buffer("rest", torch.zeros(self.n_channels))  # training median, per channel

    @property
    def n_afferents(self) -> int:
        return self.n_rows * self.config.neurons

    @property
    def max_spikes(self) -> int:
        return self.frames

    @property
    def frame_period_ms(self) -> float:
        return self.frame_ms

    @property
    def frame_hop(self) -> int:
        return self.hop

    @property
    def codes_with_past(self) -> bool:
        return True

    def gain(self) -> Tensor:
        """``[rows, neurons]``: a row's envelope times this is converter ``j``'s input current
        per frame (threshold 1)."""
        return (1.0 - self.beta) * self.inv_thr.view(1, -1) / self.level.view(-1, 1)

    def gain_matrix(self) -> Tensor:
        """``[rows, afferents]``: envelope rows -> converter currents (:meth:`gain` placed on
        each row's converters), for a graph's single MatMul."""
        g = self.gain()
        rows = torch.arange(g.shape[0]).repeat_interleave(g.shape[1])
        out = torch.zeros(g.shape[0], self.n_afferents)
        out[rows, torch.arange(self.n_afferents)] = g.flatten()
        return out

    @torch.no_grad()
    def step_matrix(self) -> Tensor:
        """float64 ``[taps - 1 + 2 K bands + hop, 2 bands (+ 2) + taps - 1 + 2 K bands]``: one
        channel's ``[tail, recursion, frame]`` -> ``[(re, im) per band, (the frame's mean sample
        and its negative, for the sustained rows), tail, recursion]`` for one frame, read off
        :meth:`CausalGaborScalogram.frames_from` column by column (it is linear)."""
        bank, tail = self.bank, self.bank.n_taps - 1
        rec = bank.n_bands * 2 * bank.order
        eye = torch.eye(tail + rec + self.hop, dtype=torch.float64)
        buf = torch.cat([eye[:, :tail], eye[:, tail + rec :]], 1)  # the tail, then the frame
        past = eye[:, tail : tail + rec].reshape(-1, bank.n_bands, 2 * bank.order)
        re, im, state = bank.frames_from(buf[:, None], past)
        assert state is not None
        env = torch.stack([re[..., 0], im[..., 0]], -1).reshape(len(eye), -1)
        mean = buf[:, tail:].mean(1, keepdim=True)  # the frame's mean sample
        parts = [env, *([mean, -mean] if self.n_sustained else []), buf[:, self.hop :],
                 state.reshape(len(eye), -1)]  # fmt: skip
        return torch.cat(parts, 1)

    @torch.no_grad()
    def envelopes(self, x: Tensor) -> Tensor:
        """Windows ``[B, C, W]`` -> band envelopes ``[B, C * bands, W // hop]`` (input units)."""
        env = self.bank(x)
        return env.reshape(x.shape[0], -1, env.shape[-1])

    def sustained_rows(self, x: Tensor) -> Tensor:
        """Windows ``[B, C, W]`` -> each frame's mean sample against the channel's training
        median, rectified: ``[B, 2 C, frames]``, rows ``(c ON, c OFF)`` channel by channel."""
        b, c, n = x.shape
        f = n // self.hop
        m = x[..., : f * self.hop].reshape(b, c, f, self.hop).mean(-1)
        d = m - self.rest.to(x.dtype).view(1, -1, 1)
        return torch.stack([torch.relu(d), torch.relu(-d)], 2).reshape(b, 2 * c, f)

    def rows(self, x: Tensor) -> Tensor:
        """Windows ``[B, C, W]`` -> every coded row ``[B, rows, frames]`` (input units): the
        band envelopes, then the sustained rows."""
        env = self.envelopes(x)
        return torch.cat([env, self.sustained_rows(x)], 1) if self.n_sustained else env

    def fit(self, X: np.ndarray, n_max: int = 1024) -> FrameCodeEncoder:
        """Each channel's rest: the median of its samples; each row's level: the median over
        (up to ``n_max``, evenly spaced) training windows of its RMS, floored at 1e-3 of its
        channel's loudest row (both over those windows)."""
        arr = np.asarray(X)
        idx = evenly_spaced(len(arr), n_max)
        batch = max(1, (1 << 27) // max(1, self.bytes_per_window()))
        samples = np.asarray(arr[idx], np.float32).transpose(1, 0, 2).reshape(self.n_channels, -1)
        self.rest.copy_(torch.from_numpy(np.median(samples, 1)))
        rms = torch.cat([
            self.rows(torch.from_numpy(np.ascontiguousarray(arr[idx[i : i + batch]],
                                                            dtype=np.float32)))
            .double().pow(2).mean(-1).sqrt()
            for i in range(0, len(idx), batch)
        ])  # fmt: skip
        med = rms.median(0).values
        nb = self.config.n_bands
        level = torch.cat([med[: self.n_channels * nb].view(self.n_channels, nb),
                           med[self.n_channels * nb :].view(self.n_channels, -1)], 1)  # fmt: skip
        if not (level > 0).any():
            raise ValueError("every channel is zero in the training windows: nothing to encode")
        loudest = level.amax(1, keepdim=True)
        floor = torch.where(loudest > 0, 1e-3 * loudest, 1e-3 * level.max())
        # and at what float32 resolves on the channel's values: a channel held near a large
        # value (a 16-bit reading stuck at 65535) varies by its rounding alone, which two
        # orders of the same sums round differently (FabricSlide: 110,386 spikes of 1.9 M
        # differed between the window graph and torch)
        resolution = RESOLUTION_ULPS * np.finfo(np.float32).eps * np.abs(samples).max(1)
        floor = torch.maximum(floor, torch.from_numpy(resolution).double().view(-1, 1))
        quiet = torch.nonzero(loudest[:, 0] <= 0).flatten().tolist()
        if quiet:
            log.warning("frames encoder: channel(s) %s silent in training; level floored at "
                        "1e-3 of the loudest channel", quiet)  # fmt: skip
        level = torch.maximum(level, floor)
        self.level.copy_(torch.cat([level[:, :nb].flatten(), level[:, nb:].flatten()]).float())
        self.fitted.fill_(True)
        return self

    def code(self, env: Tensor, u0: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Envelopes ``[B, rows, frames]`` from membranes ``u0 [B, afferents]`` (None: rest)
        -> ``(spikes [frames, B, afferents], membranes after the last frame)``."""
        b, _, f = env.shape
        cur = (env.unsqueeze(2) * self.gain().to(env.dtype).unsqueeze(-1)).reshape(b, -1, f)
        u = torch.zeros(b, self.n_afferents, dtype=env.dtype) if u0 is None else u0
        out = torch.empty(f, b, self.n_afferents, dtype=env.dtype)
        for i in range(f):
            out[i], u, _ = lif_step(u, cur[..., i], self.beta, 1.0, True)
        return out, u

    def encode_batch(self, x: Tensor) -> Tensor:
        spikes, _ = self.code(self.rows(x))
        return spike_times(spikes, self.frame_ms)

    def encode_recording(self, x: np.ndarray, starts: Sequence[int]) -> Tensor:
        """The windows of ``x [channels, samples]`` starting at ``starts`` (whole hops), each
        coded with the recording's past: the bank and the converters run once over it."""
        st = np.asarray(starts, dtype=np.int64)
        if st.size and (np.any(st % self.hop) or st.min() < 0
                        or st.max() + self.window > x.shape[-1]):  # fmt: skip
            raise ValueError(f"window starts must be whole hops ({self.hop} samples) inside the "
                             f"recording of {x.shape[-1]} samples")  # fmt: skip
        spikes = self.frame_spikes(x)  # [frames, afferents]
        out = [spike_times(spikes[s // self.hop : s // self.hop + self.frames, None], self.frame_ms)
               for s in st]  # fmt: skip
        return torch.cat(out) if out else torch.zeros(0, self.n_afferents, self.frames)

    @torch.no_grad()
    def frame_spikes(self, x: np.ndarray) -> Tensor:
        """Every frame's spikes ``[frames, afferents]`` of one recording ``x [channels,
        samples]`` coded from its start (the stream's view)."""
        self.check_fitted()
        t = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))[None]
        return self.code(self.rows(t))[0][:, 0]

    def bytes_per_window(self) -> int:
        # the bank's frames (complex, per band) and the converters' current and spikes
        rows = self.n_channels * self.config.n_bands
        return 4 * (6 * rows * self.frames + 3 * self.n_afferents * self.frames) + 8 * self.window

    def frame_module(self) -> nn.Module:
        """The code's frame step (:class:`_FrameStep`), with ``state_names``."""
        self.check_fitted()
        return _FrameStep(self)

    def initial_frame_state(self, first: np.ndarray) -> dict[str, np.ndarray]:
        """The state of fresh streams whose first frames are ``first [B, channels, >= 1]``:
        the bank's tail holds each channel's first sample (constant before the stream, as a
        window is coded), its recursion and the converters at zero."""
        x = np.asarray(first, np.float32)
        tail = self.bank.n_taps - 1
        bank = np.zeros((len(x), self.n_channels, tail + 2 * self.bank.order * self.bank.n_bands),
                        np.float32)  # fmt: skip
        bank[:, :, :tail] = x[:, :, :1]
        return {"frame_bank": bank.reshape(len(x), -1),
                "frame_code": np.zeros((len(x), self.n_afferents), np.float32)}  # fmt: skip

    def onnx_module(self) -> nn.Module:
        return _FrameCodeGraph(self)
