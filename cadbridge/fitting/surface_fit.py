"""Fitting a NURBS surface to measured or computed points: input, base parametrisation, outline,
report (above `model.py`: it reads tool files and CAD models; the math is `cadbridge.nurbs.fit`).

Pipeline (`fit_points`): read points (`read_points`: XYZ/CSV text, STL/PLY/OBJ and any meshio
mesh, a cadbridge tool file's nodes or samples on its Nagata patches) -> parameters by projection
onto a base surface (`plane_base`: best-fit plane for height fields; `face_base`: a CAD face, or
several faces joined along common edges into one strip (`join_strip`); `coons_surface`: the
bilinearly blended Coons patch of four boundary curves) -> `fit_surface` -> the fitted `Face`,
optionally trimmed by the outline of the data (`data_outline`) -> report and deviation map.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cadbridge.cad.model import Face, Model, Trim, TrimLoop
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.fit import FitError, SurfaceFit, fit_surface
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["FitInputError", "FitReport", "coons_surface", "data_outline", "face_base", "fit_points",
           "join_strip", "plane_base", "read_points", "write_fit_outputs"]

TEXT_SUFFIXES = {".xyz", ".csv", ".txt", ".asc", ".pts", ".dat"}
TOOL_SUFFIXES = {".nagata", ".tool"}


class FitInputError(FitError):
    """Points or a base that cannot be used (one line: file and reason)."""


# ---------------------------------------------------------------------------- input
def _read_text_fast(path: Path) -> np.ndarray | None:
    """numpy's compiled text reader for the plain case (one separator, at most a header line,
    comments): 5x faster than `_read_text` on a million lines. None when the file needs the
    line-by-line reader (which also names a bad line)."""
    with open(path, encoding="utf-8", errors="replace") as fh:
        head = [fh.readline() for _ in range(64)]
    k = 0
    while k < len(head) and (not head[k].strip() or head[k].strip()[0] in "#%/!"):
        k += 1
    if k == len(head):
        return None
    first = head[k]
    delim = "," if "," in first else (";" if ";" in first else None)
    parts = first.strip().split(delim) if delim else first.split()
    try:
        [float(t) for t in parts[:3]]
        skip = k
    except ValueError:
        skip = k + 1  # a header line
    if any(c in line for line in head for c in ",;" if c != delim):
        return None  # mixed separators
    try:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data": handled below
            data = np.loadtxt(path, delimiter=delim, comments=["#", "%", "//", "!"], skiprows=skip, usecols=(0, 1, 2),
                              ndmin=2, encoding="utf-8")
    except (ValueError, IndexError, UnicodeError):
        return None
    return data if len(data) else None


def _read_text(path: Path) -> np.ndarray:
    fast = _read_text_fast(path)
    if fast is not None:
        return fast
    rows = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line_no, line in enumerate(fh, 1):
            s = line.strip()
            if not s or s[0] in "#%/!":
                continue
            parts = s.replace(",", " ").replace(";", " ").replace("\t", " ").split()
            try:
                vals = [float(t) for t in parts[:3]]
            except ValueError:
                if not rows:  # a header line before the data
                    continue
                raise FitInputError(f"{path}: line {line_no}: not three numbers: {s[:60]!r}") from None
            if len(vals) < 3:
                raise FitInputError(f"{path}: line {line_no}: expected x y z, got {len(vals)} values")
            rows.append(vals)
    if not rows:
        raise FitInputError(f"{path}: no points (expected lines of x y z)")
    return np.array(rows, dtype=float)


def _tool_samples(path: Path, per_edge: int) -> np.ndarray:
    from cadbridge.io.toolfile import read_toolfile

    tool = read_toolfile(path)
    if per_edge <= 0:
        return tool.nodes
    nm = tool.nagata_mesh()  # node normals, corner overrides and edge normals (docs/toolfile.md)
    pts = nm.sample_grid(per_edge).points  # patch edges are shared: one point per position
    return np.unique(np.round(pts, 12), axis=0)


def read_points(path, *, nagata_samples: int = 0) -> tuple[np.ndarray, str]:
    """Points (N, 3) from a file, and what they are ("scan", "mesh nodes", "tool nodes", ...).

    XYZ/CSV/TXT: the first three numbers of each line (a header line is skipped; separators
    comma, semicolon, blanks). A cadbridge tool file (.nagata): its nodes, or with
    ``nagata_samples`` = n the points of an n-per-edge grid on each Nagata patch. Anything else
    goes to meshio (STL, PLY, OBJ, VTU, MSH, ...: the vertices). Raises FitInputError.
    """
    p = Path(path)
    if not p.exists():
        raise FitInputError(f"{p}: no such file")
    if p.is_dir():
        raise FitInputError(f"{p}: is a directory, not a points file")
    suffix = p.suffix.lower()
    try:
        if suffix in TEXT_SUFFIXES:
            pts, kind = _read_text(p), "scan"
        elif suffix in TOOL_SUFFIXES:
            pts = _tool_samples(p, nagata_samples)
            kind = "Nagata samples" if nagata_samples > 0 else "tool nodes"
        else:
            import meshio

            import contextlib
            import io

            try:
                with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                    m = meshio.read(p)  # its readers print their own complaints
            except (Exception, SystemExit) as exc:  # meshio raises many types (its PLY reader even exits)
                raise FitInputError(f"{p}: cannot read as a mesh ({type(exc).__name__}: "
                                    f"{str(exc).splitlines()[0] if str(exc) else 'unknown format'})") from None
            pts, kind = np.asarray(m.points, dtype=float), "mesh vertices"
            if pts.ndim != 2 or pts.shape[1] not in (2, 3):
                raise FitInputError(f"{p}: points of shape {pts.shape}")
            if pts.shape[1] == 2:
                pts = np.column_stack([pts, np.zeros(len(pts))])
    except FitInputError:
        raise
    except (OSError, UnicodeError, ValueError) as exc:
        raise FitInputError(f"{p}: cannot read ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})") from None
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        raise FitInputError(f"{p}: {int(bad.sum())} points have NaN or infinite coordinates "
                            f"(first: point {int(np.argmax(bad))}, 0-based)")
    if kind == "mesh vertices":  # facet vertices repeat (STL): one point per position
        pts = np.unique(pts, axis=0)
    return pts, kind


# ---------------------------------------------------------------------------- bases
@dataclass
class Parametrisation:
    """Start parameters of the points on a base: u, v (N,), distance to the base (N,), the base
    surface (None for the plane) and its description."""

    u: np.ndarray
    v: np.ndarray
    distance: np.ndarray
    base: NurbsSurface | None
    what: str


def _principal_axes(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid (3,) and principal axes (3, 3) (rows, largest first) of points (N, 3). Raises
    FitInputError for coincident or collinear points (nothing to span a surface)."""
    c = x.mean(axis=0)
    _, s, vt = np.linalg.svd(x - c, full_matrices=False)
    scale = s[0] if s.size else 0.0
    if not scale > 0:
        raise FitInputError("all points coincide: nothing to fit")
    if len(s) < 2 or s[1] <= 1e-9 * scale:
        raise FitInputError("the points are collinear (they lie on one line): a surface needs points spanning an area")
    return c, vt


