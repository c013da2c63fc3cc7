"""The model contract (spike times -> class scores) and the model registry.

A model is a ``torch.nn.Module`` built from its typed configuration (a frozen dataclass with a
``type`` tag) and the shape of the spikes it receives:

* input: spike times ``[batch, afferents, k]`` float32, ms from the window start, ``+inf`` = no
  spike (the encoders' output format, :mod:`tactilesnn.encoders.base`);
* :meth:`SpikeModel.scores` -> ``[batch, classes]`` (larger = more likely);
* training: either :meth:`SpikeModel.loss` (differentiable, the trainer runs Adam on it) or
  :meth:`SpikeModel.rule_update` (a local learning rule applied in place); ``learns_by_rule``
  says which;
* learned state lives in ``state_dict()`` (parameters and buffers: weights, momentum);
* :meth:`SpikeModel.onnx_module` returns the exported graph of the model, with its streaming
  state (:attr:`SpikeModel.state_names`, ``[batch, units]`` each) as graph inputs and outputs.

Adding a model: its settings class and one ``MODELS.declare("name", Config, module)`` line in
:mod:`tactilesnn.schema.models` (read without torch), and one module with a
``@register_model("name", Config)`` class; nothing else in the package names it.
"""

from __future__ import annotations

import contextlib
from abc import abstractmethod
from collections.abc import Callable
from typing import ClassVar

import numpy as np
import torch
from torch import Tensor, nn

from ..schema.models import MODELS


