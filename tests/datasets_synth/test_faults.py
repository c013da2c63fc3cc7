import numpy as np
import pytest

from tactilesnn.datasets_synth import Faults, get_task, parse_faults


def test_no_fault_is_identity_and_crosstalk_divider():
    x = np.random.default_rng(0).standard_normal((4, 50))
    rng = np.random.default_rng(1)
    assert Faults().apply(x, 100.0, rng) is x
    f = Faults(shorted=((0, 1, 1e5),), source_ohm=5e5)
    a = 5e5 / (2 * 5e5 + 1e5)  # 0.4545
    y = f.apply(x, 100.0, rng)
    assert np.allclose(y[0], x[0] - a * (x[0] - x[1]))
    assert np.allclose(y[2:], x[2:])
    assert Faults(source_ohm=5e5).crosstalk(1e6) == pytest.approx(0.25)


def test_dead_gain_and_drift():
    x = np.ones((3, 1000))
    x[1] = np.sin(np.arange(1000) / 10)
    y = Faults(dead=(1,)).apply(x, 100.0, np.random.default_rng(0))
    assert np.all(y[1] == x[1, 0])
    g = Faults(gain_sd=0.2).apply(x, 100.0, np.random.default_rng(0))
    ratio = g[0] / x[0]
    assert np.allclose(ratio, ratio[0]) and ratio[0] != 1.0
    walks = np.stack([
        Faults(drift_per_s=0.5).apply(np.zeros((1, 10000)), 100.0, np.random.default_rng(s))[0, -1]
        for s in range(300)
    ])  # fmt: skip
    assert walks.std() == pytest.approx(0.5 * np.sqrt(100.0), rel=0.15)  # rms grows as sqrt(t)


def test_parse_and_task_integration():
    f = parse_faults("dead=3;short=0-1@2e5;gain_sd=0.1")
    assert f.dead == (3,) and f.shorted == ((0, 1, 2e5),) and f.gain_sd == 0.1
    with pytest.raises(ValueError, match="unknown fault"):
        parse_faults("broken=1")
    with pytest.raises(ValueError, match="sensor has 8 channels"):
        get_task("material", faults="dead=9", n_samples=10).sample(0)
    clean = get_task("material", n_samples=10).sample(0)[0]
    dead = get_task("material", faults="dead=3", n_samples=10).sample(0)[0]
    assert np.all(dead[3] == dead[3, 0]) and np.allclose(dead[[0, 1, 2]], clean[[0, 1, 2]])