def plane_base(points: np.ndarray) -> Parametrisation:
    """Best-fit plane (principal axes): u, v the coordinates along its two largest axes (model
    units, so the parameters are lengths). Raises FitInputError for coincident or collinear
    points (nothing to span a surface)."""
    x = np.asarray(points, dtype=float)
    c, vt = _principal_axes(x)
    d = x - c
    a, b = d @ vt[0], d @ vt[1]
    # in-plane axes along the minimum-area rectangle of the points (rotating calipers over the
    # convex hull's edges): the fit's rectangular domain then wastes least area without data
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = np.column_stack([a, b])[ConvexHull(np.column_stack([a, b])).vertices]
        e = np.diff(np.vstack([hull, hull[:1]]), axis=0)
        ang = np.arctan2(e[:, 1], e[:, 0])
        cs, sn = np.cos(ang), np.sin(ang)
        ra = hull[:, 0][None, :] * cs[:, None] + hull[:, 1][None, :] * sn[:, None]
        rb = -hull[:, 0][None, :] * sn[:, None] + hull[:, 1][None, :] * cs[:, None]
        k = int(np.argmin(np.ptp(ra, axis=1) * np.ptp(rb, axis=1)))
        a, b = a * cs[k] + b * sn[k], -a * sn[k] + b * cs[k]
    except (QhullError, ValueError):
        pass
    return Parametrisation(a, b, np.abs(d @ vt[2]), None, "best-fit plane")


