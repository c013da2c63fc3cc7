"""The encoder contract (raw windows -> spike times) and the encoder registry.

An encoder is a ``torch.nn.Module`` built from its typed configuration (a frozen dataclass with a
``type`` tag), the sampling rate, the window length and the number of channels it receives:

* input: ``X`` ``[N, channels, samples]`` float at ``fs_hz`` in the sensor's units (the pipeline
  has already selected the channels);
* :meth:`SpikeEncoder.fit` learns data-dependent state from training windows and keeps it in
  buffers (so it is in ``state_dict()`` and saved with the run);
* :meth:`SpikeEncoder.encode` -> spike times ``[N, n_afferents, max_spikes]`` float32, in ms from
  the window start, ascending along the last axis, ``+inf`` where a slot holds no spike. This is
  the one spike format between stages; :class:`~tactilesnn.encoders.spiking.SpikeEvents` (event
  lists) converts to and from it;
* :meth:`SpikeEncoder.onnx_module` returns the exported graph of this encoder (same input and
  output), owned by the encoder.

Adding an encoder: its settings class and one ``ENCODERS.declare("name", Config, module)`` line
in :mod:`tactilesnn.schema.encoders` (read without torch), and one module with a
``@register_encoder("name", Config)`` class; nothing else in the package names it.
"""

from __future__ import annotations

import contextlib
import math
from abc import abstractmethod
from collections.abc import Callable, Sequence
from typing import ClassVar

import numpy as np
import torch
from torch import Tensor, nn
from tqdm.auto import tqdm

from ..core.stages import bar_disabled
from ..schema.encoders import ENCODERS


def register_encoder(name: str, config: type) -> Callable[[type], type]:
    """Class decorator: register a :class:`SpikeEncoder` under ``name`` with its config class."""
    return ENCODERS.register(name, config)


def check_recordings_and_starts(recs: Sequence[object], starts: Sequence[object]) -> None:
    """ValueError unless there is one list of window starts per recording."""
    if len(recs) != len(starts):
        raise ValueError(f"{len(recs)} recordings but {len(starts)} lists of starts")


