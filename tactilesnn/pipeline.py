"""Spike pipeline: raw windows -> encoder -> spikes -> model -> class scores.

Encoders (``encoder``): ``gwt`` / ``stft`` scalogram -> latency code (one spike per afferent), or
``lif``: a population of LIF analog-to-spike converters per channel with graded thresholds (many
spikes per afferent). Models (``model``): ``tempotron`` (exact V_max, seed 001's rule) or ``snn``
(surrogate-gradient LIF network, trained with Adam on cross-entropy).

Array contract of :class:`SpikePipeline`: ``X`` ``[N, channels, window]`` float at ``fs_hz`` (the
data's channels, in its units), ``y`` ``[N]`` int class indices. Spikes between stages are times
``[N, afferents, k]`` in ms from the window start (``+inf`` = none); the SNN sees them as a dense
raster ``[T, N, afferents]`` of ``snn_dt_ms`` steps. The pipeline selects its input channels by
name, so a configuration pairs with any sensor that provides them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, fields

import numpy as np
import torch
from torch import nn
from tqdm.auto import tqdm

from ._checks import as_float_array, check_choice, check_finite
from .encoders.gwt import GaborScalogram, log_bands
from .encoders.latency import LatencyCode
from .encoders.spiking import lif_convert
from .encoders.stft import STFTScalogram
from .models.snn import SNNClassifier
from .models.tempotron import Tempotron

ENCODERS = ("gwt", "stft", "lif")
MODELS = ("tempotron", "snn")


@dataclass
class PipelineConfig:
    """Everything that defines a trained pipeline except its weights (saved in the run folder)."""

    encoder: str = "gwt"
    model: str = "tempotron"
    # seed 001 encodes the dynamic (piezo) output; ("all",) = every channel of the data
    channels: tuple[str, ...] = ("dynamic",)
    # scalogram + latency code
    f_lo_hz: float = 3.0
    f_hi_hz: float = 90.0
    n_bands: int = 20
    stats: tuple[str, ...] = ("mean", "std")
    mapping: str = "log"
    dynamic_range_db: float = 30.0
    # LIF population code: thresholds geometric from lif_lo to lif_hi x the training RMS level
    lif_neurons: int = 8
    lif_lo: float = 0.25
    lif_hi: float = 4.0
    lif_tau_ms: float = 10.0
    lif_max_spikes: int = 8
    # "train": levels relative to each channel's training RMS; "window": relative to the peak
    # |x| of each window over all channels (gain-invariant, keeps the channels' relative levels)
    lif_norm: str = "train"
    # tempotron
    clock_afferents: int = 5  # afferents firing at fixed times in every window (time reference)
    tau_ms: float = 2000.0  # long membrane memory: integrates the whole 500 ms window
    tau_s_ms: float = 50.0
    theta: float = 1.0
    lr: float = 0.005  # seed 001 lambda
    momentum: float = 0.0
    margin: float = 0.2
    lr_decay: float = 0.05  # lr_epoch = lr / (1 + lr_decay * epoch)
    keep_best: bool = True  # keep the weights with the best validation (else training) accuracy
    tempotron_train: str = "rule"  # "rule" (seed 001) or "gradient" (Adam on a V_max hinge)
    # snn
    snn_hidden: int = 64
    snn_dt_ms: float = 5.0
    snn_tau_ms: float = 50.0
    snn_readout: str = "max"
    snn_recurrent: bool = False
    snn_lr: float = 0.003
    # training loop
    epochs: int = 40
    batch_size: int = 32
    patience: int = 0  # early stopping: epochs without validation improvement (0 = off)
    seed: int = 0

    def __post_init__(self) -> None:
        check_choice(self.encoder, "encoder", ENCODERS)
        check_choice(self.model, "model", MODELS)
        check_choice(self.tempotron_train, "tempotron_train", ("rule", "gradient"))
        check_choice(self.lif_norm, "lif_norm", ("train", "window"))
        self.channels = tuple(self.channels)
        self.stats = tuple(self.stats)
        if self.epochs < 1 or self.batch_size < 1 or self.n_bands < 1:
            raise ValueError("epochs, batch_size and n_bands must be >= 1")
        if self.patience < 0:
            raise ValueError(f"patience must be >= 0, got {self.patience}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> PipelineConfig:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown pipeline settings: {', '.join(unknown)}")
        return cls(**d)


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
        self.fs_hz = float(fs_hz)
        self.window = int(window)
        self.channel_names = tuple(channel_names)
        self.class_names = tuple(class_names)
        if tuple(config.channels) == ("all",):  # every channel the data provides, in its order
            config.channels = self.channel_names
        missing = [c for c in config.channels if c not in self.channel_names]
        if missing:
            raise ValueError(
                f"pipeline channels {missing} not provided by the data (has {self.channel_names}); "
                "set 'channels' to names the data provides"
            )
        self.channel_idx = [self.channel_names.index(c) for c in config.channels]
        self.duration_ms = 1000.0 * self.window / self.fs_hz
        n_ch = len(self.channel_idx)
        if config.encoder == "lif":
            self.encoder = None
            self.code = None
            self.lif_ref = torch.zeros(n_ch)  # per-channel RMS level, fitted on training data
            n_aff, k = n_ch * config.lif_neurons, config.lif_max_spikes
        else:
            f_hi = min(config.f_hi_hz, 0.45 * self.fs_hz)
            freqs = log_bands(min(config.f_lo_hz, f_hi / 2), f_hi, config.n_bands)
            if config.encoder == "gwt":
                self.encoder = GaborScalogram(self.fs_hz, freqs)
            else:
                self.encoder = STFTScalogram(self.fs_hz, freqs, nperseg=self.window)
            self.code = LatencyCode(
                duration_ms=self.duration_ms,
                mapping=config.mapping,
                stats=config.stats,
                dynamic_range_db=config.dynamic_range_db,
            )
            n_aff, k = n_ch * len(config.stats) * config.n_bands, 1
        self.n_afferents = n_aff + config.clock_afferents
        self.max_spikes = k
        n_cls = len(self.class_names)
        if config.model == "tempotron":
            self.model: nn.Module = Tempotron(
                self.n_afferents,
                n_cls,
                duration_ms=self.duration_ms,
                tau_ms=config.tau_ms,
                tau_s_ms=config.tau_s_ms,
                theta=config.theta,
                seed=config.seed,
            )
        else:
            torch.manual_seed(config.seed)
            self.model = SNNClassifier(
                self.n_afferents,
                config.snn_hidden,
                n_cls,
                readout=config.snn_readout,
                recurrent=config.snn_recurrent,
                tau_mem_ms=config.snn_tau_ms,
                dt_ms=config.snn_dt_ms,
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

    def calibrate(self, X: np.ndarray) -> None:
        """Fit the encoder's data-dependent state (the LIF code's RMS reference) on training X."""
        if self.config.encoder == "lif":
            arr = self.validate(X)[:, self.channel_idx]
            rms = np.sqrt((arr.astype(np.float64) ** 2).mean(-1))  # [N, C]
            self.lif_ref = torch.from_numpy(np.maximum(np.median(rms, axis=0), 1e-12)).float()

    @torch.no_grad()
    def encode(self, X: np.ndarray, batch: int = 2048) -> torch.Tensor:
        """``X [N, C, W]`` -> spike times ``[N, afferents, k]`` (ms; inf = silent)."""
        arr = self.validate(X)[:, self.channel_idx]
        out = []
        for i in range(0, arr.shape[0], batch):
            chunk = np.ascontiguousarray(arr[i : i + batch], dtype=np.float32)
            if self.config.encoder == "lif":
                out.append(self._lif_times(chunk))
            else:
                x = torch.from_numpy(chunk)
                out.append(self.code(self.encoder(x)).unsqueeze(-1))
        if not out:
            return torch.zeros(0, self.n_afferents, self.max_spikes)
        spikes = torch.cat(out)
        if self.config.clock_afferents:
            # a clock population gives the model a time reference (the tempotron's threshold
            # is fixed, so this is its time-dependent bias)
            n = self.config.clock_afferents
            clock = torch.full((spikes.shape[0], n, spikes.shape[2]), math.inf)
            clock[:, :, 0] = torch.arange(n, dtype=spikes.dtype) * (self.duration_ms / n)
            spikes = torch.cat([spikes, clock], dim=1)
        return spikes

    def _lif_times(self, chunk: np.ndarray) -> torch.Tensor:
        """LIF population: each channel drives ``lif_neurons`` converters, thresholds graded."""
        cfg = self.config
        if not torch.all(self.lif_ref > 0) or float(self.lif_ref.sum()) == 0:
            raise RuntimeError("the LIF encoder is not calibrated: call fit() or calibrate() first")
        n, c, w = chunk.shape
        scaled = chunk / self.lif_ref.numpy()[None, :, None]
        if cfg.lif_norm == "window":
            peak = np.abs(chunk).max(axis=(1, 2), keepdims=True)
            scaled = chunk / np.maximum(peak, 1e-30)
        thr = np.geomspace(cfg.lif_lo, cfg.lif_hi, cfg.lif_neurons)
        # converter j of channel i sees the input divided by its threshold (threshold 1 each)
        drive = (scaled[:, :, None, :] / thr[None, None, :, None]).reshape(n, c * len(thr), w)
        # drive is in multiples of threshold: theta = 1, V_inf = drive; tau sets the integration
        ev = lif_convert(drive, self.fs_hz, tau_ms=cfg.lif_tau_ms, threshold=1.0, reset="subtract")
        k = cfg.lif_max_spikes
        times = torch.full((n, c * len(thr), k), math.inf)
        if len(ev):
            order = np.lexsort((ev.time_ms, ev.neuron, ev.batch))
            b, nr, t = ev.batch[order], ev.neuron[order], ev.time_ms[order]
            key = b * (c * len(thr)) + nr
            first = np.r_[0, np.flatnonzero(np.diff(key)) + 1]
            rank = np.arange(key.size) - np.repeat(first, np.diff(np.r_[first, key.size]))
            keep = rank < k  # the first k spikes of each converter
            times[b[keep], nr[keep], rank[keep]] = torch.from_numpy(t[keep]).float()
        return times

    def raster(self, spikes: torch.Tensor) -> torch.Tensor:
        """Spike times ``[N, A, k]`` -> dense ``[T, N, A]`` counts at ``snn_dt_ms`` steps."""
        dt = self.config.snn_dt_ms
        steps = math.ceil(self.duration_ms / dt) + 1
        idx = torch.floor(spikes / dt)
        ok = torch.isfinite(idx) & (idx >= 0) & (idx < steps)
        out = torch.zeros(steps, spikes.shape[0], spikes.shape[1])
        n, a, _ = torch.nonzero(ok, as_tuple=True)
        out.index_put_((idx[ok].long(), n, a), torch.ones(n.numel()), accumulate=True)
        return out

    # ------------------------------------------------------------------ inference
    def _forward(self, spikes: torch.Tensor) -> torch.Tensor:
        if self.config.model == "tempotron":
            return self.model(spikes)[0]
        return self.model(self.raster(spikes))[0]

    @torch.no_grad()
    def scores(self, spikes: torch.Tensor, batch: int | None = None) -> torch.Tensor:
        """Spike times -> class scores ``[N, classes]`` (tempotron: V_max per class)."""
        if batch is None:
            batch = tempotron_batch(spikes)
        parts = [self._forward(spikes[i : i + batch]) for i in range(0, spikes.shape[0], batch)]
        return torch.cat(parts) if parts else torch.zeros(0, len(self.class_names))

    # ------------------------------------------------------------------ training
    def fit_spikes(
        self,
        spikes: torch.Tensor,
        y: np.ndarray,
        progress: bool = False,
        val: tuple[torch.Tensor, np.ndarray] | None = None,
        on_epoch: Callable[[int, dict], None] | None = None,
        resume: dict | None = None,
    ) -> list[float]:
        """Train; returns the training error per epoch.

        ``val``: held-out spikes and labels for early stopping (``patience``) and best-weight
        selection. ``on_epoch(epoch, state)`` receives a complete resumable state after each
        epoch (see :meth:`training_state`); ``resume`` continues from such a state.
        """
        cfg = self.config
        yt = torch.as_tensor(np.asarray(y), dtype=torch.long)
        if yt.ndim != 1 or yt.shape[0] != spikes.shape[0]:
            raise ValueError(f"y must be [N={spikes.shape[0]}], got shape {tuple(yt.shape)}")
        if yt.numel() and (yt.min() < 0 or yt.max() >= len(self.class_names)):
            raise ValueError(f"labels must be in [0, {len(self.class_names)}), got {yt.unique()}")
        gen = torch.Generator().manual_seed(cfg.seed)
        by_rule = cfg.model == "tempotron" and cfg.tempotron_train == "rule"
        opt = None if by_rule else torch.optim.Adam(self.model.parameters(), lr=cfg.snn_lr)
        st = {"epoch": 0, "history": [], "val_history": [], "best_score": -math.inf, "stale": 0}
        best_w = {k: v.detach().clone() for k, v in self.model.state_dict().items()}
        if resume is not None:
            self._restore(resume, gen, opt)
            st = {k: resume[k] for k in st}
            st["history"], st["val_history"] = list(st["history"]), list(st["val_history"])
            best_w = {k: torch.from_numpy(np.asarray(v)) for k, v in resume["best"].items()}
        bar = tqdm(
            range(st["epoch"], cfg.epochs),
            desc=f"train {cfg.encoder}+{cfg.model}",
            disable=not progress,
        )
        for epoch in bar:
            perm = torch.randperm(spikes.shape[0], generator=gen)
            if by_rule:
                lr = cfg.lr / (1.0 + cfg.lr_decay * epoch)
                for i in range(0, perm.numel(), cfg.batch_size):
                    idx = perm[i : i + cfg.batch_size]
                    self.model.rule_update(
                        spikes[idx], yt[idx], lr=lr, momentum=cfg.momentum, margin=cfg.margin
                    )
            else:
                self.model.train()
                for i in range(0, perm.numel(), cfg.batch_size):
                    idx = perm[i : i + cfg.batch_size]
                    if cfg.model == "snn":
                        scores = self.model(self.raster(spikes[idx]))[0]
                        loss = nn.functional.cross_entropy(scores, yt[idx])
                    else:  # differentiable exact V_max: hinge around theta with the margin
                        v = self.model(spikes[idx])[0]
                        tgt = nn.functional.one_hot(yt[idx], len(self.class_names)).to(v.dtype)
                        thr = cfg.theta
                        loss = (
                            (
                                tgt * torch.relu(thr + cfg.margin - v)
                                + (1 - tgt) * torch.relu(v - thr + cfg.margin)
                            )
                            .sum(1)
                            .mean()
                        )
                    opt.zero_grad()
                    loss.backward()
                    opt.step()
                self.model.eval()
            err = float((self.scores(spikes).argmax(1) != yt).float().mean())
            st["history"].append(err)
            score = 1.0 - err
            if val is not None:
                vy = torch.as_tensor(np.asarray(val[1]), dtype=torch.long)
                score = float((self.scores(val[0]).argmax(1) == vy).float().mean())
                st["val_history"].append(score)
            if score > st["best_score"]:
                st["best_score"], st["stale"] = score, 0
                best_w = {k: v.detach().clone() for k, v in self.model.state_dict().items()}
            else:
                st["stale"] += 1
            st["epoch"] = epoch + 1
            bar.set_postfix(
                train_error=f"{err:.4f}", **({"val_acc": f"{score:.4f}"} if val else {})
            )
            if on_epoch is not None:
                on_epoch(epoch, self.training_state(st, gen, opt, best_w))
            if cfg.patience and val is not None and st["stale"] >= cfg.patience:
                break
        if cfg.keep_best:
            self.model.load_state_dict(best_w)
        self.history = st
        return st["history"]

    def training_state(self, st: dict, gen: torch.Generator, opt, best_w: dict) -> dict:
        """Everything needed to resume: weights, optimizer/momentum state, RNG, bookkeeping."""
        state = dict(st)
        state["model"] = {k: v.detach().numpy().copy() for k, v in self.model.state_dict().items()}
        state["best"] = {k: v.numpy().copy() for k, v in best_w.items()}
        state["rng"] = gen.get_state().numpy().copy()
        vel = getattr(self.model, "velocity", None)
        if vel is not None:
            state["velocity"] = vel.numpy().copy()
        if opt is not None:
            state["optimizer"] = _flatten_optimizer(opt)
        return state

    def _restore(self, state: dict, gen: torch.Generator, opt) -> None:
        self.model.load_state_dict(
            {k: torch.from_numpy(np.asarray(v)) for k, v in state["model"].items()}
        )
        gen.set_state(torch.from_numpy(np.asarray(state["rng"], dtype=np.uint8)))
        if "velocity" in state:
            self.model.velocity = torch.from_numpy(np.asarray(state["velocity"]))
        if opt is not None and "optimizer" in state:
            _restore_optimizer(opt, state["optimizer"])

    def fit(
        self, X: np.ndarray, y: np.ndarray, progress: bool = False, **kw: object
    ) -> list[float]:
        self.calibrate(X)
        return self.fit_spikes(self.encode(X), y, progress=progress, **kw)

    def predict(self, X: np.ndarray) -> np.ndarray:
        return self.scores(self.encode(X)).argmax(1).numpy()

    def score(self, X: np.ndarray, y: np.ndarray) -> float:
        return float((self.predict(X) == np.asarray(y)).mean())

    # ------------------------------------------------------------------ persistence
    def weights(self) -> dict[str, np.ndarray]:
        """Arrays that, with the config, rebuild the trained pipeline (no pickle)."""
        out = {f"model.{k}": v.detach().numpy().copy() for k, v in self.model.state_dict().items()}
        if self.config.encoder == "lif":
            out["encoder.lif_ref"] = self.lif_ref.numpy().copy()
        return out

    def load_weights(self, arrays: dict[str, np.ndarray]) -> None:
        sd = self.model.state_dict()
        new = {}
        for k, v in sd.items():
            key = f"model.{k}"
            if key not in arrays:
                raise ValueError(f"weights file lacks {key!r}: not a {self.config.model} pipeline")
            a = np.asarray(arrays[key])
            if a.shape != tuple(v.shape):
                raise ValueError(
                    f"{key}: shape {a.shape} does not match the pipeline {tuple(v.shape)}"
                )
            new[k] = torch.from_numpy(a)
        self.model.load_state_dict(new)
        if self.config.encoder == "lif":
            self.lif_ref = torch.from_numpy(np.asarray(arrays["encoder.lif_ref"])).float()


def tempotron_batch(spikes: torch.Tensor) -> int:
    """Samples per exact-tempotron call: it holds [batch, events, events] pairwise lags."""
    events = spikes.shape[1] * spikes.shape[2] + 1
    return max(8, min(1024, (1 << 22) // (events * events)))


def _flatten_optimizer(opt: torch.optim.Optimizer) -> dict[str, np.ndarray]:
    out = {}
    for i, st in opt.state_dict()["state"].items():
        for k, v in st.items():
            out[f"{i}.{k}"] = v.numpy().copy() if torch.is_tensor(v) else np.asarray(v)
    return out


def _restore_optimizer(opt: torch.optim.Optimizer, flat: dict[str, np.ndarray]) -> None:
    sd = opt.state_dict()
    state: dict[int, dict] = {}
    for key, v in flat.items():
        i, name = key.split(".", 1)
        state.setdefault(int(i), {})[name] = torch.from_numpy(np.array(v))
    sd["state"] = state
    opt.load_state_dict(sd)


def accuracy_ci95(acc: float, n: int) -> float:
    """Half-width of a normal-approximation 95 % interval for an accuracy over ``n`` samples."""
    return 1.96 * math.sqrt(max(acc * (1 - acc), 1.0 / max(n, 1)) / max(n, 1))
