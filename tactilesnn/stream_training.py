"""A stream model scored as it runs: frame by frame over whole recordings, state carried.

For a pipeline that steps frames (:meth:`SpikePipeline.frame_problem` is None: a continuous
code and a stream model), the test windows that tile a recording
(:func:`~tactilesnn.core.data.recording_runs`) are joined back into it, coded once from its
start (``encoder.frame_spikes``) and run through the model's frame step with its state carried
(``model.stream``, the release reset included). Reported:

* ``per_window``: each window's class read at the frame its window ends (as a stream scores it;
  windows in no run are scored alone, from rest);
* ``per_recording``: the scores at those frames summed per recording (where each recording has
  one label), as the windowed pipelines' per-recording figure sums window scores;
* ``decision_latency_ms``: per label segment (a recording, or a run of windows of one class in
  a scan that changes class), from its onset (the recording's first input spike, or the end of
  the previous class's last window) to the first frame from which every decision until the
  segment ends is its class or undecided (-1), and that frame decides it: the median, its
  quartiles, and the fraction of segments that settle;
* ``decided_frames`` and ``decided_accuracy``: how many frames past the first window decide, and
  how often correctly.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from .core.data import join_run, recording_runs
from .pipeline import SpikePipeline, recording_accuracy


def _frames_and_labels(pipe: SpikePipeline, x: np.ndarray, y: np.ndarray, members: np.ndarray,
                       shift: int, hop: int) -> tuple[torch.Tensor, np.ndarray]:  # fmt: skip
    spikes = pipe.encoder.frame_spikes(join_run(x, members, shift))
    ends = _ends(len(members), shift, pipe.window, hop)
    f = np.arange(spikes.shape[0])
    labels = np.where(f <= ends[-1], y[members][np.minimum(np.searchsorted(ends, f),
                                                          len(ends) - 1)], -1)  # fmt: skip
    active = np.flatnonzero(spikes.sum(1).numpy() > 0)
    # unlabelled until the first window is complete (the windows' burn-in) and contact
    labels[: max(int(ends[0]), int(active[0]) if active.size else len(f))] = -1
    return spikes, labels


def _ends(n: int, shift: int, window: int, hop: int) -> np.ndarray:
    """The frames at which each of ``n`` windows ``shift`` samples apart ends."""
    return (np.arange(n) * shift + window) // hop - 1


def recording_frames(pipe: SpikePipeline, X: np.ndarray, y: np.ndarray, scan: np.ndarray):
    """Each recording the windows ``X`` tile, coded once from its start, one at a time:
    ``(window indices, their end frames, input spikes [frames, afferents], a label per
    frame)``; a frame's label is that of the window ending next, from the end of the first
    window and the first input spike (the contact onset) on; -1 before them and after the last
    window."""
    x = pipe.encoder_input(X)
    hop = pipe.encoder.frame_hop
    for members, shift in recording_runs(x, scan):
        spikes, labels = _frames_and_labels(pipe, x, y, members, shift, hop)
        yield members, _ends(len(members), shift, pipe.window, hop), spikes, labels


#: the training recordings' input spikes kept for the streams' epochs (bool, one byte per
#: afferent and frame) at most this large: evenly spaced recordings up to it
STREAM_BYTES = 128 << 20


def fit_streams(pipe: SpikePipeline, X: np.ndarray, y: np.ndarray, scan: np.ndarray,
                progress: bool = False) -> dict | None:  # fmt: skip
    """After the window epochs: the stream model's truncated back-propagation through time over
    the training recordings (:meth:`~tactilesnn.models.stream_snn.StreamSNNModel.fit_streams`),
    where the pipeline steps frames and its training windows tile recordings; recordings
    evenly spaced among them up to :data:`STREAM_BYTES` of spikes. Returns what it did (None:
    nothing)."""
    if pipe.frame_problem() is not None or pipe.model.config.stream_epochs == 0:
        return None
    x = pipe.encoder_input(X)
    runs = recording_runs(x, scan)
    if not runs:
        return None
    hop = pipe.encoder.frame_hop
    per = [
        (shift * (len(m) - 1) + pipe.window) // hop * pipe.encoder.n_afferents for m, shift in runs
    ]  # bytes of each recording's spikes as bool
    stride = max(1, math.ceil(sum(per) / STREAM_BYTES))  # every stride-th recording
    keep, used = [], 0
    for i in range(0, len(runs), stride):
        if used + per[i] <= STREAM_BYTES:
            keep.append(i)
            used += per[i]
    streams = []
    for i in keep:
        members, shift = runs[i]
        spikes, labels = _frames_and_labels(pipe, x, y, members, shift, hop)
        streams.append((spikes.bool(), torch.from_numpy(labels)))
    if not streams:
        return None
    losses = pipe.model.fit_streams(streams, progress=progress)
    return {"recordings": len(streams), "of_recordings": len(runs),
            "frames": int(sum(int((lab >= 0).sum()) for _, lab in streams)),
            "epochs": len(losses), "loss_history": losses}  # fmt: skip


@torch.no_grad()
def stream_evaluation(pipe: SpikePipeline, X: np.ndarray, y: np.ndarray, scan: np.ndarray,
                      window_scores: np.ndarray) -> dict | None:  # fmt: skip
    """The module docstring's figures for test windows ``X [N, C, W]``, labels ``y``, recording
    ids ``scan`` and their scores alone ``window_scores [N, classes]``; None when the pipeline
    does not step frames or no windows tile a recording."""
    if pipe.frame_problem() is not None:
        return None
    hop = pipe.encoder.frame_hop
    frame_ms = 1000.0 * hop / pipe.fs_hz
    scores = np.asarray(window_scores, np.float64).copy()
    latencies, settled, decided, correct = [], 0, 0, 0
    segments, in_streams = 0, 0
    for members, ends, spikes, _ in recording_frames(pipe, X, y, scan):
        in_streams += len(members)
        out, dec, _ = pipe.model.stream(spikes[:, None])
        out, dec = out[:, 0].numpy(), dec[:, 0].numpy()
        scores[members] = out[ends]
        labels = y[members]
        past = dec[ends[0] :]  # frames past the first window
        lab_at = np.repeat(labels, np.diff(np.append(ends, len(dec))))[: len(past)]
        decided += int((past >= 0).sum())
        correct += int((past == lab_at).sum())
        # label segments: runs of windows of one class
        cuts = np.flatnonzero(np.diff(labels)) + 1
        active = np.flatnonzero(spikes.sum(1).numpy() > 0)
        for seg in np.split(np.arange(len(members)), cuts):
            segments += 1
            c, last = labels[seg[0]], ends[seg[-1]]
            if seg[0] == 0:
                onset = int(active[0]) if active.size else 0
            else:
                onset = ends[seg[0] - 1] + 1
            lat = settle_latency_ms(dec[onset : last + 1], int(c), frame_ms)
            if lat is not None:
                settled += 1
                latencies.append(lat)
    if in_streams == 0:
        return None
    pred = scores.argmax(1)
    out_d: dict = {"frame_ms": frame_ms, "per_window": float((pred == y).mean()),
                   "windows_in_streams": in_streams,
                   "segments": segments, "settled_fraction": settled / max(segments, 1),
                   "decided_frames": decided,
                   "decided_accuracy": correct / decided if decided else None}  # fmt: skip
    if latencies:
        q = np.percentile(latencies, [25, 50, 75])
        out_d["decision_latency_ms"] = {"median": float(q[1]), "q25": float(q[0]),
                                        "q75": float(q[2])}  # fmt: skip
    per_rec = recording_accuracy(scores, y, scan)
    if per_rec is not None:
        out_d["per_recording"] = per_rec["test_accuracy_per_recording"]
    return out_d


def settle_latency_ms(decisions: np.ndarray, label: int, frame_ms: float) -> float | None:
    """From a segment's onset (its first frame) to the end of the first frame from which
    every decision is ``label`` or undecided (-1) and that frame decides ``label``: ``(k + 1)
    frame_ms`` for that frame ``k`` (a decision is known at its frame's end); None if the
    segment never settles on ``label``."""
    d = np.asarray(decisions)
    wrong = np.flatnonzero((d >= 0) & (d != label))
    start = int(wrong[-1]) + 1 if wrong.size else 0
    hits = np.flatnonzero(d[start:] == label)
    return None if hits.size == 0 else (start + int(hits[0]) + 1) * frame_ms
