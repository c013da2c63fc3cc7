"""``tactilesnn bench sim2real``: the Braille task's synthetic slides against the real iCub file.

The real recordings (``braille_icub_abc``: 45 slides, 12 taxels, A / B / C; never copied into the
repository) and slides of the ``braille`` task rendered at the real file's rate and length are
treated alike: both cut into windows as ``train --data`` cuts the real file, both through the
``train --data`` defaults (the encoder chosen once on the synthetic training set, the ``readout``
model).

1. **Signal statistics** per taxel, real next to synthetic: rest level (median of the first 10 %
   of the slide), range (99th - 1st percentile), peak time (when the taxel's rise above rest is
   largest, seconds from mid-slide) and the power spectrum (log power in 6 bands). The synthetic
   taxels are put in the real file's order by matching these statistics (Hungarian assignment on
   standardised rest, range and peak time, no labels used): the file does not say which of its
   12 channels is which pad.
2. **Synthetic only**: trained on ``--synthetic`` rendered slides, tested on all 45 real ones
   (mean and sd over ``--seeds`` render + training seeds).
3. **Few-shot**: ``k`` real slides per class (``--shots``, ``--draws`` random draws each) for
   training, the other real slides for testing; without synthetic data, and with the synthetic
   slides added to the training set (the real windows repeated to half of it: joint training).
4. **Randomisation knobs**: each of the task's knobs switched off and doubled (the others at
   their defaults), synthetic-only accuracy on the real file, the change against the defaults.
5. **Calibrated** (``--calibrated-draws``, default 3 per ``k``): for each few-shot draw, the
   sensor model is fitted (:meth:`~tactilesnn.datasets_synth.tasks.braille.BrailleTask.calibrate`,
   ``--calibration-budget-s``) to the ``k`` training slides per class *only*, the arm's speed
   held at its measured value (:func:`real_arm_speed_mm_s` over those slides); ``--calibrated-
   synthetic`` slides of the fitted model then train the pipeline (the encoder and the model's
   pretraining capacity, :func:`pretraining_candidates`, chosen by the ``k`` training slides'
   mean log-probability);
   its read-out's standardisation is re-estimated on the ``k`` training slides' windows (labels
   unused: :func:`~tactilesnn.training.adapt_pipeline`; the score before it is kept as
   ``synthetic_only_unadapted``), then it is scored on the other real slides (synthetic only)
   and fine-tuned on the ``k`` real
   slides (:func:`~tactilesnn.training.finetune_pipeline`: the read-out re-fitted with a prior
   centred on the pretrained weights), next to the same pipeline trained on the ``k`` real
   slides alone (real only). No test slide is seen by the calibration, the encoder's choice,
   the training or the fine-tune (there is no early stopping); ``tests/bench/test_sim2real.py``
   checks it. Each draw's fit is trained on with ``--calibrated-seeds`` seeds (default 3: its
   synthetic slides rendered and every pipeline trained again; one fit's synthetic-only score
   spans up to 45 points per slide from seed to seed); a draw's figure is the mean over its
   seeds, the intervals are over draws.

Writes ``sim2real.json`` (the calibrated section as ``synthetic_only_per_slide`` and ``shots:
{k: {real_only_per_window, pretrained_per_window, ...}}``, means over draws), ``sim2real.md``,
``sim2real.png`` and, per calibrated draw, the fit file and its statistics picture
(``fits/k{k}_d{d}.json``, ``.png`` for the first draw of each ``k``).
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

from .. import add_data_root, data_root
from .benchmark import run
from .data import KNOBS, load_real
from .docs_page import _fabric, page, write_page
from .references import add_references, cross_runs

log = logging.getLogger("tactilesnn")

HELP = "sim-to-real: the braille task against the real iCub Braille file (statistics, transfer)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_data_root(p, "braille_icub_abc/")
    p.add_argument("--synthetic", type=int, default=300, help="synthetic slides per seed")
    p.add_argument("--seeds", type=int, default=3, help="synthetic-only render + training seeds")
    p.add_argument("--shots", type=int, nargs="+", default=[1, 2, 5], help="real slides per class")
    p.add_argument("--draws", type=int, default=5, help="random draws per few-shot size")
    p.add_argument("--knobs", nargs="*", default=list(KNOBS), choices=KNOBS,
                   help="randomisation knobs to switch off and double (none: skip)")  # fmt: skip
    p.add_argument("--knob-synthetic", type=int, default=150, help="synthetic slides per knob run")
    p.add_argument("--epochs", type=int, default=None, help="epochs (default: the model's own)")
    p.add_argument("--calibrated-draws", type=int, default=3,
                   help="few-shot draws per k, the sensor model fitted to each (0: skip)")  # fmt: skip
    p.add_argument("--calibration-budget-s", type=float, default=600.0,
                   help="at most this many seconds per calibration (it stops at its 1200 "
                   "evaluations before, on two quiet cores)")  # fmt: skip
    p.add_argument("--calibrated-synthetic", type=int, default=200,
                   help="slides rendered by each calibrated model")  # fmt: skip
    p.add_argument("--calibrated-seeds", type=int, default=3,
                   help="training seeds per calibrated draw (the fit reused; a draw's figure is "
                   "the mean over them)")  # fmt: skip
    p.add_argument("--optimisers", nargs="*", default=[], choices=("cma", "optuna-tpe", "random"),
                   help="also compare these calibration optimisers (2 seeds on each k's first "
                   "draw; optuna-tpe needs .[bench])")  # fmt: skip
    p.add_argument("--reuse-fits", default=None,
                   help="an earlier run's --out: its fit files of the same draws are read instead "
                   "of fitting again (the downstream arms only); draws it has no file for are "
                   "fitted")  # fmt: skip
    p.add_argument("--docs", default=None,
                   help="also write the page docs/sim2real.md (and its JSON beside it) here")  # fmt: skip
    p.add_argument("--cross-runs-from", default=None,
                   help="an earlier run's --out: add what real only trained on every slide of "
                   "the other recording runs reaches on held-out runs (the file's runs of one "
                   "letter) to its sim2real.json (no run)")  # fmt: skip
    p.add_argument("--references-from", default=None,
                   help="an earlier run's --out: add the non-spiking references (and a forest "
                   "on the spike read-out's features) on its calibrated draws to its "
                   "sim2real.json (no run)")  # fmt: skip
    p.add_argument("--from-json", default=None,
                   help="only rewrite --docs from a run's sim2real.json (no run)")  # fmt: skip
    p.add_argument("--model", default="readout", choices=("readout", "forest"),
                   help="the pipelines' model (one that adapts and fine-tunes)")  # fmt: skip
    p.add_argument("--level-neurons", type=int, default=None,
                   help="level code neurons (default: train --data's; 0 = scale-invariant)")  # fmt: skip


#: the sensor and scene values of a fit file the page states, with their units


def main(out: Path | None, options: argparse.Namespace) -> int:
    from .. import require_out

    if options.cross_runs_from:
        cross_runs(Path(options.cross_runs_from), load_real(data_root(options, "sim2real")))
        return 0
    if options.references_from:
        add_references(Path(options.references_from), load_real(data_root(options, "sim2real")),
                       options.calibrated_synthetic)  # fmt: skip
        return 0
    if options.from_json:
        result = json.loads(Path(options.from_json).read_text())
        if not options.docs:
            raise ValueError("--from-json only rewrites the page: pass --docs")
        docs = Path(options.docs)
        fits = result.get("fits_first_draw") or {}
        docs.write_text(
            page(result, fits, result.get("command", "tactilesnn bench sim2real"), _fabric(docs))
        )
        return 0
    command = (
        f"tactilesnn bench sim2real --out DIR --synthetic {options.synthetic} --seeds "
        f"{options.seeds} --draws {options.draws} --shots {' '.join(map(str, options.shots))} "
        f"--knobs {' '.join(options.knobs)} --calibrated-draws {options.calibrated_draws} "
        f"--calibrated-synthetic {options.calibrated_synthetic} --calibrated-seeds "
        f"{options.calibrated_seeds}"
        + (f" --optimisers {' '.join(options.optimisers)}" if options.optimisers else "")
        + (f" --model {options.model}" if options.model != "readout" else "")
    ).replace("--knobs  ", "--knobs ")
    result = run(Path(require_out(out, "sim2real")), data_root=data_root(options, "sim2real"),
        synthetic=options.synthetic, seeds=options.seeds, shots=tuple(options.shots),
        draws=options.draws, knobs=tuple(options.knobs), knob_synthetic=options.knob_synthetic,
        epochs=options.epochs, level_neurons=options.level_neurons,
        progress=not options.quiet, calibrated_draws=options.calibrated_draws,
        calibration_budget_s=options.calibration_budget_s,
        calibrated_synthetic=options.calibrated_synthetic,
        optimisers=tuple(options.optimisers), calibrated_seeds=options.calibrated_seeds,
        reuse_fits=Path(options.reuse_fits) if options.reuse_fits else None,
        model=options.model)  # fmt: skip
    import os

    result["command"] = command
    result["machine"] = f"{os.cpu_count()} CPUs, {time.strftime('%Y-%m-%d')}"
    if options.docs:
        write_page(result, Path(out), Path(options.docs), command)
    return 0
