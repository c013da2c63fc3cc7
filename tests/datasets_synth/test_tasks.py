"""Trial tasks: contracts, determinism, generation, skip-compute, non-triviality."""

import json

import numpy as np
import pytest

from tactilesnn.baselines import linear_amplitude_baseline
from tactilesnn.core.dataset_folder import ShardDataset
from tactilesnn.datasets_synth import TASKS, get_task
from tactilesnn.datasets_synth.generate import TaskDataset, generate
from tactilesnn.datasets_synth.scenes.textures import TEXTURES
from tactilesnn.datasets_synth.sensors.pvdf import PVDFParams, PVDFTriangle

TRIAL_TASKS = ["texture", "stiffness_curvature", "material", "touch", "braille", "localise"]


@pytest.mark.slow
@pytest.mark.parametrize("name", TRIAL_TASKS)
def test_contract_and_determinism(name):
    a, b = get_task(name, seed=3), get_task(name, seed=3)
    x0, y0, info = a.sample(7)
    x1, y1, _ = b.sample(7)
    assert x0.dtype == np.float32 and x0.shape == (len(a.channel_names), a.window)
    assert np.array_equal(x0, x1) and y0 == y1 == 7 % len(a.class_names)
    assert np.isfinite(x0).all() and info["class"] == a.class_names[y0]
    assert not np.array_equal(x0, get_task(name, seed=4).sample(7)[0])
    assert a.units
    tr, te = a.split()
    assert np.intersect1d(tr, te).size == 0 and tr.size + te.size == a.n_samples


@pytest.mark.parametrize(
    "name, kw",
    [
        ("touch", {"n_samples": 40}),
        ("hook_loop", {"n_planar": 4, "n_concave": 3, "n_convex": 3, "n_test": 3}),
    ],
)
def test_the_test_split_alone_is_the_builds(name, kw):
    """``evaluate`` and ``export`` render the test split alone: the same windows, labels and
    ids as :meth:`build`'s (each sample seeded by its index, the split by the task's seed)."""
    task = get_task(name, seed=5, **kw)
    _, full = task.build()
    alone = task.test_split()
    assert alone.X.shape == full.X.shape and alone.X.shape[0] > 0
    assert np.array_equal(alone.X, full.X) and np.array_equal(alone.y, full.y)
    assert np.array_equal(alone.scan, full.scan)


def test_class_counts():
    assert len(TEXTURES) >= 10 and get_task("texture").class_names == tuple(TEXTURES)
    assert len(get_task("stiffness_curvature").class_names) == 9
    assert get_task("material").class_names == ("aluminium", "kapton", "paper", "glass", "cloth")
    assert len(get_task("touch").class_names) == 4
    with pytest.raises(ValueError, match="difficulty"):
        get_task("touch", difficulty=-1)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(TASKS))
def test_generate_every_task(tmp_path, name):
    out = tmp_path / name
    m = generate(name, 4, 0, out, shard_size=2, workers=1, progress=False)
    assert m["task"] == name and len(m["shards"]) == 2 and m["units"]
    ds = ShardDataset(out)
    x, _y = ds[0]
    assert x.shape == (len(m["channel_names"]), m["window_samples"])
    task = get_task(name, seed=0)
    assert np.array_equal(x, task.render(0)[0][0])
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["fs_hz"] == task.fs_hz and manifest["parameters"]["seed"] == 0
    if name != "hook_loop":  # on-the-fly dataset == generated shards
        live = TaskDataset(name, seed=0)
        assert np.array_equal(live[1][0], ds[1][0]) and live[1][1] == ds[1][1]
        with pytest.raises(IndexError):
            live[len(live)]


@pytest.mark.parametrize("pitch_mm", [6.0, 20.0])
def test_pvdf_skip_matches_full_simulation(pitch_mm):
    s = PVDFTriangle(PVDFParams(pitch_mm=pitch_mm))
    fs = 4000.0
    f = np.zeros(int(8 * fs))
    for t0 in (1.0, 5.0):  # two light pokes in 8 s: most taxels and time untouched
        i = int(t0 * fs)
        f[i : i + 800] = 1.0 * 0.5 * (1 - np.cos(2 * np.pi * np.arange(800) / 800))
    c = s.taxels_mm[0] + 0.5
    full = s.read(f, c, 4.0, fs, np.random.default_rng(0), skip=False)
    fast = s.read(f, c, 4.0, fs, np.random.default_rng(0), skip=True)
    spans, taxels = s._needed(f, np.repeat(c[None], f.size, 0), 4.0, fs, 1)
    assert len(spans) == 2  # only the two contacts (+ amplifier tails) are simulated
    assert sum(sp.stop - sp.start for sp in spans) < 0.2 * f.size
    if pitch_mm > 10:  # on a sparser layout far taxels are provably below tolerance
        assert taxels.size < 12
    assert np.abs(fast - full).max() < 5e-4  # below the amplifier noise (5 uV x 100 pF)
    assert np.abs(full).max() > 0.5


@pytest.mark.slow
def test_touch_spans_five_decades_without_nan():
    t = get_task("touch", amplitude_spread=1.0)
    peaks = {}
    for i in range(16):
        x, y, _ = t.sample(i)
        peaks.setdefault(t.class_names[y], []).append(np.abs(x).max())
    assert max(peaks["caress"]) < 0.1 < min(peaks["hard_poke"])
    assert max(peaks["hard_poke"]) / min(peaks["caress"]) > 1e3


@pytest.mark.slow
def test_texture_is_not_solved_by_amplitude():
    from tactilesnn.config import PipelineConfig
    from tactilesnn.training import fit_and_evaluate

    tr, te = get_task("texture", n_samples=480).build()
    base = linear_amplitude_baseline(tr.X, tr.y, te.X, te.y)
    res = fit_and_evaluate(PipelineConfig.from_flat(epochs=10), tr, te)
    assert res.metrics["test_accuracy"] > base + 0.1


def test_one_noise_scaling_for_every_sensor():
    from tactilesnn.datasets_synth.sensors.base import noise_scaled
    from tactilesnn.datasets_synth.sensors.capacitive_piezo import CapacitivePiezoParams
    from tactilesnn.datasets_synth.sensors.pvdf import PVDFParams
    from tactilesnn.datasets_synth.sensors.teng import TENGParams

    for params in (CapacitivePiezoParams(), PVDFParams(), TENGParams()):
        scaled = noise_scaled(params, 2.5)
        for f in type(params).NOISE_FIELDS:
            assert getattr(scaled, f) == pytest.approx(2.5 * getattr(params, f))
        assert noise_scaled(params, 1.0) == params
    with pytest.raises(ValueError, match="finite"):
        noise_scaled(TENGParams(), float("nan"))
    with pytest.raises(TypeError, match="NOISE_FIELDS"):
        noise_scaled(object(), 1.0)
