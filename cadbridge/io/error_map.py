"""PNG of an error field over a tool: the surface in 3D, each triangle coloured by its error.

matplotlib Agg (no pyplot state), written atomically (`cadbridge.common.atomic`).
"""

from __future__ import annotations

import os

import numpy as np

from cadbridge.common.atomic import atomic_path

__all__ = ["plot_error_map"]


def plot_error_map(path: str | os.PathLike, vertices: np.ndarray, triangles: np.ndarray, values: np.ndarray, *,
                   title: str, label: str, tolerance: float | None = None, edges: np.ndarray | None = None,
                   figsize: tuple[float, float] = (12, 6), dpi: float = 150) -> None:
    """Triangles (T, 3) over vertices (V, 3) coloured by the mean |value| (V,) of their
    corners; ``tolerance`` caps the colour scale at max(tolerance, max) and marks it on the
    colour bar; ``edges`` (K, 2, 3) optional line segments (the mesh edges) drawn on top.
    Two views: the whole tool in true proportions, and the region around the worst triangle
    (a small radius is invisible at the scale of a die)."""
    from matplotlib import cm, colors
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    v = np.asarray(vertices, dtype=float)
    t = np.asarray(triangles, dtype=np.int64)
    val = np.abs(np.asarray(values, dtype=float))
    if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3 or val.shape != (len(v),):
        raise ValueError(f"plot_error_map: vertices (V, 3), triangles (T, 3), values (V,) expected, got "
                         f"{v.shape}, {t.shape}, {val.shape}")
    if not np.all(np.isfinite(val)):
        raise ValueError("plot_error_map: values must be finite")
    fig = Figure(figsize=figsize, dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    top = max(float(val.max()), tolerance or 0.0, 1e-300)
    norm = colors.Normalize(0.0, top)
    from matplotlib import colormaps

    cmap = colormaps["viridis"]
    face = val[t].mean(axis=1)
    # left: the whole tool in true proportions; right: around its worst triangle
    worst = int(np.argmax(face))
    wc = v[t[worst]].mean(axis=0)
    span = 6.0 * float(np.max(np.linalg.norm(v[t[worst]] - wc, axis=1))) + 1e-300
    near = np.all(np.abs(v[t] - wc).max(axis=2) <= span, axis=1)
    for k, (sel, name) in enumerate(((np.ones(len(t), bool), "whole tool"), (near, "around the largest error"))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(v[t[sel]], facecolors=cmap(norm(face[sel])), edgecolors="none",
                                             linewidths=0))
        pts = v[t[sel]].reshape(-1, 3)
        if edges is not None and len(edges):
            e = np.asarray(edges, dtype=float)
            if k == 1:
                e = e[np.all(np.abs(e - wc).max(axis=2) <= span, axis=1)]
            ax.add_collection3d(Line3DCollection(e, colors="k", linewidths=0.4))
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        ext = np.maximum(hi - lo, 1e-3 * float(np.max(hi - lo)))
        ax.set_xlim(lo[0], lo[0] + ext[0])
        ax.set_ylim(lo[1], lo[1] + ext[1])
        ax.set_zlim(lo[2], lo[2] + ext[2])
        ax.set_box_aspect(tuple(ext / ext.max()))
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_zlabel("z")
        ax.set_title(name, fontsize=9)
    fig.suptitle(title)
    sm = cm.ScalarMappable(norm=norm, cmap=cmap)
    cb = fig.colorbar(sm, ax=fig.axes, shrink=0.6, label=label)
    if tolerance:
        cb.ax.axhline(tolerance, color="r", linewidth=2)
        cb.ax.text(-0.2, tolerance / top, "tolerance", color="r", transform=cb.ax.transAxes, va="center",
                   ha="right", fontsize=8)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=fig.dpi)