def _edge(s: NurbsSurface, which: str, n: int = 9) -> np.ndarray:
    u0, u1, v0, v1 = s.domain
    t = np.linspace(0.0, 1.0, n)
    if which in ("u0", "u1"):
        return s.evaluate(np.full(n, u0 if which == "u0" else u1), v0 + (v1 - v0) * t)
    return s.evaluate(u0 + (u1 - u0) * t, np.full(n, v0 if which == "v0" else v1))


def _oriented(s: NurbsSurface, swap: bool, rev_u: bool, rev_v: bool) -> NurbsSurface:
    from cadbridge.nurbs.edits import restrict_surface, surface_from_homogeneous
    from cadbridge.nurbs.knots import reverse

    s = restrict_surface(s)
    p, q, ku, kv, cw = s.degree_u, s.degree_v, s.knots_u, s.knots_v, s._pw
    if swap:
        p, q, ku, kv, cw = q, p, kv, ku, np.transpose(cw, (1, 0, 2))
    if rev_u:
        ku, cw = reverse(ku, p, cw, axis=0)
    if rev_v:
        kv, cw = reverse(kv, q, cw, axis=1)
    return surface_from_homogeneous(p, q, ku, kv, cw)


def _as_next(a: NurbsSurface, b: NurbsSurface, tol: float) -> NurbsSurface | None:
    """b turned so that its u0 edge is a's u1 edge, same direction in v; None if no edge is shared."""
    target = _edge(a, "u1")
    for swap in (False, True):
        for rev_u in (False, True):
            for rev_v in (False, True):
                c = _oriented(b, swap, rev_u, rev_v)
                if np.max(np.linalg.norm(_edge(c, "u0") - target, axis=1)) <= tol:
                    return c
    return None


