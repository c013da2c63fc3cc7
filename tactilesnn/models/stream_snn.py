"""A spiking classifier that runs on without windows: ``stream``.

The input spikes are read one frame at a time (``dt_ms``; by default the encoder's frame: the
window's duration over its spike slots, which for the ``frames`` code is one frame per step). A
hidden LIF layer and a leaky readout keep their state from frame to frame, and the readout's
membranes are the class scores *at every frame* (:func:`~tactilesnn.models.functional.
stream_step`, the same arithmetic in training, in torch streams and in the exported one-frame
graph)::

    i_t = W_in x_t + b_in  (a gather of the rows that fired)    u_t: LIF (tau_ms, threshold 1)
    v_t = beta_o v_{t-1} + W_out s_t + b_out                     scores at frame t: v_t

Training is truncated back-propagation through time: every training window is a segment of
its stream starting from rest, and the loss is the cross-entropy of the scores at every frame
after the first ``burn_in`` of the window (a label per frame), so the readout is right at
every frame, not only at a window's end. A window's score (the contract's :meth:`scores`) is
the readout at its last frame.

In a stream: the decision at a frame is the leading class where it leads the runner-up by at
least the fitted ``decision_margin`` (else undecided, -1); the state returns to rest after
``quiet_ms`` without an input spike (release / no contact). :meth:`StreamSNNModel.
frame_module` is that step for the export; :meth:`StreamSNNModel.stream` its torch form over
many frames.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor, nn

from ..schema.models import StreamSNNConfig
from .base import SpikeModel, register_model, seeded
from .functional import (
    StreamState,
    class_lead,
    decay_factor,
    li_closed,
    li_decay_matrix,
    stream_step,
)
from .onnx_ops import raster_current
from .snn import LIFLayer, _LSTMWeights, _SpikeFn


def frame_raster(times: Tensor, dt_ms: float, steps: int) -> Tensor:
    """Spike times ``[B, A, k]`` (ms; inf = none) -> counts ``[steps, B, A]``, as
    :func:`~tactilesnn.core.spikes.spike_raster` bins them (a spike at exactly the window's end
    in the last step; others outside dropped), by one scatter: memory ``O(steps B A)``, not
    ``O(steps B A k)``."""
    b, a, _ = times.shape
    idx = torch.floor(times / dt_ms)
    idx = torch.where(idx == float(steps), idx - 1.0, idx)
    ok = (idx >= 0) & (idx < steps)
    flat = torch.where(ok, idx, torch.zeros_like(idx)).long() * (b * a)
    flat = flat + torch.arange(b * a, device=times.device).view(b, a, 1)
    out = torch.zeros(steps * b * a, dtype=times.dtype, device=times.device)
    out.scatter_add_(0, flat[ok], torch.ones_like(times)[ok])
    return out.view(steps, b, a)


@register_model("stream", StreamSNNConfig)
class StreamSNNModel(SpikeModel):
    """See the module docstring. Window graph state: ``h_state`` (hidden membrane), ``o_state``
    (readout membrane) and, recurrent, ``hs_state``."""

    score_units = "stream SNN readout membrane at the window's last frame"
    has_frame_step = True
    #: window epochs, then ``stream_epochs`` over the recordings as streams (hook_loop, 15 vs 40
    #: window epochs alone: 99.12 vs 99.37 % per window; FabricSlide's 40 took ~17 min)
    default_epochs = 15
    optional_state = ("decision_margin",)
    NEVER = float(torch.finfo(torch.float32).max)
    CALIBRATION_WINDOWS = 2048

    def __init__(self, config: StreamSNNConfig, n_afferents: int, max_spikes: int,
                 n_classes: int, duration_ms: float, seed: int = 0) -> None:  # fmt: skip
        super().__init__(config, n_afferents, max_spikes, n_classes, duration_ms, seed)
        self.dt_ms = float(config.dt_ms) or self.duration_ms / self.max_spikes
        self.steps = max(1, round(self.duration_ms / self.dt_ms))
        with seeded(seed):
            self.hidden = LIFLayer(n_afferents, config.hidden, tau_mem_ms=config.tau_ms,
                                   dt_ms=self.dt_ms, recurrent=config.recurrent)  # fmt: skip
            self.out = nn.Linear(config.hidden, n_classes)
        self.readout_tau_ms = float(config.readout_tau_ms) or 2.0 * self.duration_ms
        self.beta_o = decay_factor(self.dt_ms, self.readout_tau_ms)
        self.register_buffer("decay", li_decay_matrix(self.steps, self.beta_o), persistent=False)
        self.register_buffer("decision_margin", torch.tensor(self.NEVER))
        self.burn = min(self.steps - 1, int(config.burn_in * self.steps))
        q = config.quiet_ms / self.dt_ms
        self.quiet_frames = float(max(1, round(q))) if config.quiet_ms > 0 else math.inf

    # ------------------------------------------------------------------ windows
    def raster(self, spikes: Tensor) -> Tensor:
        return frame_raster(spikes, self.dt_ms, self.steps)

    def trajectory(self, spikes: Tensor) -> Tensor:
        """Spike times ``[B, A, k]`` -> readout ``[steps, B, classes]`` from rest (a window)."""
        h, _ = self.hidden(self.raster(spikes))
        cur = self.out(h)
        v0 = torch.zeros_like(cur[0])
        return li_closed(cur, v0, self.beta_o, self.decay.to(cur.dtype))

    def scores(self, spikes: Tensor) -> Tensor:
        return self.trajectory(spikes)[-1]

    def loss(self, spikes: Tensor, y: Tensor) -> Tensor:
        v = self.trajectory(spikes)[self.burn :]  # [T', B, classes]
        return nn.functional.cross_entropy(v.reshape(-1, v.shape[-1]), y.repeat(v.shape[0]))

    def learning_rate(self) -> float:
        return self.config.lr

    def bytes_per_sample(self, afferents: int, k: int) -> int:
        units = afferents * (k + 2) + 4 * self.config.hidden + 3 * self.n_classes
        return 4 * self.steps * units

    @torch.no_grad()
    def calibrate_decision(self, spikes: Tensor) -> None:
        """The smallest margin (among 256 quantiles of the leads past the burn-in, and
        :attr:`NEVER`) at which a decided frame's class is its window's final class on
        ``early_agreement`` of the decided frames."""
        n = spikes.shape[0]
        if n == 0 or self.n_classes < 2:
            return
        pick = torch.linspace(0, n - 1, min(n, self.CALIBRATION_WINDOWS)).round().long().unique()
        leads, same = [], []
        for i in range(0, len(pick), 256):
            v = self.trajectory(spikes[pick[i : i + 256]])[self.burn :]
            lead, leader = class_lead(v)
            leads.append(lead.flatten())
            same.append((leader == v[-1].argmax(-1)).flatten())
        self.decision_margin.fill_(self._smallest_margin(torch.cat(leads), torch.cat(same)))

    def _smallest_margin(self, lead: Tensor, agree: Tensor) -> float:
        """The smallest of 256 quantiles of the positive ``lead`` s at which the frames that
        lead by at least it ``agree`` on ``early_agreement`` of them (else :attr:`NEVER`)."""
        if not bool((lead > 0).any()):
            return self.NEVER
        for m in np.unique(np.quantile(lead[lead > 0].double().numpy(), np.linspace(0, 1, 257))):
            hit = lead >= float(m)
            if hit.any() and float(agree[hit].float().mean()) >= self.config.early_agreement:
                return float(m)
        return self.NEVER

    # ------------------------------------------------------------------ streams
    @property
    def frame_period_ms(self) -> float:
        return self.dt_ms

    def initial_stream_state(self, batch: int, dtype: torch.dtype = torch.float32) -> StreamState:
        z = torch.zeros(batch, self.config.hidden, dtype=dtype)
        return StreamState(z, torch.zeros(batch, self.n_classes, dtype=dtype),
                           torch.zeros(batch, 1, dtype=dtype),
                           torch.zeros_like(z) if self.config.recurrent else None)  # fmt: skip

    @torch.no_grad()
    def stream(self, frames: Tensor, state: StreamState | None = None
               ) -> tuple[Tensor, Tensor, StreamState]:  # fmt: skip
        """Input spikes ``[frames, B, A]`` (0/1 per frame) from ``state`` (None: rest) ->
        ``(scores [frames, B, classes], decisions [frames, B] int64, -1 = undecided, state)``:
        the frame step, frame after frame, with the release reset."""
        st = self.initial_stream_state(frames.shape[1], frames.dtype) if state is None else state
        w_in, b_in = self.hidden.fc.weight, self.hidden.fc.bias
        w_rec = self.hidden.rec.weight if self.hidden.rec is not None else None
        cur = torch.matmul(frames, w_in.t()) + b_in
        out = torch.empty(frames.shape[0], frames.shape[1], self.n_classes, dtype=frames.dtype)
        for t in range(frames.shape[0]):
            _, st = stream_step(cur[t], frames[t], st, self.out.weight, self.out.bias,
                                self.hidden.beta, self.beta_o, self.quiet_frames, w_rec)  # fmt: skip
            out[t] = st.v
        return out, decide(out, self.decision_margin), st

    def _stream_grad(self, frames: Tensor, st: StreamState) -> tuple[Tensor, StreamState]:
        """:meth:`stream` with surrogate gradients: scores ``[frames, B, classes]``."""
        w_rec = self.hidden.rec.weight if self.hidden.rec is not None else None
        cur = torch.matmul(frames, self.hidden.fc.weight.t()) + self.hidden.fc.bias
        spike = lambda x: _SpikeFn.apply(x, self.hidden.surrogate, self.hidden.alpha)  # noqa: E731
        out = []
        for t in range(frames.shape[0]):
            _, st = stream_step(cur[t], frames[t], st, self.out.weight, self.out.bias,
                                self.hidden.beta, self.beta_o, self.quiet_frames, w_rec, spike)  # fmt: skip
            out.append(st.v)
        return torch.stack(out), st

    def fit_streams(self, streams: list[tuple[Tensor, Tensor]], batch: int = 64,
                    progress: bool = False) -> list[float]:  # fmt: skip
        """Truncated back-propagation through time over whole recordings: ``streams``, per
        recording its input spikes ``[frames, A]`` (bool or float) and a label per frame
        ``[frames]`` (int64, -1 where a frame has none: before contact, past the end).
        ``stream_epochs`` passes, each over mini-batches of ``batch`` recordings of similar
        length, run in chunks of one window's frames (built chunk by chunk: memory does not
        grow with the recordings' length) with the state carried (detached) from chunk to
        chunk; the loss is every labelled frame's cross-entropy. Then the decision margin is
        fitted on the streams. Returns each epoch's mean loss. (Each frame is one Python step
        for a whole mini-batch: hook_loop's 320 recordings of 2,000 frames took 3 min for 10
        epochs in mini-batches of 16.)"""
        from tqdm.auto import tqdm

        from ..core.stages import bar_disabled

        # a fine-tuning of the window-trained weights: a third of their learning rate
        opt = torch.optim.Adam(self.parameters(), lr=self.config.lr / 3)
        order = sorted(range(len(streams)), key=lambda i: len(streams[i][1]))
        groups = [order[i : i + batch] for i in range(0, len(order), batch)]
        gen = torch.Generator().manual_seed(0)
        losses = []
        bar = tqdm(range(self.config.stream_epochs), desc="streams (TBPTT)", unit="epoch",
                   disable=bar_disabled(progress))  # fmt: skip
        for _ in bar:
            total, count = 0.0, 0
            for g in torch.randperm(len(groups), generator=gen).tolist():
                idx = groups[g]
                st = self.initial_stream_state(len(idx))
                longest = max(len(streams[i][1]) for i in idx)
                for t0 in range(0, longest, self.steps):
                    x, lab = _chunk([streams[i] for i in idx], t0, self.steps)
                    if not bool((lab >= 0).any()):
                        st = _detached(self.stream(x, st)[2])  # (no labels: state only)
                        continue
                    v, st = self._stream_grad(x, st)
                    loss = nn.functional.cross_entropy(v.reshape(-1, v.shape[-1]),
                                                       lab.reshape(-1), ignore_index=-1)  # fmt: skip
                    opt.zero_grad()
                    loss.backward()
                    opt.step()
                    n = int((lab >= 0).sum())
                    total, count = total + float(loss.detach()) * n, count + n
                    st = _detached(st)
            losses.append(total / max(count, 1))
        self.calibrate_stream_decision(streams)
        return losses

    @torch.no_grad()
    def calibrate_stream_decision(self, streams: list[tuple[Tensor, Tensor]]) -> None:
        """The smallest margin (among 256 quantiles of the leads, and :attr:`NEVER`) at which
        the decided frames of ``streams`` (as :meth:`fit_streams` takes them) name their label
        on ``early_agreement`` of them."""
        if self.n_classes < 2:
            return
        leads, agrees = [], []
        for spikes, labels in streams:
            v, _, _ = self.stream(spikes.float()[:, None])
            lead, leader = class_lead(v[:, 0])
            ok = labels >= 0
            leads.append(lead[ok])
            agrees.append((leader == labels)[ok])
        self.decision_margin.fill_(self._smallest_margin(torch.cat(leads), torch.cat(agrees)))

    def frame_module(self, gather: bool = False) -> nn.Module:
        """The one-frame step for the export (:class:`_StreamStep`); ``gather``: the input
        current as a gather of the weight rows of the afferents that fired (else one dense
        product)."""
        return _StreamStep(self, gather)

    # ------------------------------------------------------------------ export
    @property
    def state_names(self) -> tuple[tuple[str, int], ...]:
        names = [("h_state", self.config.hidden), ("o_state", self.n_classes)]
        if self.config.recurrent:
            names.append(("hs_state", self.config.hidden))
        return tuple(names)

    def onnx_module(self) -> nn.Module:
        return _StreamWindowGraph(self)


def decide(scores: Tensor, margin: Tensor) -> Tensor:
    """Scores ``[..., classes]`` -> the leading class where it leads the runner-up by at least
    ``margin``, else -1 (int64 ``[...]``)."""
    if scores.shape[-1] < 2:
        return torch.zeros(scores.shape[:-1], dtype=torch.long)
    top = scores.topk(2, dim=-1)
    # the lead as one product with (1, -1): fewer graph nodes than two slices and a difference
    lead = torch.matmul(top.values, _LEAD.to(scores.dtype))
    leader = top.indices.select(-1, 0)
    return torch.where(lead >= margin, leader, _UNDECIDED)


_LEAD = torch.tensor([1.0, -1.0])
_UNDECIDED = torch.tensor(-1)  # (a constant: no nodes to build it in a graph)


class _StreamStep(nn.Module):
    """``(spikes [B, A] this frame, h, o, quiet[, hs])`` -> ``(scores [B, classes], decision
    [B] int64, h, o, quiet[, hs])``: :func:`~.functional.stream_step` once."""

    def __init__(self, model: StreamSNNModel, gather: bool) -> None:
        super().__init__()
        self.gather = bool(gather)
        self.register_buffer("w_in_t", model.hidden.fc.weight.detach().t().contiguous().clone())
        self.register_buffer("b_in", model.hidden.fc.bias.detach().clone())
        self.register_buffer("w_out", model.out.weight.detach().clone())
        self.register_buffer("b_out", model.out.bias.detach().clone())
        rec = model.hidden.rec
        self.register_buffer("w_rec", rec.weight.detach().clone() if rec is not None else None)
        self.register_buffer("margin", model.decision_margin.detach().clone())
        self.beta_h, self.beta_o = float(model.hidden.beta), float(model.beta_o)
        self.quiet_frames = float(model.quiet_frames)
        self.state_names = [*model.state_names[:2], ("quiet_state", 1), *model.state_names[2:]]

    def forward(self, x: Tensor, h: Tensor, o: Tensor, quiet: Tensor, *hs: Tensor):
        if self.gather:  # batch 1: the rows of the afferents that fired, summed
            rows = torch.nonzero(x[0] > 0).flatten()
            cur = (torch.index_select(self.w_in_t, 0, rows).sum(0) + self.b_in).unsqueeze(0)
        else:
            cur = torch.matmul(x, self.w_in_t) + self.b_in
        state = StreamState(h, o, quiet, hs[0] if hs else None)
        _, st = stream_step(cur, x, state, self.w_out, self.b_out, self.beta_h, self.beta_o,
                            self.quiet_frames, self.w_rec)  # fmt: skip
        # (one tensor may not be two graph outputs)
        out = (st.v.clone(), decide(st.v, self.margin), st.h, st.v, st.quiet)
        return (*out, st.hs) if st.hs is not None else out


class _StreamWindowGraph(nn.Module):
    """The window graph: spikes -> input current (one ``ScatterND``) -> LIF layer (one ``LSTM``)
    -> leaky readout in closed form (one MatMul); ``(scores, h, o[, hs])``."""

    def __init__(self, model: StreamSNNModel) -> None:
        super().__init__()
        fc1 = model.hidden.fc
        self.dt, self.steps = model.dt_ms, model.steps
        self.fc1, self.fc2 = fc1, model.out
        self.register_buffer(
            "updates", fc1.weight.detach().t().repeat_interleave(model.max_spikes, 0)
        )
        rec = model.hidden.rec.weight.detach().clone() if model.hidden.rec is not None else None
        self.register_buffer("w_rec", rec if rec is not None else torch.zeros(0, 0))
        self.lstm = _LSTMWeights(fc1.out_features, model.hidden.beta, 1.0, True, rec)
        self.beta_o = model.beta_o
        self.register_buffer("decay", li_decay_matrix(self.steps, self.beta_o))

    def forward(self, spikes: Tensor, h: Tensor, o: Tensor, *hs: Tensor):
        cur = raster_current(spikes, self.fc1.weight, self.fc1.bias, self.updates, self.dt,
                             self.steps)  # fmt: skip
        hid, h_new, hs_new = self.lstm(cur, h, hs[0] if hs else None, self.w_rec)
        v = li_closed(self.fc2(hid), o, self.beta_o, self.decay)
        return (v[-1], h_new, v[-1], hs_new) if hs else (v[-1], h_new, v[-1])


def _chunk(streams: list[tuple[Tensor, Tensor]], t0: int, steps: int) -> tuple[Tensor, Tensor]:
    """Frames ``[t0, t0 + steps)`` of each stream, zero-padded past its end: input spikes
    ``[steps, B, A]`` float32 and labels ``[steps, B]`` (-1 past the end)."""
    a = streams[0][0].shape[1]
    x = torch.zeros(steps, len(streams), a)
    lab = torch.full((steps, len(streams)), -1, dtype=torch.long)
    for j, (spikes, labels) in enumerate(streams):
        part = spikes[t0 : t0 + steps]
        x[: len(part), j] = part.float()
        lab[: len(part), j] = labels[t0 : t0 + steps]
    return x, lab


def _detached(st: StreamState) -> StreamState:
    return StreamState(*(None if v is None else v.detach() for v in st))
