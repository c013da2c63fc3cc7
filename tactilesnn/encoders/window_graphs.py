"""Window encoders as plain matrix products, for ONNX export (opset >= 17).

For a fixed window length a scalogram is a fixed linear map of the window followed by a modulus
(and, for the STFT, a band pooling): the map is the scalogram's own :meth:`linear_map` (built by
transforming unit impulses with the FFT implementation itself, edges included), expressed as two
MatMuls (real and imaginary parts). Array contract of :class:`WindowEncoder`: ``[batch, channels,
window]`` float32 -> spike times ``[batch, neurons]`` float32 (ms, ``+inf`` = silent).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations, pairwise
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from .latency import LatencyCode


class WindowEncoder(nn.Module):
    """(Channel selection ->) scalogram as MatMuls -> latency code, for one window length.

    ``scalogram``: any module with ``linear_map(window) -> (response, pool or None)``.
    ``float64``: the products, moduli and pooling in float64 (the result float32), for a
    transform whose torch form is float64 too: the two then agree to float32 rounding, where a
    float32 product of a long window errs by ~1e-5 of the peak, 10 % of a band 60 dB below it.
    """

    def __init__(
        self,
        scalogram: nn.Module,
        code: LatencyCode,
        window: int,
        channel_idx: Sequence[int] | None = None,
        float64: bool = False,
    ) -> None:
        super().__init__()
        self.code = code
        self.float64 = bool(float64)
        dtype = torch.float64 if self.float64 else torch.float32
        self.window = int(window)
        idx = torch.as_tensor(
            list(channel_idx) if channel_idx is not None else [], dtype=torch.long
        )
        self.select = channel_idx is not None
        self.register_buffer("channel_idx", idx)
        resp, pool = scalogram.linear_map(self.window)
        self.rows, self.frames = resp.shape[1], resp.shape[2]
        flat = resp.reshape(self.window, -1)
        self.register_buffer("re", flat.real.to(dtype).contiguous())
        self.register_buffer("im", flat.imag.to(dtype).contiguous())
        self.pooled = pool is not None
        self.register_buffer("pool", pool.to(dtype) if pool is not None else torch.empty(0))

    def scalogram(self, x: torch.Tensor) -> torch.Tensor:
        if self.select:
            x = torch.index_select(x, 1, self.channel_idx)
        if self.float64:
            x = x.double()
        re, im = x @ self.re, x @ self.im  # [B, C, rows * frames]
        mag = torch.sqrt(re * re + im * im).reshape(x.shape[0], x.shape[1], self.rows, self.frames)
        if self.pooled:
            mag = torch.einsum("fk,bckt->bcft", self.pool, mag)
        return mag.float() if self.float64 else mag

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.code(self.scalogram(x))


class GaborConvEncoder(nn.Module):
    """Gabor scalogram as an edge pad + 1-D convolution (real and imaginary FIR kernels) ->
    modulus -> latency code. Its size is ``bands x taps``, independent of the window, so long
    windows export where the ``window^2`` matrices of :class:`WindowEncoder` would not fit.
    """

    def __init__(
        self, scalogram: nn.Module, code: LatencyCode, window: int, budget_bytes: int = 64 << 20
    ) -> None:
        super().__init__()
        self.code = code
        self.window = int(window)
        self.pad = scalogram.pad_len(self.window)
        self.reflect = scalogram.padding == "reflect"
        self.hop = int(scalogram.hop)
        k = scalogram.conv_kernels(self.window)  # [F, 2L + 1], lag -L..L
        self.taps = (k.shape[1] - 1) // 2
        self.bands = k.shape[0]
        # conv1d correlates: output t = sum_u in[t + u] w[u], so the kernel is flipped
        w = torch.cat([k.real, k.imag]).flip(1).unsqueeze(1).float()  # [2F, 1, 2L + 1]
        self.register_buffer("weight", w.contiguous())

    def scalogram(self, x: torch.Tensor) -> torch.Tensor:
        b, c, n = x.shape
        flat = x.reshape(b * c, 1, n)
        if self.pad:
            mode = "reflect" if self.reflect else "constant"
            flat = nn.functional.pad(flat, (self.pad, self.pad), mode=mode)
        # output j is centred on padded sample pad + j * hop and needs taps samples either side
        extra = self.taps - self.pad
        if extra > 0:
            flat = nn.functional.pad(flat, (extra, extra))
        elif extra < 0:
            flat = flat[..., -extra : flat.shape[-1] + extra]
        out = nn.functional.conv1d(flat, self.weight, stride=self.hop)
        re, im = out[:, : self.bands], out[:, self.bands :]
        return torch.sqrt(re * re + im * im).reshape(b, c, self.bands, out.shape[-1])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.code(self.scalogram(x))


class FactoredGaborEncoder(nn.Module):
    """Gabor scalogram of one window, each band in the cheapest of three exact linear forms ->
    modulus -> latency code:

    * low rank (low bands, whose response spans few FFT bins): ``x @ U_b`` then ``@ Vh_b``
      (:meth:`~.gwt.GaborScalogram.band_factors`, rank ~ the band's time-bandwidth product);
    * a short FIR convolution, strided by the hop (high bands; one Conv in polyphase form);
    * a dense matrix (what is left, e.g. a band whose Nyquist roll-off gives it a long kernel).

    The low-rank bands' window-side factors ``U_b`` lie in one small subspace (the signals
    band-limited to just above the highest low-rank band: 11 bands of 5-72 Hz at 2 kHz have
    708 real columns spanning 147 dimensions), so the window is first projected on an
    orthonormal basis ``Q`` of that subspace and each ``U_b`` is applied as ``Q^T U_b``:
    ``window x rank`` plus ``rank x columns`` multiply-adds instead of ``window x columns``.

    Same frames and edges as :class:`WindowEncoder` (within ~1e-6 of a band's peak response:
    the rank tolerance), at a fraction of its ``window x bands x frames`` multiply-adds
    (1,000-sample windows, 20 bands, hop 10: 1.13 M instead of 4.0 M per channel; hop 1: 8.9 M
    instead of 40 M).
    """

    #: singular values kept: above this fraction of a band's largest (its error is about that
    #: fraction of the band's peak response; float32 rounding is ~1e-7 of it)
    RANK_TOL = 3e-7
    #: bands whose response spans more bins than this are not factored (the QR costs K^2 n)
    MAX_SUPPORT_BINS = 600
    #: nor bands whose ``window x bins`` factor exceeds this (long windows: the QR's working
    #: arrays are a few times 16 bytes x this)
    MAX_FACTOR_ELEMENTS = 1_000_000
    #: at most this many low-rank groups
    MAX_GROUPS = 3
    #: the FIR bands share one Conv (their longest kernel): onnxruntime's Conv gains more from
    #: output channels than it loses to the zero taps (12 windows x 7 bands at hop 10, 1 thread:
    #: one Conv of 14 channels x 190 taps 119 us, three of 6/4/4 channels x 70/110/190 taps
    #: 176 us)
    MAX_CONV_GROUPS = 1
    #: onnxruntime's one-input-channel strided Conv does ~4x fewer multiply-adds per second
    #: than its MatMul (measured: 11 vs 44 G/s on 1,000-sample windows, 1 thread)
    CONV_PENALTY = 4.0
    #: the one-product form of the low-rank bands is used up to this many times the two-product
    #: form's multiply-adds (it saves ~20 graph nodes per group: ~1 us each in onnxruntime)
    DIRECT_RATIO = 1.5

    def __init__(
        self, scalogram: nn.Module, code: LatencyCode, window: int, budget_bytes: int = 64 << 20
    ) -> None:
        super().__init__()
        self.code = code
        self.window = n = int(window)
        self.hop = int(scalogram.hop)
        self.frames = frames = -(-n // self.hop)
        self.bands = f_total = scalogram.n_bands
        support = scalogram.support_bins(n)
        self.pad = scalogram.pad_len(n)
        self.reflect = scalogram.padding == "reflect"
        if scalogram.padding == "periodic":
            kernels, taps = None, np.full(f_total, np.inf)
        else:
            kernels = scalogram.conv_kernels(n)
            taps = scalogram.band_taps(kernels).astype(float)
            taps[taps > self.pad] = np.inf  # a kernel longer than the padding would wrap
        kind, factors = self._forms(scalogram, n, frames, taps, support, budget_bytes)
        order: list[int] = []
        # low-rank bands, in at most three groups of similar rank: per group one product with
        # its bands' U's (real and imaginary parts, zero columns up to the group's largest rank)
        # and one product batched over its bands with their Vh's (rows = windows x channels)
        first: list[np.ndarray] = []  # every window-side matrix, multiplied in one product
        lr = sorted((b for b in range(f_total) if kind[b] == "low_rank"),
                    key=lambda b: factors[b][0].shape[1])  # fmt: skip
        lr_first, lr_second = self._low_rank_groups(lr, factors, f_total, n, frames, order)
        self.lr_cols = [a.shape[1] for a in lr_first]
        lead = [np.linalg.norm(factors[b][0], 2) for b in lr]  # each band's largest gain
        basis = _shared_basis(lr_first, self.RANK_TOL * min(lead)) if lr_first else None
        self.basis_rank = 0 if basis is None else basis[0].shape[1]
        self.lr_direct = False
        if basis is None:
            first += lr_first
        else:
            first.append(basis[0])
            coef = np.split(basis[1], np.cumsum(self.lr_cols)[:-1], axis=1)
            # through the basis, either each group's U then its Vh's (two products), or every
            # band's whole map from the basis (one product: fewer graph nodes, each ~1 us)
            two_step = basis[1].size + sum(v.size for v in lr_second)
            direct = self.basis_rank * len(lr) * 2 * frames
            self.lr_direct = direct <= self.DIRECT_RATIO * two_step
            if self.lr_direct:
                maps = [np.einsum("rgk,gkf->rgf", c.reshape(len(c), len(v), -1), v)
                        for c, v in zip(coef, lr_second, strict=True)]  # fmt: skip
                lr_second = [np.concatenate(maps, axis=1).reshape(self.basis_rank, -1)]
            else:
                self.register_buffer("lr_coef", torch.from_numpy(basis[1]).float().contiguous())
        self.n_second = len(lr_second)
        for gi, v in enumerate(lr_second):
            self.register_buffer(f"lr_v{gi}", torch.from_numpy(v).float().contiguous())
        self._conv_groups(kernels, taps, kind, order)
        dense = [b for b in range(f_total) if kind[b] == "dense"]
        self.n_dense = len(dense)
        if dense:
            m = torch.stack([scalogram.band_map(n, b) for b in dense], 1)  # [n, bands, frames]
            first.append(torch.stack([m.real, m.imag], 2).reshape(n, -1).numpy())
            order += dense
        self.first_cols = [a.shape[1] for a in first]
        cat = np.concatenate(first, axis=1) if first else np.zeros((n, 0))
        self.register_buffer("first", torch.from_numpy(cat).float().contiguous())
        self.kinds = kind
        perm = np.argsort(order)  # band b sits at position perm[b] of the concatenation
        self.permute = not np.array_equal(perm, np.arange(f_total))
        self.register_buffer("perm", torch.from_numpy(perm).long())
        self.order = order

    def _forms(self, scalogram: nn.Module, n: int, frames: int, taps: np.ndarray,
               support: np.ndarray, budget_bytes: int) -> tuple[list[str], dict]:  # fmt: skip
        """Each band's cheapest exact form (``dense``, ``conv`` or ``low_rank``) by multiply-adds,
        and the low-rank factors of the bands that have them."""
        f_total = len(taps)
        factors: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        kind = []
        dense_ok = 8 * n * frames <= budget_bytes // 4  # one band's float32 columns
        for b in range(f_total):
            cost = {"dense": 2 * n * frames if dense_ok else np.inf}
            cost["conv"] = self.CONV_PENALTY * 2 * frames * (2 * taps[b] + 1)
            if support[b] <= min(self.MAX_SUPPORT_BINS, self.MAX_FACTOR_ELEMENTS // n):
                factors[b] = scalogram.band_factors(n, b, tol=self.RANK_TOL)
                r = factors[b][0].shape[1]
                cost["low_rank"] = 2 * n * r + 4 * r * frames
            if not np.isfinite(min(cost.values())):
                raise ValueError(f"band {b}: no exact form fits a {n}-sample window's budget")
            kind.append(min(cost, key=cost.get))
        return kind, factors

    def _low_rank_groups(self, lr: list[int], factors: dict, f_total: int, n: int, frames: int,
                         order: list[int]) -> tuple[list[np.ndarray], list[np.ndarray]]:  # fmt: skip
        """The low-rank bands ``lr`` (by rank) in at most :data:`MAX_GROUPS` groups of similar
        rank: each group's window-side U's ``[window, columns]`` and its Vh's ``[count, 2 r_max,
        2 frames]``; the groups' bands appended to ``order``."""
        lr_first: list[np.ndarray] = []
        lr_second: list[np.ndarray] = []
        rank = np.array([factors[b][0].shape[1] if b in factors else 0 for b in range(f_total)])
        self.lr_sizes: list[tuple[int, int]] = []
        for group in _split_by_length(lr, rank, self.MAX_GROUPS):
            group = sorted(group)  # band order within a group: often no permutation at the end
            r_max = int(max(rank[b] for b in group))
            u1 = np.zeros((n, len(group), 2, r_max))
            # rows (a, b) = (Re, Im) of x U against [[Vr, Vi], [-Vi, Vr]]:
            # (a + ib)(Vr + iVi) = (a Vr - b Vi) + i (a Vi + b Vr), real and imaginary side by side
            v2 = np.zeros((len(group), 2, r_max, 2, frames))
            for i, b in enumerate(group):
                u, vh = factors[b]
                r = u.shape[1]
                u1[:, i, 0, :r], u1[:, i, 1, :r] = u.real, u.imag
                v2[i, 0, :r, 0], v2[i, 0, :r, 1] = vh.real, vh.imag
                v2[i, 1, :r, 0], v2[i, 1, :r, 1] = -vh.imag, vh.real
            lr_first.append(u1.reshape(n, -1))
            lr_second.append(v2.reshape(len(group), 2 * r_max, 2 * frames))
            self.lr_sizes.append((len(group), r_max))
            order += group
        return lr_first, lr_second

    def _conv_groups(self, kernels, taps: np.ndarray, kind: list[str], order: list[int]) -> None:
        """The convolution bands, their polyphase weights registered; appended to ``order``."""
        f_total = len(taps)
        # convolution bands, in at most MAX_CONV_GROUPS kernel lengths (one: see there)
        conv = sorted((b for b in range(f_total) if kind[b] == "conv"), key=lambda b: taps[b])
        self.conv_half: list[int] = []
        for gi, group in enumerate(_split_by_length(conv, taps, self.MAX_CONV_GROUPS)):
            group = sorted(group)
            half = int(max(taps[b] for b in group))
            centre = (kernels.shape[1] - 1) // 2
            k = kernels[group, centre - half : centre + half + 1]
            # output channels (Re, Im) per band; conv1d correlates (output t = sum_u in[t + u]
            # w[u]), so the kernel is flipped
            w = torch.stack([k.real, k.imag], 1).reshape(2 * len(group), -1)
            w = w.flip(1).unsqueeze(1).float()
            self.register_buffer(f"conv{gi}", polyphase_weight(w, self.hop))
            self.conv_half.append(half)
            order += group

    def macs_per_channel(self) -> int:
        """Multiply-adds of the linear part per channel (what the choice of forms minimised)."""
        fr = self.frames
        total = self.first.numel()
        if self.basis_rank and not self.lr_direct:
            total += self.lr_coef.numel()
        for gi in range(self.n_second):
            total += getattr(self, f"lr_v{gi}").numel()
        for gi, half in enumerate(self.conv_half):
            total += getattr(self, f"conv{gi}").shape[0] * fr * (2 * half + 1)  # nonzero taps
        return int(total)

    def scalogram(self, x: Tensor) -> Tensor:
        """``[B, C, window]`` -> magnitude ``[B, C, bands, frames]``, bands in ``self.order``.

        Every form yields ``[rows, its bands, (Re, Im), frames]``; the reshapes keep the row
        axis as ``-1`` (a constant shape in the exported graph, no run-time size arithmetic)."""
        b, c = x.shape[:2]
        n, fr = self.window, self.frames  # static sizes: constants in the exported graph
        flat = x.reshape(-1, n)
        parts = torch.split(flat @ self.first, self.first_cols, dim=1) if self.first_cols else ()
        z: list[Tensor] = []
        if self.lr_direct:  # window -> shared basis -> every low-rank band at once
            count = sum(k for k, _ in self.lr_sizes)
            z.append((parts[0] @ self.lr_v0).reshape(-1, count, 2, fr))
        elif self.lr_sizes:
            lr_parts = parts[: len(self.lr_sizes)]
            if self.basis_rank:  # window -> shared basis -> each group's U
                lr_parts = torch.split(parts[0] @ self.lr_coef, self.lr_cols, dim=1)
            for gi, (count, r_max) in enumerate(self.lr_sizes):
                y = lr_parts[gi].reshape(-1, count, 2 * r_max).transpose(0, 1)
                out = torch.matmul(y, getattr(self, f"lr_v{gi}"))  # [count, rows, 2 frames]
                z.append(out.transpose(0, 1).reshape(-1, count, 2, fr))
        if self.conv_half:
            padded = flat.unsqueeze(1)
            if self.pad:
                mode = "reflect" if self.reflect else "constant"
                padded = nn.functional.pad(padded, (self.pad, self.pad), mode=mode)
            length = self.window + 2 * self.pad
            for gi, half in enumerate(self.conv_half):
                weight = getattr(self, f"conv{gi}")
                # the samples the polyphase Conv reads, in one slice: from half before the window
                # on; past half after it they meet zero taps only (padded with zeros if short)
                start = self.pad - half
                stop = start + (fr + weight.shape[-1] - 1) * self.hop
                seg = padded[..., start : min(stop, length)]
                if stop > length:
                    seg = nn.functional.pad(seg, (0, stop - length))
                out = polyphase_conv(seg, weight, fr)
                z.append(out.reshape(-1, weight.shape[0] // 2, 2, fr))
        if self.n_dense:
            z.append(parts[-1].reshape(-1, self.n_dense, 2, fr))
        zz = torch.cat(z, 1) if len(z) > 1 else z[0]
        return torch.sqrt((zz * zz).sum(2)).reshape(b, c, self.bands, fr)

    def forward(self, x: Tensor) -> Tensor:
        """The bands are coded in the order the forms produce them (the code's per-band
        statistics and its peak normalisation do not depend on it), then put in band order."""
        times = self.code(self.scalogram(x))
        if not self.permute:
            return times
        a = times.shape[1]
        grouped = times.reshape(-1, a // self.bands, self.bands)
        return grouped.index_select(2, self.perm).reshape(-1, a)


def polyphase_weight(weight: Tensor, hop: int) -> Tensor:
    """A strided convolution's kernel ``[out, 1, K]`` in the form :func:`polyphase_conv` uses:
    ``[out, hop, ceil(K / hop)]``, tap ``j`` at phase ``j % hop``, position ``j // hop``."""
    out, _, k = weight.shape
    q = -(-k // hop)
    padded = nn.functional.pad(weight, (0, q * hop - k))
    return padded.reshape(out, q, hop).transpose(1, 2).contiguous()


def polyphase_conv(seg: Tensor, weight: Tensor, frames: int) -> Tensor:
    """``conv1d(seg, w, stride=hop)`` with ``seg [N, 1, L]``, computed as a stride-1
    convolution of the signal's ``hop`` phases with ``weight = polyphase_weight(w, hop)``:
    the same multiply-adds, but onnxruntime runs a ``hop``-channel stride-1 Conv faster than a
    one-channel strided one (12 signals of 1,184 samples, 6 kernels of 185 taps, hop 10: 88
    instead of 122 us, 1 thread). Returns ``[N, out, frames]``."""
    _, hop, q = weight.shape
    if hop == 1:
        return nn.functional.conv1d(seg, weight)[..., :frames]
    blocks = frames + q - 1
    length = seg.shape[-1]
    if blocks * hop > length:  # the extra samples meet zero taps only
        seg = nn.functional.pad(seg, (0, blocks * hop - length))
    elif blocks * hop < length:
        seg = seg[..., : blocks * hop]
    phases = seg.reshape(seg.shape[0], blocks, hop).transpose(1, 2)  # [N, hop, blocks]
    return nn.functional.conv1d(phases, weight)


def _shared_basis(
    blocks: list[np.ndarray], tol: float, max_elements: int = 20_000_000
) -> tuple[np.ndarray, np.ndarray] | None:
    """``[Q, C]`` with ``Q`` orthonormal ``[window, R]`` and ``Q @ C`` equal to the blocks side
    by side, up to singular values below ``tol`` (absolute); None when the product through the
    basis (``window x R + R x columns``) is no cheaper than the blocks themselves, or when the
    blocks are too large to decompose quickly (more than ``max_elements``)."""
    w = np.concatenate(blocks, axis=1)
    n, cols = w.shape
    if w.size > max_elements:
        return None
    q, sv, vt = np.linalg.svd(w, full_matrices=False)
    rank = max(1, int((sv > tol).sum()))
    if n * rank + rank * cols >= n * cols:
        return None
    return q[:, :rank], sv[:rank, None] * vt[:rank]


def _split_by_length(bands: list[int], size: np.ndarray, groups: int) -> list[list[int]]:
    """``bands`` (sorted by ``size``: kernel half-length or rank) cut into at most ``groups``
    runs so that the summed ``run length x largest size in the run`` is smallest."""
    if not bands:
        return []
    best: tuple[float, list[list[int]]] = (np.inf, [])
    m = len(bands)
    for cuts in _cut_points(m, min(groups, m)):
        runs = [bands[a:e] for a, e in pairwise([0, *cuts, m])]
        total = sum(len(r) * (2 * size[r[-1]] + 1) for r in runs)
        if total < best[0]:
            best = (total, runs)
    return best[1]


def _cut_points(m: int, groups: int):
    for k in range(groups):
        yield from combinations(range(1, m), k)


def export_window_encoder(
    encoder: WindowEncoder, n_channels: int, path: str | Path, opset: int = 17
) -> Path:
    """Write ``encoder`` as ONNX with a dynamic batch axis (opset at least ``opset``: the
    ``torch.export``-based exporter writes 18); returns the path."""
    import onnx

    from ..core.onnx_graph import component_to_onnx

    path = Path(path)
    dummy = torch.randn(2, n_channels, encoder.window, generator=torch.Generator().manual_seed(0))
    model = component_to_onnx(encoder, (dummy,), ["window"], ["spike_times_ms"], opset=opset)
    onnx.save(model, str(path))
    return path