def _u_length(s: NurbsSurface) -> float:
    u0, u1, v0, v1 = s.domain
    t = np.linspace(u0, u1, 65)
    lens = []
    for v in np.linspace(v0, v1, 5):
        pts = s.evaluate(t, np.full_like(t, v))
        lens.append(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
    return float(np.mean(lens))


def join_strip(surfaces: list[NurbsSurface], tol: float | None = None) -> NurbsSurface:
    """One NURBS surface from faces that join edge to edge in a chain (e.g. wall - radius -
    land of a die). Each piece's u runs along the chain over its mean arc length (so parameters
    are lengths), v is shared (the pieces are made compatible in v; their v parametrisations
    must agree along the common edges). The join is C0 in parameter (a knot of multiplicity p),
    the geometry exactly that of the pieces. Raises FitInputError if they do not chain."""
    from cadbridge.nurbs.edits import surface_from_homogeneous
    from cadbridge.nurbs.knots import elevate_degree, merge_knots, refine_knots, reparametrize

    surfs = list(surfaces)
    if len(surfs) == 1:
        return surfs[0]
    size = max(float(np.linalg.norm(np.ptp(s.bbox(), axis=0))) for s in surfs)
    tol = 1e-6 * size if tol is None else tol
    chain = [_oriented(surfs[0], False, False, False)]
    rest = surfs[1:]
    while rest:
        for k, s in enumerate(rest):
            nxt = _as_next(chain[-1], s, tol)
            if nxt is not None:
                chain.append(nxt)
                rest.pop(k)
                break
            # or in front of the chain: reverse the chain's first piece view
            first = _oriented(chain[0], False, True, False)
            prv = _as_next(first, s, tol)
            if prv is not None:
                chain = [_oriented(c, False, True, False) for c in chain[::-1]]
                chain.append(prv)
                rest.pop(k)
                break
        else:
            raise FitInputError(f"the {len(surfaces)} base faces do not join edge to edge in a chain")
    # common degrees
    p = max(c.degree_u for c in chain)
    q = max(c.degree_v for c in chain)
    pieces = []
    start = 0.0
    for c in chain:
        cw = c._pw
        ku, kv = c.knots_u, c.knots_v
        if c.degree_u < p:
            ku, cw = elevate_degree(ku, c.degree_u, cw, p - c.degree_u, axis=0)
        if c.degree_v < q:
            kv, cw = elevate_degree(kv, c.degree_v, cw, q - c.degree_v, axis=1)
        length = _u_length(c)
        ku = reparametrize(ku, (start, start + length))
        start += length
        pieces.append([ku, kv, cw])
    # v: the same range, then the same knots
    v_lo, v_hi = pieces[0][1][0], pieces[0][1][-1]
    for pc in pieces:
        pc[1] = reparametrize(pc[1], (v_lo, v_hi))
    common = merge_knots([pc[1] for pc in pieces])
    for pc in pieces:
        have = list(pc[1])
        missing = []
        for t in common:
            if t in have:
                have.remove(t)
            else:
                missing.append(t)
        if missing:
            pc[1], pc[2] = refine_knots(pc[1], q, pc[2], missing, axis=1)
    # weights: scale each piece so its first row matches the previous piece's last row
    for a, b in zip(pieces, pieces[1:]):
        ratio = a[2][-1, :, 3] / b[2][0, :, 3]
        if np.ptp(ratio) > 1e-9 * ratio.max():
            raise FitInputError("the base faces' weights along a common edge are not proportional: cannot join")
        b[2] = b[2] * ratio[0]
        if np.max(np.abs(a[2][-1] - b[2][0])) > tol * max(1.0, np.abs(a[2][-1]).max()):
            raise FitInputError("the base faces meet, but their v parametrisations along the common edge differ")
    ku = [pieces[0][0][: -(p + 1)]]
    cw = [pieces[0][2]]
    for pc in pieces[1:]:
        ku.append(np.full(p, pc[0][0]))
        ku.append(pc[0][p + 1 : -(p + 1)])
        cw.append(pc[2][1:])
    ku.append(np.full(p + 1, pieces[-1][0][-1]))
    return surface_from_homogeneous(p, q, np.concatenate(ku), pieces[0][1], np.concatenate(cw, axis=0))


def face_base(points: np.ndarray, model: Model, face: int | None = None) -> Parametrisation:
    """Parameters by projection onto a CAD face (``face``), or onto all faces of ``model``
    joined into one strip (`join_strip`). Feet on the base's edge are kept (the fit extends
    over the data; parameter correction moves them onto the fit)."""
    from cadbridge.nurbs.fit import reproject
    from cadbridge.nurbs.project import FAILED, project_to_surface, smooth_pieces, surface_samples

    if not model.faces:
        raise FitInputError("the base CAD has no faces")
    if face is not None:
        if not 0 <= face < len(model.faces):
            raise FitInputError(f"--face {face}: the base CAD has faces 0..{len(model.faces) - 1}")
        base, what = model.faces[face].surface, f"CAD face {face}"
    elif len(model.faces) == 1:
        base, what = model.faces[0].surface, "CAD face"
    else:
        base, what = join_strip([f.surface for f in model.faces]), f"{len(model.faces)} CAD faces joined"
    # Newton from the nearest base sample (one compiled pass, `reproject`); the global
    # local-minimum check (3/4 of the time on a million points) only for the points that came
    # out far from the base or whose Newton did not end on an orthogonal foot
    smp = surface_samples(base)
    if smp.closed_u or smp.closed_v or len(smooth_pieces(base)) > 1:
        # a closed base (full cylinder: Newton must wrap across the seam) or one with crease
        # lines inside (each smooth piece projected onto, the nearest kept): the projection module
        res = project_to_surface(base, points, tol=1e-10, global_check=False)
        u, v, dist, ok = res.u.copy(), res.v.copy(), res.distance.copy(), res.status != FAILED
    else:
        first = np.asarray(smp.tree.query(points, workers=-1)[1]).reshape(len(points))
        u, v, dist, _, ok = reproject(base, points, smp.uv[first, 0], smp.uv[first, 1], tol=1e-10, max_iter=30)
    far = ~(dist <= 10.0 * max(float(np.nanmedian(dist)), 1e-12 * model.size())) | ~ok
    if far.any():
        again = project_to_surface(base, points[far], tol=1e-10)
        take = (again.status != FAILED) & (~ok[far] | ~(again.distance >= dist[far]))
        idx = np.nonzero(far)[0][take]
        u[idx], v[idx], dist[idx] = again.u[take], again.v[take], again.distance[take]
        ok[idx] = True
    bad = ~ok
    if bad.all():
        raise FitInputError("no point could be projected onto the base surface")
    u[bad], v[bad] = np.nanmedian(u[ok]), np.nanmedian(v[ok])
    d = np.where(bad, np.inf, dist)
    return Parametrisation(u, v, d, base, what)


def coons_surface(c_v0: NurbsCurve, c_v1: NurbsCurve, c_u0: NurbsCurve, c_u1: NurbsCurve) -> NurbsSurface:
    """Bilinearly blended Coons patch (Piegl & Tiller §10.5, eq. 10.21) of four polynomial
    boundary curves: c_v0(u), c_v1(u) the edges v = 0, 1 and c_u0(v), c_u1(v) the edges u = 0, 1,
    meeting at the corners. S = R_u + R_v - T (two ruled surfaces minus the bilinear corner
    patch), made compatible and summed on the control net: exact, parameters over [0, 1]^2."""
    from cadbridge.nurbs.edits import elevate_surface, make_compatible, refine_surface

    for c in (c_v0, c_v1, c_u0, c_u1):
        if c.rational:
            raise FitInputError("a Coons base needs polynomial boundary curves (a rational one is not additive)")
    corners = [(c_v0, 0, c_u0, 0), (c_v0, 1, c_u1, 0), (c_v1, 0, c_u0, 1), (c_v1, 1, c_u1, 1)]
    for a, ta, b, tb in corners:
        pa = a.evaluate(np.array([a.domain[ta]]))[0]
        pb = b.evaluate(np.array([b.domain[tb]]))[0]
        if np.linalg.norm(pa - pb) > 1e-6 * max(1.0, np.abs(pa).max()):
            raise FitInputError("the four boundary curves do not meet at their corners")
    a0, a1 = make_compatible([c_v0, c_v1])
    b0, b1 = make_compatible([c_u0, c_u1])
    ru = NurbsSurface(a0.degree, 1, a0.knots, [0, 0, 1, 1], np.stack([a0.control_points, a1.control_points], axis=1))
    rv = NurbsSurface(1, b0.degree, [0, 0, 1, 1], b0.knots, np.stack([b0.control_points, b1.control_points], axis=0))
    p00, p10 = a0.control_points[0], a0.control_points[-1]
    p01, p11 = a1.control_points[0], a1.control_points[-1]
    t = NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], np.array([[p00, p01], [p10, p11]]))
    p, q = max(ru.degree_u, rv.degree_u), max(ru.degree_v, rv.degree_v)
    parts = [elevate_surface(s, p - s.degree_u, q - s.degree_v) for s in (ru, rv, t)]
    ku = np.unique(np.concatenate([s.knots_u for s in parts]))
    kv = np.unique(np.concatenate([s.knots_v for s in parts]))

    def fill(s):
        mu = [k for k in ku[(ku > 0) & (ku < 1)] for _ in range(max(0, _mult(parts, "u", k) - _mult([s], "u", k)))]
        mv = [k for k in kv[(kv > 0) & (kv < 1)] for _ in range(max(0, _mult(parts, "v", k) - _mult([s], "v", k)))]
        return refine_surface(s, mu, mv)

    a, b, c = (fill(s) for s in parts)
    return NurbsSurface(p, q, a.knots_u, a.knots_v, a.control_points + b.control_points - c.control_points)


