"""The ``--data`` policy: what ``tactilesnn train --data FILE`` (and ``SpikeClassifier``, ``bench
real``) starts from when the user sets nothing, derived from the file's facts
(:class:`~tactilesnn.core.data.DataFacts`: events or analog, taxel grid, window): the
defaults of the pipeline, and those that go with one component only. Every value below says
what it was measured against. :mod:`tactilesnn.resolve` applies them between the data's facts
and the user's choices; the cut of long recordings is :func:`~tactilesnn.recordings.auto_cut`'s,
the selection's budget (how much of a run the encoder comparison may cost)
:mod:`tactilesnn.selection`'s.
"""

from __future__ import annotations

from typing import Any

from .recordings import DataFacts


def data_file_defaults(facts: DataFacts) -> dict[str, Any]:
    """Flat settings ``train --data FILE`` starts from (each yields to an explicit setting):
    every channel, the linear-cost ``readout`` model (on real recordings it beats the tempotron,
    whose gradient training fails with hundreds of inputs: Braille 81.5 vs 70.4 %), the
    calibrated level code (:mod:`~tactilesnn.encoders.level`: the channels' levels that window-
    normalised codes drop), and for
    event files (``X [N, taxels, polarity, bins]``) the ``events`` encoder; event taxels that form
    a ``grid`` (``"ROWSxCOLS"``, declared or square) or sit in its ``cells`` (placed from their
    positions) get the convolutional ``csnn`` model, with the settings of
    :func:`model_defaults` for it."""
    events, grid = facts.events, facts.grid
    out: dict[str, Any] = {"channels": ("all",), "model": "readout",
                           "level_neurons": DATA_LEVEL_NEURONS, "level_scale": DATA_LEVEL_SCALE,
                           "level_share": DATA_LEVEL_SHARE}  # fmt: skip
    if events:  # counts: the rank pair alone (see DATA_LEVEL_SCALE)
        out.update(encoder="events", level_scale="rank", level_share=False)
    if events and grid is not None:  # the conv model maps every afferent onto the grid
        out["model"] = "csnn"
    return out


def model_defaults(facts: DataFacts, model: str) -> dict[str, Any]:
    """Flat settings that go with ``model`` on this data, whichever way it was chosen (by
    :func:`data_file_defaults` or by the user), and only with it: the ``csnn`` on an event file
    whose taxels form a grid gets the grid (and the taxels' ``cells``), every afferent on it (no
    level code), its epochs and the cosine schedule (:data:`CSNN_DATA_EPOCHS`), and its time step
    and constant from the window. Another model on the same file keeps its own defaults."""
    if model != "csnn" or not facts.events or facts.grid is None:
        return {}
    out: dict[str, Any] = {"csnn_grid": facts.grid, "level_neurons": 0,
                           "epochs": CSNN_DATA_EPOCHS, "lr_schedule": "cosine",
                           "csnn_dt_ms": 0.0, "csnn_tau_ms": 0.0}  # fmt: skip
    if facts.cells:
        out["csnn_cells"] = tuple(facts.cells)
    return out


#: the csnn's epochs for ``train --data`` (with the cosine learning-rate schedule and its time
#: step and constant from the window: 10 steps, tau half the window; ST-MNIST's 100-bin trials
#: of unstated bin width 95.37 % at 5 / 50 ms in 9.5 s per epoch, 95.22 % at 10 / 50 ms in 60 %
#: of the time per step). ST-MNIST,
#: seed 0, source split, on a 2-core machine (2026-11-28): 40 epochs at a constant rate 95.73 %
#: in 7 min 31 s of fit; 12 with the cosine schedule 95.37 % in 2 min 26 s; 10: 94.14 % in 2 min
#: 6 s, below the random forest on summary statistics (94.28 %) in the same run
CSNN_DATA_EPOCHS = 12

#: the level code's neurons per statistic for ``train --data``: its ON / OFF rank-latency pair
#: (why the pair: :mod:`tactilesnn.encoders.level`). LIF + readout, seed 0, without -> with it:
#: FabricSlide 99.14 -> 99.68 % per window (the amplitude-only baseline 99.63 %); a synthetic
#: 22-channel file of level patterns 99.79 -> 99.50 % (+-0.37 %; baseline 100 %)
DATA_LEVEL_NEURONS = 2
#: and its pairs code each statistic's rank and its linear position (the readout weighs the two),
#: with each channel's share of the window's total level as a third statistic. Defaults + readout,
#: seeds 0-2, per window, rank pair -> both pairs and the share: synthetic localise (100 taxels)
#: 82.99 -> 86.42 % (amplitude-only baseline 83.13 %), iCub Braille 97.88 -> 99.47 %, texture
#: 72.99 -> 73.96 % (docs/benchmarks.md, "Generality", for every set). Event files keep the rank
#: pair alone: ST-MNIST's 40 taxels without positions (events + readout, 80 afferents of counts)
#: 85.67 % with it, 67.95 % with both pairs and the share (three times the level afferents put
#: the readout's features over its exact-solve budget; solved exactly on the window end alone
#: 69.25 %)
DATA_LEVEL_SCALE = "rank+linear"
DATA_LEVEL_SHARE = True


#: encoders ``train --data`` chooses among on held-out training recordings when none is set
#: (analog files): no one encoder wins everywhere (readout model, seed 0: iCub Braille LIF 92.6 %
#: vs GWT 81.5 %; stiffness x curvature STFT 95.6 % vs GWT 85.0 % vs LIF 41.7 %; texture GWT 55.8 %
#: vs STFT 42.9 % vs LIF 30.2 %). The Gabor candidate is the causal bank (``cgwt``: streamable,
#: its stream graph transforms each sample once), which matched or beat the windowed FFT one on
#: every set compared (readout, seeds 0-1: texture 74.58 vs 73.23 %, material 76.39 vs 73.06 %,
#: touch 99.06 vs 98.12 %, hook_loop 99.72 vs 99.66 %, FabricSlide 99.21 vs 99.12 %, iCub Braille
#: 92.86 % both) in less encoding time
DATA_ENCODER_CANDIDATES = ("cgwt", "stft", "lif")
