"""Outputs of a mapped field (Hawkins 1989, §3.5: bands as coloured trimmed surfaces).

- `write_cad_vtu`: the exact CAD under the mesh, each parameter sub-triangle refined (one
  division count per face) until its chords deviate from the surface by at most
  ``chord_tol``, points on S(u, v), with the field interpolated, the band and the face;
- `write_lines_vtu`: the contour polylines (points, level, face, u, v);
- `write_csv`: bands.csv (band, level range, area, colour, IGES name), band_faces.csv (one
  row per IGES band face) and lines.csv;
- `write_bands_iges`: one trimmed surface (144 over a 128 that is the face's surface as it
  is, 142 loops of 126 degree-1 curves in (u, v)) per band, face and connected region, one
  314 colour per level range and the level range in its 406 name (`cadbridge.iges.writer`);
- `write_png`: the CAD shaded by band with the contour lines on top.

Every file is written atomically (`cadbridge.common.atomic`).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from cadbridge.common.atomic import atomic_path, atomic_write
from cadbridge.cad.model import Face, Trim, TrimLoop
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.results.bands import band_index
from cadbridge.results.borders import loop_curves

__all__ = ["band_colors", "band_faces", "tessellate", "write_all", "write_bands_iges", "write_cad_vtu", "write_csv",
           "write_lines_vtu", "write_png"]


def band_colors(n_levels: int) -> np.ndarray:
    """RGB in 0..1 per band (L + 1, 3): the interior bands along matplotlib's 'turbo' map,
    below the range dark grey, above it light grey; all distinct."""
    from matplotlib import colormaps

    L = n_levels
    out = np.empty((L + 1, 3))
    inner = max(L - 1, 1)
    cmap = colormaps["turbo"]
    for i in range(1, L):
        out[i] = cmap(0.08 + 0.84 * (i - 0.5) / inner)[:3]
    out[0] = (0.30, 0.30, 0.32)
    out[L] = (0.82, 0.82, 0.80)
    return np.round(out, 4)  # four decimals survive IGES percent values exactly


def _hex(rgb) -> str:
    return "#" + "".join(f"{int(round(255 * c)):02x}" for c in rgb)


def _fmt(x: float) -> str:
    x = float(x)
    if np.isnan(x):
        raise ValueError("NaN reached an output")
    return repr(x) if np.isfinite(x) else ("inf" if x > 0 else "-inf")


def tessellate(mapping, chord_tol: float, max_div: int = 8, max_points: int = 2_000_000):
    """Refine every sub-triangle m x m (m per face, from the chord deviation at the edge
    midpoints: m = ceil(sqrt(dev / chord_tol)), at most ``max_div``; fewer if the total would
    exceed ``max_points``). Returns points (M, 3), triangles (K, 3), field (M,), face (M,),
    u (M,), v (M,)."""
    m = mapping
    model = m.model
    F = len(model.faces)
    uv = m.tri_uv
    mids = 0.5 * (uv + np.roll(uv, -1, axis=1))  # (T, 3, 2) edge midpoints
    dev = np.zeros(len(uv))
    for f in np.unique(m.tri_face):
        sel = np.flatnonzero(m.tri_face == f)
        s = model.faces[int(f)].surface
        pv = s.evaluate(uv[sel].reshape(-1, 2)[:, 0], uv[sel].reshape(-1, 2)[:, 1]).reshape(-1, 3, 3)
        pm = s.evaluate(mids[sel].reshape(-1, 2)[:, 0], mids[sel].reshape(-1, 2)[:, 1]).reshape(-1, 3, 3)
        chord = 0.5 * (pv + np.roll(pv, -1, axis=1))
        dev[sel] = np.linalg.norm(pm - chord, axis=2).max(axis=1)
    arcs = m.arcs
    if arcs is not None and len(arcs):  # curved-trim borders: their sagitta counts too
        mid = arcs.arc(np.arange(len(arcs)), np.full(len(arcs), 0.5))[:, 0]
        sag = np.linalg.norm(mid - 0.5 * (arcs.a + arcs.b), axis=1)
        for f in np.unique(arcs.face):
            s = model.faces[int(f)].surface
            b = s.bbox()
            u0, u1, v0, v1 = s.domain
            scale = float(np.linalg.norm(b[1] - b[0])) / max(float(np.hypot(u1 - u0, v1 - v0)), 1e-300)
            sel = arcs.face == f
            dev[arcs.tri[sel]] = np.maximum(dev[arcs.tri[sel]], sag[sel] * scale)  # (u, v) -> model units, roughly
    div = np.ones(F, dtype=np.int64)
    for f in np.unique(m.tri_face):
        d = dev[m.tri_face == f].max()
        div[f] = int(np.clip(np.ceil(np.sqrt(d / max(chord_tol, 1e-300))), 1, max_div))
    counts = np.bincount(m.tri_face, minlength=F)
    while np.sum(counts * (div + 1) * (div + 2) // 2) > max_points and div.max() > 1:
        div[div == div.max()] -= 1
    pts_all, tri_all, f_all, face_all, u_all, v_all = [], [], [], [], [], []
    base = 0
    for f in np.unique(m.tri_face):
        n = int(div[f])
        sel = np.flatnonzero(m.tri_face == f)
        # barycentric lattice of order n and its small triangles
        ij = [(i, j) for i in range(n + 1) for j in range(n + 1 - i)]
        index = {p: k for k, p in enumerate(ij)}
        bary = np.array([[1 - (i + j) / n, i / n, j / n] for i, j in ij]) if n > 0 else np.array([[1.0, 0, 0]])
        small = []
        for i in range(n):
            for j in range(n - i):
                small.append((index[(i, j)], index[(i + 1, j)], index[(i, j + 1)]))
                if i + j < n - 1:
                    small.append((index[(i + 1, j)], index[(i + 1, j + 1)], index[(i, j + 1)]))
        small = np.array(small, dtype=np.int64)
        q = len(bary)
        puv = np.einsum("qk,tkd->tqd", bary, uv[sel])  # (t, q, 2)
        _bend_to_arcs(m, f, sel, bary, puv)
        puv = puv.reshape(-1, 2)
        pf = np.einsum("qk,tk->tq", bary, m.tri_f[sel]).reshape(-1)
        s = model.faces[int(f)].surface
        u0, u1, v0, v1 = s.domain
        puv[:, 0] = np.clip(puv[:, 0], u0, u1)
        puv[:, 1] = np.clip(puv[:, 1], v0, v1)
        pts_all.append(s.evaluate(puv[:, 0], puv[:, 1]))
        tri_all.append((small[None, :, :] + (base + q * np.arange(len(sel)))[:, None, None]).reshape(-1, 3))
        f_all.append(pf)
        face_all.append(np.full(len(pf), f, dtype=np.int64))
        u_all.append(puv[:, 0])
        v_all.append(puv[:, 1])
        base += q * len(sel)
    return (np.concatenate(pts_all), np.concatenate(tri_all), np.concatenate(f_all), np.concatenate(face_all),
            np.concatenate(u_all), np.concatenate(v_all))


def _bend_to_arcs(m, face: int, sel: np.ndarray, bary: np.ndarray, puv: np.ndarray) -> None:
    """In place: lattice points (t, q, 2) of sub-triangles ``sel`` whose edge is a border chord
    on a curved trim curve follow the curve (linear blending from the opposite vertex:
    uv += (l_j + l_j+1) (c(tau(s)) - chord(s)), s = l_j+1 / (l_j + l_j+1)), so the
    tessellation ends at the exact trim curve."""
    arcs = m.arcs
    if arcs is None or not len(arcs):
        return
    ks = np.flatnonzero(arcs.face == face)
    if not len(ks):
        return
    pos = np.full(len(m.tri_face), -1)
    pos[sel] = np.arange(len(sel))
    for k in ks:
        r = pos[arcs.tri[k]]
        if r < 0:
            continue
        j = int(arcs.edge[k])
        lj, lk = bary[:, j], bary[:, (j + 1) % 3]
        w = lj + lk
        t = np.where(w > 0, lk / np.where(w > 0, w, 1.0), 0.0)
        chord = arcs.a[k] + t[:, None] * (arcs.b[k] - arcs.a[k])
        puv[r] += w[:, None] * (arcs.arc(np.full(len(t), k), t)[:, 0] - chord)


def write_cad_vtu(path, contours, chord_tol: float) -> int:
    """The CAD tessellation (`tessellate`) with the field, band and face as point data; the
    band of each triangle (at its centroid) as cell data. Returns the number of points."""
    from cadbridge.io.vtu import write_surface_vtu

    m = contours.mapping
    pts, tri, f, face, u, v = tessellate(m, chord_tol)
    fc = f[tri].mean(axis=1)
    write_surface_vtu(path, pts, tri,
                      point_data={m.field_name: f, "band": band_index(f, contours.levels), "face_id": face, "u": u, "v": v},
                      cell_data={"band": band_index(fc, contours.levels)})
    return len(pts)


def write_lines_vtu(path, contours) -> None:
    """Contour polylines as VTK line cells, point data level / face / u / v, cell data level."""
    import meshio

    L = contours.lines
    n = len(L)
    segs = []
    seg_line = []
    for i in range(n):
        a, b = int(L.offsets[i]), int(L.offsets[i + 1])
        idx = np.arange(a, b)
        if len(idx) >= 2:
            segs.append(np.column_stack([idx[:-1], idx[1:]]))
            seg_line.append(np.full(len(idx) - 1, i))
    seg = np.concatenate(segs) if segs else np.zeros((0, 2), dtype=np.int64)
    sl = np.concatenate(seg_line) if seg_line else np.zeros(0, dtype=np.int64)
    lev_pt = L.levels[np.repeat(L.level, np.diff(L.offsets))] if n else np.zeros(0)
    pts = L.points if len(L.points) else np.zeros((1, 3))
    if not len(L.points):
        lev_pt = np.zeros(1)
    mesh = meshio.Mesh(pts, [("line", seg.astype(np.int64))],
                       point_data={"level": lev_pt,
                                   "face_id": L.face if len(L.points) else np.zeros(1, dtype=np.int64),
                                   "u": L.u if len(L.points) else np.zeros(1),
                                   "v": L.v if len(L.points) else np.zeros(1)},
                       cell_data={"line": [sl.astype(np.int64)], "level": [L.levels[L.level[sl]] if len(sl) else np.zeros(0)]})
    for a in (pts, lev_pt):
        if not np.all(np.isfinite(a)):
            raise ValueError("non-finite value in the contour lines")
    with atomic_path(path) as tmp:
        meshio.write(tmp, mesh, file_format="vtu", binary=True, compression="zlib")


def band_faces(contours) -> list[tuple[Face, dict]]:
    """The IGES band faces: one trimmed `Face` per band, face and connected region, over the
    face's surface as it is, with its colour and name; and a CSV row for each."""
    m = contours.mapping
    bands = contours.bands
    colors = band_colors(len(contours.levels))
    out = []
    regions = bands.regions()
    per = {}
    for r in regions:
        per.setdefault((r.band, r.face), []).append(r)
    k = 0
    for (b, f), regs in sorted(per.items()):
        src = m.model.faces[f]
        for j, r in enumerate(regs):
            name = f"{m.field_name} {bands.label(b)}"
            rgb = tuple(float(c) for c in colors[b])
            u0, u1, v0, v1 = src.surface.domain
            diag = float(np.hypot(u1 - u0, v1 - v0))
            trims = Trim(TrimLoop(loop_curves(r.outer, f, m.arcs, diag)),
                         [TrimLoop(loop_curves(h, f, m.arcs, diag)) for h in r.holes])
            face = Face(src.surface, de=0, name=name, color=rgb, trims=trims)
            out.append((face, {"iges_face": k, "band": b, "face": f, "face_name": src.name or "", "region": j,
                               "lower": bands.lower[b], "upper": bands.upper[b], "name": name, "color": _hex(rgb),
                               "r": rgb[0], "g": rgb[1], "b": rgb[2], "area": r.area}))
            k += 1
    return out