class SpikeEncoder(nn.Module):
    """Base class of every encoder; see the module docstring for the contract."""

    #: the exported module must be scripted (it has a data-dependent loop) rather than traced
    onnx_scripted: ClassVar[bool] = False
    #: the exported module traces under ``torch.export`` (the supported exporter; a scripted
    #: module's loops then as scan operators): else only the TorchScript-based exporter writes it
    onnx_exportable: ClassVar[bool] = True
    #: True when :meth:`fit` learns state that :meth:`encode` needs
    needs_fit: ClassVar[bool] = False
    #: buffers a saved run may lack (added later); they keep their constructed, neutral value
    optional_state: ClassVar[tuple[str, ...]] = ()
    #: codes any analog channels (so it can code a transform's band envelopes: ``bands``)
    codes_envelopes: ClassVar[bool] = False
    #: has a stream form (:meth:`stream_module`: each sample transformed once, state carried)
    has_stream_form: ClassVar[bool] = False
    #: codes one frame at a time with state carried for ever (:meth:`frame_module`): a
    #: continuous code, which a stream model (``--model stream``) steps frame by frame
    has_frame_step: ClassVar[bool] = False

    def __init__(self, config: object, fs_hz: float, window: int, n_channels: int) -> None:
        super().__init__()
        self.config = config
        self.fs_hz, self.window, self.n_channels = float(fs_hz), int(window), int(n_channels)
        self.duration_ms = 1000.0 * self.window / self.fs_hz
        self.register_buffer("fitted", torch.tensor(not self.needs_fit))

    @property
    @abstractmethod
    def n_afferents(self) -> int:
        """Number of afferent neurons (the second axis of the spike times)."""

    @property
    def max_spikes(self) -> int:
        """Spike slots per afferent (the last axis of the spike times)."""
        return 1

    def fit(self, X: np.ndarray) -> SpikeEncoder:
        """Learn data-dependent state from training windows ``[N, channels, samples]``."""
        self.fitted.fill_(True)
        return self

    def check_fitted(self) -> None:
        if not bool(self.fitted):
            raise RuntimeError(f"the {self.registry_name} encoder is not fitted: call fit() first")

    @abstractmethod
    def encode_batch(self, x: Tensor) -> Tensor:
        """``[n, channels, samples]`` float32 -> spike times ``[n, afferents, max_spikes]``."""

    def bytes_per_window(self) -> int:
        """Peak intermediate bytes per window (for batching by a byte budget)."""
        return 64 * self.n_channels * self.window

    def graph_bytes_per_window(self) -> int:
        """Peak intermediate bytes per window of the exported graph (the service's and the
        export check's onnxruntime batches): :meth:`bytes_per_window` unless the graph computes
        differently from the eager code."""
        return self.bytes_per_window()

    @torch.no_grad()
    def encode(
        self,
        X: np.ndarray,
        budget_bytes: int = 1 << 27,
        progress: bool = False,
        device: torch.device | str | None = None,
    ) -> Tensor:
        """``X [N, channels, samples]`` -> spike times ``[N, afferents, max_spikes]`` (ms, on the
        CPU), in batches of at most ``budget_bytes`` working memory (a progress bar if
        ``progress``). ``device``: where the batches are encoded (default: the CPU); the encoder
        is moved there for the call and back to the CPU after it."""
        self.check_fitted()
        arr = np.asarray(X)
        if arr.ndim != 3 or arr.shape[1:] != (self.n_channels, self.window):
            raise ValueError(
                f"encoder input must be [N, {self.n_channels}, {self.window}], got {arr.shape}"
            )
        batch = max(1, min(4096, budget_bytes // max(1, self.bytes_per_window())))
        out = torch.full((arr.shape[0], self.n_afferents, self.max_spikes), math.inf)
        starts = range(0, arr.shape[0], batch)
        bar = tqdm(starts, desc=f"encode ({self.registry_name})", unit="batch",
                   disable=bar_disabled(progress and len(starts) >= 2))  # fmt: skip
        dev = torch.device("cpu") if device is None else torch.device(device)
        moved = dev.type != "cpu"
        if moved:
            self.to(dev)
        try:
            for i in bar:
                chunk = torch.from_numpy(np.ascontiguousarray(arr[i : i + batch], np.float32))
                out[i : i + batch] = self.encode_batch(chunk.to(dev) if moved else chunk).cpu()
        finally:
            if moved:
                self.to("cpu")
        return out

    def transform(self, x: np.ndarray | Tensor) -> Tensor:
        """One window ``[channels, samples]`` -> its spike times ``[afferents, max_spikes]``
        (ms), or a batch ``[N, channels, samples]`` -> ``[N, afferents, max_spikes]``: use it as
        a dataset transform (``WindowDataset.with_transform(encoder.transform)``, tonic style)."""
        arr = x.detach().cpu().numpy() if isinstance(x, Tensor) else np.asarray(x)
        if arr.ndim == 2:
            return self.encode(arr[None])[0]
        return self.encode(arr)

    @property
    def codes_with_past(self) -> bool:
        """Whether :meth:`encode_recording` codes a recording's windows with their past, as the
        stream form serves them (a window then differs from the same window alone)."""
        return False

    def encode_recordings(
        self, recs: Sequence[np.ndarray], starts: Sequence[Sequence[int]]
    ) -> list[Tensor]:
        """``encode_recording`` of each ``(recs[i], starts[i])`` (where :attr:`codes_with_past`);
        an encoder whose bank runs faster on many recordings at once batches them."""
        check_recordings_and_starts(recs, starts)
        return [self.encode_recording(r, s) for r, s in zip(recs, starts, strict=True)]

    def stream_module(self, step: int | None = None) -> nn.Module:
        """The stream step: ``step`` new samples + state -> the completed window's spikes + the
        next state (default: half a window); only where :attr:`has_stream_form`."""
        raise ValueError(
            f"the {self.registry_name} encoder has no stream form (the cgwt encoder has): serve "
            "its window graph, which the service feeds a window every half window"
        )

    @property
    def frame_period_ms(self) -> float | None:
        """The code's frame period (ms) where it codes frame by frame (:attr:`has_frame_step`),
        else None."""
        return None

    @property
    def frame_hop(self) -> int | None:
        """Samples per frame where the code codes frame by frame, else None."""
        return None

    def frame_module(self) -> nn.Module:
        """The frame step: ``frame [B, channels, hop]`` + state (``state_names``: ``(name,
        units)``, ``[B, units]`` each) -> ``(spikes [B, afferents], *next state)``; only where
        :attr:`has_frame_step`."""
        raise ValueError(
            f"the {self.registry_name} encoder codes whole windows: a frame-by-frame stream "
            "needs a continuous code (the frames encoder)"
        )

    def initial_frame_state(self, first: np.ndarray) -> dict[str, np.ndarray]:
        """The state of fresh frame streams (:meth:`frame_module`) whose first frames are
        ``first [B, channels, >= 1]``."""
        raise ValueError(f"the {self.registry_name} encoder has no frame step")

    def encode_recording(self, x: np.ndarray, starts: Sequence[int]) -> Tensor:
        """Spike times ``[len(starts), afferents, max_spikes]`` of the windows of one recording
        ``x [channels, samples]`` starting at ``starts``, each coded with the recording's past;
        only where :attr:`codes_with_past`."""
        raise ValueError(f"the {self.registry_name} encoder codes windows alone")

    def skip_stats(self) -> dict | None:
        """What the encoder skips, per mechanism (e.g. ``{"activity_gate": {...}}``: the fraction
        of (window, channel) pairs not transformed since it was built; ``"band_restriction"``:
        the bands outside the sensor's passband), or None if it skips nothing."""
        return None

    @contextlib.contextmanager
    def skipping(self, enabled: bool):
        """Within the block, skip (default) or compute everything, to measure what skipping
        changes."""
        yield

    def export_metadata(self) -> dict[str, tuple]:
        """Fields of :class:`~tactilesnn.core.graph_contract.GraphContract` a runtime needs to
        reproduce this encoder's skipping (``gate_rms``, ``bands_hz``, ``bands_transformed``)."""
        return {}

    def feature_map(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """For pictures: the intermediate map one window ``[channels, samples]`` is coded from,
        as ``(map [rows, frames], row centre frequencies in Hz)``; None if the code has none."""
        return None

    @abstractmethod
    def onnx_module(self) -> nn.Module:
        """Module ``window [B, channels, samples] -> spike times [B, afferents, max_spikes]``."""

    def upgrade_state(self, state: dict) -> dict:
        """Map a ``state_dict`` saved before the component layer to the current keys (a saved
        encoder was fitted; buffers the old format lacked keep their current values)."""
        current = {k: v.numpy() for k, v in self.state_dict().items()}
        return {**current, "fitted": np.array(True), **state}


def build_encoder(config: object, fs_hz: float, window: int, n_channels: int) -> SpikeEncoder:
    """Instantiate the registered encoder whose config class ``config`` is."""
    cls = ENCODERS.component_for(config)
    return cls(config, fs_hz, window, n_channels)
