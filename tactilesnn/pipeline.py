"""Spike pipeline: channel selection -> encoder (+ level code) -> clock afferents -> model.

It only composes registered components (:mod:`tactilesnn.encoders`, :mod:`tactilesnn.models`);
training lives in :class:`tactilesnn.trainer.Trainer`. Array contract: ``X`` ``[N, channels,
window]`` float at ``fs_hz`` (the data's channels, in its units), ``y`` ``[N]`` int class indices.
Spikes between stages are times ``[N, afferents, k]`` in ms from the window start (``+inf`` =
none, :mod:`tactilesnn.core.spikes`). Channels are selected by name, so a configuration pairs with any
sensor that provides them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from .config import PipelineConfig
from .core.checks import as_float_array, check_allocation, check_finite, check_float32_range
from .core.data import join_run, recording_runs
from .core.spikes import clock_times
from .encoders import build_encoder
from .encoders.level import LevelCode
from .models import MODELS, build_model
from .trainer import Trainer


def select_channels(wanted: Sequence[str], available: Sequence[str]) -> list[int]:
    """Indices of ``wanted`` channel names in ``available`` (``("all",)`` = every channel)."""
    if tuple(wanted) == ("all",):
        return list(range(len(available)))
    missing = [c for c in wanted if c not in available]
    if missing:
        raise ValueError(
            f"pipeline channels {missing} not provided by the data (has {tuple(available)}); "
            "set 'channels' to names the data provides (or 'all')"
        )
    return [list(available).index(c) for c in wanted]


def gain_normalised(x: np.ndarray) -> np.ndarray:
    """Windows ``[N, C, W]`` each divided by its mean absolute value over channels and samples
    (as the exported graph computes it; a silent window stays zero): the pattern
    across channels and time without the overall level a harder press or a more sensitive
    sensor scales."""
    x = np.asarray(x, np.float32)
    # the level summed in float64, then rounded: any summation order gives the same float32
    # (onnxruntime's and numpy's float32 sums differ in the last bit, which a latency code near
    # a threshold turned into a 1.6 ms spike shift on FabricSlide's harder presses)
    level = np.abs(x.astype(np.float64)).mean(axis=(1, 2), keepdims=True).astype(np.float32)
    return x / np.maximum(level, np.finfo(np.float32).tiny)


def rest_referenced(x: np.ndarray, n_rest: int) -> np.ndarray:
    """Windows ``[N, C, W]``, each channel less its mean over the window's first ``n_rest``
    samples (its rest level before contact; summed in float64 as the exported graph sums it), so
    an offset that a re-mounted sensor or a new session moves drops out."""
    x = np.asarray(x, np.float32)
    rest = x[..., : max(1, int(n_rest))].astype(np.float64).mean(-1, keepdims=True)
    return x - rest.astype(np.float32)


#: float32 weights, their gradients and Adam's two moments
TRAINING_BYTES_PER_PARAMETER = 16


def parameter_count(*model_args: object) -> int:
    """Parameters and buffers of the model ``build_model(*model_args)`` would build, counted
    on torch's ``meta`` device (nothing allocated): the size is checked before the model
    exists (a million channels would otherwise ask for tens of GB in its constructor)."""
    try:
        with torch.device("meta"):
            model = build_model(*model_args)
    except Exception:  # a model that cannot be built on meta: its own checks apply
        return 0
    return sum(t.numel() for t in (*model.parameters(), *model.buffers()))


#: recordings joined from their windows and held at once while coded with their past (bytes)
JOINED_RECORDINGS_BYTES = 1 << 27


class SpikePipeline:
    """Encoder + model with scikit-learn-style ``fit`` / ``predict``; see the module docstring."""

    def __init__(
        self,
        config: PipelineConfig,
        fs_hz: float,
        window: int,
        channel_names: Sequence[str],
        class_names: Sequence[str],
    ) -> None:
        self.config = config
        self.fs_hz, self.window = float(fs_hz), int(window)
        self.channel_names, self.class_names = tuple(channel_names), tuple(class_names)
        self.channel_idx = select_channels(config.channels, self.channel_names)
        self.duration_ms = 1000.0 * self.window / self.fs_hz
        self.encoder = build_encoder(config.encoder, self.fs_hz, self.window, len(self.channel_idx))
        # a stream model reads frame after frame with no window: a window's level code and
        # clock (a time reference from the window's start) have no meaning there
        windows = not MODELS.get(config.model_type).has_frame_step
        self.level = (LevelCode(len(self.channel_idx), config.level_neurons, self.duration_ms,
                                scale=config.level_scale, share=config.level_share)
                      if config.level_neurons and windows else None)  # fmt: skip
        self.n_level = self.level.n_afferents if self.level is not None else 0
        self.n_clock = config.clock_afferents if windows else 0
        self.n_afferents = self.encoder.n_afferents + self.n_level + self.n_clock
        self.max_spikes = self.encoder.max_spikes
        args = (config.model, self.n_afferents, self.max_spikes, len(self.class_names),
                self.duration_ms)  # fmt: skip
        check_allocation(self.encoder.bytes_per_window(),
                         f"one window through the {config.encoder_type} encoder")  # fmt: skip
        check_allocation(TRAINING_BYTES_PER_PARAMETER * parameter_count(*args),
                         f"the {config.model_type} model for {self.n_afferents} afferents "
                         f"({len(self.channel_idx)} channels; select fewer with 'channels')")  # fmt: skip
        self.model = build_model(*args, seed=config.train.seed)

    # ------------------------------------------------------------------ encoding
    def validate(self, X: np.ndarray) -> np.ndarray:
        arr = as_float_array(X, "X", ndim=3)
        if arr.shape[1:] != (len(self.channel_names), self.window):
            raise ValueError(
                f"X must be [N, {len(self.channel_names)} channels, {self.window} samples], "
                f"got shape {arr.shape}"
            )
        check_finite(arr, "X")
        check_float32_range(arr, "X")
        return arr

    def bytes_per_window(self) -> int:
        """Peak intermediate bytes of one window through encoder and model (byte budgets)."""
        return max(self.encoder.bytes_per_window(), self._model_bytes())

    def graph_bytes_per_window(self) -> int:
        """:meth:`bytes_per_window` of the exported graph (onnxruntime batches by a budget)."""
        return max(self.encoder.graph_bytes_per_window(), self._model_bytes())

    def _model_bytes(self) -> int:
        return self.model.bytes_per_sample(self.n_afferents, self.max_spikes)

    def encoder_input(self, X: np.ndarray) -> np.ndarray:
        """Validated ``X`` restricted to the pipeline's channels (a view when that is all), each
        window less its rest level (:func:`rest_referenced`) and divided by its level
        (:func:`gain_normalised`) where the configuration asks."""
        arr = self.validate(X)
        if list(self.channel_idx) != list(range(arr.shape[1])):
            arr = arr[:, self.channel_idx]
        if self.config.rest_ms:
            arr = rest_referenced(arr, self.rest_samples)
        return gain_normalised(arr) if self.config.gain_norm else arr

    @property
    def rest_samples(self) -> int:
        """Samples of the window's start that are its rest reference (``rest_ms``; at least
        one, at most the window)."""
        return min(self.window, max(1, round(self.config.rest_ms * self.fs_hz / 1000.0)))

    def calibrate(self, X: np.ndarray) -> None:
        """Fit the encoder's data-dependent state (e.g. the LIF code's level) and the level
        code's ranks on training X."""
        x = self.encoder_input(X)
        self.encoder.fit(x)
        if self.level is not None:
            self.level.fit(x)

    def encode(
        self, X: np.ndarray, progress: bool = False, device: torch.device | str | None = None
    ) -> torch.Tensor:
        """``X [N, C, W]`` -> spike times ``[N, afferents, k]`` (ms; inf = silent, on the CPU):
        the encoder's (computed on ``device``, default the CPU), the level code's (one slot
        each), the clock's."""
        n = np.shape(X)[0] if np.ndim(X) == 3 else 0
        check_allocation(4 * n * self.n_afferents * self.max_spikes, f"spike times of {n} windows")
        x = self.encoder_input(X)
        return self._with_extra(self.encoder.encode(x, progress=progress, device=device), x)

    def _with_extra(self, spikes: torch.Tensor, x: np.ndarray) -> torch.Tensor:
        """The encoder's spike times of windows ``x`` with the level code's and the clock's."""
        if self.level is not None:
            spikes = torch.cat([spikes, self.level_spikes(x)], dim=1)
        if self.n_clock:
            clock = clock_times(self.n_clock, self.max_spikes, self.duration_ms)
            spikes = torch.cat([spikes, clock.expand(spikes.shape[0], -1, -1)], dim=1)
        return spikes

    @property
    def streams_recordings(self) -> bool:
        """Whether the encoder codes a window with its recording's past (its stream form
        carries state across windows: the encoder's ``codes_with_past``), so that a window
        served in a stream differs from the same window alone. Not for a pipeline that runs
        frame by frame: its model's state is carried too, and it is scored so
        (:mod:`~tactilesnn.stream_training`), not as windows served one by one."""
        return (self.encoder.codes_with_past and self.frame_problem() is not None
                and self.window_stage() is None)  # fmt: skip

    def window_stage(self) -> str | None:
        """The stage that reads a whole window before coding it (None: none), which a stream
        or frame graph, coding each sample once, cannot have."""
        if self.config.gain_norm:
            return "gain_norm divides a whole window by its level"
        if self.config.rest_ms:
            return "rest_ms subtracts the window's first samples' level"
        return None

    def encode_in_recordings(
        self, X: np.ndarray, scan: np.ndarray
    ) -> tuple[np.ndarray, torch.Tensor] | None:
        """Spike times of the windows of ``X [N, C, W]`` that have a past, coded with it as the
        stream graph codes them: ``(indices, spikes [len(indices), afferents, k])`` for every
        window after the first of each group of ``scan`` whose windows tile one recording
        (:func:`~tactilesnn.core.data.recording_runs`); None when the encoder has no such form
        (:attr:`streams_recordings`) or no window has a past."""
        if not self.streams_recordings:
            return None
        x = self.encoder_input(X)
        runs = recording_runs(x, scan)
        if not runs:
            return None
        n = sum(len(m) - 1 for m, _ in runs)
        check_allocation(4 * n * self.n_afferents * self.max_spikes, f"spike times of {n} windows")
        parts: list[torch.Tensor] = []
        recs: list[np.ndarray] = []
        starts: list[np.ndarray] = []
        held = 0
        for members, shift in runs:  # the encoder codes them together, a bounded share at a time
            recs.append(join_run(x, members, shift))
            starts.append(shift * np.arange(1, len(members)))
            held += recs[-1].nbytes
            if held >= JOINED_RECORDINGS_BYTES:
                parts += self.encoder.encode_recordings(recs, starts)
                recs, starts, held = [], [], 0
        if recs:
            parts += self.encoder.encode_recordings(recs, starts)
        at = np.concatenate([members[1:] for members, _ in runs])
        return at, self._with_extra(torch.cat(parts), x[at])

    @torch.no_grad()
    def level_spikes(self, x: np.ndarray, budget_bytes: int = 1 << 26) -> torch.Tensor:
        """The level code of windows ``[N, C, W]`` as ``[N, level afferents, k]`` (first slot),
        in batches of at most ``budget_bytes`` (the float32 window, its float64 copy and
        deviations)."""
        assert self.level is not None
        batch = max(1, budget_bytes // (28 * x.shape[1] * x.shape[2]))
        out = torch.full((len(x), self.n_level, self.max_spikes), math.inf)
        for i in range(0, len(x), batch):
            chunk = torch.from_numpy(np.ascontiguousarray(x[i : i + batch], dtype=np.float32))
            out[i : i + batch, :, 0] = self.level(chunk)
        return out

    def frame_problem(self) -> str | None:
        """Why this pipeline cannot run frame by frame (None: it can): it needs a continuous
        code (an encoder with ``has_frame_step``), a stream model (``has_frame_step``), no
        window codes appended, and the model stepping at the code's frame."""
        enc, model = self.encoder, self.model
        if not enc.has_frame_step:
            return (f"the {self.config.encoder_type} encoder codes whole windows: a frame step "
                    "needs a continuous code (--encoder frames)")  # fmt: skip
        if not model.has_frame_step:
            return (f"the {self.config.model_type} model classifies whole windows: a frame step "
                    "needs a stream model (--model stream)")  # fmt: skip
        if self.level is not None or self.n_clock:  # (a stream model gets neither)
            return "the level code and clock afferents are window codes"
        if stage := self.window_stage():
            return f"{stage}: a window code"
        f_enc, f_model = enc.frame_period_ms, model.frame_period_ms
        if f_enc is None or f_model is None or abs(f_enc - f_model) > 1e-6 * f_enc:
            return (f"the model steps every {f_model} ms but the code's frame is {f_enc} ms: "
                    "leave the model's dt_ms at 0 (the code's frame)")  # fmt: skip
        return None

    # ------------------------------------------------------------------ inference
    def scores(self, spikes: torch.Tensor) -> torch.Tensor:
        """Spike times -> class scores ``[N, classes]`` in batches bounded by a byte budget."""
        return self.model.batched_scores(spikes)

    def predict(self, X: np.ndarray) -> np.ndarray:
        return self.scores(self.encode(X)).argmax(1).numpy()

    def score(self, X: np.ndarray, y: np.ndarray) -> float:
        return float((self.predict(X) == np.asarray(y)).mean())

    def fit(
        self, X: np.ndarray, y: np.ndarray, progress: bool = False, **kw: object
    ) -> list[float]:
        """Fit the encoder, encode, and train the model (:class:`~tactilesnn.trainer.Trainer`)."""

        self.calibrate(X)
        return Trainer(self.model, self.config.train, progress=progress).fit(
            self.encode(X), y, **kw
        )

    # ------------------------------------------------------------------ persistence
    def parts(self) -> tuple[str, ...]:
        """The attributes whose ``state_dict`` is the pipeline's learned state."""
        return ("encoder", "level", "model") if self.level is not None else ("encoder", "model")

    def weights(self) -> dict[str, np.ndarray]:
        """Arrays that, with the config, rebuild the trained pipeline (no pickle)."""
        out = {}
        for part in self.parts():
            for k, v in getattr(self, part).state_dict().items():
                out[f"{part}.{k}"] = v.detach().cpu().numpy().copy()
        return out

    def load_weights(self, arrays: dict[str, np.ndarray], legacy: bool = False) -> None:
        """Restore :meth:`weights`; ``legacy``: arrays written before the component layer."""
        for part in self.parts():
            module = getattr(self, part)
            state = {k[len(part) + 1 :]: v for k, v in arrays.items() if k.startswith(part + ".")}
            if legacy and part != "level":
                state = module.upgrade_state(state)
            current = module.state_dict()
            # buffers added in later versions keep their neutral constructed value
            for k in module.optional_state:
                state.setdefault(k, current[k].numpy())
            new = {}
            for k, v in current.items():
                if k not in state:
                    raise ValueError(
                        f"weights lack {part}.{k}: not a {self.config.encoder_type}+"
                        f"{self.config.model_type} pipeline"
                    )
                a = np.asarray(state[k])
                if a.shape != tuple(v.shape):
                    raise ValueError(f"{part}.{k}: shape {a.shape} does not match {tuple(v.shape)}")
                if a.dtype.kind == "f" and not np.isfinite(a).all():
                    raise ValueError(f"{part}.{k} holds NaN or Inf: the weights are corrupt")
                new[k] = torch.from_numpy(a.copy()).to(v.dtype)
            module.load_state_dict(new)


def accuracy_ci95(acc: float, n: int) -> float:
    """Half-width of a normal-approximation 95 % interval for an accuracy over ``n`` samples."""
    return 1.96 * math.sqrt(max(acc * (1 - acc), 1.0 / max(n, 1)) / max(n, 1))


def recording_accuracy(scores: np.ndarray, y: np.ndarray, groups: np.ndarray) -> dict | None:
    """Evidence accumulated over the windows of each recording (mean score, then argmax).

    Only when every recording has one label and some have several windows (a scan that visits
    several textures, like hook_loop's, has no single answer); None otherwise.
    """
    ids, inv = np.unique(groups, return_inverse=True)
    if ids.size == 0 or ids.size == y.size:
        return None
    lab_min = np.full(ids.size, np.iinfo(np.int64).max)
    lab_max = np.full(ids.size, -1)
    np.minimum.at(lab_min, inv, y)
    np.maximum.at(lab_max, inv, y)
    if (lab_min != lab_max).any():
        return None
    total = np.zeros((ids.size, scores.shape[1]))
    np.add.at(total, inv, scores)
    acc = float((total.argmax(1) == lab_min).mean())
    return {
        "test_accuracy_per_recording": acc,
        "test_accuracy_per_recording_ci95": accuracy_ci95(acc, ids.size),
        "n_test_recordings": int(ids.size),
    }
