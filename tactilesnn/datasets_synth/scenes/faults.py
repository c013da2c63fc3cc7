"""Hardware faults, switchable on any sensor model's output ``[channels, samples]``.

Seed 000 reports neighbouring electrodes short-circuiting through 100 kOhm - 1 MOhm after
repeated contacts, and a per-sensor calibration spread; every readout drifts. The faults act on
what a sensor model returns, so they apply to any model:

- ``dead``: channels stuck at their first sample (an open electrode / broken trace).
- ``shorted``: pairs ``(i, j, R_short_ohm)``. Two sources of output impedance ``source_ohm``
  joined by ``R_short`` form a divider: ``v_i' = v_i - (v_i - v_j) R_s / (2 R_s + R_short)``
  (crosstalk; 100 kOhm between 500 kOhm sources mixes 45 % of the difference).
- ``gain_sd``: per-channel gain ``exp(N(0, gain_sd))``, fixed for a device (the calibration spread).
- ``drift_per_s``: a slow random-walk offset per channel, rms growth ``drift_per_s`` (output
  units) per sqrt(second) (baseline wander, charge accumulation).

The device-level draws (gains) come from the generator passed to :meth:`Faults.apply`; tasks pass
a stream that depends only on (task, seed), so a device keeps its gains across samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.checks import check_finite


@dataclass(frozen=True)
class Faults:
    """Fault configuration; the default (no faults) returns the input unchanged."""

    dead: tuple[int, ...] = ()
    shorted: tuple[tuple[int, int, float], ...] = ()
    gain_sd: float = 0.0
    drift_per_s: float = 0.0
    source_ohm: float = 5e5

    def __post_init__(self) -> None:
        for _, _, r in self.shorted:
            if not np.isfinite(r) or r <= 0:
                raise ValueError(f"short-circuit resistance must be > 0 ohm, got {r}")
        if self.gain_sd < 0 or self.drift_per_s < 0 or self.source_ohm <= 0:
            raise ValueError("gain_sd and drift_per_s must be >= 0 and source_ohm > 0")

    @property
    def active(self) -> bool:
        return bool(self.dead or self.shorted or self.gain_sd or self.drift_per_s)

    def crosstalk(self, r_short_ohm: float) -> float:
        """Fraction of the neighbour difference mixed into a channel through ``r_short_ohm``."""
        return self.source_ohm / (2 * self.source_ohm + r_short_ohm)

    def apply(
        self, x: np.ndarray, fs_hz: float, device_rng: np.random.Generator,
        rng: np.random.Generator | None = None,
    ) -> np.ndarray:  # fmt: skip
        """Return a faulty copy of ``x [channels, samples]`` (``x`` itself when no fault is set)."""
        if not self.active:
            return x
        y = np.array(x, dtype=np.float64)
        check_finite(y, "sensor output")
        c = y.shape[0]
        for idx in list(self.dead) + [k for i, j, _ in self.shorted for k in (i, j)]:
            if not -c <= idx < c:
                raise ValueError(f"fault names channel {idx}; the sensor has {c} channels")
        if self.gain_sd:
            y *= np.exp(self.gain_sd * device_rng.standard_normal(c))[:, None]
        if self.shorted:
            src = y.copy()
            for i, j, r in self.shorted:
                a = self.crosstalk(r)
                y[i] -= a * (src[i] - src[j])
                y[j] -= a * (src[j] - src[i])
        if self.drift_per_s:
            walk_rng = rng if rng is not None else device_rng
            steps = walk_rng.standard_normal(y.shape) * self.drift_per_s / np.sqrt(fs_hz)
            y += np.cumsum(steps, axis=1)
        for i in self.dead:
            y[i] = y[i, 0]
        return y


def parse_faults(text: str) -> Faults:
    """Parse ``"dead=3,5;short=0-1@1e5;gain_sd=0.1;drift_per_s=0.01"`` into :class:`Faults`."""
    kw: dict = {}
    for part in filter(None, (p.strip() for p in text.split(";"))):
        key, _, val = part.partition("=")
        key = key.strip()
        try:
            if key == "dead":
                kw["dead"] = tuple(int(v) for v in val.split(","))
            elif key == "short":
                pairs = []
                for item in val.split(","):
                    ij, _, r = item.partition("@")
                    i, j = (int(v) for v in ij.split("-"))
                    pairs.append((i, j, float(r or 1e5)))
                kw["shorted"] = tuple(pairs)
            elif key in ("gain_sd", "drift_per_s", "source_ohm"):
                kw[key] = float(val)
            else:
                raise KeyError(key)
        except KeyError:
            raise ValueError(
                f"unknown fault {key!r}; use dead=, short=i-j@ohm, gain_sd=, drift_per_s="
            ) from None
        except ValueError as e:
            raise ValueError(f"cannot parse fault {part!r}: {e}") from None
    return Faults(**kw)
