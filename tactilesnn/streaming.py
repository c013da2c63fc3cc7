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

import numpy as np
import torch

from .core.data import join_run, recording_runs
from .pipeline import SpikePipeline


@torch.no_grad()
def stream_evaluation(pipe: SpikePipeline, X: np.ndarray, y: np.ndarray, scan: np.ndarray,
                      window_scores: np.ndarray) -> dict | None:  # fmt: skip
    """The module docstring's figures for test windows ``X [N, C, W]``, labels ``y``, recording
    ids ``scan`` and their scores alone ``window_scores [N, classes]``; None when the pipeline
    does not step frames or no windows tile a recording."""
    if pipe.frame_problem() is not None:
        return None
    x = pipe.encoder_input(X)
    runs = recording_runs(x, scan)
    if not runs:
        return None
    enc, model = pipe.encoder, pipe.model
    hop = round(enc.frame_period_ms * pipe.fs_hz / 1000.0)
    frame_ms = 1000.0 * hop / pipe.fs_hz
    scores = np.asarray(window_scores, np.float64).copy()
    latencies, settled, decided, correct = [], 0, 0, 0
    segments = 0
    for members, shift in runs:
        rec = join_run(x, members, shift)
        spikes = enc.frame_spikes(rec)  # [frames, A]
        out, dec, _ = model.stream(spikes[:, None])
        out, dec = out[:, 0].numpy(), dec[:, 0].numpy()
        ends = (np.arange(len(members)) * shift + pipe.window) // hop - 1  # window-end frames
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
            d = dec[onset : last + 1]
            wrong = np.flatnonzero((d >= 0) & (d != c))
            start = wrong[-1] + 1 if wrong.size else 0
            hits = np.flatnonzero(d[start:] == c)
            if hits.size:
                settled += 1
                latencies.append((start + hits[0] + 1) * frame_ms)  # known at the frame's end
    pred = scores.argmax(1)
    out_d: dict = {"frame_ms": frame_ms, "per_window": float((pred == y).mean()),
                   "windows_in_streams": int(sum(len(m) for m, _ in runs)),
                   "segments": segments, "settled_fraction": settled / max(segments, 1),
                   "decided_frames": decided,
                   "decided_accuracy": correct / decided if decided else None}  # fmt: skip
    if latencies:
        q = np.percentile(latencies, [25, 50, 75])
        out_d["decision_latency_ms"] = {"median": float(q[1]), "q25": float(q[0]),
                                        "q75": float(q[2])}  # fmt: skip
    per_rec = _per_recording(scores, y, scan)
    if per_rec is not None:
        out_d["per_recording"] = per_rec
    return out_d


def _per_recording(scores: np.ndarray, y: np.ndarray, scan: np.ndarray) -> float | None:
    ids, inv = np.unique(scan, return_inverse=True)
    if ids.size == y.size:
        return None
    total = np.zeros((ids.size, scores.shape[1]))
    np.add.at(total, inv, scores)
    lab = np.full(ids.size, -1)
    lab[inv] = y
    same = np.array([np.all(y[inv == i] == lab[i]) for i in range(ids.size)])
    if not same.all():
        return None
    return float((total.argmax(1) == lab).mean())
