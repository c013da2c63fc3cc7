"""Tables and the picture of a run, and the cross-run section."""

from __future__ import annotations

import logging
from itertools import pairwise
from pathlib import Path

import numpy as np

from ...core.data import WindowDataset
from .protocol import LETTER_SHARE
from .stats import by_letter_summary, by_run_summary, count_draws, draw_means

log = logging.getLogger("tactilesnn")


# ---------------------------------------------------------------- report
def _ms(values: list[float]) -> str:
    v = 100 * np.asarray(values)
    return f"{v.mean():.1f} +- {v.std(ddof=1) if v.size > 1 else 0.0:.1f}"


def table(r: dict) -> str:
    st = r["statistics"]
    lines = [f"Real: {r['real_slides']} slides of {r['real_file']} ({r['fs_hz']:.2f} Hz); synthetic: "
             f"{r['synthetic_slides']} braille slides per seed; encoder {r['encoder']} + readout, "
             f"level code {r.get('level_neurons', '-')} neurons.", "",
             "| taxel (real order) | rest real / synth | range real / synth | peak s real / synth |",
             "|---|---|---|---|"]  # fmt: skip
    re_, sy = st["real"], st["synthetic_matched"]
    for i in range(len(re_["rest"])):
        lines.append(f"| {i} (synth {st['taxel_order'][i]}) | {re_['rest'][i]:.0f} / {sy['rest'][i]:.0f} | "
                     f"{re_['range'][i]:.0f} / {sy['range'][i]:.0f} | "
                     f"{re_['peak_s'][i]:+.2f} / {sy['peak_s'][i]:+.2f} |")  # fmt: skip
    b = st["spectrum_bands_hz"]
    lines += ["", "| band Hz | " + " | ".join(f"{lo:g}-{hi:g}" for lo, hi in pairwise(b)) + " |",
              "|---|" + "---|" * (len(b) - 1),
              "| log10 power real | " + " | ".join(f"{v:.2f}" for v in re_["spectrum"]) + " |",
              "| log10 power synth | " + " | ".join(f"{v:.2f}" for v in sy["spectrum"]) + " |",
              ""]  # fmt: skip
    fr = r["force_rise_N"]
    lines += ["| letter | " + " | ".join(fr) + " |", "|---|" + "---|" * len(fr),
              "| force rise over the letter, real (N) | " + " | ".join(
                  "-" if v["real"] is None else f"{v['real']:.2f}" for v in fr.values()) + " |",
              "| ... synthetic (N) | " + " | ".join(f"{v['synthetic']:.2f}" for v in fr.values()) + " |",
              ""]  # fmt: skip
    lines += ["| trained on | tested on | per window % | per slide % |", "|---|---|---|---|"]
    for name in ("matched", "file order"):
        sel = [x for x in r["synthetic_only"] if x["taxels"] == name]
        acc, per = _ms([x["accuracy"] for x in sel]), _ms([x["per_slide"] for x in sel])
        lines.append(f"| synthetic only (taxels {name}, {len(sel)} seeds) | all {r['real_slides']} "
                     f"real | {acc} | {per} |")  # fmt: skip
    for k in sorted({x["k"] for x in r["few_shot"]}):
        for arm in ("real only", "synthetic + real"):
            sel = [x for x in r["few_shot"] if x["k"] == k and x["arm"] == arm]
            lines.append(f"| {k} real per class, {arm} ({len(sel)} draws) | the other "
                         f"{sel[0]['test_slides']} real | {_ms([x['accuracy'] for x in sel])} | "
                         f"{_ms([x['per_slide'] for x in sel])} |")  # fmt: skip
    lines += [
        "",
        "| knob | value | synthetic-only accuracy on real % | change (points) |",
        "|---|---|---|---|",
    ]
    for x in r["knobs"]:
        ch = "-" if x["knob"] == "defaults" else f"{x['change_points']:+.1f}"
        val = "-" if x["value"] is None else f"{x['value']:g}"
        lines.append(f"| {x['knob']} | {val} | {100 * x['accuracy']:.1f} | {ch} |")
    if r.get("calibrated"):
        lines += ["", "Calibrated sensor model (fitted to each draw's k training slides per class only):",
                  "", "| k real per class | draws | calibration s | synthetic only per window / per "
                  "slide % | real only per window / per slide % | pretrained + fine-tuned per "
                  "window / per slide % | gain per window (points) | fine-tuned on the "
                  "letter's share per window / per slide % |",
                  "|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for k in sorted({x["k"] for x in r["calibrated"]}):
            sel = [x for x in r["calibrated"] if x["k"] == k]

            def pair(a: str, b: str, sel: list = sel) -> str:
                return f"{_ms(draw_means(sel, a))} / {_ms(draw_means(sel, b))}"

            gain = 100 * np.mean(draw_means(sel, fn=lambda x: x["pretrained"] - x["real_only"]))
            has = all("pretrained_letter" in x for x in sel)
            soft = pair("pretrained_letter", "pretrained_letter_per_slide") if has else "-"
            lines.append(f"| {k} | {count_draws(sel)} | {np.mean([x['calibration_s'] for x in sel]):.0f} | "
                         f"{pair('synthetic_only', 'synthetic_only_per_slide')} | "
                         f"{pair('real_only', 'real_only_per_slide')} | "
                         f"{pair('pretrained', 'pretrained_per_slide')} | {gain:+.1f} | "
                         f"{soft} |")  # fmt: skip
    lines.append(f"\n({r['seconds']:.0f} s)")
    return "\n".join(lines) + "\n"


def plot(real: WindowDataset, synth: WindowDataset, order: np.ndarray, r: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    st = r["statistics"]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.2))
    x = np.arange(len(st["real"]["rest"]))
    ax = axes[0]
    ax.bar(x - 0.2, st["real"]["range"], 0.4, label="real: range", color="tab:blue")
    ax.bar(
        x + 0.2, st["synthetic_matched"]["range"], 0.4, label="synthetic: range", color="tab:orange"
    )
    ax.plot(x, st["real"]["rest"], "o", color="navy", label="real: rest level")
    ax.plot(
        x, st["synthetic_matched"]["rest"], "s", color="darkorange", label="synthetic: rest level"
    )
    ax.set_xticks(x)
    ax.set_xlabel("taxel (real file's order; synthetic matched)")
    ax.set_ylabel("counts (0..255)")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    ax.set_title("per-taxel rest level and range")
    ax = axes[1]
    t = (np.arange(real.X.shape[-1]) - real.X.shape[-1] / 2) / real.fs_hz
    for c, name in enumerate(real.class_names):
        for ds, style, o in ((real, "-", np.arange(12)), (synth, "--", order)):
            X = ds.X[ds.y == c][:, o].astype(np.float64)
            rise = (X - np.median(X[..., : X.shape[-1] // 10], -1, keepdims=True)).sum(1).mean(0)
            ax.plot(
                t,
                rise,
                style,
                color=f"C{c}",
                label=f"{name} {'real' if ds is real else 'synthetic'}",
            )
    ax.set_xlabel("time from mid-slide (s)")
    ax.set_ylabel("sum over taxels of the rise above rest (counts)")
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("mean slide per letter (solid: real, dashed: synthetic)")
    ax = axes[2]
    b = st["spectrum_bands_hz"]
    mids = np.sqrt(np.array(b[:-1]) * np.array(b[1:]))
    ax.semilogx(mids, st["real"]["spectrum"], "o-", label="real")
    ax.semilogx(mids, st["synthetic_matched"]["spectrum"], "s--", label="synthetic")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("log10 power (counts^2 / Hz)")
    ax.legend()
    ax.set_title("power spectrum (mean over taxels and slides)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _cross_run_section(cross: dict, r: dict) -> list[str]:
    """The page's table of :func:`cross_runs`: means over the held-out triples, 95 % intervals."""
    rows = cross["rows"]
    n = len({tuple(x["held_runs"]) for x in rows})
    k1 = (r.get("shots") or {}).get("1", {}).get("by_letter", {}).get("pretrained", {})
    lines = ["", "## What many real slides reach on runs they never saw", "",
             f"Real only trained on every slide of six runs (two per letter; 30 slides), tested "
             f"on the other three runs' windows, {n} held-out triples (`bench sim2real "
             "--cross-runs-from DIR`); the slides as recorded and each slide minus its rest "
             f"level (its median over the first {cross['rest_s']} s, per taxel); `letter` / "
             f"`none`: the windows the fitted model (`{cross['fit']}`) places the letter in and "
             "the others. Per window / per slide / letter / none (%), means over the triples "
             "with 95 % intervals.", "",
             "| slides | encoder | per window | per slide | letter | none |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    for mode in dict.fromkeys(x["slides"] for x in rows):
        for enc in dict.fromkeys(x["encoder"] for x in rows):
            sel = [x for x in rows if x["slides"] == mode and x["encoder"] == enc]
            cells = [_cell([x[key] for x in sel if np.isfinite(x[key])])
                     for key in ("per_window", "per_slide", "letter", "none")]  # fmt: skip
            lines.append(f"| {mode.replace('_', ' ')} | {enc} | " + " | ".join(cells) + " |")
    if k1.get("letter_unseen") is not None:
        lines += ["", f"For comparison, the pretrained arm at k = 1 (three real slides) on the "
                  f"unseen runs' letter windows: {100 * k1['letter_unseen']:.1f} %."]  # fmt: skip
    return lines


def _cell(values: list[float], scale: float = 100.0, sign: str = "") -> str:
    v = scale * np.asarray(values, np.float64)
    if v.size < 2:
        return f"{v.mean():{sign}.1f}"
    lo, hi = ci95_t(v)
    if not sign:  # an accuracy's interval ends at 0 and 100 %
        lo, hi = max(lo, 0.0), min(hi, scale)
    return f"{v.mean():{sign}.1f} ({lo:{sign}.1f} to {hi:{sign}.1f})"


def ci95_t(v: np.ndarray) -> tuple[float, float]:
    """The 95 % interval of a mean over draws (Student's t)."""
    from scipy import stats

    half = stats.t.ppf(0.975, v.size - 1) * v.std(ddof=1) / np.sqrt(v.size)
    return float(v.mean() - half), float(v.mean() + half)


def _fabric_section(fab: dict) -> list[str]:
    sh = fab["spectrum_shape_bands_hz"]
    return ["", "## A second sensor: FabricSlide against the `texture` task's capacitive stack", "",
            "`tactilesnn calibrate --statistics-only --task texture --data "
            "../shared/data/fabric_slide/fabric --out docs/sim2real_fabric.json --plot "
            "docs/sim2real_fabric.png` (15 s): the CPM-Finger's recordings "
            f"({fab['recordings']} windows) next to the stack model at its defaults "
            f"({fab['model_samples']} windows). There is nothing to fit: "
            + "; ".join(fab["cannot_express"]) + ". What compares is unit-free: the spectra's "
            f"shapes over the bands both resolve ({sh[0][0]:g}-{sh[-1][1]:g} Hz) are "
            f"{fab['spectrum_shape_rms_decades']:.2f} decades apart (rms; the fabric's power "
            "falls off with frequency, "
            + ", ".join(f"{v:.2f}" for v in fab["spectrum_shape_real"])
            + " log10 shares per octave band, the model's is flatter: "
            + ", ".join(f"{v:.2f}" for v in fab["spectrum_shape_model"])
            + "), and the mean cross-channel correlation is "
            f"{fab['mean_cross_channel_correlation']['real']:.2f} (recordings) against "
            f"{fab['mean_cross_channel_correlation']['model']:.2f} (the model's two channels). A "
            "calibration of this sensor needs a finger model with 16 taxels and a fabric scene "
            "(the fingertip model reads dots, not weaves).", "",
            "![FabricSlide against the texture task's stack](sim2real_fabric.png)"]  # fmt: skip


def _by_run_table(cal: list[dict], ks: list[int]) -> list[str]:
    """The page's table of each arm per window by recording run (rows with ``by_run``)."""
    if not all("by_run" in x for x in cal):
        return []
    lines = ["", "By recording run (per window, %; a run: five consecutive slides of one "
             "letter, `RUN_SLIDES`): on the test slides of the runs the k training slides come "
             "from (seen) and of the other runs (unseen); the last column pretrained minus real "
             "only on the unseen runs (points).", "",
             "| k | test windows in seen runs | real only: seen / unseen | synthetic only | "
             "pretrained (the mean) | labels' fine-tune | letter's share's | pretrained minus "
             "real only, unseen runs |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for k in ks:
        sel = [x for x in cal if x["k"] == k]
        b = by_run_summary(sel)

        def pair(arm: str, b: dict = b) -> str:
            return " / ".join("-" if b[f"{arm}_{p}"] is None else f"{100 * b[f'{arm}_{p}']:.1f}"
                              for p in ("seen", "unseen"))  # fmt: skip

        gain = [v for v in draw_means(sel, fn=lambda x: x["by_run"]["pretrained"][1]
                                      - x["by_run"]["real_only"][1]) if np.isfinite(v)]  # fmt: skip
        lines.append(f"| {k} | {100 * b['seen_fraction']:.0f} % | {pair('real_only')} | "
                     f"{pair('synthetic_only')} | {pair('pretrained')} | "
                     f"{pair('pretrained_labels')} | {pair('pretrained_letter')} | "
                     + (_cell(gain, sign="+") if gain else "-") + " |")  # fmt: skip
    return lines


def _by_letter_table(cal: list[dict], ks: list[int]) -> list[str]:
    """The page's table of each arm per window on the test windows that hold the letter and on
    the others (rows with ``by_letter``), and on those of unseen recording runs."""
    if not all("by_letter" in x for x in cal):
        return []
    runs = all("letter_unseen" in x["by_letter"]["pretrained"] for x in cal)
    lines = ["", "By where the letter is (per window, %): on the test windows in which the fitted "
             f"model places at least {100 * LETTER_SHARE:.0f} % of the letter's signal (`letter`) and on "
             "the others (`none`: the slide before and after the letter, where only a rest level "
             "tells the letters apart)" + (", over all test windows and on the unseen runs" if runs
                                           else "") + ".", "",
             "| k | test windows with the letter | real only: letter / none | synthetic only | "
             "pretrained | " + ("unseen runs: real only | unseen runs: pretrained |" if runs
                                else ""),
             "|---|---|---|---|---|" + ("---|---|" if runs else "")]  # fmt: skip

    def pair(b: dict, arm: str, suffix: str = "") -> str:
        return " / ".join("-" if b[arm][f"{p}{suffix}"] is None
                          else f"{100 * b[arm][f'{p}{suffix}']:.1f}" for p in ("letter", "none"))  # fmt: skip

    for k in ks:
        b = by_letter_summary([x for x in cal if x["k"] == k])
        cells = [str(k), f"{100 * b['letter_fraction']:.0f} %", pair(b, "real_only"),
                 pair(b, "synthetic_only"), pair(b, "pretrained")]  # fmt: skip
        if runs:
            cells += [pair(b, "real_only", "_unseen"), pair(b, "pretrained", "_unseen")]
        lines.append("| " + " | ".join(cells) + " |")
    return lines
