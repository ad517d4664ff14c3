"""Contour levels: chosen from the data (`make_levels`) and ranked against each sub-triangle's
value range (`level_ranks`), which both the lines and the bands of a mapping use.

Values equal to a level (the tie-break every part of the results follows): inside a
sub-triangle the field is linear, so a level c with fmin < c < fmax cuts it into two parts of
positive area, and a level equal to fmin or fmax only touches it (at a vertex or along an
edge: a set of zero area). Such a touching level decides nothing about the triangle: it lies
in the band of its interior values, on the one side of c where its area is. Only a triangle
of constant value equal to a level needs the rule of `bands.band_index`: a value equal to a
level counts as above it, except the top level (its value counts as below).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["level_ranks", "make_levels"]


def make_levels(values: np.ndarray, levels, vmin: float | None = None, vmax: float | None = None) -> np.ndarray:
    """Increasing contour levels (L,): ``levels`` an int n gives n equal bands between vmin
    and vmax (defaults: the data range), i.e. n + 1 levels; a sequence is taken as is (it must
    be finite and strictly increasing; vmin / vmax then drop levels outside them)."""
    lo = float(np.min(values)) if vmin is None else float(vmin)
    hi = float(np.max(values)) if vmax is None else float(vmax)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ValueError("--min / --max must be finite")
    if isinstance(levels, (int, np.integer)):
        n = int(levels)
        if n < 1:
            raise ValueError(f"the number of bands must be at least 1, got {n}")
        if not hi > lo:
            if vmin is None and vmax is None:
                hi = lo + max(abs(lo), 1.0) * 1e-9  # a constant field: one band around it
            else:
                raise ValueError(f"--max ({hi:g}) must be greater than --min ({lo:g})")
        return np.linspace(lo, hi, n + 1)
    lv = np.asarray(levels, dtype=float).reshape(-1)
    if lv.size < 1 or not np.all(np.isfinite(lv)):
        raise ValueError("levels must be finite numbers")
    if np.any(np.diff(lv) <= 0):
        raise ValueError(f"levels must be strictly increasing: {lv.tolist()}")
    if vmin is not None or vmax is not None:
        lv = lv[(lv >= lo) & (lv <= hi)]
        if lv.size == 0:
            raise ValueError(f"no level lies within --min {lo:g} .. --max {hi:g}")
    return lv


@numba.njit(cache=True)
def _ranks_kernel(fmin, fmax, levels, lo, hi):  # pragma: no cover - compiled
    n_lv = len(levels)
    for i in range(len(fmin)):
        a, b = fmin[i], fmax[i]
        k = 0
        while k < n_lv and levels[k] <= a:
            k += 1
        lo[i] = k
        while k < n_lv and levels[k] < b:
            k += 1
        hi[i] = k


def level_ranks(mapping, levels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per sub-triangle, the number of levels <= its smallest value (lo) and < its largest
    (hi), (T,) int64 each (``searchsorted(levels, fmin, "right")``, ``max(lo, searchsorted(levels,
    fmax, "left"))``, one compiled pass): the levels that cut it, fmin < c < fmax, are those
    with rank in [lo, hi), and a triangle that is not constant meets bands lo .. hi with
    positive area (a constant one: hi = lo, its band but for the top level's exception)."""
    fmin, fmax = mapping.tri_range
    lo = np.empty(len(fmin), dtype=np.int64)
    hi = np.empty(len(fmin), dtype=np.int64)
    _ranks_kernel(fmin, fmax, np.ascontiguousarray(levels, dtype=float), lo, hi)
    return lo, hi
