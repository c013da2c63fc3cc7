"""A Braille cell: the raised dots of each letter, standard dot geometry (mm)."""

from __future__ import annotations

import numpy as np

#: the raised dots (1..6) of each letter of the Braille alphabet (grade 1)
BRAILLE_DOTS: dict[str, tuple[int, ...]] = {
    "a": (1,), "b": (1, 2), "c": (1, 4), "d": (1, 4, 5), "e": (1, 5), "f": (1, 2, 4),
    "g": (1, 2, 4, 5), "h": (1, 2, 5), "i": (2, 4), "j": (2, 4, 5), "k": (1, 3), "l": (1, 2, 3),
    "m": (1, 3, 4), "n": (1, 3, 4, 5), "o": (1, 3, 5), "p": (1, 2, 3, 4), "q": (1, 2, 3, 4, 5),
    "r": (1, 2, 3, 5), "s": (2, 3, 4), "t": (2, 3, 4, 5), "u": (1, 3, 6), "v": (1, 2, 3, 6),
    "w": (2, 4, 5, 6), "x": (1, 3, 4, 6), "y": (1, 3, 4, 5, 6), "z": (1, 3, 5, 6),
}  # fmt: skip

DOT_DIAMETER_MM = 1.44
DOT_HEIGHT_MM = 0.48
DOT_SPACING_MM = 2.34


def scaled_dot_diameter_mm(spacing_mm: float, row_spacing_mm: float | None = None) -> float:
    """The dots' base diameter (mm) of a cell printed at dot pitch ``spacing_mm`` between its
    columns and ``row_spacing_mm`` (default: the same) between its rows (mm): the standard
    dot scaled with the cell (by the geometric mean of the two pitches' scales)."""
    rows = spacing_mm if row_spacing_mm is None else row_spacing_mm
    return DOT_DIAMETER_MM * float(np.sqrt(spacing_mm * rows)) / DOT_SPACING_MM


def cell_dots_mm(
    letter: str, spacing_mm: float = DOT_SPACING_MM, row_spacing_mm: float | None = None
) -> np.ndarray:
    """Dot centres ``[k, 2]`` (mm; x along the slide, y across; the cell's centre at 0):
    columns ``spacing_mm`` apart, rows ``row_spacing_mm`` (default: the same) apart."""
    if letter not in BRAILLE_DOTS:
        raise ValueError(f"unknown Braille letter {letter!r}; letters: {''.join(BRAILLE_DOTS)}")
    rows = spacing_mm if row_spacing_mm is None else row_spacing_mm
    pos = {d: ((d > 3) - 0.5, 1 - (d - 1) % 3) for d in range(1, 7)}  # (column, row)
    return np.array([pos[d] for d in BRAILLE_DOTS[letter]], np.float64) * [spacing_mm, rows]
