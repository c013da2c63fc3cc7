"""Taxel geometry: positions ``taxel_xy`` ``[taxels, 2]`` (mm) -> cells of a grid.

A sensor whose taxels do not form a grid (an iCub fingertip's triangle, a fingertip with 39
taxels, a subset of an array in any order) is placed on the coarsest grid that keeps every taxel in
its own cell: pitch from the layout's own spacing (the median distance from each taxel to its
nearest neighbour, widened while no two taxels share a cell: :func:`grid_pitch`; nothing is tuned
to a sensor), each taxel in the cell nearest its position, a taxel whose cell is taken moved to
the nearest free cell. The grid is then an image a convolutional model
reads, empty cells at zero. Pure NumPy.
"""

from __future__ import annotations

import numpy as np

#: the largest taxel coordinate taken (mm, 1 km): beyond it positions are in the wrong units or
#: corrupt, and their differences would lose the millimetres between neighbours
MAX_POSITION_MM = 1e6
#: a placement grid larger than this many cells means positions in the wrong units (or an outlier)
MAX_CELLS = 1 << 16


def check_taxel_xy(xy: object, taxels: int, where: str = "taxel_xy") -> np.ndarray:
    """``xy`` as float64 ``[taxels, 2]``: finite, within +-:data:`MAX_POSITION_MM`, pairwise
    distinct (ValueError otherwise, naming the first taxel out of range)."""
    arr = np.asarray(xy)
    if arr.dtype.kind not in "fiu" or arr.shape != (taxels, 2):
        raise ValueError(f"{where} must be [{taxels} taxels, 2] numbers (x, y in mm), got "
                         f"{arr.dtype} {arr.shape}")  # fmt: skip
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise ValueError(f"{where} holds NaN or Inf")
    far = np.abs(arr).max(1) > MAX_POSITION_MM
    if far.any():
        i = int(np.argmax(far))
        raise ValueError(f"{where}: taxel {i} at ({arr[i, 0]:g}, {arr[i, 1]:g}) mm, beyond "
                         f"+-{MAX_POSITION_MM:g} mm: positions are millimetres on the sensor")  # fmt: skip
    if taxels > 1 and len(np.unique(arr, axis=0)) < taxels:
        raise ValueError(f"{where}: two taxels share a position")
    return arr


def nearest_neighbour_mm(xy: np.ndarray) -> np.ndarray:
    """Each taxel's distance to its nearest other taxel ``[taxels]`` (in blocks: memory bounded)."""
    out = np.empty(len(xy))
    for i in range(0, len(xy), 1024):
        d = np.linalg.norm(xy[i : i + 1024, None] - xy[None], axis=-1)
        d[np.arange(d.shape[0]), np.arange(i, i + d.shape[0])] = np.inf
        out[i : i + 1024] = d.min(1)
    return out


def grid_pitch(rel: np.ndarray, spacing: float) -> float:
    """The largest cell pitch in ``[0.8, 1.5] x spacing`` at which the fewest taxels share a cell
    (the nearest-neighbour median alone is biased low by position jitter: a jittered 2.5 mm array
    gave 2.3 mm and an extra row)."""
    best, best_key = spacing, None
    for p in spacing * np.geomspace(0.8, 1.5, 40):
        cells = np.rint(rel / p).astype(np.int64)
        shared = len(rel) - len(np.unique(cells, axis=0))
        key = (shared, -p)
        if best_key is None or key < best_key:
            best, best_key = float(p), key
    return best


def place_on_grid(xy: object) -> tuple[int, int, np.ndarray]:
    """Positions ``[taxels, 2]`` (mm; x along columns, y along rows) -> ``(rows, cols, cells)``:
    ``cells[i]`` is taxel ``i``'s row-major cell; distinct. See the module docstring."""
    arr = np.asarray(xy, dtype=np.float64)
    arr = check_taxel_xy(arr, len(arr))
    if len(arr) == 1:
        return 1, 1, np.zeros(1, np.int64)
    rel = arr[:, ::-1] - arr[:, ::-1].min(0)  # (row, col) axes, from the corner
    pitch = grid_pitch(rel, float(np.median(nearest_neighbour_mm(arr))))
    ij = np.rint(rel / pitch).astype(np.int64)
    rows, cols = (int(v) + 1 for v in ij.max(0))
    if rows * cols > MAX_CELLS:
        raise ValueError(f"taxel_xy spans {rows} x {cols} cells of its {pitch:.3g} mm spacing "
                         f"(more than {MAX_CELLS}): positions in mm expected")  # fmt: skip
    taken = np.zeros((rows, cols), bool)
    cells = np.empty(len(arr), np.int64)
    # taxels nearest their cell centre first, so a displaced taxel is the worse-fitting one
    err = np.linalg.norm(rel / pitch - ij, axis=1)
    for i in np.argsort(err, kind="stable"):
        r, c = ij[i]
        if taken[r, c]:  # the nearest free cell to the taxel's position
            if taken.all():  # grid full: grow a row
                taken = np.vstack([taken, np.zeros((1, cols), bool)])
                rows += 1
            rr, cc = np.mgrid[0:rows, 0:cols]
            pos = rel[i] / pitch
            d = np.where(taken, np.inf, (rr - pos[0]) ** 2 + (cc - pos[1]) ** 2)
            r, c = np.unravel_index(int(np.argmin(d)), taken.shape)
        taken[r, c] = True
        cells[i] = r * cols + c
    # cells were numbered with the final column count (rows only ever grow)
    return rows, cols, cells
