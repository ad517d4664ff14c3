"""PNG of an error field over a Nagata tool: where the error is, not only how much.

Each element is drawn as one polygon (its Nagata edges, sampled) coloured by the element's
largest error, in two views: the whole tool and a close-up around the worst element. The
worst elements are outlined and labelled with their number in the tool file (1-based) and
their error. Each view looks along a direction chosen from the geometry
(`view_direction`): the whole tool so that its curved elements (radii) face the viewer,
the close-up so that the elements carrying the error do; in both the worst element is
seen within 60 degrees of its normal, never edge-on.

Drawing is 2D: the polygons projected along the view direction, sorted far to near
(painter's order, by mean depth) into one `PolyCollection`. Where two elements overlap in
the view the nearer centre wins: exact for a tool surface seen from one side, approximate
where it folds behind itself. On the production die (85 898 elements, 2 cores shared, load
about 4.5) one picture takes 2.1 s; the previous mplot3d drawing (`Poly3DCollection`, the
same elements as 171 796 triangles, no labels) took 3.1 s. The 2D drawing is not chosen for
speed alone: it gives the view direction, the crop of the close-up and the label positions
in screen coordinates directly.

matplotlib Agg (no pyplot state), written atomically (`cadbridge.common.atomic`).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import numpy as np

from cadbridge.common.atomic import atomic_path

__all__ = ["ErrorMap", "element_max", "plot_error_map", "view_direction"]

GRAZING_DEG = 70.0  # a surface seen at more than this from its normal counts as edge-on
LABEL_FLOOR = 0.05  # elements below this fraction of the largest error are not labelled
MUST_SEE_DEG = 60.0  # the worst element is seen at most this far from its normal
EDGE_SAMPLES = 3  # points per element edge in the close-up outlines (corners only in the whole view)


@dataclass
class ErrorMap:
    """What `plot_error_map` drew: ``worst`` (K,) 0-based element ids, worst first, and their
    ``values`` (K,); the view directions ``whole_view`` / ``close_view`` (3,) (unit, from the
    tool towards the viewer); ``close_elements`` (C,) the elements of the close-up;
    ``unmeasured`` how many elements had no finite value (drawn grey, never labelled);
    ``seconds`` the wall time of the picture."""

    worst: np.ndarray
    values: np.ndarray
    whole_view: np.ndarray
    close_view: np.ndarray
    close_elements: np.ndarray
    unmeasured: int
    seconds: float

    @property
    def labels(self) -> list[str]:
        """The element numbers as printed: 1-based, like the tool file."""
        return [str(int(e) + 1) for e in self.worst]


def element_max(elem: np.ndarray, values: np.ndarray, n_elements: int) -> np.ndarray:
    """Largest |value| per element over its samples: ``elem`` (M,) 0-based element of each
    sample, ``values`` (M,) -> (n_elements,); NaN samples are skipped, NaN where an element
    has no finite sample."""
    elem = np.asarray(elem, dtype=np.int64)
    v = np.abs(np.asarray(values, dtype=float))
    if elem.shape != v.shape or v.ndim != 1:
        raise ValueError(f"element_max: elem and values must be (M,), got {elem.shape}, {v.shape}")
    out = np.full(n_elements, np.nan)
    np.fmax.at(out, elem, v)  # fmax ignores NaN on either side
    return out


def view_direction(normals: np.ndarray, weights: np.ndarray, *, must_see: np.ndarray | None = None,
                   grazing_deg: float = GRAZING_DEG, candidates: int = 400) -> np.ndarray:
    """Unit view direction (3,) (from the surface towards the viewer) that sees the weighted
    surface best: it maximises sum(w_i cos a_i) over the elements seen at a_i < ``grazing_deg``
    from their unit ``normals`` (E, 3) (``weights`` (E,) >= 0). Candidates: the weighted mean
    normal, then ``candidates`` directions spread over the sphere; the mean normal wins ties
    (it is the optimum when every element is seen at less than ``grazing_deg``). With
    ``must_see`` (3,) (the worst element's unit normal) only directions within `MUST_SEE_DEG`
    of it count (and itself): that element is never seen edge-on."""
    n = np.asarray(normals, dtype=float)
    w = np.asarray(weights, dtype=float)
    ok = np.isfinite(w) & np.all(np.isfinite(n), axis=1) & (w > 0)
    n, w = n[ok], w[ok]
    if not len(w):
        return np.array([0.0, 0.0, 1.0])
    mean = w @ n
    # normals on one point of a 1/128 grid (about 0.4 degrees) are one: a die has few distinct
    # directions, so the score matrix is (distinct normals, candidates), not (E, candidates):
    # 8 071 x 400 instead of 85 898 x 400 on the production die (1.6 s -> 0.25 s a picture)
    _, group = np.unique(np.round(n * 128.0).astype(np.int64), axis=0, return_inverse=True)
    group = group.ravel()
    w_g = np.bincount(group, weights=w)
    n_g = np.stack([np.bincount(group, weights=w * n[:, k]) for k in range(3)], axis=1) / w_g[:, None]
    n, w = n_g / np.maximum(np.linalg.norm(n_g, axis=1, keepdims=True), 1e-300), w_g
    cand = [_fibonacci_sphere(candidates)]
    if np.linalg.norm(mean) > 1e-12 * w.sum():
        cand.insert(0, (mean / np.linalg.norm(mean))[None])
    cand = np.concatenate(cand)
    if must_see is not None and np.all(np.isfinite(must_see)):
        cand = np.concatenate([cand[cand @ must_see >= np.cos(np.radians(MUST_SEE_DEG))], [must_see]])
    c = n @ cand.T  # (distinct normals, C)
    score = w @ np.where(c > np.cos(np.radians(grazing_deg)), c, 0.0)
    return cand[int(np.argmax(score))]


def _fibonacci_sphere(k: int) -> np.ndarray:
    i = np.arange(k) + 0.5
    z = 1.0 - 2.0 * i / k
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + 5 ** 0.5) * i
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _screen_axes(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Right and up (3,) of a view along ``d``: up is the global z (the press axis) as seen
    in the view, y when looking along z."""
    up = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.95 else np.array([0.0, 1.0, 0.0])
    right = np.cross(up, d)
    right /= np.linalg.norm(right)
    return right, np.cross(d, right)


def _outlines(nm, elems: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boundary of each element on its Nagata patch, ``m`` points per edge: points (n, 4m, 3)
    (a triangle's last edge repeated: one array for both kinds), normals at the points and
    unit normals (n, 3) at the parametric centres."""
    s = np.arange(m) / m
    one, zero = np.ones(m), np.zeros(m)
    # corners (0,0), (1,0), (1,1)[, (0,1)]: the element's corner order x00, x10, x11[, x01]
    quad = np.concatenate([np.c_[s, zero], np.c_[one, s], np.c_[1 - s, one], np.c_[zero, 1 - s]])
    # a triangle's fourth "edge" stays at its first corner (0, 0): a degenerate polygon side
    tri = np.concatenate([np.c_[s, zero], np.c_[one, s], np.c_[1 - s, 1 - s], np.zeros((m, 2))])
    is_tri = nm.element_kind[elems] == 3
    par = np.where(is_tri[:, None, None], tri[None], quad[None])  # (n, 4m, 2)
    el = np.repeat(elems, 4 * m)
    pts, nrm = nm.evaluate(el, par[..., 0].ravel(), par[..., 1].ravel())
    _, cn = nm.evaluate(elems, np.where(is_tri, 2 / 3, 0.5), np.where(is_tri, 1 / 3, 0.5))
    return pts.reshape(len(elems), 4 * m, 3), nrm.reshape(len(elems), 4 * m, 3), cn


def _area(p: np.ndarray) -> np.ndarray:
    """Area (n,) of closed polygons p (n, k, 3) (vector area; exact for planar polygons)."""
    return 0.5 * np.linalg.norm(np.cross(p, np.roll(p, -1, axis=1)).sum(axis=1), axis=1)


def plot_error_map(path: str | os.PathLike, nagata, values: np.ndarray, *, title: str, label: str,
                   unit: str = "", length_unit: str = "", tolerance: float | None = None, n_worst: int = 5,
                   negligible: float = 0.0,
                   figsize: tuple[float, float] = (16, 8), dpi: float = 110) -> ErrorMap:
    """One PNG of the error per element of ``nagata`` (a `cadbridge.nagata.NagataMesh`, E
    elements): ``values`` (E,) the largest |error| of each element (`element_max`; NaN: not
    measured, drawn grey, never coloured or labelled). ``label`` names the colour bar,
    ``unit`` follows the labelled values, ``length_unit`` the scale bar; ``tolerance`` (if
    given) is marked on the colour bar and included in its range.

    Left: the whole tool; right: the elements within 8 sizes of the worst one, cropped to a
    square around it. The ``n_worst`` largest values (above ``negligible`` and above
    `LABEL_FLOOR` x the largest) are outlined in red and labelled "element: value" (element
    numbers 1-based, as in the tool file) in each view that shows them, and listed under the
    pictures with their centres. Returns what was drawn (`ErrorMap`)."""
    from matplotlib import colormaps, colors
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure

    t0 = time.perf_counter()
    val = np.abs(np.asarray(values, dtype=float))
    ne = nagata.n_elements
    if val.shape != (ne,):
        raise ValueError(f"plot_error_map: values must be (E,) = ({ne},), got {val.shape}")
    if ne == 0:
        raise ValueError("plot_error_map: the tool has no elements")
    finite = np.isfinite(val)
    fv = np.where(finite, val, -1.0)
    # worst first; ties by element number; never a NaN
    order = np.lexsort((np.arange(ne), -fv))
    # the worst: the n_worst largest, of those within a factor LABEL_FLOOR of the largest (no
    # label on round-off in flat elements; none at or below ``negligible``)
    labelled = (fv >= LABEL_FLOOR * fv.max()) & (fv > negligible)
    worst = order[: min(n_worst, int(labelled.sum()))]
    # round-off (at or below ``negligible``) does not stretch the scale: it shows as 0
    top = max(float(fv.max()), tolerance or 0.0, negligible)
    top = top if top > 0 else 1.0  # an error-free tool: the scale 0..1, every element at 0
    norm = colors.Normalize(0.0, top)
    cmap = colormaps["plasma"]

    all_el = np.arange(ne)
    corners, cornn, cnorm = _outlines(nagata, all_el, 1)
    size = np.linalg.norm(corners - corners.mean(axis=1, keepdims=True), axis=2).max(axis=1) * 2
    area = _area(corners)
    # curvature weight: the turning of the normal over the element (corner normals against
    # the centre normal, radians) times its size ~ area x curvature; flat elements weigh 0
    turn = np.arccos(np.clip(np.einsum("ekj,ej->ek", cornn, cnorm), -1, 1)).max(axis=1)
    curved = turn * size
    worst_normal = cnorm[worst[0]] if len(worst) else None
    whole_view = view_direction(cnorm, curved if np.any(curved > 1e-9 * size.max()) else area, must_see=worst_normal)

    if len(worst):
        centre = corners.mean(axis=1)
        w0 = worst[0]
        radius = 8.0 * size[w0]
        close = np.flatnonzero(np.linalg.norm(centre - centre[w0], axis=1) <= radius)
        # weighted by the error alone, not by area: a sliver with the largest error counts
        ew = np.where(finite[close], val[close], 0.0)
        close_view = view_direction(cnorm[close], ew if np.any(ew > 0) else area[close], must_see=worst_normal)
    else:  # nothing labelled: the close-up shows the whole tool
        close = all_el
        close_view = whole_view
        radius = np.inf

    fig = Figure(figsize=figsize, dpi=dpi)  # fixed margins: a constrained layout costs a second per picture
    FigureCanvasAgg(fig)
    gs = fig.add_gridspec(2, 5, width_ratios=[1, 0.24, 1, 0.3, 0.04], height_ratios=[1, 0.16], left=0.02,
                          right=0.94, bottom=0.02, top=0.92, wspace=0.05, hspace=0.08)
    ax_whole, ax_close = fig.add_subplot(gs[0, 0]), fig.add_subplot(gs[0, 2])  # columns 1, 3: their labels
    for ax, elems, d, m, name in ((ax_whole, all_el, whole_view, 1, "whole tool"),
                                  (ax_close, close, close_view, EDGE_SAMPLES, "around the largest error")):
        pts = corners[elems] if m == 1 else _outlines(nagata, elems, m)[0]
        right, up = _screen_axes(d)
        xy = np.stack([pts @ right, pts @ up], axis=-1)  # (n, k, 2)
        depth = (pts @ d).mean(axis=1)
        back = np.argsort(depth, kind="stable")  # far first: the nearer elements are drawn over them
        rgba = cmap(norm(np.where(finite[elems], val[elems], 0.0)))
        rgba[~finite[elems]] = (0.8, 0.8, 0.8, 1.0)
        # light from the viewer, a little from the upper left: the shape reads without
        # changing the hue much (brightness 0.7..1)
        light = d + 0.5 * up - 0.3 * right
        shade = 0.7 + 0.3 * np.abs(cnorm[elems] @ (light / np.linalg.norm(light)))
        rgba[:, :3] *= shade[:, None]
        edge = "face" if m == 1 else (0.15, 0.15, 0.15, 0.6)
        ax.add_collection(PolyCollection(xy[back], facecolors=rgba[back], edgecolors=edge,
                                         linewidths=0.3 if m == 1 else 0.4, antialiased=m != 1),
                          autolim=False)  # the limits are set below: no extents of 86 000 paths
        lo, hi = xy.reshape(-1, 2).min(axis=0), xy.reshape(-1, 2).max(axis=0)
        if m != 1 and np.isfinite(radius):  # the close-up: a square around the worst element
            c = np.array([centre[worst[0]] @ right, centre[worst[0]] @ up])
            lo, hi = np.maximum(lo, c - 0.7 * radius), np.minimum(hi, c + 0.7 * radius)  # inside the selection
        pad = 0.04 * float(max(hi - lo)) + 1e-12
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        _triad(ax, right, up)
        _scale_bar(ax, float(max(hi - lo)), length_unit)
        wpts = _outlines(nagata, worst, EDGE_SAMPLES)[0]
        wxy = np.stack([wpts @ right, wpts @ up], axis=-1)
        wc = wxy.mean(axis=1)
        # labelled in this view: in its elements and inside its limits (the close-up's crop)
        shown = np.flatnonzero(np.isin(worst, elems) & np.all((wc >= lo) & (wc <= hi), axis=1))
        if len(shown):
            wxy, wc = wxy[shown], wc[shown]
            ax.add_collection(PolyCollection(wxy, facecolors="none", edgecolors="red", linewidths=1.6), autolim=False)
            if m == 1:  # on a die an element is a few pixels: a ring around it as well
                ax.scatter(wc[:, 0], wc[:, 1], s=160, facecolors="none", edgecolors="red", linewidths=1.4)
            for i, y in zip(*_label_heights((wc[:, 1] - lo[1] + pad) / (hi[1] - lo[1] + 2 * pad))):
                e = worst[shown[i]]
                ax.annotate(f"{e + 1}: {val[e]:.3g} {unit}".rstrip(), wc[i], xytext=(1.03, y),
                            textcoords="axes fraction", fontsize=9, color="red", fontweight="bold", va="center",
                            annotation_clip=False, bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="red", lw=0.5),
                            arrowprops=dict(arrowstyle="-", color="red", lw=0.7, shrinkA=0, shrinkB=0))
        ax.set_title(f"{name} (view from {d[0]:+.2f}, {d[1]:+.2f}, {d[2]:+.2f})", fontsize=10)

    cax = fig.add_subplot(gs[0, 4])
    from matplotlib import cm

    cb = fig.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), cax=cax, label=label)
    if tolerance:
        cb.ax.axhline(tolerance, color="r", linewidth=2)
        cb.ax.text(-0.3, tolerance / top, "tolerance", color="r", transform=cb.ax.transAxes, va="center",
                   ha="right", fontsize=8, rotation=90)
    tax = fig.add_subplot(gs[1, :])
    tax.axis("off")
    rows = [f"element {e + 1}: {val[e]:.4g} {unit} at ({c[0]:.5g}, {c[1]:.5g}, {c[2]:.5g})"
            for e, c in zip(worst, corners[worst].mean(axis=1))]
    if not finite.any():
        rows = ["no element has a measured error"]
    elif not rows:
        floor = f" (not above {negligible:.3g} {unit}: round-off)" if negligible > 0 else ""
        rows = [f"largest error {fv.max():.4g} {unit}{floor}: no element labelled"]
    notes = ["largest errors, worst first (red; element numbers as in the tool file, 1-based; the VTU's "
             "'element' is this - 1):"] + ["    ".join(rows[i:i + 3]) for i in range(0, len(rows), 3)]
    if (~finite).any():
        notes.append(f"{int((~finite).sum())} elements without a measured error (grey)")
    tax.text(0.0, 1.0, "\n".join(notes), va="top", ha="left", fontsize=9, transform=tax.transAxes)
    fig.suptitle(title)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=fig.dpi)
    return ErrorMap(worst=worst, values=val[worst], whole_view=whole_view, close_view=close_view,
                    close_elements=close, unmeasured=int((~finite).sum()), seconds=time.perf_counter() - t0)


def _label_heights(y: np.ndarray, gap: float = 0.06) -> tuple[np.ndarray, np.ndarray]:
    """Heights (axes fraction) of labels in a column beside the view: each at its element's
    height ``y`` (K,), pushed apart to ``gap`` from the top down and kept inside [gap/2, 1 -
    gap/2]. Returns (order (K,), heights (K,)), the labels top first: leaders do not cross."""
    order = np.argsort(-y, kind="stable")
    h = np.minimum(y[order], 1 - gap / 2)
    for k in range(1, len(h)):  # K <= n_worst labels
        h[k] = min(h[k], h[k - 1] - gap)
    shift = max(0.0, gap / 2 - float(h[-1])) if len(h) else 0.0
    for k in range(len(h) - 1, -1, -1):  # the bottom one inside: lift the column as needed
        h[k] = h[k] + shift if k == len(h) - 1 else max(h[k], h[k + 1] + gap)
    return order, h


_HALO = dict(boxstyle="square,pad=0.1", fc="white", ec="none", alpha=0.8)


def _triad(ax, right: np.ndarray, up: np.ndarray) -> None:
    """The x, y, z axes as seen in the view, in the lower left corner."""
    o = np.array([0.07, 0.08])
    for k, name in enumerate("xyz"):
        e = np.zeros(3)
        e[k] = 1.0
        v = np.array([e @ right, e @ up]) * 0.05
        if np.linalg.norm(v) < 1e-3:
            ax.text(*(o - [0.03, 0.0]), name, transform=ax.transAxes, fontsize=8, ha="center", va="center",
                    bbox=_HALO)  # along the view: beside the origin
            continue
        for colour, lw in (("white", 3.0), ("k", 1.0)):  # a white halo: readable over dark elements
            ax.annotate("", xy=o + v, xytext=o, xycoords="axes fraction",
                        arrowprops=dict(arrowstyle="->", lw=lw, color=colour))
        ax.text(*(o + 1.35 * v), name, transform=ax.transAxes, fontsize=8, ha="center", va="center", bbox=_HALO)


def _scale_bar(ax, extent: float, unit: str) -> None:
    """A bar of a round length (about a fifth of the view) in the lower right corner."""
    target = extent / 5
    if not target > 0:
        return
    p = 10 ** np.floor(np.log10(target))
    length = max(s * p for s in (1, 2, 5) if s * p <= target)
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    xe, ye = x1 - 0.04 * (x1 - x0), y0 + 0.04 * (y1 - y0)
    ax.plot([xe - length, xe], [ye, ye], color="white", lw=5)
    ax.plot([xe - length, xe], [ye, ye], color="k", lw=2)
    ax.text(xe - length / 2, ye + 0.015 * (y1 - y0), f"{length:g} {unit}".rstrip(), ha="center", va="bottom",
            fontsize=8, bbox=_HALO)