def _polyline(loop: np.ndarray) -> NurbsCurve:
    """Closed (u, v) polygon as a degree-1 NURBS curve (first point repeated at the end)."""
    pts = np.vstack([loop, loop[:1]])
    n = len(pts)
    knots = np.concatenate([[0.0], np.arange(n, dtype=float), [n - 1.0]])
    return NurbsCurve(1, knots, pts)


def write_bands_iges(path, contours) -> list[dict]:
    """The bands as IGES trimmed surfaces (see the module text); returns the CSV rows."""
    from cadbridge.iges.writer import write_iges

    faces = band_faces(contours)
    m = contours.mapping
    labels = [(f"BAND{row['band']}"[:8], row["iges_face"] % 100000000) for _, row in faces]
    write_iges([f for f, _ in faces], path, units=m.model.units, labels=labels,
               description=f"cadbridge map: {m.field_name} bands ({len(faces)} trimmed surfaces over the original surfaces)")
    return [row for _, row in faces]


def write_csv(folder: Path, contours, rows: list[dict] | None = None) -> list[str]:
    """bands.csv, band_faces.csv (when ``rows`` from the IGES export are given), lines.csv."""
    m = contours.mapping
    bands = contours.bands
    colors = band_colors(len(contours.levels))
    files = []
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["band", "lower", "upper", "range", "area", "faces", "color", "r", "g", "b", "iges_name"])
    for b in range(len(bands.area)):
        if not bands.present[b]:
            continue
        faces = np.flatnonzero(bands.face_area[b] > 0)
        w.writerow([b, _fmt(bands.lower[b]), _fmt(bands.upper[b]), bands.label(b), _fmt(bands.area[b]),
                    " ".join(map(str, faces.tolist())), _hex(colors[b]), *(repr(float(c)) for c in colors[b]),
                    f"{m.field_name} {bands.label(b)}"])
    with atomic_write(folder / "bands.csv") as fh:
        fh.write(f"# field {m.field_name} ({m.source}); areas on the exact CAD, model units^2\n" + buf.getvalue())
    files.append("bands.csv")
    if rows is not None:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["iges_face", "band", "face", "face_name", "region", "lower", "upper", "area", "name", "color", "r", "g", "b"])
        for row in rows:
            a = row["area"]
            w.writerow([row["iges_face"], row["band"], row["face"], row["face_name"], row["region"], _fmt(row["lower"]),
                        _fmt(row["upper"]), _fmt(a), row["name"], row["color"], repr(row["r"]), repr(row["g"]), repr(row["b"])])
        with atomic_write(folder / "band_faces.csv") as fh:
            fh.write(buf.getvalue())
        files.append("band_faces.csv")
    L = contours.lines
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["line", "level", "closed", "points", "length", "faces"])
    lengths = L.lengths() if len(L) else np.zeros(0)
    for i in range(len(L)):
        a, b = L.offsets[i], L.offsets[i + 1]
        w.writerow([i, _fmt(L.levels[L.level[i]]), int(L.closed[i]), int(b - a), _fmt(lengths[i]),
                    " ".join(map(str, np.unique(L.face[a:b]).tolist()))])
    with atomic_write(folder / "lines.csv") as fh:
        fh.write(buf.getvalue())
    files.append("lines.csv")
    return files


