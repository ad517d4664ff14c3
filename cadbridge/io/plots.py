"""PNG report plots (matplotlib, Agg canvas, no pyplot global state).

Styles follow the figures of Neto (2010): radial error along a cross-section per normal
source (Fig. 49), error histograms in percent of points (Fig. 17/29), normal-estimate error
per algorithm (Fig. 32/35/38) and log-log convergence with fitted slopes (Fig. 8b/9b).

Every function takes plain numpy arrays, writes one PNG of ``figsize * dpi`` pixels
(default 1600 x 1000) atomically, and raises ValueError naming the offending series when
array lengths or values do not fit.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

from cadbridge.common.atomic import atomic_path
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

__all__ = [
    "plot_section_error",
    "plot_error_histogram",
    "plot_normal_sources",
    "plot_arc_convergence",
]

ArrayLike = np.ndarray | Sequence[float]

_MARKERS = ("o", "s", "^", "v", "D", "<", ">", "p", "h", "*")
_LINESTYLES = ("-", "-", "-", "-.", "-", "-.", "-", "-.", "-", "-.")


# ----------------------------------------------------------------------------- helpers

def _figure(figsize: tuple[float, float], dpi: float) -> Figure:
    fig = Figure(figsize=figsize, dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: str | os.PathLike) -> None:
    # no bbox_inches="tight": the PNG keeps exactly figsize * dpi pixels
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=fig.dpi)


def _vector(what: str, a: ArrayLike, *, min_len: int = 1) -> np.ndarray:
    """1-D float array with at least ``min_len`` entries."""
    v = np.asarray(a)
    if v.dtype.kind not in "iuf":
        raise ValueError(f"{what} must be numeric, got dtype {v.dtype}")
    v = v.astype(float, copy=False)
    if v.ndim != 1:
        raise ValueError(f"{what} must be 1-D, got shape {v.shape}")
    if v.size < min_len:
        raise ValueError(f"{what} needs at least {min_len} values, got {v.size}")
    return v


def _finite(what: str, v: np.ndarray) -> np.ndarray:
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{what} has non-finite values at {np.flatnonzero(~np.isfinite(v))[:10].tolist()}")
    return v


def _pair(what: str, pair) -> tuple[np.ndarray, np.ndarray]:
    """(s, err) -> two 1-D arrays of equal length."""
    if not isinstance(pair, (tuple, list)) or len(pair) != 2:
        raise ValueError(f"{what} must be an (s, err) pair of arrays")
    s = _finite(f"{what} s", _vector(f"{what} s", pair[0]))
    e = _vector(f"{what} err", pair[1])
    if s.shape != e.shape:
        raise ValueError(f"{what}: s has {s.size} values but err has {e.size}")
    return s, e


def _nonempty(what: str, d: Mapping) -> None:
    if not isinstance(d, Mapping) or len(d) == 0:
        raise ValueError(f"{what} must be a non-empty dict of name -> array")


# ----------------------------------------------------------------------------- plots

def plot_section_error(
    path: str | os.PathLike,
    series: Mapping[str, tuple[ArrayLike, ArrayLike]],
    *,
    element_boundaries: ArrayLike | None = None,
    xlabel: str = "normalized arc length",
    ylabel: str = "radial error [%]",
    title: str | None = None,
    polyhedral: tuple[ArrayLike, ArrayLike] | None = None,
    legend_outside: bool = False,
    figsize: tuple[float, float] = (8, 5),
    dpi: float = 200,
) -> None:
    """Error along a cross-section, one curve per normal source (Fig. 49 style).

    series : name -> (s (K,), err (K,)), position along the section and error there (K may
    differ between series; NaN in err leaves a gap). element_boundaries : (B,) positions of
    element boundaries, drawn as vertical dotted lines. polyhedral : optional (s, err) of the
    flat (polyhedral) mesh, drawn as a dashed black reference. legend_outside puts the
    legend right of the axes, so it never hides a curve.
    """
    _nonempty("series", series)
    data = {name: _pair(f"series {name!r}", pair) for name, pair in series.items()}
    ref = _pair("polyhedral", polyhedral) if polyhedral is not None else None
    bounds = (_finite("element_boundaries", _vector("element_boundaries", element_boundaries))
              if element_boundaries is not None else None)

    fig = _figure(figsize, dpi)
    ax = fig.add_subplot()
    if bounds is not None:
        for i, b in enumerate(bounds):
            ax.axvline(b, color="0.45", linestyle=":", linewidth=1.0,
                       label="element boundary" if i == 0 else None, zorder=1)
    if ref is not None:
        ax.plot(*ref, color="k", linestyle="--", linewidth=1.2, label="polyhedral", zorder=5)  # on top: it coincides with collapsed patches
    for i, (name, (s, e)) in enumerate(data.items()):
        ax.plot(s, e, label=name, linewidth=1.5, marker=_MARKERS[i % len(_MARKERS)],
                markersize=4, markevery=max(1, s.size // 12),
                linestyle=_LINESTYLES[i % len(_LINESTYLES)], zorder=3)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    ax.grid(True, alpha=0.4)
    if legend_outside:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
    else:
        ax.legend(loc="best", fontsize="small")
    _save(fig, path)


def plot_error_histogram(
    path: str | os.PathLike,
    errors: Mapping[str, ArrayLike],
    *,
    bins: int | ArrayLike = 30,
    xlabel: str,
    title: str | None = None,
    cumulative: bool = False,
    figsize: tuple[float, float] = (8, 5),
    dpi: float = 200,
) -> None:
    """Histogram of error values in percent of points (Fig. 17 / 29 style).

    errors : name -> (M,) finite error values (M may differ between series; each series is
    normalised by its own M). All series share the same bin edges: ``bins`` is a bin count
    over the common range or an increasing (B+1,) array of edges. cumulative=True draws the
    cumulative percentage as step curves.
    """
    _nonempty("errors", errors)
    data = {n: _finite(f"errors {n!r}", _vector(f"errors {n!r}", v)) for n, v in errors.items()}
    if np.ndim(bins) == 0:
        nb = int(bins)
        if nb < 1 or nb != bins:
            raise ValueError(f"bins must be a positive integer or an array of edges, got {bins!r}")
        allv = np.concatenate(list(data.values()))
        lo, hi = float(allv.min()), float(allv.max())
        if hi <= lo:  # all values equal: a unit-width bin around them
            lo, hi = lo - 0.5, hi + 0.5
        edges = np.linspace(lo, hi, nb + 1)
    else:
        edges = _finite("bins", _vector("bins", bins, min_len=2))
        if np.any(np.diff(edges) <= 0):
            raise ValueError("bins edges must be strictly increasing")

    names = list(data)
    arrays = [data[n] for n in names]
    weights = [np.full(a.size, 100.0 / a.size) for a in arrays]

    fig = _figure(figsize, dpi)
    ax = fig.add_subplot()
    if cumulative:
        ax.hist(arrays, bins=edges, weights=weights, cumulative=True, histtype="step",
                linewidth=1.5, label=names)
        ax.set_ylabel("cumulative points [%]")
    else:
        ax.hist(arrays, bins=edges, weights=weights, histtype="bar", rwidth=0.9,
                edgecolor="k", linewidth=0.3, label=names)
        ax.set_ylabel("points [%]")
    ax.set_xlabel(xlabel)
    if title:
        ax.set_title(title)
    ax.grid(True, axis="y", alpha=0.4)
    ax.set_axisbelow(True)
    ax.legend(loc="best", fontsize="small")
    _save(fig, path)


def plot_normal_sources(
    path: str | os.PathLike,
    angles: Mapping[str, ArrayLike],
    *,
    title: str | None = None,
    kind: str = "bar",
    ylabel: str = "normal vector error [°]",
    figsize: tuple[float, float] = (8, 5),
    dpi: float = 200,
) -> None:
    """Angle between each method's normals and the reference (CAD) normals (Fig. 32/35/38).

    angles : method -> (N,) angles in degrees, each in [0, 180] (N may differ between
    methods, e.g. crease nodes with several normals). kind="bar" draws max and mean per
    method side by side with their values printed; kind="box" draws a box plot per method
    (whiskers at min/max) with the mean marked.
    """
    _nonempty("angles", angles)
    if kind not in ("bar", "box"):
        raise ValueError(f"kind must be 'bar' or 'box', got {kind!r}")
    data = {}
    for n, v in angles.items():
        a = _finite(f"angles {n!r}", _vector(f"angles {n!r}", v))
        if a.min() < 0.0 or a.max() > 180.0:
            raise ValueError(f"angles {n!r} must be in degrees within [0, 180], "
                             f"got range [{a.min():g}, {a.max():g}]")
        data[n] = a
    names = list(data)
    x = np.arange(len(names))

    fig = _figure(figsize, dpi)
    ax = fig.add_subplot()
    if kind == "bar":
        mx = np.array([data[n].max() for n in names])
        mean = np.array([data[n].mean() for n in names])
        w = 0.38
        b1 = ax.bar(x - w / 2, mx, w, label="maximum", color="C3", edgecolor="k", linewidth=0.4)
        b2 = ax.bar(x + w / 2, mean, w, label="mean", color="C0", edgecolor="k", linewidth=0.4)
        ax.bar_label(b1, fmt="%.3g", fontsize="x-small", padding=2)
        ax.bar_label(b2, fmt="%.3g", fontsize="x-small", padding=2)
        ax.margins(y=0.12)
        ax.legend(loc="best", fontsize="small")
    else:
        ax.boxplot([data[n] for n in names], positions=x, whis=(0, 100), showmeans=True,
                   widths=0.5)
    ax.set_xticks(x, names, rotation=20 if len(names) > 4 else 0)
    ax.set_ylabel(ylabel)
    ax.set_ylim(bottom=0)
    if title:
        ax.set_title(title)
    ax.grid(True, axis="y", alpha=0.4)
    ax.set_axisbelow(True)
    _save(fig, path)


def plot_arc_convergence(
    path: str | os.PathLike,
    h: ArrayLike,
    err: Mapping[str, ArrayLike],
    *,
    slopes: bool = True,
    xlabel: str = "normalized edge length",
    ylabel: str = "maximum error",
    title: str | None = None,
    figsize: tuple[float, float] = (8, 5),
    dpi: float = 200,
) -> None:
    """Maximum error versus element size on log-log axes (Fig. 8b / 9b style).

    h : (K,) positive element sizes. err : name -> (K,) positive errors at those sizes.
    slopes=True fits log10(err) = p log10(h) + c by least squares (needs K >= 2), draws the
    fitted line dashed and puts the order p in the legend.
    """
    _nonempty("err", err)
    hv = _finite("h", _vector("h", h, min_len=2 if slopes else 1))
    if np.any(hv <= 0):
        raise ValueError("h must be positive for a log-log plot")
    data = {}
    for n, v in err.items():
        e = _finite(f"err {n!r}", _vector(f"err {n!r}", v))
        if e.size != hv.size:
            raise ValueError(f"err {n!r} has {e.size} values but h has {hv.size}")
        if np.any(e <= 0):
            raise ValueError(f"err {n!r} must be positive for a log-log plot")
        data[n] = e
    if slopes and np.unique(hv).size < 2:
        raise ValueError("h needs at least two distinct values to fit a slope")

    fig = _figure(figsize, dpi)
    ax = fig.add_subplot()
    order = np.argsort(hv)
    for i, (n, e) in enumerate(data.items()):
        color = f"C{i % 10}"
        label = n
        if slopes:
            p, c = np.polyfit(np.log10(hv), np.log10(e), 1)
            label = f"{n} (slope {p:.2f})"
            hh = hv[order][[0, -1]]
            ax.plot(hh, 10.0 ** (p * np.log10(hh) + c), color=color, linestyle="--",
                    linewidth=1.0)
        ax.plot(hv[order], e[order], color=color, marker=_MARKERS[i % len(_MARKERS)],
                linestyle="none" if slopes else "-", label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    ax.grid(True, which="both", alpha=0.35)
    ax.legend(loc="best", fontsize="small")
    _save(fig, path)
