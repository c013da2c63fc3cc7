"""Spike pipeline: raw windows -> scalogram (GWT | STFT) -> latency code -> tempotron.

Array contract of :class:`SpikePipeline`: ``X`` ``[N, channels, window]`` float at ``fs_hz`` (the
task's channels, in its units), ``y`` ``[N]`` int class indices. The pipeline selects its input
channels by name, so the same configuration pairs with any sensor that provides them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np
import torch
from tqdm.auto import tqdm

from ._checks import as_float_array, check_choice, check_finite
from .encoders.gwt import GaborScalogram, log_bands
from .encoders.latency import LatencyCode
from .encoders.stft import STFTScalogram
from .models.tempotron import Tempotron

ENCODERS = ("gwt", "stft")
MODELS = ("tempotron",)


@dataclass
class PipelineConfig:
    """Everything that defines a trained pipeline except its weights (saved in the run folder)."""

    encoder: str = "gwt"
    model: str = "tempotron"
    channels: tuple[str, ...] = ("dynamic",)  # seed 001 encodes the dynamic (piezo) output
    f_lo_hz: float = 3.0
    f_hi_hz: float = 90.0
    n_bands: int = 20
    stats: tuple[str, ...] = ("mean", "std")
    mapping: str = "log"
    dynamic_range_db: float = 30.0
    clock_afferents: int = 5  # afferents firing at fixed times in every window (time reference)
    tau_ms: float = 2000.0  # long membrane memory: integrates the whole 500 ms window
    tau_s_ms: float = 50.0
    theta: float = 1.0
    lr: float = 0.002
    momentum: float = 0.0
    margin: float = 0.2
    lr_decay: float = 0.05  # lr_epoch = lr / (1 + lr_decay * epoch)
    keep_best: bool = True  # "pocket": keep the weights with the lowest training error
    epochs: int = 40
    batch_size: int = 32
    seed: int = 0
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_choice(self.encoder, "encoder", ENCODERS)
        check_choice(self.model, "model", MODELS)
        self.channels = tuple(self.channels)
        self.stats = tuple(self.stats)
        if self.epochs < 1 or self.batch_size < 1 or self.n_bands < 1:
            raise ValueError("epochs, batch_size and n_bands must be >= 1")

    def to_dict(self) -> dict:
        return asdict(self)


class SpikePipeline:
    """Encoder + latency code + tempotron, with scikit-learn-style ``fit`` / ``predict``."""

    def __init__(
        self,
        config: PipelineConfig,
        fs_hz: float,
        window: int,
        channel_names: Sequence[str],
        class_names: Sequence[str],
    ) -> None:
        self.config = config
        self.fs_hz = float(fs_hz)
        self.window = int(window)
        self.channel_names = tuple(channel_names)
        self.class_names = tuple(class_names)
        missing = [c for c in config.channels if c not in self.channel_names]
        if missing:
            raise ValueError(
                f"pipeline channels {missing} not provided by the data (has {self.channel_names})"
            )
        self.channel_idx = [self.channel_names.index(c) for c in config.channels]
        freqs = log_bands(config.f_lo_hz, min(config.f_hi_hz, 0.45 * self.fs_hz), config.n_bands)
        if config.encoder == "gwt":
            self.encoder: torch.nn.Module = GaborScalogram(self.fs_hz, freqs)
        else:
            self.encoder = STFTScalogram(self.fs_hz, freqs, nperseg=self.window)
        self.duration_ms = 1000.0 * self.window / self.fs_hz
        self.code = LatencyCode(
            duration_ms=self.duration_ms,
            mapping=config.mapping,
            stats=config.stats,
            dynamic_range_db=config.dynamic_range_db,
        )
        n_inputs = len(self.channel_idx) * len(config.stats) * config.n_bands
        n_inputs += config.clock_afferents
        self.model = Tempotron(
            n_inputs,
            len(self.class_names),
            duration_ms=self.duration_ms,
            tau_ms=config.tau_ms,
            tau_s_ms=config.tau_s_ms,
            theta=config.theta,
            seed=config.seed,
        )

    # ------------------------------------------------------------------ encoding
    def validate(self, X: np.ndarray) -> np.ndarray:
        arr = as_float_array(X, "X", ndim=3)
        if arr.shape[1:] != (len(self.channel_names), self.window):
            raise ValueError(
                f"X must be [N, {len(self.channel_names)} channels, {self.window} samples], "
                f"got shape {arr.shape}"
            )
        check_finite(arr, "X")
        return arr

    @torch.no_grad()
    def encode(self, X: np.ndarray, batch: int = 2048) -> torch.Tensor:
        """``X [N, C, W]`` -> spike times ``[N, inputs]`` (ms; inf = silent)."""
        arr = self.validate(X)[:, self.channel_idx]
        out = []
        for i in range(0, arr.shape[0], batch):
            x = torch.from_numpy(np.ascontiguousarray(arr[i : i + batch], dtype=np.float32))
            out.append(self.code(self.encoder(x)))
        if not out:
            return torch.zeros(0, self.model.n_inputs)
        spikes = torch.cat(out)
        if self.config.clock_afferents:
            # a clock population gives the tempotron a time-dependent bias (its threshold is fixed)
            n = self.config.clock_afferents
            clock = torch.arange(n, dtype=spikes.dtype) * (self.duration_ms / n)
            spikes = torch.cat([spikes, clock.expand(spikes.shape[0], n)], dim=1)
        return spikes

    # ------------------------------------------------------------------ training / inference
    @torch.no_grad()
    def scores(self, spikes: torch.Tensor, batch: int = 1024) -> torch.Tensor:
        """Spike times -> ``V_max`` per class ``[N, classes]``."""
        parts = [self.model(spikes[i : i + batch])[0] for i in range(0, spikes.shape[0], batch)]
        return torch.cat(parts) if parts else torch.zeros(0, self.model.n_classes)

    def fit_spikes(
        self,
        spikes: torch.Tensor,
        y: np.ndarray,
        progress: bool = False,
        on_epoch: Callable[[int, float], None] | None = None,
    ) -> list[float]:
        """Tempotron rule over shuffled mini-batches; returns training error per epoch."""
        cfg = self.config
        yt = torch.as_tensor(np.asarray(y), dtype=torch.long)
        if yt.ndim != 1 or yt.shape[0] != spikes.shape[0]:
            raise ValueError(f"y must be [N={spikes.shape[0]}], got shape {tuple(yt.shape)}")
        if yt.numel() and (yt.min() < 0 or yt.max() >= len(self.class_names)):
            raise ValueError(f"labels must be in [0, {len(self.class_names)}), got {yt.unique()}")
        gen = torch.Generator().manual_seed(cfg.seed)
        history: list[float] = []
        best = (math.inf, self.model.weight.detach().clone())
        bar = tqdm(range(cfg.epochs), desc=f"train {cfg.encoder}+{cfg.model}", disable=not progress)
        for epoch in bar:
            lr = cfg.lr / (1.0 + cfg.lr_decay * epoch)
            perm = torch.randperm(spikes.shape[0], generator=gen)
            for i in range(0, perm.numel(), cfg.batch_size):
                idx = perm[i : i + cfg.batch_size]
                self.model.rule_update(
                    spikes[idx], yt[idx], lr=lr, momentum=cfg.momentum, margin=cfg.margin
                )
            err = float((self.scores(spikes).argmax(1) != yt).float().mean())
            history.append(err)
            if err < best[0]:
                best = (err, self.model.weight.detach().clone())
            bar.set_postfix(train_error=f"{err:.4f}")
            if on_epoch is not None:
                on_epoch(epoch, err)
        if cfg.keep_best:
            with torch.no_grad():
                self.model.weight.copy_(best[1])
        return history

    def fit(self, X: np.ndarray, y: np.ndarray, progress: bool = False) -> list[float]:
        return self.fit_spikes(self.encode(X), y, progress=progress)

    def predict(self, X: np.ndarray) -> np.ndarray:
        return self.scores(self.encode(X)).argmax(1).numpy()

    def score(self, X: np.ndarray, y: np.ndarray) -> float:
        return float((self.predict(X) == np.asarray(y)).mean())

    # ------------------------------------------------------------------ persistence
    def weights(self) -> dict[str, np.ndarray]:
        return {"tempotron.weight": self.model.weight.detach().numpy().copy()}

    def load_weights(self, arrays: dict[str, np.ndarray]) -> None:
        w = np.asarray(arrays["tempotron.weight"])
        if w.shape != tuple(self.model.weight.shape):
            raise ValueError(
                f"weight shape {w.shape} does not match the pipeline {tuple(self.model.weight.shape)}"
            )
        with torch.no_grad():
            self.model.weight.copy_(torch.from_numpy(w))


def accuracy_ci95(acc: float, n: int) -> float:
    """Half-width of a normal-approximation 95 % interval for an accuracy over ``n`` samples."""
    return 1.96 * math.sqrt(max(acc * (1 - acc), 1.0 / max(n, 1)) / max(n, 1))
