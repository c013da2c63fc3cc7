"""The models' settings: one frozen dataclass per registered model, declared without torch.

As :mod:`tactilesnn.schema.encoders`: each model's module (:mod:`tactilesnn.models`) registers
its class under the name declared here (:data:`MODELS`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..core.checks import check_choice, check_int, check_positive, check_range
from ..core.registry import Registry
from ..core.settings import ComponentSettings, setting

MODELS: Registry = Registry("model")

#: class scores of the SNN's output layer
READOUTS = ("count", "max", "mean")
#: class scores of the convolutional SNN's leaky-integrator output
CSNN_READOUTS = ("max", "mean")
#: time steps per window of the convolutional SNN's ``dt_ms = 0``
AUTO_STEPS = 10
#: the read-out's solvers
SOLVERS = ("exact", "adam")
#: how the tempotron learns: seed 001's rule, or Adam on a V_max hinge
LEARNING = ("rule", "gradient")


def parse_grid(text: str) -> tuple[int, int]:
    """``"10x10"`` -> ``(10, 10)``; ValueError otherwise."""
    parts = str(text).lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() and int(p) > 0 for p in parts):
        raise ValueError(f"grid must be ROWSxCOLS (e.g. 10x10) or auto, got {text!r}")
    return int(parts[0]), int(parts[1])


@dataclass(frozen=True)
class ConvSNNConfig(ComponentSettings):
    grid: str = setting(
        "auto", flag="csnn_grid",
        help="taxel grid ROWSxCOLS (row-major taxels, polarities interleaved) or auto (square)",
    )  # fmt: skip
    channels: int = setting(
        32, flag="csnn_channels",
        help="feature maps of the first convolution (the second has twice as many)",
    )  # fmt: skip
    dt_ms: float = setting(
        5.0, flag="csnn_dt_ms",
        help=f"time step (ms); the window is rasterised at this step (0 = the window / "
        f"{AUTO_STEPS})",
    )  # fmt: skip
    tau_ms: float = setting(
        50.0, flag="csnn_tau_ms",
        help="membrane time constant of every layer (ms; 0 = half the window)",
    )  # fmt: skip
    readout: str = setting(
        "mean", flag="csnn_readout", choices=CSNN_READOUTS,
        help="class score: max or mean over time of the leaky-integrator output",
    )  # fmt: skip
    lr: float = setting(0.003, flag="csnn_lr", help="Adam learning rate")
    shift: int = setting(
        1, flag="csnn_shift",
        help="training only: each sample's grid moved by up to this many taxels (0 = off)",
    )  # fmt: skip
    dropout: float = setting(
        0.2, flag="csnn_dropout", help="training only: dropout on the second layer's spikes"
    )
    cells: tuple[int, ...] = setting(
        (), flag="csnn_cells",
        help="row-major grid cell of each taxel, in taxel order (empty: the taxels fill the grid "
        "row by row)",
    )  # fmt: skip

    def __post_init__(self) -> None:
        object.__setattr__(self, "cells", tuple(int(c) for c in self.cells))
        if self.grid != "auto":
            rows, cols = parse_grid(self.grid)
            if self.cells and (min(self.cells) < 0 or max(self.cells) >= rows * cols
                               or len(set(self.cells)) != len(self.cells)):  # fmt: skip
                raise ValueError(f"cells must be distinct cells of the {self.grid} grid")
        elif self.cells:
            raise ValueError("cells need an explicit grid (ROWSxCOLS)")
        check_int(self.channels, "channels", 1)
        for name in ("dt_ms", "tau_ms"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number of ms >= 0 (0 = from the "
                                 f"window), got {value}")  # fmt: skip
        check_choice(self.readout, "readout", CSNN_READOUTS)
        check_positive(self.lr, "lr")
        check_int(self.shift, "shift", 0)
        check_range(self.dropout, "dropout", 0.0, 0.9)

    def times_ms(self, duration_ms: float) -> tuple[float, float]:
        """``(dt_ms, tau_ms)`` for windows of ``duration_ms``: the set values, or for 0 the
        window / :data:`AUTO_STEPS` and half the window (the same network on any time scale)."""
        return (self.dt_ms or duration_ms / AUTO_STEPS, self.tau_ms or duration_ms / 2)


@dataclass(frozen=True)
class ForestConfig(ComponentSettings):
    tau_ms: float = setting(  # 0: the window's duration
        0.0, flag="forest_tau_ms",
        help="leaky-integrator time constant of the forest's traces (ms; 0 = the window)",
    )  # fmt: skip
    n_times: int = setting(
        16, flag="forest_times", help="instants across the window at which the traces are read"
    )
    trees: int = setting(200, flag="forest_trees", help="trees in the forest")
    leaves: int = setting(64, flag="forest_leaves", help="most leaves per tree")
    min_leaf: int = setting(
        2, flag="forest_min_leaf", help="fewest training windows (weighted) in a leaf"
    )

    def __post_init__(self) -> None:
        if self.tau_ms != 0:
            check_positive(self.tau_ms, "tau_ms")
        check_int(self.n_times, "n_times", 1)
        check_int(self.trees, "trees", 1)
        check_int(self.leaves, "leaves", 2)
        check_int(self.min_leaf, "min_leaf", 1)


@dataclass(frozen=True)
class ReadoutConfig(ComponentSettings):
    tau_ms: float = setting(  # 0: the window's duration
        0.0, flag="readout_tau_ms",
        help="leaky-integrator time constant of the readout traces (ms; 0 = the window)",
    )  # fmt: skip
    n_times: int = setting(
        16, flag="readout_times", help="instants across the window at which the traces are read"
    )
    lr: float = setting(0.003, flag="readout_lr", help="Adam learning rate of the readout")
    weight_decay: float = setting(
        0.03, flag="readout_weight_decay",
        help="L2 penalty on the readout weights (their inputs are standardised) at 256 training "
        "windows, scaled by 256 / N for N",
    )  # fmt: skip
    # saved_before: what a saved configuration without these fields meant (runs written before
    # them); while_selecting (:func:`~tactilesnn.selection.select_encoder`): one exact fit at the
    # configured penalty, every instant (the ranking of encoders, at a third of the cost)
    solver: str = setting(
        "exact", flag="readout_solver", choices=SOLVERS, saved_before="adam",
        help="exact: the convex loss minimised to its optimum (full-batch L-BFGS); adam: the "
        "trainer's epochs of mini-batch Adam",
    )  # fmt: skip
    choose: bool = setting(
        True, flag="readout_choose", saved_before=False, while_selecting=False,
        help="exact solver: the penalty (x 1/3 to 30) and the read-out instants used (all, or "
        "the last) chosen by 3-fold cross-validation over recordings",
    )  # fmt: skip

    def __post_init__(self) -> None:
        if self.tau_ms != 0:
            check_positive(self.tau_ms, "tau_ms")
        check_int(self.n_times, "n_times", 1)
        check_positive(self.lr, "lr")
        check_range(self.weight_decay, "weight_decay", 0.0, 1.0)
        check_choice(self.solver, "solver", SOLVERS)
        if not isinstance(self.choose, bool):
            raise ValueError(f"choose must be true or false, got {self.choose!r}")


@dataclass(frozen=True)
class SNNConfig(ComponentSettings):
    """Two-layer surrogate-gradient SNN on the spike raster, trained with Adam on cross-entropy."""

    hidden: int = setting(64, flag="snn_hidden", help="hidden LIF units")
    dt_ms: float = setting(
        5.0, flag="snn_dt_ms", help="SNN time step (ms); the window is rasterised at this step"
    )
    tau_ms: float = setting(
        50.0, flag="snn_tau_ms", help="membrane time constant of every SNN layer (ms)"
    )
    readout: str = setting(
        "max", flag="snn_readout", choices=READOUTS,
        help=f"class score from the output layer ({', '.join(READOUTS)})",
    )  # fmt: skip
    recurrent: bool = setting(
        False, flag="snn_recurrent",
        help="recurrent hidden layer (W_rec s_{t-1} added to the input current)",
    )  # fmt: skip
    lr: float = setting(0.003, flag="snn_lr", help="Adam learning rate")
    #: early decision: the margin is the smallest at which the early class is the full-window
    #: class on at least this fraction of the training windows (1 = never earlier than needed
    #: on any training window)
    early_agreement: float = setting(
        0.99, flag="snn_early_agreement",
        help="early decision: fraction of training windows on which it must name the "
        "full-window class (higher: later, safer decisions)",
    )  # fmt: skip
    # runs written before the component layer simulated ceil(D / dt) + 1 steps, so they load
    # with 1 (legacy) and score exactly as they were trained
    extra_steps: int = setting(
        0,
        flat=False,
        legacy=1,
        help="time steps simulated after the window end (1 in pre-0.2 runs)",
    )

    def __post_init__(self) -> None:
        check_int(self.hidden, "hidden", 1)
        check_positive(self.dt_ms, "dt_ms")
        check_positive(self.tau_ms, "tau_ms")
        check_choice(self.readout, "readout", READOUTS)
        if not isinstance(self.recurrent, bool):
            raise ValueError(f"recurrent must be true or false, got {self.recurrent!r}")
        check_positive(self.lr, "lr")
        if not 0 < self.early_agreement <= 1:
            raise ValueError(f"early_agreement must be in (0, 1], got {self.early_agreement}")
        check_int(self.extra_steps, "extra_steps", 0)


@dataclass(frozen=True)
class StreamSNNConfig(ComponentSettings):
    """Stream SNN: LIF hidden layer and leaky readout read every frame (module docstring)."""

    hidden: int = setting(64, flag="stream_hidden", help="hidden LIF units")
    dt_ms: float = setting(
        0.0, flag="stream_dt_ms",
        help="time step (ms); 0: the encoder's frame (the window over its spike slots)",
    )  # fmt: skip
    tau_ms: float = setting(50.0, flag="stream_tau_ms", help="hidden membrane time constant (ms)")
    # hook_loop (0.5 s windows), frames + stream, 15 epochs, seed 0: 30 / 100 / 300 / 1000 ms
    # 92.5 / 97.8 / 98.6 / 98.8 %: evidence is held for about two windows
    readout_tau_ms: float = setting(
        0.0, flag="stream_readout_tau_ms",
        help="readout membrane time constant (ms): how long evidence is held; 0: twice the "
        "window",
    )  # fmt: skip
    burn_in: float = setting(
        0.25, flag="stream_burn_in",
        help="fraction of each training window's first frames left out of the loss",
    )  # fmt: skip
    quiet_ms: float = setting(
        250.0, flag="stream_quiet_ms",
        help="a stream's state returns to rest after this long without an input spike (ms; "
        "0: never)",
    )  # fmt: skip
    recurrent: bool = setting(False, flag="stream_recurrent", help="recurrent hidden layer")
    lr: float = setting(0.003, flag="stream_lr", help="Adam learning rate")
    stream_epochs: int = setting(
        10, flag="stream_epochs",
        help="epochs of truncated back-propagation through time over the training recordings "
        "(state carried from chunk to chunk), after the window epochs; 0: windows only",
    )  # fmt: skip
    early_agreement: float = setting(
        0.95, flag="stream_agreement",
        help="decision margin: fraction of training frames past the burn-in on which a "
        "decided class must be the window's final class",
    )  # fmt: skip

    def __post_init__(self) -> None:
        check_int(self.hidden, "hidden", 1)
        # 0 = derived (the code's frame; twice the window)
        for name in ("dt_ms", "readout_tau_ms", "quiet_ms"):
            check_range(getattr(self, name), name, 0.0, math.inf)
        check_positive(self.tau_ms, "tau_ms")
        if not 0 <= self.burn_in < 1:
            raise ValueError(f"burn_in must be in [0, 1), got {self.burn_in}")
        if not isinstance(self.recurrent, bool):
            raise ValueError(f"recurrent must be true or false, got {self.recurrent!r}")
        check_positive(self.lr, "lr")
        check_int(self.stream_epochs, "stream_epochs", 0)
        if not 0 < self.early_agreement <= 1:
            raise ValueError(f"early_agreement must be in (0, 1], got {self.early_agreement}")


@dataclass(frozen=True)
class TempotronConfig(ComponentSettings):
    """One exact tempotron per class, trained by seed 001's rule (or Adam on a V_max hinge)."""

    # the flags of earlier versions (tau_ms, theta, lr, ...) are kept as aliases
    tau_ms: float = setting(  # long membrane memory: integrates the whole 500 ms window
        2000.0, flag="tempotron_tau_ms", aliases=("tau_ms",),
        help="tempotron membrane time constant (ms)",
    )  # fmt: skip
    tau_s_ms: float = setting(
        50.0, flag="tempotron_tau_s_ms", aliases=("tau_s_ms",),
        help="tempotron synaptic time constant (ms, < tau)",
    )  # fmt: skip
    theta: float = setting(
        1.0, flag="tempotron_theta", aliases=("theta",), help="tempotron firing threshold"
    )
    learning: str = setting(
        "rule", flag="tempotron_train", choices=LEARNING,
        help="rule (seed 001) or gradient (Adam on a V_max hinge)",
    )  # fmt: skip
    lr: float = setting(
        0.005, flag="tempotron_lr", aliases=("lr",),
        help="tempotron rule learning rate lambda (seed 001: 0.005)",
    )  # fmt: skip
    adam_lr: float = setting(
        0.003, flag="tempotron_adam_lr", help="Adam learning rate when learning = gradient"
    )
    momentum: float = setting(
        0.0, flag="tempotron_momentum", aliases=("momentum",),
        help="tempotron rule momentum (0 = seed 001)",
    )  # fmt: skip
    margin: float = setting(
        0.2, flag="tempotron_margin", aliases=("margin",),
        help="rule margin kappa: also learn from near misses (0 = seed 001)",
    )  # fmt: skip
    lr_decay: float = setting(
        0.05, flag="tempotron_lr_decay", aliases=("lr_decay",),
        help="rule learning rate / (1 + lr_decay * epoch)",
    )  # fmt: skip

    def __post_init__(self) -> None:
        check_positive(self.tau_s_ms, "tau_s_ms")
        if not self.tau_ms > self.tau_s_ms:
            raise ValueError(f"need tau_ms > tau_s_ms, got {self.tau_ms}, {self.tau_s_ms}")
        check_positive(self.theta, "theta")
        check_choice(self.learning, "learning", LEARNING)
        check_positive(self.lr, "lr")
        check_positive(self.adam_lr, "adam_lr")
        check_range(self.momentum, "momentum", 0.0, 0.999)
        check_range(self.margin, "margin", 0.0, 1e3)
        check_range(self.lr_decay, "lr_decay", 0.0, 1e6)


MODELS.declare("csnn", ConvSNNConfig, "tactilesnn.models.conv_snn")
MODELS.declare("forest", ForestConfig, "tactilesnn.models.forest_readout")
MODELS.declare("readout", ReadoutConfig, "tactilesnn.models.li_readout")
MODELS.declare("snn", SNNConfig, "tactilesnn.models.snn")
MODELS.declare("stream", StreamSNNConfig, "tactilesnn.models.stream_snn")
MODELS.declare("tempotron", TempotronConfig, "tactilesnn.models.tempotron")