def _mult(surfs, d, k) -> int:
    return max(int(np.count_nonzero((s.knots_u if d == "u" else s.knots_v) == k)) for s in surfs)


# ---------------------------------------------------------------------------- outline
def data_outline(u: np.ndarray, v: np.ndarray, domain, cells: int | None = None) -> TrimLoop:
    """Outer outline of the parameters (u, v) (N,) as a closed degree-1 trim loop in (u, v):
    occupied cells of a grid (about 4 points per cell), closed over gaps of one cell, holes
    filled, the largest connected region, its boundary traced (marching squares) and kept
    inside ``domain`` (u0, u1, v0, v1). Counter-clockwise (IGES outer loop)."""
    from contourpy import contour_generator
    from scipy import ndimage

    u0, u1, v0, v1 = domain
    n = len(u)
    if cells is None:
        cells = int(np.clip(math.sqrt(n / 4.0), 8, 1000))
    aspect = (u1 - u0) / (v1 - v0)
    nu = max(4, int(round(cells * math.sqrt(aspect))))
    nv = max(4, int(round(cells / math.sqrt(aspect))))
    iu = np.clip(((u - u0) / (u1 - u0) * nu).astype(int), 0, nu - 1)
    iv = np.clip(((v - v0) / (v1 - v0) * nv).astype(int), 0, nv - 1)
    occ = np.zeros((nv + 4, nu + 4), dtype=bool)
    occ[iv + 2, iu + 2] = True
    occ = ndimage.binary_closing(occ, structure=np.ones((3, 3)), iterations=1)
    occ = ndimage.binary_fill_holes(occ)
    lab, k = ndimage.label(occ)
    if k > 1:
        sizes = ndimage.sum(occ, lab, range(1, k + 1))
        occ = lab == (1 + int(np.argmax(sizes)))
    img = ndimage.gaussian_filter(occ.astype(float), 0.7)
    gx = u0 + (np.arange(nu + 4) - 2 + 0.5) * (u1 - u0) / nu
    gy = v0 + (np.arange(nv + 4) - 2 + 0.5) * (v1 - v0) / nv
    lines = contour_generator(gx, gy, img).lines(0.5)
    if not lines:
        raise FitInputError("no outline of the data could be traced")
    line = max(lines, key=len)
    poly = np.asarray(line, dtype=float)[:, :2]
    poly[:, 0] = np.clip(poly[:, 0], u0, u1)
    poly[:, 1] = np.clip(poly[:, 1], v0, v1)
    keep = np.r_[True, np.linalg.norm(np.diff(poly, axis=0), axis=1) > 1e-12 * (u1 - u0)]
    poly = poly[keep]
    if np.linalg.norm(poly[0] - poly[-1]) > 0:
        poly = np.vstack([poly, poly[:1]])
    area = 0.5 * np.sum(poly[:-1, 0] * poly[1:, 1] - poly[1:, 0] * poly[:-1, 1])
    if area < 0:
        poly = poly[::-1]
    t = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(poly, axis=0), axis=1))]
    t /= t[-1]
    knots = np.r_[0.0, t, 1.0]
    return TrimLoop([NurbsCurve(1, knots, poly)])