@contextlib.contextmanager
def seeded(seed: int):
    """Within the block torch's global generator is seeded with ``seed``; afterwards it is as
    before (layers that draw initial weights from it are reproducible without reseeding the
    user's generator)."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(seed))
        yield


def register_model(name: str, config: type) -> Callable[[type], type]:
    """Class decorator: register a :class:`SpikeModel` under ``name`` with its config class."""
    return MODELS.register(name, config)


#: the factors of :meth:`SpikeModel.finetune_penalty` a fine-tune chooses from
FINETUNE_FACTORS = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0)


class SpikeModel(nn.Module):
    """Base class of every model; see the module docstring for the contract."""

    #: True: trained by :meth:`rule_update`; False: by Adam on :meth:`loss`
    learns_by_rule: ClassVar[bool] = False
    #: the exported module must be scripted (it has a time loop) rather than traced
    onnx_scripted: ClassVar[bool] = False
    #: the exported module traces under ``torch.export`` (the supported exporter; a scripted
    #: module's loops then as scan operators): else only the TorchScript-based exporter writes it
    onnx_exportable: ClassVar[bool] = True
    #: what the scores mean (written into the exported graph's metadata)
    #: buffers a saved run may lack (added later); they keep their constructed, neutral value
    optional_state: ClassVar[tuple[str, ...]] = ()
    score_units: ClassVar[str] = "class scores (larger = more likely)"
    #: runs on frame by frame with its state carried (:meth:`frame_module`): a stream model
    has_frame_step: ClassVar[bool] = False
    #: the training epochs a run takes for this model when none are given (None: the
    #: settings' default)
    default_epochs: ClassVar[int | None] = None
    #: trains on soft targets from each window's confidence (:meth:`solve` and :meth:`loss`
    #: take ``confidence``; :func:`~.softmax_fit.soft_targets`)
    trains_on_confidence: ClassVar[bool] = False

    def __init__(
        self,
        config: object,
        n_afferents: int,
        max_spikes: int,
        n_classes: int,
        duration_ms: float,
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.config = config
        self.n_afferents, self.max_spikes = int(n_afferents), int(max_spikes)
        self.n_classes, self.duration_ms = int(n_classes), float(duration_ms)

    # ------------------------------------------------------------------ inference
    @abstractmethod
    def scores(self, spikes: Tensor) -> Tensor:
        """Spike times ``[B, A, k]`` -> class scores ``[B, classes]``."""

    def forward(self, spikes: Tensor) -> Tensor:
        return self.scores(spikes)

    def batch_size(self, spikes: Tensor, budget_bytes: int = 1 << 26) -> int:
        """Samples per call so one call's intermediates stay within ``budget_bytes``."""
        per = max(1, self.bytes_per_sample(spikes.shape[1], spikes.shape[2]))
        return int(max(1, min(4096, budget_bytes // per)))

    @torch.no_grad()
    def batched_scores(self, spikes: Tensor) -> Tensor:
        """:meth:`scores` of any number of samples, in batches bounded by a byte budget."""
        batch = self.batch_size(spikes)
        parts = [self.scores(spikes[i : i + batch]) for i in range(0, spikes.shape[0], batch)]
        return torch.cat(parts) if parts else torch.zeros(0, self.n_classes)

    def bytes_per_sample(self, afferents: int, k: int) -> int:
        """Peak intermediate bytes per sample (for batching by a byte budget)."""
        return 4 * afferents * k

    #: the model decides before the window ends (:meth:`early_decision`), and its
    #: :meth:`onnx_module` returns ``(scores, *new state, early class [B] int64, decision_ms [B])``
    decides_early: ClassVar[bool] = False

    def early_decision(self, spikes: Tensor) -> tuple[Tensor, Tensor] | None:
        """``(classes [B], decision_ms [B])`` if the model can decide before the window ends."""
        return None

    def calibrate_decision(self, spikes: Tensor) -> None:
        """After training: fit what :meth:`early_decision` needs on the training spikes
        ``[N, A, k]`` (e.g. the SNN's decision margin); default: nothing."""

    # ------------------------------------------------------------------ training
    def prepare(self, spikes: Tensor) -> None:
        """Fit input statistics on the training spikes ``[N, A, k]`` before the first epoch
        (e.g. feature scaling, kept as buffers so they are saved and exported); default: none."""

    @classmethod
    def solves_in_one_go(cls, config: object) -> bool:
        """Whether a model of ``config`` fits by :meth:`solve` (its cost is then a few passes
        over the training spikes, which a run's plan can estimate) rather than by epochs."""
        return False

    @classmethod
    def pretraining_capacities(cls, config: object) -> dict[str, object]:
        """The configurations a pretraining on another domain (synthetic recordings) tries,
        by a short name: the transfer keeps the one whose pretrained model explains the target
        domain's few labelled windows best, since the capacity the source's own
        cross-validation picks fits the source, not the transfer. Default: ``config`` alone."""
        return {"configured": config}

    def solve(self, spikes: Tensor, y: Tensor, groups=None, confidence=None) -> dict | None:
        """Fit in one go instead of the trainer's epochs (a convex model solved to its optimum),
        after :meth:`prepare`: labels ``y [N]`` int64, ``groups`` recording ids ``[N]`` (for
        cross-validation; None: each window its own), ``confidence`` ``[N]`` in [0, 1] (only
        where :attr:`trains_on_confidence`). Returns what the fit chose (reported in
        ``metrics.json``), or None (default): train by epochs."""
        return None

    def loss(self, spikes: Tensor, y: Tensor) -> Tensor:
        """Differentiable training loss (models that learn by gradient)."""
        raise NotImplementedError(f"{type(self).__name__} learns by a rule, not by gradient")

    def adapt(self, spikes: Tensor) -> dict:
        """Re-estimate the model's input statistics on a new domain's unlabelled spikes
        ``[N, A, k]`` (after training on another: synthetic pretraining, then the user's
        sensor), leaving what it learnt alone. Default: the model has none to re-estimate."""
        raise NotImplementedError(f"{type(self).__name__} has no input statistics to adapt")

    def finetune_parameters(self) -> list[nn.Parameter]:
        """The parameters :meth:`finetune` adapts (the read-out layer); default: none."""
        return []

    def finetune_penalty(self, n: int) -> float:
        """The pull of :meth:`finetune` towards the trained values for ``n`` new windows."""
        return 0.03 * 256 / max(n, 1)

    def finetune_loss(self, spikes: Tensor, y: Tensor, confidence: Tensor | None = None) -> Tensor:
        """The data term :meth:`finetune` minimises (default: :meth:`loss`; with
        ``confidence``, models that :attr:`trains_on_confidence` take soft targets)."""
        if confidence is not None:
            raise NotImplementedError(f"{type(self).__name__} does not train on confidences")
        return self.loss(spikes, y)

    def check_finetune_inputs(self, spikes: Tensor, y: Tensor, groups: np.ndarray | None,
                              confidence: Tensor | None) -> tuple[int, Tensor | None]:  # fmt: skip
        """:meth:`finetune`'s arguments checked -> (windows, confidence as a tensor or None)."""
        if confidence is not None and not self.trains_on_confidence:
            raise ValueError(f"{type(self).__name__} does not train on window confidences")
        n = int(spikes.shape[0])
        if n == 0 or y.shape[0] != n:
            raise ValueError(
                f"fine-tuning needs windows and one label each, got {n} / {y.shape[0]}"
            )
        if groups is not None and len(groups) != n:
            raise ValueError(f"groups must name the recording of each of the {n} windows")
        conf = None if confidence is None else torch.as_tensor(confidence)
        if conf is not None and conf.shape != (n,):
            raise ValueError(f"confidence must be [N={n}], got {tuple(conf.shape)}")
        return n, conf

    def finetune(self, spikes: Tensor, y: Tensor, groups: np.ndarray | None = None,
                 factors: tuple[float, ...] = FINETUNE_FACTORS, max_iter: int = 200,
                 confidence: Tensor | None = None) -> dict:  # fmt: skip
        """Adapt a trained model to a few windows of a new domain (pretrain, then fine-tune):
        :meth:`finetune_parameters` re-fitted by full-batch L-BFGS to :meth:`finetune_loss`
        plus a penalty times their squared distance from the trained values (a prior centred on
        what pretraining learnt, not on zero; biases free). The penalty is
        :meth:`finetune_penalty` times one of ``factors``, chosen by leave-one-recording-out
        cross-validation over ``groups`` (recording ids ``[N]``; the held-out recordings'
        cross-entropy; ties: the stronger prior) where there are two recordings or more, else
        the factor 1. Spikes ``[N, A, k]``, labels ``y [N]`` int64; ``confidence`` ``[N]`` in
        [0, 1]: soft targets (:func:`~.softmax_fit.soft_targets`; models that
        :attr:`trains_on_confidence`). Returns the penalty, the cross-validation's table and
        the data term before and after."""
        params = self.finetune_parameters()
        if not params:
            raise NotImplementedError(f"{type(self).__name__} does not fine-tune")
        n, conf = self.check_finetune_inputs(spikes, y, groups, confidence)

        def rows(at: Tensor) -> tuple[Tensor, Tensor, Tensor | None]:
            return spikes[at], y[at], None if conf is None else conf[at]

        anchors = [q.detach().clone() for q in params]
        named = {id(q): name for name, q in self.named_parameters()}
        pulled = [not named.get(id(q), "").endswith("bias") for q in params]

        def fit(idx: np.ndarray, lam: float, iters: int) -> None:
            with torch.no_grad():
                for q, a in zip(params, anchors, strict=True):
                    q.copy_(a)
            part = rows(torch.from_numpy(idx))
            opt = torch.optim.LBFGS(params, lr=1.0, max_iter=iters, history_size=20,
                                    tolerance_grad=1e-7, line_search_fn="strong_wolfe")  # fmt: skip

            def closure() -> Tensor:
                opt.zero_grad()
                loss = self.finetune_loss(*part) + lam * sum(
                    (q - a).pow(2).sum()
                    for q, a, pull in zip(params, anchors, pulled, strict=True) if pull
                )  # fmt: skip
                loss.backward()
                return loss

            opt.step(closure)

        with torch.no_grad():
            before = float(self.finetune_loss(spikes, y, conf))
        everything = np.arange(n)
        ids = np.unique(groups) if groups is not None else np.zeros(0)
        table = []
        factor = 1.0
        if ids.size >= 2 and len(factors) > 1:
            for f in factors:
                lam = self.finetune_penalty(n) * f
                held = []
                for g in ids:
                    out = np.asarray(groups) == g
                    fit(everything[~out], lam, max_iter // 2)
                    at = torch.from_numpy(everything[out])
                    with torch.no_grad():
                        held.append(float(self.finetune_loss(*rows(at))))
                table.append({"factor": f, "penalty": lam, "held_out_loss": float(np.mean(held))})
            best = min(r["held_out_loss"] for r in table)
            factor = max(r["factor"] for r in table if r["held_out_loss"] <= best + 1e-9)
        lam = self.finetune_penalty(n) * factor
        fit(everything, lam, max_iter)
        with torch.no_grad():
            after = float(self.finetune_loss(spikes, y, conf))
        return {"penalty": lam, "factor": factor, "windows": n, "cross_validation": table,
                "loss_before": before, "loss_after": after}  # fmt: skip

    def rule_update(self, spikes: Tensor, y: Tensor, epoch: int) -> None:
        """Apply the model's learning rule for one mini-batch (models that learn by rule)."""
        raise NotImplementedError(f"{type(self).__name__} learns by gradient, not by a rule")

    def learning_rate(self) -> float:
        """Adam learning rate for models trained by gradient."""
        raise NotImplementedError(f"{type(self).__name__} learns by a rule, not by gradient")

    # ------------------------------------------------------------------ export
    @property
    def state_names(self) -> tuple[tuple[str, int], ...]:
        """Streaming state carried between windows: ``(graph input name, units)`` pairs."""
        return ()

    def frame_module(self, gather: bool = False) -> nn.Module:
        """The one-frame step ``(spikes [B, A] of one frame, *state) -> (scores, decision [B]
        int64, *next state)`` (``state_names`` on the module); only where
        :attr:`has_frame_step`."""
        raise ValueError(
            f"the {self.registry_name} model classifies whole windows: a frame-by-frame stream "
            "needs a stream model (--model stream)"
        )

    def export_problem(self) -> str | None:
        """Why this configured model cannot be exported to ONNX (None: it can)."""
        return None

    @abstractmethod
    def onnx_module(self) -> nn.Module:
        """Module ``(spikes [B, A, k], *state) -> (scores, *new state)`` for ONNX export (then
        ``early class, decision_ms`` if :attr:`decides_early`)."""

    def upgrade_state(self, state: dict) -> dict:
        """Map a ``state_dict`` saved before the component layer to the current keys (buffers
        the old format lacked keep their current values)."""
        return {**{k: v.numpy() for k, v in self.state_dict().items()}, **state}

    def to_nir(self):
        """The model as a NIR graph (input: the spike raster); ValueError where NIR has no match."""
        raise ValueError(
            f"the {self.registry_name} model has no NIR equivalent; export it with ONNX"
        )


def build_model(
    config: object,
    n_afferents: int,
    max_spikes: int,
    n_classes: int,
    duration_ms: float,
    seed: int = 0,
) -> SpikeModel:
    """Instantiate the registered model whose config class ``config`` is (``seed``: weights)."""
    cls = MODELS.component_for(config)
    return cls(config, n_afferents, max_spikes, n_classes, duration_ms, seed=seed)


def to_tensor_labels(y: object, n_classes: int, n: int) -> Tensor:
    """Labels as int64 ``[n]`` in ``[0, n_classes)``, or a ValueError."""
    yt = torch.as_tensor(y)
    if yt.dtype.is_floating_point or yt.dtype.is_complex or yt.dtype == torch.bool:
        raise ValueError(f"labels must be integers, got dtype {yt.dtype}")
    yt = yt.long()
    if yt.ndim != 1 or yt.shape[0] != n:
        raise ValueError(f"y must be [N={n}], got shape {tuple(yt.shape)}")
    if yt.numel() and (int(yt.min()) < 0 or int(yt.max()) >= n_classes):
        raise ValueError(f"labels must be in [0, {n_classes}), got {yt.unique().tolist()}")
    return yt