def write_png(path, contours, *, title: str | None = None, elev: float = 28.0, azim: float = -58.0,
              box=None, max_triangles: int = 60_000) -> None:
    """The CAD shaded by band (Lambert shading), the contour lines on top, a colour bar of the
    levels. Band pieces are drawn as they are clipped, so band borders are crisp. ``box``
    ((2, 3) [min, max], model units) shows only that part (e.g. a die radius); elev / azim
    (degrees) set the view."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import BoundaryNorm, ListedColormap
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    m = contours.mapping
    bands = contours.bands
    colors = band_colors(len(contours.levels))
    model = m.model
    # polygons: whole sub-triangles and clipped pieces, one division each way for curvature
    sel = np.flatnonzero(bands.whole >= 0)
    polys_uv = [m.tri_uv[sel]]
    pband = [bands.whole[sel]]
    pface = [m.tri_face[sel]]
    for j in range(1, 4):
        r = np.flatnonzero(bands.pieces_count > j + 1)
        if len(r):
            pp = bands.pieces_poly[r]
            polys_uv.append(np.stack([pp[:, 0, :2], pp[:, j, :2], pp[:, j + 1, :2]], axis=1))
            pband.append(bands.pieces_band[r])
            pface.append(bands.pieces_face[r])
    tuv = np.concatenate(polys_uv)
    tb = np.concatenate(pband)
    tf = np.concatenate(pface)
    if len(tuv) * 4 <= max_triangles:  # split each at its edge midpoints: follows curvature
        mid = 0.5 * (tuv + np.roll(tuv, -1, axis=1))
        a, b, c = tuv[:, 0], tuv[:, 1], tuv[:, 2]
        mab, mbc, mca = mid[:, 0], mid[:, 1], mid[:, 2]
        tuv = np.concatenate([np.stack(x, 1) for x in ((a, mab, mca), (mab, b, mbc), (mca, mbc, c), (mab, mbc, mca))])
        tb, tf = np.tile(tb, 4), np.tile(tf, 4)
    def on_surface(tuv, tf):
        xyz = np.empty((len(tuv), 3, 3))
        for f in np.unique(tf):
            s = np.flatnonzero(tf == f)
            surf = model.faces[int(f)].surface
            u0, u1, v0, v1 = surf.domain
            q = tuv[s].reshape(-1, 2)
            xyz[s] = surf.evaluate(np.clip(q[:, 0], u0, u1), np.clip(q[:, 1], v0, v1)).reshape(-1, 3, 3)
        return xyz

    xyz = on_surface(tuv, tf)
    if box is not None:  # split triangles reaching into the box until they are small against it
        box = np.asarray(box, dtype=float).reshape(2, 3)
        h = float(np.linalg.norm(box[1] - box[0])) / 40.0
        for _ in range(8):
            lo_t, hi_t = xyz.min(axis=1), xyz.max(axis=1)
            meets = np.all((hi_t >= box[0]) & (lo_t <= box[1]), axis=1)
            size = np.linalg.norm(hi_t - lo_t, axis=1)
            big = meets & (size > h)
            if not big.any() or len(tuv) + 3 * big.sum() > 4 * max_triangles:
                break
            t = tuv[big]
            mid = 0.5 * (t + np.roll(t, -1, axis=1))
            a, b, c = t[:, 0], t[:, 1], t[:, 2]
            mab, mbc, mca = mid[:, 0], mid[:, 1], mid[:, 2]
            new = np.concatenate([np.stack(x, 1) for x in ((a, mab, mca), (mab, b, mbc), (mca, mbc, c), (mab, mbc, mca))])
            keep = meets & ~big
            tuv = np.concatenate([tuv[keep], new])
            tb = np.concatenate([tb[keep], np.tile(tb[big], 4)])
            tf = np.concatenate([tf[keep], np.tile(tf[big], 4)])
            xyz = np.concatenate([xyz[keep], on_surface(new, tf[keep.sum():])])
    segs = []
    L = contours.lines
    if box is not None:
        box = np.asarray(box, dtype=float).reshape(2, 3)
    for i in range(len(L)):
        p = L.points[L.offsets[i] : L.offsets[i + 1]]
        if box is not None:  # runs of points inside the box
            inside = np.all((p >= box[0]) & (p <= box[1]), axis=1)
            cuts = np.flatnonzero(np.diff(inside.astype(np.int8))) + 1
            segs += [q for q, ok in zip(np.split(p, cuts), np.split(inside, cuts)) if ok[0] and len(q) >= 2]
        elif len(p) >= 2:
            segs.append(p)
    n = np.cross(xyz[:, 1] - xyz[:, 0], xyz[:, 2] - xyz[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    polys: list[np.ndarray] | np.ndarray = xyz
    if box is not None:
        inside = np.all((xyz >= box[0]) & (xyz <= box[1]), axis=2)  # (T, 3) corners
        full = inside.all(axis=1)
        lo_t, hi_t = xyz.min(axis=1), xyz.max(axis=1)
        part = ~full & np.all((hi_t >= box[0]) & (lo_t <= box[1]), axis=1)
        polys = list(xyz[full])
        keep = [np.flatnonzero(full)]
        for i in np.flatnonzero(part):  # the few triangles on the box's faces: clipped flat
            q = _clip_box(xyz[i], box)
            if len(q) >= 3:
                polys.append(q)
                keep.append(np.array([i]))
        keep = np.concatenate(keep)
        if not len(keep):
            raise ValueError(f"nothing of the CAD lies in the view box {box.tolist()}")
        tb, n = tb[keep], n[keep]
        xyz = np.concatenate([np.asarray(p) for p in polys])[None]
    el, az = np.radians(elev), np.radians(azim)
    view = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    light = view + np.array([0.0, 0.0, 0.6])
    light /= np.linalg.norm(light)
    shade = 0.45 + 0.55 * np.abs(n @ light)
    fc = np.clip(colors[tb] * shade[:, None], 0, 1)

    fig = Figure(figsize=(10, 6.5), dpi=120, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(projection="3d")
    ax.computed_zorder = False  # lines over the surface (matplotlib's depth sort is per collection)
    ax.add_collection3d(Poly3DCollection(polys, facecolors=fc, edgecolors=fc, linewidths=0.25, zorder=1))
    if segs:
        ax.add_collection3d(Line3DCollection(segs, colors="k", linewidths=0.7, zorder=2))
    lo, hi = xyz.reshape(-1, 3).min(axis=0), xyz.reshape(-1, 3).max(axis=0)
    ctr, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(np.maximum(2 * half, 1e-3 * max(2 * half.max(), 1e-300)))
    del ctr
    ax.view_init(elev=elev, azim=azim)
    from matplotlib.ticker import MaxNLocator

    for axis, name in ((ax.xaxis, "x"), (ax.yaxis, "y"), (ax.zaxis, "z")):
        axis.set_major_locator(MaxNLocator(4))
        axis.pane.set_alpha(0.15)
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    present = np.flatnonzero(bands.present)
    inner = [b for b in present if 1 <= b <= len(contours.levels) - 1]
    if inner:
        lv = contours.levels
        cmap = ListedColormap(colors[1 : len(lv)])
        norm = BoundaryNorm(lv, cmap.N)
        from matplotlib.cm import ScalarMappable

        cb = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.7, pad=0.02,
                          ticks=lv if len(lv) <= 12 else None)
        cb.set_label(m.field_name)
    ax.set_title(title or f"{m.field_name} on the exact CAD: {int(bands.present.sum())} bands, {len(L)} contour lines",
                 fontsize="medium")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=fig.dpi)


def _clip_box(poly: np.ndarray, box: np.ndarray) -> np.ndarray:
    """A flat polygon (k, 3) clipped to an axis-aligned box (Sutherland-Hodgman, 6 planes)."""
    p = poly
    for axis in range(3):
        for bound, keep_below in ((box[1, axis], True), (box[0, axis], False)):
            if not len(p):
                return p
            out = []
            for a, b in zip(p, np.roll(p, -1, axis=0)):
                ina = a[axis] <= bound if keep_below else a[axis] >= bound
                inb = b[axis] <= bound if keep_below else b[axis] >= bound
                if ina:
                    out.append(a)
                if ina != inb:
                    t = (bound - a[axis]) / (b[axis] - a[axis])
                    out.append(a + t * (b - a))
            p = np.array(out).reshape(-1, 3)
    return p


def write_all(folder: Path, contours, *, chord_tol: float, stem: str = "result", png: bool = True,
              png_options: dict | None = None) -> list[str]:
    """All outputs into ``folder`` (which exists): {stem}_cad.vtu, {stem}_lines.vtu,
    {stem}_bands.igs, bands.csv, band_faces.csv, lines.csv, {stem}.png. Returns the names."""
    folder = Path(folder)
    files = []
    write_cad_vtu(folder / f"{stem}_cad.vtu", contours, chord_tol)
    files.append(f"{stem}_cad.vtu")
    write_lines_vtu(folder / f"{stem}_lines.vtu", contours)
    files.append(f"{stem}_lines.vtu")
    rows = write_bands_iges(folder / f"{stem}_bands.igs", contours)
    files.append(f"{stem}_bands.igs")
    files += write_csv(folder, contours, rows)
    if png:
        write_png(folder / f"{stem}.png", contours, **(png_options or {}))
        files.append(f"{stem}.png")
    return files

