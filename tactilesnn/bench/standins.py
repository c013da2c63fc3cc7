"""Stand-ins of common recording shapes, generated with numpy (``tactilesnn bench fit``).

Real files the project does not have come in a few shapes that stress ``train --data`` in
different ways; each generator here writes one, as a user would hand it over, deterministically
from a seed. They are stand-ins for time and memory (their sizes and layouts match the files
measured in issue 42), with class structure that a good classifier learns but no single summary
statistic gives away:

* ``electrode``: 1,000 recordings x 22 channels x 600 samples at 100 Hz, 20 classes (a 53 MB
  float32 ``.npz``): large drifting baselines (offset, slope and a random walk per channel and
  recording) under small class-specific deflections (a few channels, a few hundred ms,
  jittered in time);
* ``vibration``: 1,000 recordings x 1 channel x 13,200 samples at 2.2 kHz (6 s), 10 classes:
  two partials per class (some classes a few Hz apart), amplitude modulation, noise;
* ``slide_csv``: a folder of 800 CSVs (header ``timestamp, ch1..ch16``, 357 Hz, 700-900 rows),
  8 classes labelled by file-name prefix: a periodic texture at a class-specific spatial
  frequency sweeping across the taxels at a random speed;
* ``events``: 300 trials x 39 taxels x 2 polarities x 325 bins of 20 ms, 20 classes, ~66 events
  per taxel and trial, ~10 % of bins non-zero, no taxel positions: each class a trajectory
  (which taxels fire, in which order) with jittered timing;
* ``glove``: 560 grasps x 5 fingertip force resistors x 50 samples at 10 Hz, 28 objects (the
  small-file shape of issue 74, where a random forest on summary statistics beat the defaults
  by 3 points): each object a share of the grip per finger and a closing time, each grasp a
  different grip force, timing, drift and noise; objects come in similar pairs.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np


def _classes(prefix: str, n: int) -> np.ndarray:
    return np.array([f"{prefix}{i:02d}" for i in range(n)])


def electrode(path: Path, seed: int = 0, n: int = 1000, channels: int = 22, samples: int = 600,
              n_classes: int = 20, fs_hz: float = 100.0) -> Path:  # fmt: skip
    """Drifting baselines with small electrode-like class deflections (``.npz``, float64)."""
    rng = np.random.default_rng([seed, 1])
    t = np.arange(samples) / fs_hz
    # each class: 3 deflections (channel, centre s, width s, amplitude in units of the noise)
    proto = [(rng.integers(0, channels, 3), rng.uniform(1.0, 5.0, 3), rng.uniform(0.1, 0.4, 3),
              rng.choice([-1.0, 1.0], 3) * rng.uniform(1.0, 2.5, 3)) for _ in range(n_classes)]  # fmt: skip
    y = np.arange(n) % n_classes
    rng.shuffle(y)
    X = np.empty((n, channels, samples), dtype=np.float32)
    for i in range(n):
        offset = rng.normal(0.0, 50.0, (channels, 1))
        slope = rng.normal(0.0, 2.0, (channels, 1)) * t
        walk = np.cumsum(rng.normal(0.0, 0.05, (channels, samples)), axis=1)
        x = offset + slope + walk + rng.normal(0.0, 1.0, (channels, samples))
        ch, centre, width, amp = proto[y[i]]
        shift = rng.normal(0.0, 0.15)
        for c, m, w, a in zip(ch, centre, width, amp, strict=True):
            x[c] += a * rng.uniform(0.7, 1.3) * 6.0 * np.exp(-0.5 * ((t - m - shift) / w) ** 2)
        X[i] = x
    np.savez(path, X=X, y=y, fs=np.array(fs_hz), class_names=_classes("class", n_classes))
    return path


def vibration(path: Path, seed: int = 0, n: int = 1000, samples: int = 13200, n_classes: int = 10,
              fs_hz: float = 2200.0) -> Path:  # fmt: skip
    """One accelerometer-like channel: class partials, amplitude modulation, noise (float32)."""
    rng = np.random.default_rng([seed, 2])
    t = np.arange(samples) / fs_hz
    base = np.sort(rng.uniform(60.0, 600.0, n_classes))
    base[1::3] = base[0::3][: len(base[1::3])] + rng.uniform(1.0, 3.0, len(base[1::3]))
    ratio = rng.uniform(1.5, 3.2, n_classes)
    y = np.arange(n) % n_classes
    rng.shuffle(y)
    X = np.empty((n, 1, samples), dtype=np.float32)
    for i in range(n):
        c = y[i]
        f1 = base[c] * rng.uniform(0.985, 1.015)
        am = 1.0 + 0.5 * np.sin(2 * np.pi * rng.uniform(0.5, 3.0) * t + rng.uniform(0, 6.3))
        x = am * np.sin(2 * np.pi * f1 * t + rng.uniform(0, 6.3))
        x += 0.4 * np.sin(2 * np.pi * ratio[c] * f1 * t + rng.uniform(0, 6.3))
        X[i, 0] = (x + rng.normal(0.0, 4.0, samples)) * rng.uniform(0.5, 2.0)
    np.savez(path, X=X, y=y, fs=np.array(fs_hz), class_names=_classes("vib", n_classes))
    return path


def slide_csv(folder: Path, seed: int = 0, n: int = 800, channels: int = 16, n_classes: int = 8,
              fs_hz: float = 357.0) -> Path:  # fmt: skip
    """A folder of CSV slides labelled by file-name prefix, with a timestamp column."""
    rng = np.random.default_rng([seed, 3])
    folder.mkdir(parents=True, exist_ok=True)
    period_mm = np.geomspace(0.8, 3.0, n_classes)
    names = [f"Fabric{chr(65 + c)}" for c in range(n_classes)]
    pos_mm = np.arange(channels) * 1.0
    for i in range(n):
        c = i % n_classes
        rows = int(rng.integers(700, 901))
        t = np.arange(rows) / fs_hz
        speed = rng.uniform(20.0, 30.0) * rng.choice([-1, 1])  # mm/s
        phase = rng.uniform(0, 6.3)
        x = pos_mm[:, None] + speed * t[None, :]
        sig = np.sin(2 * np.pi * x / period_mm[c] + phase) * rng.uniform(5.0, 15.0)
        sig += rng.normal(0.0, 2.0, sig.shape) + rng.normal(2000.0, 200.0, (channels, 1))
        ticks = np.round(t * 1e4).astype(np.int64)  # 0.1 ms ticks, as FabricSlide's
        head = "timestamp," + ",".join(f"ch{k + 1}" for k in range(channels))
        body = np.column_stack([ticks, np.round(sig.T).astype(np.int64)])
        np.savetxt(folder / f"{names[c]}_{i:04d}.csv", body, fmt="%d", delimiter=",",
                   header=head, comments="")  # fmt: skip
    return folder


def events(path: Path, seed: int = 0, n: int = 300, taxels: int = 39, bins: int = 325,
           n_classes: int = 20, bin_ms: float = 20.0) -> Path:  # fmt: skip
    """Binned ON/OFF event counts: a class is a trajectory over the taxels (``.npz``)."""
    rng = np.random.default_rng([seed, 4])
    # each class: 8 taxels visited in order, each for ~0.6 s; ON at contact, OFF at release
    pool = rng.choice(taxels, 16, replace=False)  # classes share taxels
    visits = [rng.choice(pool, 8, replace=False) for _ in range(n_classes)]
    start = rng.uniform(0.5, 1.5, n_classes)
    y = np.arange(n) % n_classes
    rng.shuffle(y)
    X = np.zeros((n, taxels, 2, bins), dtype=np.uint8)
    tb = np.arange(bins) * bin_ms / 1000.0
    for i in range(n):
        c = y[i]
        rate = np.full((taxels, 2, bins), 0.08)  # background events per bin
        t0 = start[c] + rng.normal(0.0, 0.5)
        step = rng.uniform(0.45, 0.65)
        for k, tax in enumerate(visits[c]):
            on = t0 + k * step
            rate[tax, 0] += 0.35 * np.exp(-0.5 * ((tb - on) / 0.12) ** 2)
            rate[tax, 1] += 0.35 * np.exp(-0.5 * ((tb - on - 0.4) / 0.12) ** 2)
        X[i] = np.minimum(rng.poisson(rate), 255)
    np.savez(path, X=X, y=y, bin_ms=np.array(bin_ms), class_names=_classes("ev", n_classes))
    return path


def glove(path: Path, seed: int = 0, n: int = 560, fingers: int = 5, samples: int = 50,
          n_classes: int = 28, fs_hz: float = 10.0) -> Path:  # fmt: skip
    """Force-sensitive resistors on a glove's fingertips, one grasp of ``samples`` samples per
    recording (``.npz``, float32 readings of 0-10 units): an object is each finger's share of
    the grip and when it closes; a grasp scales the whole grip (sd 0.4 in log), shifts the
    closing by up to 0.3 s and adds each resistor's drift and noise, and each reading saturates
    as a resistor's does. Objects come in pairs of similar shape, so a few are hard to tell."""
    rng = np.random.default_rng([seed, 5])
    base = rng.uniform(0.0, 1.0, (n_classes // 2, fingers)) ** 2
    share = np.concatenate([base, np.clip(base + rng.normal(0, 0.06, base.shape), 0, None)])
    share = share[rng.permutation(n_classes)]
    onset = rng.uniform(0.8, 2.0, (n_classes, fingers))  # s from the recording's start
    y = np.arange(n) % n_classes
    rng.shuffle(y)
    t = np.arange(samples) / fs_hz
    X = np.empty((n, fingers, samples), np.float32)
    for i in range(n):
        c = y[i]
        grip = 8.0 * np.exp(rng.normal(0.0, 0.4))  # N at full share
        on = onset[c] + rng.uniform(-0.3, 0.3) + rng.normal(0, 0.1, fingers)
        rise = 1.0 / (1.0 + np.exp(-(t[None, :] - on[:, None]) / 0.15))
        drift = rng.normal(0, 0.05, (fingers, 1)) + rng.normal(0, 0.02, (fingers, 1)) * t
        force = grip * share[c][:, None] * rise
        # a resistor's reading saturates (10 F / (F + 4 N)): a harder grip moves it less
        X[i] = 10.0 * force / (force + 4.0) + drift + rng.normal(0, 0.08, (fingers, samples))
    np.savez(path, X=X, y=y, fs=np.array(fs_hz), class_names=_classes("obj", n_classes),
             channel_names=np.array([f"fsr{k}" for k in range(fingers)]))  # fmt: skip
    return path


#: name -> (generator, file name it writes under the stand-in folder)
STANDINS: dict[str, tuple[Callable[..., Path], str]] = {
    "electrode": (electrode, "electrode_22ch_100hz.npz"),
    "vibration": (vibration, "vibration_1ch_2200hz.npz"),
    "slide_csv": (slide_csv, "slides_16ch_357hz"),
    "events": (events, "events_39tx_20ms.npz"),
    "glove": (glove, "glove_5fsr_10hz.npz"),
}


def make(name: str, folder: Path, seed: int = 0) -> Path:
    """The stand-in ``name`` under ``folder`` (generated once; reused when present)."""
    gen, fname = STANDINS[name]
    path = Path(folder) / fname
    if not path.exists():
        Path(folder).mkdir(parents=True, exist_ok=True)
        gen(path, seed=seed)
    return path
