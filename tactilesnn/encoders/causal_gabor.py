"""Causal recursive Gabor filter bank: a scalogram that streams, touching every input sample once.

Band ``b`` (centre ``f_b`` Hz) is a ``K``-fold complex pole with a zero at DC (``K = order``):

    H_b(z) = g_b (1 - z^-1) / (1 - p_b z^-1)^K,   p_b = exp(-1 / (tau_b fs) + i 2 pi f_b / fs).

Near its centre ``|H_b|`` is a Gaussian of the cmor1.5-1.0 Gabor's relative width (``sigma_f =
f_b / (pi C sqrt(2 B))`` = 0.184 f_b): ``|1 + i 2 pi df tau|^-K`` has the Gaussian's curvature at
``df = 0`` when ``tau_b = 1 / (2 pi sigma_f sqrt(K))``. ``g_b`` makes ``H_b(e^{i w_b}) = 2``, so a
unit-amplitude sinusoid at ``f_b`` gives a magnitude of 1.0, as the Gabor scalogram's convention
(:mod:`.gwt`). The DC zero keeps a sensor's static offset (a pressure, a bias voltage) out of every
band exactly; the impulse response is one-sided (causal), so a frame exists as soon as its last
sample has arrived, at the cost of a group delay of about ``(K - 1) tau_b`` (the price of any
narrow band: ~0.26 s at 5 Hz, 1.6 ms at 800 Hz).

Frames: frame ``m`` is the output at sample ``(m + 1) hop - 1`` (the end of its hop). Computed
multirate and exactly: the polyphase identity ``1 / (1 - p z^-1)^K = N(z) / (1 - q z^-hop)^K``
with ``q = p^hop`` and ``N(z) = (sum_{j<hop} p^j z^-j)^K`` splits each band into a strided FIR of
``K (hop - 1) + 2`` taps (``g (1 - z^-1) N(z)``: one output per hop) and a ``K``-fold first-order
recursion at the frame rate, so the work per input sample is ``bands x taps / hop`` (the FIR) plus
``bands x frames-per-block / hop`` (the recursion, run in blocks of frames as one exact matrix
product per block, the state carried between blocks). Before the first sample the input is taken
as constant (its first value): with the DC zero that is the zero state, so a window and a stream
start alike.

Array contract: input ``[batch, channels, samples]`` float at ``fs_hz``; output magnitude
``[batch, channels, bands, samples // hop]``. :class:`CausalGaborStream` carries the state across
chunks of any length (the frames equal one pass over the concatenated input);
:func:`reference_frames` is the float64 sample-rate cascade (``scipy.signal.lfilter``) that the
fast paths are tested against.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import scipy.signal
import torch
from numpy.lib.stride_tricks import sliding_window_view
from torch import nn

from ..core.checks import check_int, check_positive
from .gwt import check_bands

#: frames per block of the frame-rate recursion (one [block x block] product per band and block)
BLOCK_FRAMES = 64


def band_poles(
    fs_hz: float,
    freqs_hz: Sequence[float],
    order: int = 4,
    bandwidth: float = 1.5,
    center: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(p, g, tau_s)`` of every band: complex poles, complex gains (``H_b(e^{i w_b}) = 2``) and
    the time constants (s), float64 / complex128."""
    fs = check_positive(fs_hz, "fs_hz")
    f = check_bands(freqs_hz, fs)
    check_int(order, "order", 1)
    sigma_f = f / (math.pi * center * math.sqrt(2.0 * bandwidth))
    tau = 1.0 / (2.0 * math.pi * sigma_f * math.sqrt(order))
    w = 2.0 * math.pi * f / fs
    p = np.exp(-1.0 / (tau * fs) + 1j * w)
    z1 = np.exp(-1j * w)  # z^-1 at the band centre
    g = 2.0 * (1.0 - p * z1) ** order / (1.0 - z1)
    return p, g, tau


