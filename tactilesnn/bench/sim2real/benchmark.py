"""The whole benchmark: statistics, synthetic only, few-shot, knobs and calibrated draws
(:func:`run`).
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np

from .calibrated import calibrated_draw
from .data import (
    KNOBS,
    REAL_FILE,
    SPECTRUM_BANDS_HZ,
    load_real,
    match_taxels,
    real_arm_speed_mm_s,
    real_force_rise,
    render_synthetic,
    reorder,
    taxel_stats,
)
from .protocol import (
    base_config,
    concat,
    cut,
    few_shot_split,
    fit_score,
    has_letter_runs,
    reused_fit,
    run_rest_spread,
    slides,
    with_seed,
)
from .report import plot, table
from .stats import compare_optimisers, summarise_calibrated

log = logging.getLogger("tactilesnn")


def run(out: Path, data_root: Path, synthetic: int = 300, seeds: int = 3,
        shots: tuple[int, ...] = (1, 2, 5), draws: int = 5, knobs: tuple[str, ...] = KNOBS,
        knob_synthetic: int = 150, epochs: int | None = None, level_neurons: int | None = None,
        progress: bool = True, calibrated_draws: int = 3, calibration_budget_s: float = 600.0,
        calibrated_synthetic: int = 200, optimisers: tuple[str, ...] = (),
        reuse_fits: Path | None = None, calibrated_seeds: int = 3,
        model: str = "readout") -> dict:  # fmt: skip
    t_start = time.perf_counter()
    real = load_real(data_root)
    real_stats = taxel_stats(real.X, real.fs_hz)
    result: dict = {"real_file": REAL_FILE, "real_slides": int(real.y.size), "fs_hz": real.fs_hz,
                    "synthetic_slides": synthetic, "model": model}  # fmt: skip

    # 1. statistics and the taxel correspondence (from seed 0's slides)
    synth0, synth_rise = render_synthetic(real, synthetic, 0, progress)
    synth_stats = taxel_stats(synth0.X, real.fs_hz)
    rise = real_force_rise(data_root)
    result["force_rise_N"] = {
        name: {"real": None if rise is None else float(np.median(rise[real.y == c])),
               "synthetic": float(np.median(synth_rise[synth0.y == c]))}
        for c, name in enumerate(real.class_names)
    }  # fmt: skip
    order = match_taxels(real_stats, synth_stats)
    matched = {k: v[order] if k != "spectrum" else v for k, v in synth_stats.items()}
    result["statistics"] = {"real": {k: v.tolist() for k, v in real_stats.items()},
                            "synthetic_matched": {k: v.tolist() for k, v in matched.items()},
                            "taxel_order": order.tolist(),
                            "spectrum_bands_hz": list(SPECTRUM_BANDS_HZ)}  # fmt: skip
    real_w = cut(real)

    # 2. synthetic only, every seed; the encoder chosen on seed 0's synthetic windows
    cfg, chosen = base_config(cut(reorder(synth0, order)), 0, epochs, model)
    if level_neurons is not None:  # after the choice: the encoder is the defaults' own
        cfg = cfg.replace(level_neurons=int(level_neurons))
    result["encoder"] = chosen
    result["level_neurons"] = cfg.level_neurons
    rows = []
    for seed in range(seeds):
        synth = synth0 if seed == 0 else render_synthetic(real, synthetic, seed, progress)[0]
        for name, o in (("matched", order), ("file order", np.arange(12))):
            acc = fit_score(with_seed(cfg, seed), cut(reorder(synth, o)), real_w, progress)
            rows.append({"seed": seed, "taxels": name, "accuracy": acc[0], "per_slide": acc[1]})
    result["synthetic_only"] = rows

    # 3. few-shot with and without the synthetic slides
    synth_w = cut(reorder(synth0, order))
    shots_rows = _few_shot(real, synth_w, cfg, shots, draws, progress)
    result["few_shot"] = shots_rows

    # 4. randomisation knobs (synthetic only, seed 0, knob_synthetic slides)
    knob_rows = _knobs(real, cfg, order, real_w, knobs, knob_synthetic, progress)
    result["knobs"] = knob_rows

    # 5. calibrated: the sensor model fitted to each draw's training slides only
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cal_rows = _calibrated(real, data_root, out, shots, calibrated_draws, calibrated_seeds,
                           calibrated_synthetic, calibration_budget_s, epochs, reuse_fits,
                           model)  # fmt: skip
    result["calibrated"] = cal_rows
    result["references"] = [{"k": x["k"], "draw": x["draw"], "seed": x["seed"],
                             **x.pop("references")} for x in cal_rows if "references" in x]  # fmt: skip
    if cal_rows:
        result.update(summarise_calibrated(cal_rows))
        if has_letter_runs(real.y):
            result["run_rest_spread"] = run_rest_spread(real)
    if optimisers:
        result["optimisers"] = compare_optimisers(real, shots, optimisers)
    result["seconds"] = time.perf_counter() - t_start

    (out / "sim2real.json").write_text(json.dumps(result, indent=2))
    text = table(result)
    (out / "sim2real.md").write_text(text)
    plot(real, synth0, order, result, out / "sim2real.png")
    print(text)
    return result


def _few_shot(real, synth_w, cfg, shots, draws, progress) -> list[dict]:
    """k real slides per class (``draws`` random draws each), with and without the synthetic
    windows (the real ones repeated to their number: joint training); the rest scored."""
    shots_rows = []
    for k in shots:
        for d in range(draws):
            tr, te = few_shot_split(real, k, np.random.default_rng([31, k, d]))
            real_tr = cut(slides(real, tr))
            real_te = cut(slides(real, te))
            reps = max(1, round(synth_w.y.size / real_tr.y.size))
            joint = concat(synth_w, *([real_tr] * reps))
            c = with_seed(cfg, d)
            for arm, train in (("real only", real_tr), ("synthetic + real", joint)):
                acc = fit_score(c, train, real_te, progress)
                shots_rows.append({"k": k, "draw": d, "arm": arm, "accuracy": acc[0],
                                   "per_slide": acc[1], "test_slides": int(te.size)})  # fmt: skip
    return shots_rows


def _knobs(real, cfg, order, real_w, knobs, knob_synthetic, progress) -> list[dict]:
    """Each randomisation knob switched off and doubled (synthetic only, seed 0,
    ``knob_synthetic`` slides), the change against the defaults."""
    from ...datasets_synth import TASKS

    defaults = {f: getattr(TASKS["braille"](), f) for f in KNOBS}
    knob_rows = []
    base = fit_score(
        cfg, cut(reorder(render_synthetic(real, knob_synthetic, 0)[0], order)), real_w, progress
    )
    knob_rows.append({"knob": "defaults", "value": None, "accuracy": base[0], "per_slide": base[1]})
    for knob in knobs:
        for scale in (0.0, 2.0):
            kw = {knob: defaults[knob] * scale}
            if knob == "force_spread":
                kw[knob] = min(kw[knob], 0.9)
            s = render_synthetic(real, knob_synthetic, 0, **kw)[0]
            acc = fit_score(cfg, cut(reorder(s, order)), real_w, progress)
            knob_rows.append({"knob": knob, "value": kw[knob], "accuracy": acc[0], "per_slide": acc[1],
                              "change_points": 100 * (acc[0] - base[0])})  # fmt: skip
    return knob_rows


def _calibrated(real, data_root, out, shots, calibrated_draws, calibrated_seeds,
                calibrated_synthetic, calibration_budget_s, epochs, reuse_fits,
                model) -> list[dict]:  # fmt: skip
    """The calibrated draws (:func:`~.calibrated.calibrated_draw`): one sensor fit per draw,
    fitted to its training slides only, trained on with ``calibrated_seeds`` seeds."""
    cal_rows = []
    if calibrated_draws > 0:
        (out / "fits").mkdir(exist_ok=True)
    for k in shots:
        for d in range(calibrated_draws):
            tr, te = few_shot_split(real, k, np.random.default_rng([31, k, d]))
            fit_file = out / "fits" / f"k{k}_d{d}.json"
            # the arm's speed, measured by its encoder on the training slides, held fixed: it
            # trades against the contact's width in time, which k slides cannot tell apart
            speed = real_arm_speed_mm_s(data_root, tr, real.fs_hz)
            known = None if speed is None else {"speed_mm_s": speed}
            old = reused_fit(reuse_fits, k, d)
            # one fit per draw; its synthetic slides and pipelines drawn again per training
            # seed (seed to seed, one fit spans up to 45 points per slide: one run is not a figure)
            for s in range(max(1, int(calibrated_seeds))):
                t0 = time.perf_counter()
                row = calibrated_draw(real, tr, te, calibrated_synthetic, calibration_budget_s,
                                      d, epochs, fit_file,
                                      out / "fits" / f"k{k}_d{d}.png" if d == s == 0 else None,
                                      reuse=old if s == 0 else fit_file,
                                      train_seed=d + 100 * s, known=known,
                                      references=s == 0, model=model)  # fmt: skip
                row.update(k=k, draw=d, seconds=time.perf_counter() - t0)
                cal_rows.append(row)
                log.info("calibrated k=%d draw %d seed %d: synthetic only %.3f / %.3f, real only "
                         "%.3f, pretrained %.3f per window (%.0f s)", k, d, row["seed"],
                         row["synthetic_only"], row["synthetic_only_per_slide"],
                         row["real_only"], row["pretrained"], row["seconds"])  # fmt: skip
    return cal_rows