# ---------------------------------------------------------------------------- the job
@dataclass
class FitReport:
    """What `fit_points` did: the fitted face, the fit, the parametrisation and the numbers."""

    face: Face
    fit: SurfaceFit
    points: np.ndarray
    source: str
    base: str
    seconds: float
    ignored: int = 0  # points left out as stray (farther than max_distance from the base)

    def as_dict(self) -> dict:
        f = self.fit
        d_in, rms_in = f.inlier_stats()
        nu, nv = f.surface.shape
        beyond = int(np.count_nonzero((f.distance > f.tolerance) & ~f.outliers))
        return dict(points=len(self.points), source=self.source, base=self.base,
                    degree=[f.surface.degree_u, f.surface.degree_v], control_net=[nu, nv],
                    rational=bool(f.surface.rational), tolerance=f.tolerance, noise_sigma=f.noise,
                    stop=f.stop, max_deviation=f.max_deviation, rms_deviation=f.rms,
                    max_deviation_inliers=d_in, rms_deviation_inliers=rms_in,
                    p99_deviation=float(np.quantile(f.distance, 0.99)),
                    outliers_down_weighted=int(np.count_nonzero(f.outliers)),
                    partly_down_weighted=int(np.count_nonzero((f.weight > 0) & (f.weight < 0.5))),
                    beyond_tolerance_inliers=beyond, trimmed=self.face.trims is not None,
                    ignored_far_from_base=self.ignored,
                    levels=[dict(h, ctrl=list(h["ctrl"])) for h in f.history], seconds=self.seconds)

    def format(self) -> str:
        d = self.as_dict()
        stop = {"tolerance": "tolerance reached (no cell deviates beyond it)",
                "control-net limit": "control-net limit reached before the tolerance",
                "no improvement": "refinement stopped improving before the tolerance",
                "fixed knots": "fixed knots (no refinement asked); tolerance not met"}.get(d["stop"], d["stop"])
        lines = [
            f"points        {d['points']} ({d['source']}), parametrised on the {d['base']}"
            + (f"; {d['ignored_far_from_base']} more left out as stray (far from the base)" if d['ignored_far_from_base'] else ""),
            f"surface       degree {d['degree'][0]}x{d['degree'][1]}, control net {d['control_net'][0]}x"
            f"{d['control_net'][1]}, {'rational' if d['rational'] else 'polynomial'}"
            f"{', trimmed by the data outline' if d['trimmed'] else ''}",
            f"stop          {stop}",
            f"deviation     max {d['max_deviation']:.6g}, RMS {d['rms_deviation']:.6g}, 99 % {d['p99_deviation']:.6g}"
            f" (all points, projected onto the fit)",
            f"inliers       max {d['max_deviation_inliers']:.6g}, RMS {d['rms_deviation_inliers']:.6g}; "
            f"{d['beyond_tolerance_inliers']} beyond the tolerance {d['tolerance']:g}"
            + (" (noise: the tolerance is checked on local means of the points)"
               if d["noise_sigma"] > 0.05 * d["tolerance"] else ""),
            f"noise sigma   {d['noise_sigma']:.3g} (estimated from the data unless given)",
            f"outliers      {d['outliers_down_weighted']} down-weighted to 0, {d['partly_down_weighted']} below half weight",
            f"time          {d['seconds']:.1f} s",
        ]
        return "\n".join(lines)


