"""The sensor fit file (round trip, hostile files refused), the calibration's statistics against
closed-form cases, the fingertip's compliant mount against its rigid limit, and the Braille fit's
exact steps (pad placement, levels, randomisation widths) on a fingertip whose answer is known."""

import json

import numpy as np
import pytest

from tactilesnn.datasets_synth import get_task
from tactilesnn.datasets_synth.calibration import (
    MAX_FIT_BYTES,
    SensorFit,
    slide_statistics,
    statistic_distances,
)
from tactilesnn.datasets_synth.scenes.braille_cell import DOT_DIAMETER_MM, DOT_HEIGHT_MM
from tactilesnn.datasets_synth.sensors.capacitive_fingertip import (
    CapacitiveFingertip,
    FingertipParams,
)
from tactilesnn.datasets_synth.tasks import braille_fit as bf
from tactilesnn.datasets_synth.tasks.braille import BrailleTask


def _fit(**over) -> SensorFit:
    ch = {"pad_x_mm": [0.0] * 12, "pad_y_mm": [0.0] * 12, "gain": [1.0] * 12, "offset": [0.0] * 12,
          "noise": [0.5] * 12, "offset_sd": [0.0] * 12}  # fmt: skip
    ch["pad_x_mm"] = [3.5 * (i % 4) - 5.25 for i in range(12)]
    ch["pad_y_mm"] = [3.0 * (i // 4) - 3.0 for i in range(12)]
    base = {"task": "braille", "sensor": "capacitive_fingertip", "params": {"grid_mm": 0.5},
            "channels": ch, "scene": {"row_mm": 2.34, "t_mid_offset_s": 0.0, "speed_mm_s": 10.0,
                                      "force_N": 1.5, "force_ramp": 0.0},
            "randomisation": {"position_mm": 0.1, "force_spread": 0.05, "gain_spread": 0.05,
                              "speed_spread": 0.0, "drift_counts": 0.0, "time_jitter_s": 0.0}}  # fmt: skip
    base.update(over)
    return SensorFit(**base)


def test_fit_file_round_trip_and_overwrite(tmp_path):
    fit = _fit()
    path = fit.save(tmp_path / "fit.json")
    back = SensorFit.load(path)
    assert back == fit
    with pytest.raises(FileExistsError, match="overwrite"):
        fit.save(path)
    fit.save(path, overwrite=True)


@pytest.mark.parametrize(
    ("edit", "match"),
    [(lambda d: d.update(kind="other"), "not a tactilesnn.sensor_fit"),
     (lambda d: d.update(version=99), "version 99 unknown"),
     (lambda d: d.pop("scene"), "lacks scene"),
     (lambda d: d["scene"].update(force_N="1.5"), "finite number"),
     (lambda d: d["channels"].update(gain=[1.0] * 11 + [float("nan")]), "finite numbers"),
     (lambda d: d.update(params=[1, 2]), "must be an object")],
)  # fmt: skip
def test_fit_file_refuses_bad_content(tmp_path, edit, match):
    raw = json.loads(_fit().to_json())
    edit(raw)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(raw))
    with pytest.raises(ValueError, match=match):
        SensorFit.load(path)


def test_fit_file_refuses_non_json_and_huge(tmp_path):
    (tmp_path / "a.json").write_bytes(b"\x80\x00 pickle?")
    with pytest.raises(ValueError, match="not a sensor fit file"):
        SensorFit.load(tmp_path / "a.json")
    (tmp_path / "b.json").write_text(" " * (MAX_FIT_BYTES + 1))
    with pytest.raises(ValueError, match="over"):
        SensorFit.load(tmp_path / "b.json")
    with pytest.raises(FileNotFoundError):
        SensorFit.load(tmp_path / "none.json")


def test_statistics_closed_form():
    fs, n = 100.0, 400
    t = np.arange(n) / fs
    rng = np.random.default_rng(0)
    X = np.zeros((4, 3, n))
    X[:, 0] = 10.0  # constant: range 0, no noise, correlation 0
    X[:, 1] = 5 * np.sin(2 * np.pi * 3.0 * t)  # a 3 Hz sine: its power in the 2-4 Hz band
    X[:, 2] = -X[:, 1] + 0.01 * rng.standard_normal((4, n))
    y = np.array([0, 1, 0, 1])
    st = slide_statistics(X, y, fs, 2)
    assert st["rest"][0] == 10 and st["range"][0] == 0 and st["noise"][0] == 0
    assert np.isclose(st["range"][1], 10, rtol=0.01)
    assert st["correlation"][0, 1] == 0 and st["correlation"][1, 2] < -0.99
    bands = st["spectrum_bands_hz"]
    peak = bands[int(np.nanargmax(st["spectrum"]))]
    assert peak == (2.0, 4.0)
    assert st["mean"].shape == (2, 3, n) and np.allclose(st["mean"][0], X[[0, 2]].mean(0))
    d = statistic_distances(st, st)
    assert all(v == 0 for v in d.values())
    other = dict(st, mean=st["mean"] + 1.0)
    assert statistic_distances(st, other)["mean_response"] > 0
    # a response common to every class does not tell them apart; swapping the classes does
    # (closed form: the class differences negated, (2d)^2 / d^2 = 4)
    assert statistic_distances(st, other)["class_difference"] < 1e-20
    real = dict(st, mean=np.stack([st["mean"][0], st["mean"][0] + 2.0]))
    swapped = dict(st, mean=real["mean"][::-1])
    assert np.isclose(statistic_distances(real, swapped)["class_difference"], 4.0)


def _state(sensor, force, x_dot):
    bumps = np.array([[[x_dot, 0.0]]])
    return sensor.contact_state(np.array([force]), bumps, DOT_HEIGHT_MM, DOT_DIAMETER_MM,
                                np.zeros(2))  # fmt: skip


def test_flat_approach_matches_bisection():
    s = CapacitiveFingertip()
    grid = s.contact_grid(np.zeros(2), DOT_HEIGHT_MM)
    h = s.height_mm(grid, np.zeros(2))
    f = np.array([0.2, 1.0, 1.47, 3.0, 8.0])
    ref = s.approach_mm(f, grid, h, np.zeros((f.size, grid.shape[0])))
    assert np.allclose(s.flat_approach_mm(f, h), ref, atol=1e-6)


def test_compliant_mount_lifts_and_rolls():
    rigid = CapacitiveFingertip()
    soft = CapacitiveFingertip(FingertipParams(mount_N_per_mm=2.0))
    rolling = CapacitiveFingertip(FingertipParams(tilt_Nmm_per_rad=200.0))
    stiff = CapacitiveFingertip(FingertipParams(mount_N_per_mm=1e9))
    pads = np.array([[-4.0, 0.0], [0.0, 0.0], [4.0, 0.0]])
    # a dot under the +x pad: rigid keeps the approach, a soft mount gives some back (the other
    # pads unload), a rolling one lifts the dot's side (theta > 0) and presses the other
    r, s_, o, k = (_state(m, 1.5, 3.0) for m in (rigid, soft, rolling, stiff))
    assert s_["delta"][0] < r["delta"][0] and s_["load_N"][0] < r["load_N"][0]
    assert o["theta"][0] > 0 and r["theta"][0] == 0
    code_r, code_s, code_o = (m.codes_at(pads, st)[:, 0]
                              for m, st in ((rigid, r), (soft, s_), (rolling, o)))  # fmt: skip
    assert code_s[0] < code_r[0]  # the pad away from the dot unloads
    assert code_o[2] < code_r[2] and code_o[0] > code_r[0]
    # a very stiff mount is the rigid limit
    assert np.isclose(k["delta"][0], r["delta"][0], atol=1e-5)
    # on the flat surface (the dot far away) every mount is the same
    far = [_state(m, 1.5, 100.0) for m in (rigid, soft, rolling)]
    assert np.allclose([f["delta"][0] for f in far], far[0]["delta"][0])


def test_pads_override_layout_and_checks():
    pads = tuple((float(i), 0.0) for i in range(12))
    s = CapacitiveFingertip(FingertipParams(pads_mm=pads))
    assert np.allclose(s.taxels_mm[:, 0], np.arange(12))
    with pytest.raises(ValueError, match="pads_mm"):
        FingertipParams(pads_mm=((0.0, 0.0),))
    with pytest.raises(ValueError, match="mount_N_per_mm"):
        FingertipParams(mount_N_per_mm=0.0)
    with pytest.raises(ValueError, match="grid_mm"):  # a fit file cannot ask for a huge grid
        FingertipParams(grid_mm=1e-4)
    with pytest.raises(ValueError, match="pad_rings"):
        FingertipParams(pad_rings=1000)


def test_place_pads_recovers_a_known_layout():
    values = bf.start_values(get_task("braille"), 3.75)
    fs, n = 93.3 / 2, 175
    codes = bf.letter_codes(values, "abc", fs, n)  # [3, P, T]
    cands = bf.candidates_mm()
    joined = codes.transpose(1, 0, 2).reshape(len(cands), -1)
    # 12 channels: pads on candidate centres (>= 3 mm apart), gains and offsets known; the
    # silent ones (off the contact) read 0
    truth = np.array([cands.tolist().index(list(c)) for c in
                      [(-3.0, 0.0), (0.0, 0.0), (3.0, 0.0), (-1.5, 2.5), (1.5, 2.5), (-1.5, -2.5),
                       (1.5, -2.5), (4.5, 2.5), (-4.5, -2.5), (-8.0, -6.5), (8.0, 6.5),
                       (-8.0, 6.5)]])  # fmt: skip
    gain = np.linspace(0.01, 0.03, 12)
    offset = np.linspace(-3, 3, 12)
    means = gain[:, None] * joined[truth] + offset[:, None]
    pad, g, o = bf.place_pads(joined, means, cands)
    live = joined[truth].std(1) * gain > 1.0
    assert live.sum() >= 7
    assert np.array_equal(pad[live], truth[live])
    assert np.allclose(g[live], gain[live], rtol=1e-6) and np.allclose(
        o[live], offset[live], atol=1e-6
    )
    gl, ol = bf.fit_levels(joined[truth], means)
    assert np.allclose(ol[live], offset[live], atol=1e-6)
    assert np.allclose(gl[live], gain[live], rtol=1e-6)


def test_spreads_recover_a_known_width_and_keep_unseen_defaults():
    values = bf.start_values(get_task("braille"), 3.75)
    fs, n = 93.3, 350
    pads = np.array([[-3.0, 0.0], [0.0, 0.0], [3.0, 0.0], [0.0, 2.5]] + [[-8.0, -6.5]] * 8)
    gain, offset = np.full(12, 0.02), np.zeros(12)
    rng = np.random.default_rng(3)
    # recordings whose only spread is the force's (0.08), three per letter
    X = np.stack([bf.render_counts(values, pads, gain, offset, letter, fs / bf.DECIMATE, n // 2,
                                   {"force_spread": 0.08}, rng)
                  for letter in "abc" for _ in range(4)])  # fmt: skip
    X = np.repeat(X, 2, axis=-1)  # back to the full rate (each frame twice)
    y = np.repeat(np.arange(3), 4)
    defaults = {"position_mm": 0.5, "force_spread": 0.2, "gain_spread": 0.25, "speed_spread": 0.1}
    w, _left, on = bf.fit_spreads(values, pads, gain, offset, "abc", X, y, fs, np.zeros(12),
                                 defaults, draws=6)  # fmt: skip
    assert on == "about the class means"
    assert 0.04 < w["force_spread"] < 0.16
    # rest levels alone cannot see the speed: it keeps the task's default
    w1, _, on1 = bf.fit_spreads(values, pads, gain, offset, "abc", X[::4], y[::4], fs,
                                np.zeros(12), defaults, draws=3)  # fmt: skip
    assert on1 == "rest levels" and w1["speed_spread"] == defaults["speed_spread"]


def test_pitch_start_recovers_a_printed_cells_pitches():
    # class means of a cell printed larger along the slide than across it (4.5 / 2.5 mm): the
    # search's start finds both pitches from the standard cell's values
    task = get_task("braille")
    truth = {**bf.start_values(task, 3.75), "dot_spacing_mm": 4.5, "row_spacing_mm": 2.5,
             "row_mm": 2.5, "t_mid_offset_s": 0.2}  # fmt: skip
    fs, n = 93.3 / 2, 175
    cands = bf.candidates_mm()
    pads = cands[[cands.tolist().index(list(c)) for c in
                  [(-3.5, 2.5), (0.0, 2.5), (3.5, 2.5), (-1.5, 0.0), (1.5, 0.0), (-1.5, 5.0),
                   (1.5, 5.0), (5.0, 0.0), (-5.0, 0.0), (0.0, -3.0), (4.0, 5.0),
                   (-4.0, 5.0)]]]  # fmt: skip
    codes = bf.pad_codes(truth, "abc", fs, n, pads)  # [3, 12, T]
    means = 0.02 * codes + 2.0
    start = {**truth, "dot_spacing_mm": 2.34, "row_spacing_mm": 2.34, "row_mm": 2.34,
             "t_mid_offset_s": 0.0}  # fmt: skip
    found = bf.pitch_start(start, "abc", fs, n, cands, means)
    # the column pitch is timing (C's second dot follows its first), the row pitch which pads
    # see B's second dot with its first
    assert found["dot_spacing_mm"] == 4.5 and found["row_spacing_mm"] == 2.5
    assert abs(found["t_mid_offset_s"] - 0.2) <= 1.5 / fs
    standard = {**start, "t_mid_offset_s": bf.response_lag_s(start, "abc", fs, n, means)}
    loss = {k: bf._objective(v, "abc", fs, n, cands, means)[0]
            for k, v in (("found", found), ("standard", standard))}  # fmt: skip
    assert loss["found"] < 0.5 * loss["standard"]


@pytest.mark.slow
def test_fit_is_the_same_on_one_or_two_workers():
    # a small fit of synthetic slides: the search's points evaluated here or on a pool of two
    # give the same history, values and channels
    task = get_task("braille", n_samples=6, duration_s=2.0)
    X = np.stack([task.sample(i)[0] for i in range(6)])
    y = np.arange(6) % 3
    fits = [bf.fit(BrailleTask(letters="abc", duration_s=2.0), X, y, 93.3, max_evals=20, seed=1,
                   workers=w) for w in (1, 2)]  # fmt: skip
    assert fits[0].objective["evaluations"] == fits[1].objective["evaluations"] == 20
    assert fits[0].objective["history"] == fits[1].objective["history"]
    assert fits[0].scene == fits[1].scene and fits[0].channels == fits[1].channels
    assert bf.search_workers() >= 1


def test_task_renders_a_fit_file_and_refuses_another_task(tmp_path):
    path = _fit().save(tmp_path / "fit.json")
    task = get_task("braille", calibration=str(path), n_samples=6, fs_frames_hz=93.3,
                    duration_s=2.0)  # fmt: skip
    assert np.allclose(task.sensor.taxels_mm[:, 0], [3.5 * (i % 4) - 5.25 for i in range(12)])
    x, _, _ = task.sample(0)
    assert x.shape == (12, round(2.0 * 93.3)) and np.isfinite(x).all() and x.max() > 0
    assert x.min() >= 0 and x.max() <= 255 and np.allclose(x, np.round(x))
    other = _fit(task="texture")
    other.save(tmp_path / "other.json")
    with pytest.raises(ValueError, match="not braille"):
        get_task("braille", calibration=str(tmp_path / "other.json"))
    short = _fit(scene={"row_mm": 2.0})
    short.save(tmp_path / "short.json")
    with pytest.raises(ValueError, match="scene lacks t_mid_offset_s"):
        get_task("braille", calibration=str(tmp_path / "short.json"))
    huge = _fit()
    huge.scene["dot_spacing_mm"] = 1e6  # a hostile file: a cell larger than the slide
    huge.save(tmp_path / "huge.json")
    with pytest.raises(ValueError, match=r"dot_spacing_mm must be in \[1, 10\] mm"):
        get_task("braille", calibration=str(tmp_path / "huge.json"))
    bad = _fit()
    bad.randomisation["position_mm"] = -1.0
    bad.save(tmp_path / "bad.json")
    with pytest.raises(ValueError, match="must be >= 0"):
        get_task("braille", calibration=str(tmp_path / "bad.json"))


def test_calibrate_checks_its_input():
    X = np.zeros((3, 12, 100))
    with pytest.raises(ValueError, match="12 taxels"):
        BrailleTask.calibrate(np.zeros((3, 5, 100)), np.arange(3), 93.3, ("A", "B", "C"))
    with pytest.raises(ValueError, match="NaN"):
        BrailleTask.calibrate(X + np.nan, np.arange(3), 93.3, ("A", "B", "C"))
    with pytest.raises(ValueError, match="no recording of letter"):
        BrailleTask.calibrate(X, np.zeros(3, np.int64), 93.3, ("A", "B", "C"))
    with pytest.raises(ValueError, match="cannot be calibrated; tasks that can: braille"):
        get_task("texture").calibrate(X, np.arange(3), 93.3, ("a", "b", "c"))


@pytest.mark.parametrize("kind", ["cma", "optuna-tpe", "random"])
def test_every_optimiser_finds_a_quadratic_minimum(kind):
    if kind == "optuna-tpe":
        pytest.importorskip("optuna")
    target = np.array([0.2, 0.7, 0.5])
    best = np.inf
    for i, rnd in enumerate(bf.ask_tell(kind, np.full(3, 0.5), seed=1)):
        losses = [float(((np.asarray(u) - target) ** 2).sum()) for u in rnd.points]
        assert all(0 <= v <= 1 for u in rnd.points for v in np.asarray(u))
        rnd.tell(losses)
        best = min(best, *losses)
        if i == 29 or rnd.done:
            break
    assert best < (0.05 if kind == "random" else 0.01)
    with pytest.raises(ValueError, match="unknown optimiser"):
        next(bf.ask_tell("nelder", np.zeros(3), 0))


def test_the_start_keeps_held_values(monkeypatch):
    """The search's start grids the cell's pitches unless they are held; held values (a pitch,
    the timing) stay in every candidate, whatever the grid or the timing's alignment sets."""
    tried = []

    def spy(values, letters, fs_hz, n, cands, real_dec, known):
        v = {**values, "t_mid_offset_s": 0.3, **known}
        tried.append(v)
        return -v["row_spacing_mm"], v

    monkeypatch.setattr(bf, "_start_candidate", spy)
    start = {"dot_spacing_mm": 2.34, "row_spacing_mm": 2.34, "row_mm": 2.34, "t_mid_offset_s": 0.0}
    held = {"dot_spacing_mm": 4.4, "t_mid_offset_s": -0.1}
    got = bf.pitch_start(start, "abc", 93.3, 10, None, None, None, held)
    assert len(tried) == len(bf.START_ROW_PITCHES_MM)
    assert all(v["dot_spacing_mm"] == 4.4 and v["t_mid_offset_s"] == -0.1 for v in tried)
    assert got["row_spacing_mm"] == max(bf.START_ROW_PITCHES_MM)
    tried.clear()
    bf.pitch_start(start, "abc", 93.3, 10, None, None)
    assert len(tried) == len(bf.START_PITCHES_MM) * len(bf.START_ROW_PITCHES_MM)


def test_known_values_are_held_and_checked():
    # a measured value is not searched: the fit keeps it exactly and the search moves the rest
    task = get_task("braille", n_samples=6, duration_s=2.0)
    X = np.stack([task.sample(i)[0] for i in range(6)])
    y = np.arange(6) % 3
    fit = bf.fit(BrailleTask(letters="abc", duration_s=2.0), X, y, 93.3, max_evals=20, seed=1,
                 workers=1, known={"speed_mm_s": 10.07, "force_scale_b": 1.2})  # fmt: skip
    assert fit.scene["speed_mm_s"] == 10.07 and fit.scene["force_scale_b"] == 1.2
    assert fit.objective["held_fixed"] == {"speed_mm_s": 10.07, "force_scale_b": 1.2}
    free = bf.fit(BrailleTask(letters="abc", duration_s=2.0), X, y, 93.3, max_evals=20, seed=1,
                  workers=1)  # fmt: skip
    assert free.scene["speed_mm_s"] != 10.07 and free.objective["held_fixed"] == {}
    with pytest.raises(ValueError, match=r"unknown fitted value 'speed'.*speed_mm_s"):
        bf.check_known({"speed": 10.0}, "abc")
    with pytest.raises(ValueError, match=r"outside the model's range \[5, 16\]"):
        bf.check_known({"speed_mm_s": 40.0}, "abc")
    with pytest.raises(ValueError, match="outside"):
        bf.check_known({"force_N": float("nan")}, "abc")
    with pytest.raises(ValueError, match="unknown fitted value 'force_scale_d'"):
        bf.check_known({"force_scale_d": 1.0}, "abc")
    everything = {k: lo for k, (lo, _, _) in bf.bounds_for("abc").items()}
    with pytest.raises(ValueError, match="nothing is left to search"):
        bf.check_known(everything, "abc")


def test_a_fitted_fingertips_class_signal_is_its_letters_response(tmp_path):
    from tests.datasets_synth.test_braille import check_class_signal

    path = _fit().save(tmp_path / "fit.json")
    check_class_signal(get_task("braille", calibration=str(path), n_samples=6, seed=3))