def polyphase_taps(p: np.ndarray, g: np.ndarray, hop: int, order: int) -> np.ndarray:
    """``[bands, K (hop - 1) + 2]`` complex128: tap ``j`` multiplies ``x[n - j]`` in the FIR part
    ``g (1 - z^-1) (sum_{j<hop} p^j z^-j)^K`` sampled at the frame instants."""
    out = []
    for pb, gb in zip(p, g, strict=True):
        box = pb ** np.arange(hop)
        taps = np.array([gb, -gb])
        for _ in range(order):
            taps = np.convolve(taps, box)
        out.append(taps)
    return np.stack(out)


def block_maps(q: np.ndarray, order: int, frames: int) -> dict[str, np.ndarray]:
    """The ``K``-fold first-order recursion ``s_k[m] = q s_k[m-1] + s_{k-1}[m]`` (``s_0 = v``,
    output ``s_K``) over a block of ``frames``, as exact linear maps (complex128, per band):

    * ``T [bands, F, F]``: outputs from the block's inputs (lower triangular Toeplitz);
    * ``G [bands, F, K]``: outputs from the state before the block;
    * ``S [bands, K, F]``: state after the block from its inputs (column ``n`` depends on
      ``F - 1 - n`` only, so a block of ``f < F`` frames uses the last ``f`` columns);
    * ``P [bands, F, K, K]``: state after ``m + 1`` frames from the state before.
    """
    q = np.asarray(q, np.complex128)
    nb, k, f = q.size, int(order), int(frames)

    def run(v: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # v [bands, cases, F], s [bands, cases, K] -> outputs [.., F], states after each frame
        s = s.copy()
        ys, states = [], []
        for m in range(f):
            prev = v[..., m]
            for j in range(k):
                s[..., j] = q[:, None] * s[..., j] + prev
                prev = s[..., j]
            ys.append(prev.copy())
            states.append(s.copy())
        return np.stack(ys, -1), np.stack(states, -2)  # [b, c, F], [b, c, F, K]

    eye_f = np.broadcast_to(np.eye(f, dtype=np.complex128), (nb, f, f))
    y, st = run(eye_f, np.zeros((nb, f, k), np.complex128))
    T = y.transpose(0, 2, 1)  # [b, m, n]
    S = st[:, :, -1, :].transpose(0, 2, 1)  # [b, K, n]
    eye_k = np.broadcast_to(np.eye(k, dtype=np.complex128), (nb, k, k))
    y0, st0 = run(np.zeros((nb, k, f), np.complex128), eye_k.copy())
    G = y0.transpose(0, 2, 1)  # [b, m, j]
    P = st0.transpose(0, 2, 3, 1)  # [b, m, K_after, j]
    return {"T": T, "G": G, "S": S, "P": P}


def reference_frames(
    x: np.ndarray, fs_hz: float, freqs_hz: Sequence[float], hop: int = 1, order: int = 4
) -> np.ndarray:
    """The float64 reference: each band's cascade run sample by sample (``scipy.signal.lfilter``,
    one first-order section per pole, the input's first value as its constant past), sampled at
    the frame instants. ``[..., samples]`` -> complex128 ``[..., bands, samples // hop]``."""
    x = np.asarray(x, np.float64)
    p, g, _ = band_poles(fs_hz, freqs_hz, order)
    d = np.diff(x, axis=-1, prepend=x[..., :1])
    out = []
    for pb, gb in zip(p, g, strict=True):
        y = gb * d.astype(np.complex128)
        for _ in range(order):
            y = scipy.signal.lfilter([1.0], [1.0, -pb], y, axis=-1)
        out.append(y[..., hop - 1 :: hop][..., : x.shape[-1] // hop])
    return np.stack(out, axis=-2)


class CausalGaborScalogram(nn.Module):
    """The causal Gabor scalogram magnitude (see the module docstring).

    Args:
        fs_hz: sampling rate of the input (Hz).
        freqs_hz: band centre frequencies (Hz), each below Nyquist.
        hop: one frame every ``hop`` samples (at the end of each hop).
        order: poles per band (4: a gammatone-like shape; higher is closer to a Gaussian).
    """

    def __init__(
        self, fs_hz: float, freqs_hz: Sequence[float], hop: int = 1, order: int = 4
    ) -> None:
        super().__init__()
        self.fs_hz = check_positive(fs_hz, "fs_hz")
        self.freqs_hz = check_bands(freqs_hz, self.fs_hz)
        self.hop = check_int(hop, "hop", 1)
        self.order = check_int(order, "order", 1)
        p, g, self.tau_s = band_poles(self.fs_hz, self.freqs_hz, self.order)
        taps = polyphase_taps(p, g, self.hop, self.order)[:, ::-1]  # oldest sample first
        self.n_taps = taps.shape[1]
        # Conv1d weights, band-major: (band 0 re, band 0 im, band 1 re, ...)
        w = np.stack([taps.real, taps.imag], 1).reshape(-1, 1, taps.shape[1])
        self.register_buffer("fir", torch.from_numpy(np.ascontiguousarray(w)), persistent=False)
        self.q = p**self.hop
        self._maps: dict[int, dict[str, np.ndarray]] = {}
        self._tensors: dict[tuple, torch.Tensor] = {}

    @property
    def n_bands(self) -> int:
        return self.freqs_hz.size

    def maps(self, frames: int) -> dict[str, np.ndarray]:
        """:func:`block_maps` for blocks of ``frames`` (cached)."""
        if frames not in self._maps:
            self._maps[frames] = block_maps(self.q, self.order, frames)
        return self._maps[frames]

    def linear_map_shape(self, window: int) -> tuple[int, int]:
        """``(rows, frames)`` of :meth:`linear_map` for a ``window``-sample input."""
        return self.n_bands, int(window) // self.hop

    @torch.no_grad()
    def linear_map(self, window: int) -> tuple[torch.Tensor, None]:
        """``(response [window, bands, frames] complex128, None)``: ``|x @ response|`` is
        :meth:`forward` (the constant past included: it is linear in the first sample)."""
        eye = torch.eye(int(window), dtype=torch.float64).unsqueeze(1)
        re, im = self.analytic(eye)
        return torch.complex(re, im)[:, 0], None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``[batch, channels, samples]`` -> magnitude ``[batch, channels, bands, samples // hop]``."""
        re, im = self.analytic(x)  # (a size-2 sum over a stacked axis costs more in a graph)
        return torch.sqrt(re * re + im * im)

    def analytic(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Real and imaginary parts ``[batch, channels, bands, frames]`` of one window from the
        zero state: one strided convolution, then the frame recursion one block at a time."""
        b, c, n = x.shape
        frames = n // self.hop
        if frames < 1:
            raise ValueError(f"a window of {n} samples holds no frame of hop {self.hop}")
        rows = x.reshape(b * c, 1, n)[..., : frames * self.hop]
        past = rows[..., :1].expand(-1, -1, self.n_taps - 1)  # the constant past
        re, im, _ = self.frames_from(torch.cat([past, rows], -1), None, want_state=False)
        shape = (b, c, self.n_bands, frames)
        return re.reshape(shape), im.reshape(shape)

    def frames_from(
        self, buf: torch.Tensor, state: torch.Tensor | None, want_state: bool = True
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """The frames of ``buf [rows, 1, taps - 1 + frames * hop]`` (the ``taps - 1`` samples
        before the first frame's hop, then the hops) continuing from ``state [rows, bands, 2 K]``
        (real parts, then imaginary; None: zero). Returns the real and imaginary parts
        ``[rows, bands, frames]`` and the state after the last frame (None unless
        ``want_state``).

        Each block of ``f`` frames is one real MatMul per band: ``[v_re, v_im, s_re, s_im] @ W``
        gives ``[y_re, y_im, s'_re, s'_im]`` (:meth:`block_matrix`), cut by one ``split`` (one
        ``Split`` node in a graph, where slicing and squeezing took seven)."""
        rows = buf.shape[0]
        frames = (buf.shape[-1] - (self.n_taps - 1)) // self.hop
        nb = self.n_bands
        # drop the first hop's leading samples: output i then ends at the i-th hop's last sample
        fir = self.fir.to(device=buf.device, dtype=buf.dtype)
        v = nn.functional.conv1d(buf[..., self.hop - 1 :], fir, stride=self.hop)
        v = v.reshape(rows, nb, 2, frames)  # band-major channels: (band, re / im)
        block = min(frames, BLOCK_FRAMES)
        res, ims = [], []
        for start in range(0, frames, block):
            f = min(block, frames - start)
            keep = want_state or start + f < frames
            blk = v if f == frames else v[..., start : start + f]
            u = blk.reshape(rows, nb, 2 * f)
            if state is not None:
                u = torch.cat([u, state], -1)
            w = self.block_matrix(f, state is not None, keep, buf.dtype, buf.device)
            out = (u.transpose(0, 1) @ w).transpose(0, 1)  # [rows, bands, 2 f (+ 2 K)]
            parts = out.split([f, f, out.shape[-1] - 2 * f] if keep else [f, f], -1)
            res.append(parts[0])
            ims.append(parts[1])
            if keep:
                state = parts[2]
        re = res[0] if len(res) == 1 else torch.cat(res, -1)
        im = ims[0] if len(ims) == 1 else torch.cat(ims, -1)
        return re, im, (state if want_state else None)

    def block_matrix(
        self,
        f: int,
        state_in: bool,
        state_out: bool,
        dtype: torch.dtype,
        device: torch.device | None = None,
    ) -> torch.Tensor:
        """``[bands, 2 f (+ 2 K), 2 f (+ 2 K)]``: a block of ``f`` frames (and the state before
        it, ``state_in``) -> its outputs (and the state after it, ``state_out``): the complex
        maps of :func:`block_maps` in real form, for a row vector ``[re..., im...]`` times it."""
        device = torch.device("cpu") if device is None else torch.device(device)
        key = (f, state_in, state_out, dtype, device)
        if key not in self._tensors:
            m = self.maps(max(f, BLOCK_FRAMES))
            big = m["T"].shape[1]
            T, G = m["T"][:, :f, :f], m["G"][:, :f]
            S, P = m["S"][:, :, big - f :], m["P"][:, f - 1]
            # outputs from inputs: [y; s'] = [[T, G], [S, P]] (the parts asked for)
            top = np.concatenate([T, G], 2) if state_in else T
            if state_out:
                top = np.concatenate([top, np.concatenate([S, P], 2) if state_in else S], 1)
            w = _real_form(top.transpose(0, 2, 1), f, self.order, state_in, state_out)
            # (a traced graph copies it at every block; the export merges identical constants)
            self._tensors[key] = torch.from_numpy(w).to(device=device, dtype=dtype)
        return self._tensors[key]


def _real_form(a: np.ndarray, f: int, k: int, state_in: bool, state_out: bool) -> np.ndarray:
    """Complex row-vector maps ``a [bands, n_in, n_out]`` (``f`` frames, then ``K`` states where
    asked, on either side) -> real ``[bands, 2 n_in, 2 n_out]`` on the layout ``[frames re,
    frames im, states re, states im]``, the output in the same layout."""

    def parts(with_state: bool) -> list[slice]:
        return [slice(0, f)] + ([slice(f, f + k)] if with_state else [])

    rows = []
    for part_in in parts(state_in):
        for imag in (False, True):
            row = []
            for part_out in parts(state_out):
                blk = a[:, part_in, part_out]
                # (u_re + i u_im) a: u_re -> (a_re, a_im), u_im -> (-a_im, a_re)
                row += [-blk.imag, blk.real] if imag else [blk.real, blk.imag]
            rows.append(np.concatenate(row, 2))
    return np.ascontiguousarray(np.concatenate(rows, 1))


class CausalGaborStream:
    """Streams :class:`CausalGaborScalogram` over chunks of any length (NumPy fast path).

    ``push(chunk [channels, n])`` returns the magnitudes of the frames completed by the chunk,
    ``[channels, bands, frames]``; the concatenated output of any chunking equals one pass over the
    whole input (:func:`reference_frames`). State: the last ``taps - 1`` samples (plus the samples
    of an unfinished hop) and each band's ``K`` recursion values.
    """

    def __init__(self, bank: CausalGaborScalogram, channels: int, dtype: type = np.float32) -> None:
        self.bank, self.channels = bank, check_int(channels, "channels", 1)
        self.dtype = np.dtype(dtype)
        if self.dtype not in (np.float32, np.float64):
            raise ValueError(f"dtype must be float32 or float64, got {self.dtype}")
        taps = polyphase_taps(
            *band_poles(bank.fs_hz, bank.freqs_hz, bank.order)[:2], bank.hop, bank.order
        )
        cdt = np.complex64 if self.dtype == np.float32 else np.complex128
        # [taps, bands] with the newest sample last, as real and imaginary columns
        t = taps[:, ::-1].T
        self._fir = np.concatenate([t.real, t.imag], axis=1).astype(self.dtype)
        m = bank.maps(BLOCK_FRAMES)
        self._T = m["T"].astype(cdt)
        self._G = m["G"].astype(cdt)
        self._S = m["S"].astype(cdt)
        self._P = m["P"].astype(cdt)
        self._tail: np.ndarray | None = None  # [channels, taps - 1 + unfinished]
        self._state = np.zeros((channels, bank.n_bands, bank.order), cdt)
        self.samples_seen = 0

    def push(self, chunk: np.ndarray) -> np.ndarray:
        x = np.asarray(chunk)
        if x.ndim != 2 or x.shape[0] != self.channels:
            raise ValueError(
                f"chunk must be [channels={self.channels}, samples], got shape {x.shape}"
            )
        if not np.all(np.isfinite(x)):
            raise ValueError("chunk holds NaN or Inf")
        x = x.astype(self.dtype, copy=False)
        bank, nt = self.bank, self.bank.n_taps
        if self._tail is None:
            if x.shape[1] == 0:
                return np.zeros((self.channels, bank.n_bands, 0), self.dtype)
            self._tail = np.repeat(x[:, :1], nt - 1, axis=1)
        buf = np.concatenate([self._tail, x], axis=1)
        self.samples_seen += x.shape[1]
        frames = (buf.shape[1] - (nt - 1)) // bank.hop
        used = (nt - 1) + frames * bank.hop
        self._tail = buf[:, used - (nt - 1) :].copy()
        if frames == 0:
            return np.zeros((self.channels, bank.n_bands, 0), self.dtype)
        win = sliding_window_view(buf[:, :used], nt, axis=1)[:, bank.hop - 1 :: bank.hop]
        vv = win.reshape(-1, nt) @ self._fir  # [channels * frames, 2 bands]
        nb = bank.n_bands
        v = (vv[:, :nb] + 1j * vv[:, nb:]).reshape(self.channels, frames, nb).transpose(2, 0, 1)
        out = np.empty((nb, self.channels, frames), v.dtype)
        s = self._state.transpose(1, 0, 2)  # [bands, channels, K]
        for start in range(0, frames, BLOCK_FRAMES):
            f = min(BLOCK_FRAMES, frames - start)
            blk = v[:, :, start : start + f]
            out[:, :, start : start + f] = blk @ self._T[:, :f, :f].transpose(
                0, 2, 1
            ) + s @ self._G[:, :f].transpose(0, 2, 1)
            s = blk @ self._S[:, :, -f:].transpose(0, 2, 1) + s @ self._P[:, f - 1].transpose(
                0, 2, 1
            )
        self._state = np.ascontiguousarray(s.transpose(1, 0, 2))
        return np.abs(out).transpose(1, 0, 2).astype(self.dtype, copy=False)