def fit_points(
    points: np.ndarray,
    *,
    base: str | Model | NurbsSurface = "plane",
    face: int | None = None,
    degree: int = 3,
    tolerance: float = 0.01,
    smoothing: float = 1e-6,
    max_ctrl: tuple[int, int] = (60, 60),
    trim: bool = False,
    rational: bool = False,
    noise: float | None = None,
    robust: str | None = "tukey",
    max_distance: float | None = None,
    source: str = "points",
    name: str = "FIT",
    base_name: str = "given base surface",
    progress=None,
) -> FitReport:
    """Fit one NURBS surface to (N, 3) points; see the module doc. base: "plane", a Model (its
    face ``face`` or all faces joined) or a NurbsSurface; rational: take degrees, knots and
    weights from the base surface (conics, fillets), else a polynomial fit of ``degree``;
    max_distance: points farther than this from the base are stray (fixtures, the press bed,
    a neighbouring part) and left out (default: 1 % of the base's size for a CAD base, no
    limit for the plane); base_name: what a NurbsSurface base is, for the report.

    Example::

        >>> pts, _ = cadbridge.fitting.surface_fit.read_points("scan.xyz")   # doctest: +SKIP
        >>> report = cadbridge.fit_points(pts, base="plane", tolerance=0.01)
        >>> report.face.surface, report.fit.distance.max()     # the NURBS face and its largest distance
    """
    import time

    t0 = time.perf_counter()
    x = np.asarray(points, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3 or len(x) == 0:
        raise FitInputError(f"points must have shape (N, 3) with N > 0, got {x.shape}")
    if not np.isfinite(x).all():
        bad = ~np.isfinite(x).all(axis=1)
        raise FitInputError(f"{int(bad.sum())} points have NaN or infinite coordinates (first: point {int(np.argmax(bad))})")
    stage = getattr(progress, "stage", None) or (lambda text: None)
    stage(f"parametrising {len(x)} points")
    _principal_axes(x)  # coincident / collinear points: one clear error whatever the base
    if isinstance(base, str):
        if base != "plane":
            raise FitInputError(f"unknown base {base!r}")
        par = plane_base(x)
    elif isinstance(base, Model):
        par = face_base(x, base, face)
    else:
        from cadbridge.nurbs.project import FAILED, project_to_surface

        res = project_to_surface(base, x, tol=1e-10)
        par = Parametrisation(res.u, res.v, res.distance, base, base_name)
        if np.any(res.status == FAILED):
            raise FitInputError("points could not be projected onto the base surface")
    ignored = 0
    if par.base is not None:
        limit = 0.01 * float(np.linalg.norm(np.ptp(par.base.bbox(), axis=0))) if max_distance is None else max_distance
        near = par.distance <= limit
        ignored = int(np.count_nonzero(~near))
        if ignored:
            if near.sum() == 0:
                raise FitInputError(f"no point is within {limit:g} of the base surface (--max-distance)")
            x = x[near]
            par = Parametrisation(par.u[near], par.v[near], par.distance[near], par.base, par.what)
    elif max_distance is not None:
        near = par.distance <= max_distance
        ignored = int(np.count_nonzero(~near))
        x = x[near]
        par = Parametrisation(par.u[near], par.v[near], par.distance[near], None, par.what)
    if rational and par.base is None:
        raise FitInputError("rational fitting takes its weights from a base surface: give --base CAD.igs")
    p = int(degree)
    nmin = (p + 1) ** 2
    if len(x) < nmin:
        raise FitInputError(f"{len(x)} points are fewer than the {p + 1}x{p + 1} = {nmin} control points "
                            f"of the smallest degree-{p} surface")
    fit = fit_surface(x, par.u, par.v, degree=(p, p), tolerance=tolerance, max_ctrl=max_ctrl, smoothing=smoothing,
                      robust=robust, noise=noise, rational_base=par.base if rational else None, progress=progress)
    surf = fit.surface
    trims = None
    if trim:
        stage("tracing the data outline")
        trims = Trim(data_outline(fit.u[~fit.outliers], fit.v[~fit.outliers], surf.domain))
    out = Face(surf, de=1, name=name, trims=trims, entity_type=144 if trims else 128)
    return FitReport(out, fit, x, source, par.what, time.perf_counter() - t0, ignored)


def write_fit_outputs(report: FitReport, iges_path, *, units=None, extras: bool = True) -> list[Path]:
    """Write the IGES (128, or 144 over it when trimmed) and, with ``extras``, beside it:
    STEM_report.txt / .json, STEM_deviation.vtu (points with signed deviation, weight,
    outlier flag), STEM_deviation.png (map over (u, v)) and STEM_beyond.csv (inliers beyond the
    tolerance, and outliers). Every file is written atomically. Returns the paths."""
    from cadbridge.common.atomic import atomic_path, atomic_write
    from cadbridge.iges.writer import write_iges

    path = Path(iges_path)
    f = report.fit
    for name, arr in (("control points", f.surface.control_points), ("weights", f.surface.weights)):
        if not np.all(np.isfinite(arr)):
            raise FitError(f"the fit has non-finite {name}: nothing written")
    write_iges([report.face], path, units=units, description=f"cadbridge fit: NURBS surface fitted to {report.source}")
    written = [path]
    if not extras:
        return written
    stem = path.with_suffix("")
    txt = Path(f"{stem}_report.txt")
    with atomic_write(txt) as fh:
        fh.write(report.format() + "\n")
    js = Path(f"{stem}_report.json")
    with atomic_write(js) as fh:
        json.dump(report.as_dict(), fh, indent=1)
        fh.write("\n")
    written += [txt, js]
    # deviation map: the points as VTK vertices
    import meshio

    vtu = Path(f"{stem}_deviation.vtu")
    n = len(report.points)
    mesh = meshio.Mesh(report.points, [("vertex", np.arange(n).reshape(-1, 1))],
                       point_data={"deviation": f.signed, "distance": f.distance, "weight": f.weight,
                                   "outlier": f.outliers.astype(np.uint8), "u": f.u, "v": f.v})
    with atomic_path(vtu) as tmp:
        meshio.write(tmp, mesh, file_format="vtu", binary=True, compression="zlib")
    written.append(vtu)
    png = Path(f"{stem}_deviation.png")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 5), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    lim = max(3 * f.tolerance, float(np.quantile(np.abs(f.signed[~f.outliers]), 0.999)) if (~f.outliers).any() else f.tolerance)
    step = max(1, n // 200000)
    sc = ax.scatter(f.u[::step], f.v[::step], c=np.clip(f.signed[::step], -lim, lim), s=1.0, cmap="coolwarm",
                    vmin=-lim, vmax=lim, linewidths=0)
    out = f.outliers
    if out.any():
        ax.scatter(f.u[out][::step], f.v[out][::step], s=3, c="k", marker="x", linewidths=0.5, label="outliers")
        ax.legend(loc="upper right")
    fig.colorbar(sc, ax=ax, label="signed deviation (model units)")
    ax.set_xlabel("u")
    ax.set_ylabel("v")
    ax.set_title(f"deviation of the points from the fit: max {f.max_deviation:.3g}, RMS {f.rms:.3g}, tol {f.tolerance:g}")
    ax.set_aspect("equal", adjustable="datalim")
    with atomic_path(png) as tmp:
        fig.savefig(tmp, format="png")
    written.append(png)
    csv = Path(f"{stem}_beyond.csv")
    out_flag = f.outliers  # (N,): computed once (a property; per row it made the file O(N^2))
    sel = np.nonzero((f.distance > f.tolerance) | out_flag)[0]
    vals = np.column_stack([report.points[sel], f.u[sel], f.v[sel], f.signed[sel], f.weight[sel]])
    row = ",".join(["%d"] + ["%.17g"] * 7 + ["%d"]) + "\n"
    with atomic_write(csv) as fh:
        fh.write("index,x,y,z,u,v,deviation,weight,outlier\n")
        for i, v, o in zip(sel.tolist(), vals.tolist(), out_flag[sel].tolist()):
            fh.write(row % (i, *v, o))
    written.append(csv)
    return written
