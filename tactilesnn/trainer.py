"""The training loop of any spike model: mini-batches, epochs, validation, early stopping,
resumable state. Used by :meth:`tactilesnn.pipeline.SpikePipeline.fit`, the scikit-learn
estimator and :func:`tactilesnn.training.fit_and_evaluate`; a user's own loop can replace it
(the models are plain ``nn.Module``s with a ``loss``)."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np
import torch
from tqdm.auto import tqdm

from .config import TrainConfig
from .core.data import evenly_spaced
from .core.device import resolve_device
from .core.perf import refit_threads
from .core.stages import bar_disabled
from .models.base import SpikeModel, to_tensor_labels

log = logging.getLogger("tactilesnn")


class Trainer:
    """Training loop for any :class:`~tactilesnn.models.base.SpikeModel`.

    Models that learn by a rule get :meth:`~SpikeModel.rule_update` per mini-batch; the others
    Adam on :meth:`~SpikeModel.loss`. After each epoch: training error, validation accuracy
    (if given), best-weight bookkeeping, early stopping (``patience``) and a resumable state
    (weights, optimizer, RNG; momentum is a model buffer) for ``on_epoch``.
    """

    def __init__(self, model: SpikeModel, config: TrainConfig, progress: bool = False) -> None:
        self.model, self.config, self.progress = model, config, progress
        self.history: dict = {}

    def fit(
        self,
        spikes: torch.Tensor,
        y: np.ndarray,
        val: tuple[torch.Tensor, np.ndarray] | None = None,
        on_epoch: Callable[[int, dict], None] | None = None,
        resume: dict | None = None,
        groups: np.ndarray | None = None,
        confidence: np.ndarray | None = None,
    ) -> list[float]:
        """Train on spike times ``[N, A, k]`` and labels ``[N]``; returns the error per epoch.

        A model that solves in one go (:meth:`~SpikeModel.solve`) does so instead of the epochs:
        one entry of history, what it chose in ``self.history["solved"]``; ``groups``: the
        windows' recording ids ``[N]`` for its cross-validation. ``confidence`` ``[N]`` in
        [0, 1]: soft targets (:func:`~.models.softmax_fit.soft_targets`), for a model that
        :attr:`~SpikeModel.trains_on_confidence`."""
        cfg, model = self.config, self.model
        yt = to_tensor_labels(np.asarray(y), model.n_classes, spikes.shape[0])
        ct = None if confidence is None else _confidence(model, confidence, yt)
        gen = torch.Generator().manual_seed(cfg.seed)
        by_rule = model.learns_by_rule
        opt = None if by_rule else torch.optim.Adam(model.parameters(), lr=model.learning_rate())
        st = {"epoch": 0, "history": [], "val_history": [], "best_score": -math.inf, "stale": 0}
        solved = None
        if resume is None:
            model.prepare(spikes)  # resumed runs restore what it fitted with their weights
            solved = model.solve(spikes, yt, groups, **({} if ct is None else {"confidence": ct}))
        best_w = {k: v.detach().clone() for k, v in model.state_dict().items()}
        if solved is not None and not solved.get("train_epochs"):  # the optimum: no epochs
            _record(st, model, spikes, yt, val, solved.get("train_error"))
            st["epoch"] = cfg.epochs
            if on_epoch is not None:
                on_epoch(0, self.state(st, gen, opt, best_w))
        if resume is not None:
            st, best_w = _resumed(model, resume, gen, opt, st)
        # gradient steps on the configured device (rule learning stays on the CPU); the model
        # comes back to the CPU after each epoch, where evaluation, checkpoints and export run
        device = torch.device("cpu") if by_rule else resolve_device(cfg.device)
        desc = f"train {type(model).registry_name}" + (
            f" on {device}" if device.type != "cpu" else ""
        )
        bar = tqdm(range(st["epoch"], cfg.epochs), desc=desc,
                   disable=bar_disabled(self.progress and st["epoch"] < cfg.epochs))  # fmt: skip
        # without a terminal (a piped log) the bar is off: a line every LOG_EVERY_S instead
        lines = _EpochLines(desc, st["epoch"], cfg.epochs, self.progress and bar.disable)
        for epoch in bar:
            perm = torch.randperm(spikes.shape[0], generator=gen)
            model.train()
            if device.type != "cpu":
                model.to(device)
                _optimizer_to(opt, device)
            self._epoch(spikes, yt, ct, perm, opt, device, epoch)
            model.to("cpu")
            model.eval()
            err, score = _record(st, model, spikes, yt, val)
            if score > st["best_score"]:
                st["best_score"], st["stale"] = score, 0
                best_w = {k: v.detach().clone() for k, v in model.state_dict().items()}
            else:
                st["stale"] += 1
            st["epoch"] = epoch + 1
            bar.set_postfix(
                train_error=f"{err:.4f}", **({"val_acc": f"{score:.4f}"} if val else {})
            )
            lines.epoch_done(epoch + 1, err, score if val else None)
            refit_threads()  # other processes come and go during a long training
            if on_epoch is not None:
                on_epoch(epoch, self.state(st, gen, opt, best_w))
            if cfg.patience and val is not None and st["stale"] >= cfg.patience:
                break
        if cfg.keep_best:
            model.load_state_dict(best_w)
        model.eval()
        model.calibrate_decision(spikes)  # on the weights kept
        self.history = {**st, "solved": solved}
        return st["history"]

    def _epoch(self, spikes: torch.Tensor, yt: torch.Tensor, ct: torch.Tensor | None,
               perm: torch.Tensor, opt, device: torch.device, epoch: int) -> None:  # fmt: skip
        """One epoch's mini-batches in the order ``perm``: the local rule, or Adam steps on the
        model's loss at the scheduled learning rate (a function of the step: resumes exactly)."""
        cfg, model = self.config, self.model
        steps = -(-perm.numel() // cfg.batch_size)
        for j, i in enumerate(range(0, perm.numel(), cfg.batch_size)):
            idx = perm[i : i + cfg.batch_size]
            if opt is not None and cfg.lr_schedule != "constant":
                for group in opt.param_groups:
                    group["lr"] = scheduled_lr(model.learning_rate(), cfg.lr_schedule,
                                               epoch * steps + j, cfg.epochs * steps)  # fmt: skip
            if model.learns_by_rule:
                with torch.no_grad():
                    model.rule_update(spikes[idx], yt[idx], epoch)
            else:
                extra = {} if ct is None else {"confidence": ct[idx].to(device)}
                loss = model.loss(spikes[idx].to(device), yt[idx].to(device), **extra)
                opt.zero_grad()
                loss.backward()
                opt.step()

    def state(self, st: dict, gen: torch.Generator, opt, best_w: dict) -> dict:
        """Everything needed to resume: weights, optimizer state, RNG, bookkeeping."""
        state = dict(st)
        state["model"] = {k: v.detach().numpy().copy() for k, v in self.model.state_dict().items()}
        state["best"] = {k: v.numpy().copy() for k, v in best_w.items()}
        state["rng"] = gen.get_state().numpy().copy()
        if opt is not None:
            state["optimizer"] = _flatten_optimizer(opt)
        return state


def scheduled_lr(base: float, schedule: str, step: int, total: int) -> float:
    """The learning rate at mini-batch ``step`` of ``total``: ``base`` (constant), or ``base``
    on a half cosine down to 0 at the last step (cosine; SGDR without restarts, Loshchilov &
    Hutter 2017)."""
    if schedule == "constant":
        return base
    return 0.5 * base * (1.0 + math.cos(math.pi * min(step, total) / max(1, total)))


#: seconds between the progress lines of a training without a terminal
LOG_EVERY_S = 30.0


class _EpochLines:
    """One log line per epoch at most every :data:`LOG_EVERY_S` (elapsed, an estimate of what is
    left), for a training whose progress bar is off because the output is not a terminal."""

    def __init__(self, desc: str, first: int, epochs: int, enabled: bool) -> None:
        import time

        self.clock, self.desc, self.first, self.epochs = time.monotonic, desc, first, epochs
        self.enabled, self.t0 = bool(enabled), time.monotonic()
        self.last = self.t0

    def epoch_done(self, done: int, err: float, val: float | None) -> None:
        now = self.clock()
        if not self.enabled or (now - self.last < LOG_EVERY_S and done < self.epochs):
            return
        self.last = now
        per = (now - self.t0) / max(1, done - self.first)
        left = per * (self.epochs - done)
        log.info("%s: epoch %d/%d, train error %.4f%s, %.0f s elapsed, ~%.0f s left (or less "
                 "with early stopping)", self.desc, done, self.epochs, err,
                 "" if val is None else f", validation accuracy {val:.4f}", now - self.t0, left)  # fmt: skip


#: the training error recorded after each epoch is measured on at most this many windows
TRAIN_ERROR_WINDOWS = 2048


def _record(st: dict, model: SpikeModel, spikes: torch.Tensor, yt: torch.Tensor,
            val: tuple[torch.Tensor, np.ndarray] | None,
            train_error: float | None = None) -> tuple[float, float]:  # fmt: skip
    """Append the training error (``train_error`` where the model's solve measured it; else
    computed) and the validation accuracy to ``st``; returns ``(error, score)`` with score the
    validation accuracy, or ``1 - error`` without validation."""
    if train_error is None:
        # on at most TRAIN_ERROR_WINDOWS evenly spaced windows: scoring every training window
        # after each epoch took a fifth of ST-MNIST's csnn epoch (5,571 windows)
        idx = torch.from_numpy(evenly_spaced(spikes.shape[0], TRAIN_ERROR_WINDOWS))
        err = float((model.batched_scores(spikes[idx]).argmax(1) != yt[idx]).float().mean())
    else:
        err = float(train_error)
    st["history"].append(err)
    if val is None:
        return err, 1.0 - err
    vy = torch.as_tensor(np.asarray(val[1]), dtype=torch.long)
    score = float((model.batched_scores(val[0]).argmax(1) == vy).float().mean())
    st["val_history"].append(score)
    return err, score


def _load_state(module: torch.nn.Module, arrays: dict) -> None:
    module.load_state_dict({k: torch.from_numpy(np.asarray(v)) for k, v in arrays.items()})


def _flatten_optimizer(opt: torch.optim.Optimizer) -> dict[str, np.ndarray]:
    out = {}
    for i, st in opt.state_dict()["state"].items():
        for k, v in st.items():
            out[f"{i}.{k}"] = (
                v.detach().cpu().numpy().copy() if torch.is_tensor(v) else np.asarray(v)
            )
    return out


def _optimizer_to(opt: torch.optim.Optimizer | None, device: torch.device) -> None:
    """The optimizer's state (Adam's moments) onto ``device``, beside the parameters (a resumed
    run's state is loaded while the model is on the CPU)."""
    if opt is None:
        return
    for st in opt.state.values():
        for k, v in st.items():
            if torch.is_tensor(v) and v.device != device and k != "step":
                st[k] = v.to(device)


def _restore_optimizer(opt: torch.optim.Optimizer, flat: dict[str, np.ndarray]) -> None:
    sd = opt.state_dict()
    state: dict[int, dict] = {}
    for key, v in flat.items():
        i, name = key.split(".", 1)
        state.setdefault(int(i), {})[name] = torch.from_numpy(np.array(v))
    sd["state"] = state
    opt.load_state_dict(sd)


def _confidence(model: SpikeModel, confidence: np.ndarray, yt: torch.Tensor) -> torch.Tensor:
    """``confidence`` ``[N]`` as a tensor, checked (finite, in [0, 1], one per window) for a
    model that trains on it."""
    if not model.trains_on_confidence:
        raise ValueError(f"{type(model).registry_name} does not train on window "
                         "confidences (soft targets)")  # fmt: skip
    ct = torch.as_tensor(np.asarray(confidence, np.float32))
    if (ct.shape != yt.shape or not bool(torch.isfinite(ct).all())
            or (float(ct.min()) < 0 or float(ct.max()) > 1)):  # fmt: skip
        raise ValueError(f"confidence must be [N={yt.numel()}] finite in [0, 1]")
    return ct


def _resumed(model: SpikeModel, resume: dict, gen: torch.Generator, opt,
             st: dict) -> tuple[dict, dict]:  # fmt: skip
    """A checkpoint's weights, generator and optimizer state restored in place; returns its
    bookkeeping (the keys of ``st``) and best weights."""
    _load_state(model, resume["model"])
    gen.set_state(torch.from_numpy(np.asarray(resume["rng"], dtype=np.uint8)))
    if opt is not None and "optimizer" in resume:
        _restore_optimizer(opt, resume["optimizer"])
    st = {k: resume[k] for k in st}
    st["history"], st["val_history"] = list(st["history"]), list(st["val_history"])
    return st, {k: torch.from_numpy(np.asarray(v)) for k, v in resume["best"].items()}
