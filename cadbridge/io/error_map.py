"""PNG of an error field over a tool: the surface in 3D, each triangle coloured by its error.

matplotlib Agg (no pyplot state), written atomically (`cadbridge.io.atomic`).
"""

from __future__ import annotations

import os

import numpy as np

from cadbridge.io.atomic import atomic_path

__all__ = ["plot_error_map"]


def plot_error_map(path: str | os.PathLike, vertices: np.ndarray, triangles: np.ndarray, values: np.ndarray, *,
                   title: str, label: str, tolerance: float | None = None, edges: np.ndarray | None = None,
                   figsize: tuple[float, float] = (9, 6), dpi: float = 150) -> None:
    """Triangles (T, 3) over vertices (V, 3) coloured by the mean |value| (V,) of their
    corners; ``tolerance`` caps the colour scale at max(tolerance, max) and marks it on the
    colour bar; ``edges`` (K, 2, 3) optional line segments (the mesh edges) drawn on top."""
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
    ax = fig.add_subplot(projection="3d")
    top = max(float(val.max()), tolerance or 0.0, 1e-300)
    norm = colors.Normalize(0.0, top)
    cmap = cm.get_cmap("viridis") if hasattr(cm, "get_cmap") else colors.Colormap("viridis")
    face = val[t].mean(axis=1)
    pc = Poly3DCollection(v[t], facecolors=cmap(norm(face)), edgecolors="none", linewidths=0)
    ax.add_collection3d(pc)
    if edges is not None and len(edges):
        ax.add_collection3d(Line3DCollection(np.asarray(edges, dtype=float), colors="k", linewidths=0.3))
    lo, hi = v.min(axis=0), v.max(axis=0)
    c, r = 0.5 * (lo + hi), 0.5 * float(np.max(hi - lo))
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    ax.set_title(title)
    sm = cm.ScalarMappable(norm=norm, cmap=cmap)
    cb = fig.colorbar(sm, ax=ax, shrink=0.7, label=label)
    if tolerance:
        cb.ax.axhline(tolerance, color="r", linewidth=2)
        cb.ax.text(1.05, tolerance / top, "tolerance", color="r", transform=cb.ax.transAxes, va="center",
                   fontsize=8)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=fig.dpi)
