"""Hook-vs-loop task: protocol, labels, determinism, non-triviality."""

import numpy as np
import pytest

from tactilesnn.datasets_synth import HookLoopTask, get_task
from tactilesnn.datasets_synth.scenes.sliding_scan import SlidingScanScene
from tactilesnn.datasets_synth.scenes.textures import ridge_comb_kernel


@pytest.fixture(scope="session")
def small_task():
    return HookLoopTask(n_planar=10, n_concave=5, n_convex=5, n_test=4)


def test_scan_protocol_and_labels(small_task):
    stream, labels, info = small_task.scan(0)
    assert stream.shape[0] == 2 and stream.dtype == np.float32
    assert labels.shape == (stream.shape[1],)
    assert sorted(info["order"]) == ["hook", "loop"]
    fs = small_task.fs_hz
    for seg in info["segments"]:
        # 9 strides of 6 cm at ~10 cm/s plus turnarounds: ~5-8 s of sliding per texture
        assert 4.5 < seg["t_off_s"] - seg["t_on_s"] < 9.0
        on, off = round(seg["t_on_s"] * fs), round(seg["t_off_s"] * fs)
        # 250 ms null bands at texture onset and offset
        assert np.all(labels[on : on + 45] == -1)
        assert np.all(labels[off - 45 : off] == -1)
        k = small_task.class_names.index(seg["texture"])
        assert np.all(labels[on + 55 : off - 55] == k)
    assert np.all(labels[: int(1.5 * fs)] == -1), "no contact during the baseline"


def test_deterministic_and_seed_dependent(small_task):
    a = small_task.scan(3)[0]
    np.testing.assert_array_equal(a, small_task.scan(3)[0])
    other = HookLoopTask(seed=1, n_planar=10, n_concave=5, n_convex=5, n_test=4).scan(3)[0]
    assert not np.array_equal(a[:, : min(a.shape[1], other.shape[1])], other[:, : a.shape[1]])


def test_surfaces_split_and_windows(small_task):
    surf = [small_task.surface(i) for i in range(small_task.n_scans)]
    assert surf.count("planar") == 10 and surf.count("concave") == 5 and surf.count("convex") == 5
    tr_idx, te_idx = small_task.split()
    assert len(te_idx) == 4 and len(set(tr_idx) | set(te_idx)) == small_task.n_scans
    train, test = small_task.build()
    assert train.X.shape[1:] == (2, 100) and set(np.unique(train.y)) == {0, 1}
    assert not set(train.scan) & set(test.scan), "windows of one scan never cross the split"


def test_loop_has_larger_dynamic_amplitude(small_task):
    train, _ = small_task.build()
    rms = np.sqrt((train.X[:, 1] ** 2).mean(-1))
    assert np.median(rms[train.y == 1]) > 1.3 * np.median(rms[train.y == 0])


def test_fingerprint_comb_passes_ridge_pitch():
    k = ridge_comb_kernel(4, 0.01)
    x = np.arange(k.size) * 0.01

    def gain(period_mm):
        return abs((k * np.exp(2j * np.pi * x / period_mm)).sum())

    assert gain(1.5) > 0.8 and gain(3.0) < 0.05  # 1.5 mm pitch passes, half-pitch cancels


def test_bad_names_and_arguments():
    with pytest.raises(ValueError, match="unknown task"):
        get_task("velcro")
    with pytest.raises(ValueError, match="unknown texture"):
        SlidingScanScene(textures=("hook", "silk"))
    with pytest.raises(ValueError, match="difficulty"):
        HookLoopTask(difficulty=-1)
    with pytest.raises(IndexError):
        HookLoopTask().surface(500)


def test_the_set_point_centre_scales_the_load_and_is_checked():
    """``set_point_Pa`` (the texture task's ``pressure_kpa``) moves every scan's load set point
    by the same factor, the same draws otherwise (the default: 1 kPa, as before); a pressure
    that is not a finite positive number is refused by name."""
    from tactilesnn.datasets_synth import get_task

    light = SlidingScanScene().render(np.random.default_rng(3))
    hard = SlidingScanScene(set_point_Pa=3000.0).render(np.random.default_rng(3))
    assert hard[2]["pressure_set_Pa"] == pytest.approx(3 * light[2]["pressure_set_Pa"])
    assert np.array_equal(light[1], hard[1])  # the same scan, pressed harder
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="set_point_Pa"):
            SlidingScanScene(set_point_Pa=bad)
    default = get_task("texture", seed=0, n_samples=24).build()[0]
    same = get_task("texture", seed=0, n_samples=24, pressure_kpa=1.0).build()[0]
    harder = get_task("texture", seed=0, n_samples=24, pressure_kpa=3.0).build()[0]
    assert np.array_equal(default.X, same.X) and not np.array_equal(default.X, harder.X)
