"""Quasi-isotropic triangulation (QIT) directly on NURBS faces (Herrero Adan & Cardoso 2020).

The image of a hexagonal lattice ("pattern space", section 3.1) is built on each face by
arcs of physical radius R (sections 4-6); the lattice connectivity then gives nearly
equilateral triangles of one size, the meshes Nagata patches are most accurate on.

Pipeline per model (`qit_mesh`):

1. edges: every face's boundary (its four iso-lines, or its exact trim loops) as curves in
   the face's (u, v); edges of two faces that coincide in 3D (within ``match_tol``) are one
   edge, discretised once (conformal meshes, section 3.2, Fig. 8);
2. edge vertices (section 4): dC-mesh (error-controlled trapezoidal rule, eqs. 11-13 with
   A.4), NS = round(L/R) equal arc-length segments, positions by PPI (eqs. 14-16);
3. surface vertices (section 5): dS-mesh (6 paths per partition, extended beyond the
   domain by semi-infinite perimeter/corner partitions), EPP (5.2), AIP cases A-D (5.3),
   hexagon rings with side/corner base vertices (5.4, Table 2) and rescue (5.5);
4. triangulation (section 6): SI/SE/SO classification (Dx_th = R/3; SO decided on the
   exact trims for trimmed faces), pattern coordinates of the edge vertices (eqs. 19-20),
   constrained Delaunay in pattern space (scipy Delaunay + constraint recovery by flips),
   edge-strip diagonal flips (6.4).

Derivatives are exact (analytic `NurbsSurface.derivatives`), not estimated as in
appendix B. Every choice where the paper is silent or misprinted is in docs/qit.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import Delaunay, cKDTree

from cadbridge.mesh.mesh import CellBlock, Mesh, MeshError
from cadbridge.nurbs.curve import NurbsCurve

__all__ = ["QitError", "QitJacobianError", "QitOptions", "QitFaceReport", "qit_mesh"]

_DIRS = np.array([(1, 0), (0, 1), (-1, 1), (-1, 0), (0, -1), (1, -1)])  # axial hex directions, CCW


class QitError(MeshError):
    """A face QIT cannot mesh (zero Jacobian, failed constraint recovery, ...), named."""


class QitJacobianError(QitError):
    """A face with a vanishing Jacobian (pole, degenerate edge): bad input, no fallback."""


@dataclass
class QitOptions:
    """Inputs of QIT (Table D.1). Tolerances in percent (eq. 13).

    size : target edge length R (model units); threshold : Dx_th, default R/3;
    edge_tol / surface_tol : dC- / dS-mesh tolerances; beta_amp : initial AIP arc
    amplitude (degrees); n_lines : NL; aip_tol : AIP convergence (percent of the arc
    radius in parameter space); match_tol : 3D distance under which two faces' edges are one
    edge (default 1e-5 x model size); max_depth : dS/dC refinement levels at most;
    strip_opt : beyond the paper (default on): valence flips, spring relocation of the SI
    vertices near the edges and a max-angle clean-up after the edge-strip amendment
    (`cadbridge.mesh.qit.relax`, docs/qit.md); strip_max_angle : the clean-up flips triangles
    with an angle above it (degrees; 110 improves Q and every angle and size measure on the
    paper's examples, 120 gives the higher Q at a larger worst angle).
    """

    size: float
    threshold: float | None = None
    edge_tol: float = 1.0
    surface_tol: float = 4.0
    beta_amp: float = 15.0
    n_lines: int = 3
    aip_tol: float = 1.0
    match_tol: float | None = None
    max_depth: int = 14
    edge_flips: bool = True
    chord_polish: bool = True
    strip_opt: bool = True
    strip_max_angle: float = 110.0


@dataclass
class QitFaceReport:
    """What QIT did on one face: vertex counts by class, rings, AIP failures, flips; for a face
    QIT refused (``refused``, why), ``mesher`` "gmsh" (on QIT's edge vertices) or "gmsh-face"
    (gmsh's own mesh of a face alone) and ``choice`` (the two candidates' shares of angles
    within 60 +- 10 deg)."""

    face: int
    rings: int = 0
    computed: int = 0
    si: int = 0
    se: int = 0
    so: int = 0
    edge_vertices: int = 0
    triangles: int = 0
    aip_failed: int = 0
    rescued: int = 0
    flips: int = 0
    ds_partitions: int = 0
    seam_dropped: int = 0
    valence_flips: int = 0
    relaxed: int = 0
    strip_reverted: bool = False
    mesher: str = "qit"
    refused: str = ""
    choice: str = ""


# ---------------------------------------------------------------------------------------
# the surface with its C1 linear extension beyond the domain (section 5.1)


class _Surf:
    """A face's surface, evaluated with derivatives constant beyond the domain limits (the
    perimeter and corner partitions of section 5.1); points there lie on the tangent
    extension S(c) + Su(c)(u - uc) + Sv(c)(v - vc), c the clamped parameter."""

    def __init__(self, surface) -> None:
        self.s = surface
        u0, u1, v0, v1 = surface.domain
        self.lo = np.array([u0, v0])
        self.hi = np.array([u1, v1])
        self.diag = float(np.hypot(u1 - u0, v1 - v0))

    def clamp(self, uv: np.ndarray) -> np.ndarray:
        return np.clip(uv, self.lo, self.hi)

    def d1(self, uv: np.ndarray):
        """x (N, 3), Su (N, 3), Sv (N, 3) at (N, 2) parameters (extended)."""
        c = self.clamp(uv)
        d = self.s.derivatives(c[:, 0], c[:, 1], order=1)
        su, sv = d[:, 1, 0], d[:, 0, 1]
        x = d[:, 0, 0] + su * (uv[:, :1] - c[:, :1]) + sv * (uv[:, 1:] - c[:, 1:])
        return x, su, sv

    def h(self, uv: np.ndarray, nu: np.ndarray) -> np.ndarray:
        """|S,lambda| (eq. 9) along unit parameter directions nu (N, 2)."""
        c = self.clamp(uv)
        d = self.s.derivatives(c[:, 0], c[:, 1], order=1)
        return np.linalg.norm(d[:, 1, 0] * nu[:, :1] + d[:, 0, 1] * nu[:, 1:], axis=1)


def _trap_error(f_a, f_b, ddf_a, ddf_b, dl, ddf_m=None):
    """Trapezoid length (eq. 11) and its error in percent (eqs. 12-13), alpha at the end
    (or the midpoint, ``ddf_m``) with the largest |f''|."""
    length = 0.5 * (f_a + f_b) * dl
    big = np.maximum(np.abs(ddf_a), np.abs(ddf_b))
    if ddf_m is not None:
        big = np.maximum(big, np.abs(ddf_m))
    err = big * dl**3 / 12.0
    return length, 100.0 * err / np.where(length > 0, length, np.inf)


def _norm_derivs(g1, g2, g3):
    """f = |g'| and f'' (appendix A, eqs. A.2-A.4) from g', g'', g''' (N, 3)."""
    f = np.linalg.norm(g1, axis=1)
    fs = np.where(f > 0, f, 1.0)
    a = np.einsum("ij,ij->i", g1, g2)
    ddf = (np.einsum("ij,ij->i", g2, g2) + np.einsum("ij,ij->i", g1, g3)) / fs - a * a / fs**3
    return f, ddf


def _ppi(h_a, slope, length):
    """PPI (eqs. 14-16): the root of slope/2 d^2 + h_a d - L = 0 nearest the interval,
    in the cancellation-free form d = 2L / (h_a + sqrt(h_a^2 + 2 slope L))."""
    disc = np.maximum(h_a * h_a + 2.0 * slope * length, 0.0)
    den = h_a + np.sqrt(disc)
    return np.where(den > 0, 2.0 * length / np.where(den > 0, den, 1.0), 0.0)


# ---------------------------------------------------------------------------------------
# edges: dC-mesh and arc-length discretisation (section 4)


def _edge_derivs(surface, curve: NurbsCurve, t: np.ndarray) -> np.ndarray:
    """C = S(c(t)) and its first three t-derivatives (chain rule), (N, 4, 3).

    Trim curves of analytic IGES entities (`cadbridge.cad.analytic` mapped / inverted
    curves) give derivatives up to order 2 only: their third derivative is taken as 0, which
    touches only C''' and so only the dC-mesh error estimate (A.4), never a length or a
    position."""
    try:
        c = curve.derivatives(t, 3)[:, :, :2]
    except ValueError:
        c2 = curve.derivatives(t, 2)[:, :, :2]
        c = np.concatenate([c2, np.zeros((len(c2), 1, 2))], axis=1)
    u0, u1, v0, v1 = surface.domain
    uu = np.clip(c[:, 0, 0], u0, u1)
    vv = np.clip(c[:, 0, 1], v0, v1)
    d = surface.derivatives(uu, vv, order=3)
    a1, b1 = c[:, 1, :1], c[:, 1, 1:]
    a2, b2 = c[:, 2, :1], c[:, 2, 1:]
    a3, b3 = c[:, 3, :1], c[:, 3, 1:]
    su, sv = d[:, 1, 0], d[:, 0, 1]
    suu, suv, svv = d[:, 2, 0], d[:, 1, 1], d[:, 0, 2]
    out = np.empty((len(t), 4, 3))
    out[:, 0] = d[:, 0, 0]
    out[:, 1] = su * a1 + sv * b1
    out[:, 2] = suu * a1**2 + 2 * suv * a1 * b1 + svv * b1**2 + su * a2 + sv * b2
    out[:, 3] = (d[:, 3, 0] * a1**3 + 3 * d[:, 2, 1] * a1**2 * b1 + 3 * d[:, 1, 2] * a1 * b1**2 + d[:, 0, 3] * b1**3
                 + 3 * (suu * a1 * a2 + suv * (a1 * b2 + a2 * b1) + svv * b1 * b2) + su * a3 + sv * b3)
    return out


def _edge_seeds(surface, curve: NurbsCurve) -> np.ndarray:
    """Initial dC-mesh nodes: the curve's knots, plus for a straight (degree-1) piece the
    crossings of the surface's knot lines (so no partition straddles a surface knot)."""
    t0, t1 = curve.domain
    k = np.unique(curve.knots)
    seeds = [t0, t1, *k[(k > t0) & (k < t1)]]
    if curve.degree == 1 and len(curve.control_points) == 2:
        a, b = curve.control_points[0, :2], curve.control_points[1, :2]
        for dim, kn in ((0, surface.knots_u), (1, surface.knots_v)):
            if abs(b[dim] - a[dim]) > 0:
                s = (np.unique(kn) - a[dim]) / (b[dim] - a[dim])
                s = s[(s > 1e-12) & (s < 1 - 1e-12)]
                seeds += list(t0 + s * (t1 - t0))
    return np.unique(np.array(seeds, dtype=float))


def _dc_mesh(surface, curve: NurbsCurve, tol: float, max_depth: int):
    """dC-mesh (section 4.1): nodes t (M,), |C'| at them, partition lengths (M-1,)."""
    t = _edge_seeds(surface, curve)
    span = t[-1] - t[0]
    for _ in range(max_depth + 8):
        d = _edge_derivs(surface, curve, t)
        f, ddf = _norm_derivs(d[:, 1], d[:, 2], d[:, 3])
        dm = _edge_derivs(surface, curve, 0.5 * (t[:-1] + t[1:]))
        _, ddm = _norm_derivs(dm[:, 1], dm[:, 2], dm[:, 3])
        length, ep = _trap_error(f[:-1], f[1:], ddf[:-1], ddf[1:], np.diff(t), ddm)
        bad = (ep > tol) & (np.diff(t) > 1e-12 * span)
        if not bad.any():
            break
        t = np.sort(np.concatenate([t, 0.5 * (t[:-1] + t[1:])[bad]]))
    return t, f, length


def discretise_edge(surface, curve: NurbsCurve, size: float, tol: float, max_depth: int = 14,
                    min_segments: int = 1) -> tuple[np.ndarray, float]:
    """Edge vertices of one edge curve (section 4.2): parameters t (NS+1,) of NS = round(L/R)
    segments of equal estimated arc length Rc = L/NS, and the estimated length L."""
    t, f, length = _dc_mesh(surface, curve, tol, max_depth)
    lacc = np.concatenate([[0.0], np.cumsum(length)])
    total = float(lacc[-1])
    ns = max(int(min_segments), int(round(total / size)))
    ra = total / ns * np.arange(1, ns)
    i = np.clip(np.searchsorted(lacc, ra, side="right") - 1, 0, len(t) - 2)
    dt = t[i + 1] - t[i]
    slope = (f[i + 1] - f[i]) / dt
    step = _ppi(f[i], slope, ra - lacc[i])
    out = np.concatenate([[t[0]], t[i] + np.minimum(step, dt), [t[-1]]])
    return out, total


# ---------------------------------------------------------------------------------------
# dS-mesh (section 5.1)


class _DSMesh:
    """Quadtree partitions of the domain (leaves (K, 4): u0, u1, v0, v1) refined until the
    trapezoid error of the 4 sides and 2 diagonals is within ``tol`` (Fig. 15), and a
    tensor-grid lookup of the leaf containing a point."""

    def __init__(self, surf: _Surf, tol: float, max_depth: int, face_label: str) -> None:
        s = surf.s
        u0, u1, v0, v1 = s.domain
        ku = np.unique(np.clip(s.knots_u, u0, u1))
        kv = np.unique(np.clip(s.knots_v, v0, v1))
        uu, vv = np.meshgrid(np.arange(len(ku) - 1), np.arange(len(kv) - 1), indexing="ij")
        leaves = np.column_stack([ku[uu.ravel()], ku[uu.ravel() + 1], kv[vv.ravel()], kv[vv.ravel() + 1]])
        done = []
        min_jac = np.inf
        for depth in range(max_depth + 1):
            err, jac = self._errors(s, leaves)
            min_jac = min(min_jac, float(jac.min()))
            bad = err > tol
            if depth == max_depth:
                bad[:] = False
            done.append(leaves[~bad])
            leaves = leaves[bad]
            if len(leaves) == 0:
                break
            um = 0.5 * (leaves[:, 0] + leaves[:, 1])
            vm = 0.5 * (leaves[:, 2] + leaves[:, 3])
            leaves = np.concatenate([
                np.column_stack([leaves[:, 0], um, leaves[:, 2], vm]),
                np.column_stack([um, leaves[:, 1], leaves[:, 2], vm]),
                np.column_stack([leaves[:, 0], um, vm, leaves[:, 3]]),
                np.column_stack([um, leaves[:, 1], vm, leaves[:, 3]]),
            ])
        if not min_jac > 1e-10:
            raise QitJacobianError(f"{face_label}: QIT needs a Jacobian |Su x Sv| > 0 on the whole face; it vanishes "
                           "(degenerate edge or pole: relative Jacobian "
                           f"{min_jac:.1e}); mesh this face with --mesher gmsh")
        self.leaves = np.concatenate(done)
        self.ub = np.unique(self.leaves[:, :2])
        self.vb = np.unique(self.leaves[:, 2:])
        look = np.full((len(self.ub) - 1, len(self.vb) - 1), -1, dtype=np.int64)
        i0 = np.searchsorted(self.ub, self.leaves[:, 0])
        i1 = np.searchsorted(self.ub, self.leaves[:, 1])
        j0 = np.searchsorted(self.vb, self.leaves[:, 2])
        j1 = np.searchsorted(self.vb, self.leaves[:, 3])
        for k in range(len(self.leaves)):
            look[i0[k]:i1[k], j0[k]:j1[k]] = k
        self.look = look
        self.surf = surf

    @staticmethod
    def _errors(s, leaves: np.ndarray):
        """Max trapezoid error (percent) over the 6 paths of each leaf, and the min relative
        Jacobian |Su x Sv| / (|Su||Sv|) at its corners."""
        n = len(leaves)
        um, vm = 0.5 * (leaves[:, 0] + leaves[:, 1]), 0.5 * (leaves[:, 2] + leaves[:, 3])
        # corners 00, 10, 01, 11, then the path midpoints: sides v0, v1, u0, u1 and centre
        cu = np.column_stack([leaves[:, [0, 1, 0, 1]], um, um, leaves[:, 0], leaves[:, 1], um])
        cv = np.column_stack([leaves[:, [2, 2, 3, 3]], leaves[:, 2], leaves[:, 3], vm, vm, vm])
        d = s.derivatives(cu.ravel(), cv.ravel(), order=3).reshape(n, 9, 4, 4, 3)
        su, sv = d[:, :, 1, 0], d[:, :, 0, 1]
        cr = np.linalg.norm(np.cross(su, sv), axis=2)
        jac = cr[:, :4] / np.maximum(np.linalg.norm(su, axis=2) * np.linalg.norm(sv, axis=2), 1e-300)[:, :4]
        err = np.zeros(n)
        for a, b, mid in ((0, 1, 4), (2, 3, 5), (0, 2, 6), (1, 3, 7), (0, 3, 8), (1, 2, 8)):
            du = cu[:, b] - cu[:, a]
            dv = cv[:, b] - cv[:, a]
            dl = np.hypot(du, dv)
            n1, n2 = (du / dl)[:, None], (dv / dl)[:, None]
            ff, dd = [], []
            for c in (a, b, mid):
                g1 = d[:, c, 1, 0] * n1 + d[:, c, 0, 1] * n2
                g2 = d[:, c, 2, 0] * n1**2 + 2 * d[:, c, 1, 1] * n1 * n2 + d[:, c, 0, 2] * n2**2
                g3 = (d[:, c, 3, 0] * n1**3 + 3 * d[:, c, 2, 1] * n1**2 * n2 + 3 * d[:, c, 1, 2] * n1 * n2**2
                      + d[:, c, 0, 3] * n2**3)
                f, ddf = _norm_derivs(g1, g2, g3)
                ff.append(f)
                dd.append(ddf)
            _, ep = _trap_error(ff[0], ff[1], dd[0], dd[1], dl, dd[2])
            err = np.maximum(err, ep)
        return err, jac.min(axis=1)

    def boxes(self, uv: np.ndarray, nu: np.ndarray) -> np.ndarray:
        """Partition box (K, 4) the ray from each point along ``nu`` (K, 2) enters (a point
        on a partition side belongs to the partition ahead); beyond the domain the
        perimeter / corner partitions, semi-infinite on the outer side."""
        surf = self.surf
        c = surf.clamp(uv)
        iu = np.where(nu[:, 0] < 0, np.searchsorted(self.ub, c[:, 0], side="left"),
                      np.searchsorted(self.ub, c[:, 0], side="right")) - 1
        jv = np.where(nu[:, 1] < 0, np.searchsorted(self.vb, c[:, 1], side="left"),
                      np.searchsorted(self.vb, c[:, 1], side="right")) - 1
        i = np.clip(iu, 0, len(self.ub) - 2)
        j = np.clip(jv, 0, len(self.vb) - 2)
        b = self.leaves[self.look[i, j]].copy()
        lo, hi = surf.lo, surf.hi
        b[(uv[:, 0] < lo[0]) | ((uv[:, 0] <= lo[0]) & (nu[:, 0] < 0)), :2] = (-np.inf, lo[0])
        b[(uv[:, 0] > hi[0]) | ((uv[:, 0] >= hi[0]) & (nu[:, 0] > 0)), :2] = (hi[0], np.inf)
        b[(uv[:, 1] < lo[1]) | ((uv[:, 1] <= lo[1]) & (nu[:, 1] < 0)), 2:] = (-np.inf, lo[1])
        b[(uv[:, 1] > hi[1]) | ((uv[:, 1] >= hi[1]) & (nu[:, 1] > 0)), 2:] = (hi[1], np.inf)
        return b


def _epp(surf: _Surf, ds: _DSMesh, start: np.ndarray, theta: np.ndarray, length: np.ndarray) -> np.ndarray:
    """EPP (section 5.2): end (K, 2) of the paths from ``start`` (K, 2) along parameter
    directions ``theta`` (K,) with physical lengths ``length`` (K,), by the trapezoidal rule
    over the dS-mesh partitions the ray crosses; a ray leaving through a semi-infinite
    partition uses a trial point one parameter-domain diagonal ahead (Fig. 19)."""
    nu = np.column_stack([np.cos(theta), np.sin(theta)])
    nu[np.abs(nu) < 1e-15] = 0.0  # cos(pi/2) is 6e-17, not 0: no crawl along a partition side
    p = start.astype(float).copy()
    acc = np.zeros(len(p))
    hp = surf.h(p, nu)
    end = np.full_like(p, np.nan)
    act = np.arange(len(p))
    eps = 1e-9 * surf.diag
    for _ in range(100000):
        if act.size == 0:
            break
        pa, na = p[act], nu[act]
        box = ds.boxes(pa, na)
        with np.errstate(divide="ignore", invalid="ignore"):
            tu = np.where(na[:, 0] > 0, (box[:, 1] - pa[:, 0]) / na[:, 0],
                          np.where(na[:, 0] < 0, (box[:, 0] - pa[:, 0]) / na[:, 0], np.inf))
            tv = np.where(na[:, 1] > 0, (box[:, 3] - pa[:, 1]) / na[:, 1],
                          np.where(na[:, 1] < 0, (box[:, 2] - pa[:, 1]) / na[:, 1], np.inf))
        t = np.minimum(tu, tv)
        t = np.where(np.isfinite(t), np.maximum(t, eps), surf.diag)
        q = pa + t[:, None] * na
        hq = surf.h(q, na)
        seg = 0.5 * (hp[act] + hq) * t
        fin = acc[act] + seg >= length[act]
        if fin.any():
            k = act[fin]
            step = _ppi(hp[k], (hq[fin] - hp[k]) / t[fin], length[k] - acc[k])
            end[k] = pa[fin] + np.minimum(step, t[fin])[:, None] * na[fin]
        go = ~fin
        k = act[go]
        acc[k] += seg[go]
        p[k] = q[go]
        hp[k] = hq[go]
        act = k
    return end


# ---------------------------------------------------------------------------------------
# AIP (section 5.3)


def _frames(surf: _Surf, uva: np.ndarray, uvb: np.ndarray):
    """At a: Su, Sv and the local base (p_hat, w_hat) of Fig. 23, w = n x p. p is the
    tangent image Su du + Sv dv of the parameter chord (du, dv) = uv_b - uv_a rather than
    the projection of x_b - x_a (Fig. 21): both agree to first order in R, but on faces
    curved strongly within R the projected chord can point anywhere, while the tangent of
    the parameter chord is the direction of the EPP ray that reaches b (docs/qit.md)."""
    _, su, sv = surf.d1(uva)
    n = np.cross(su, sv)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = uvb - uva
    px = su * d[:, :1] + sv * d[:, 1:]
    px /= np.maximum(np.linalg.norm(px, axis=1, keepdims=True), 1e-300)
    w = np.cross(n, px)
    return su, sv, px, w


def _beta_to_theta(su, sv, px, w, beta):
    """theta (K, M) of the tangent vectors at beta (K, M) radians from px (section 2.5,
    eqs. 17-18 solved in least squares, theta = atan2(s, c))."""
    v = np.cos(beta)[..., None] * px[:, None] + np.sin(beta)[..., None] * w[:, None]  # (K, M, 3)
    g11 = np.einsum("ij,ij->i", su, su)[:, None]
    g12 = np.einsum("ij,ij->i", su, sv)[:, None]
    g22 = np.einsum("ij,ij->i", sv, sv)[:, None]
    r1 = np.einsum("imj,ij->im", v, su)
    r2 = np.einsum("imj,ij->im", v, sv)
    det = g11 * g22 - g12 * g12
    c = (g22 * r1 - g12 * r2) / det
    s = (g11 * r2 - g12 * r1) / det
    return np.arctan2(s, c)


def _polyline_intersections(A: np.ndarray, B: np.ndarray):
    """First crossing of polylines A, B (K, M+1, 2): found (K,), point (K, 2), segment
    index and fraction on A (ia, sa) and on B (ib, sb)."""
    a0, da = A[:, :-1, None], (A[:, 1:] - A[:, :-1])[:, :, None]
    b0, db = B[:, None, :-1], (B[:, 1:] - B[:, :-1])[:, None]
    den = da[..., 0] * db[..., 1] - da[..., 1] * db[..., 0]
    r = b0 - a0
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (r[..., 0] * db[..., 1] - r[..., 1] * db[..., 0]) / den
        t = (r[..., 0] * da[..., 1] - r[..., 1] * da[..., 0]) / den
    ok = (den != 0) & (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1) & np.isfinite(s) & np.isfinite(t)
    k, m = A.shape[0], A.shape[1] - 1
    flat = ok.reshape(k, -1)
    found = flat.any(axis=1)
    first = np.argmax(flat, axis=1)
    ia, ib = first // m, first % m
    rows = np.arange(k)
    sa = np.where(found, s[rows, ia, ib], 0.0)
    sb = np.where(found, t[rows, ia, ib], 0.0)
    pt = A[rows, ia] + sa[:, None] * (A[rows, ia + 1] - A[rows, ia])
    return found, pt, ia, sa, ib, sb


def _aip(surf: _Surf, ds: _DSMesh, uva, uvb, ra, rb, beta_a, beta_b, side, opt: QitOptions):
    """AIP (section 5.3) for K vertex problems at once: the point at physical distances
    ra, rb (K,) from a, b (K, 2) on the side ``side`` (+1 left of a->b in (u, v), -1 right),
    starting from trial angles beta_a, beta_b (K,) radians. Returns uv (K, 2), NaN where
    no intersection converged. Cases A-D as in the paper."""
    k = len(uva)
    su_a, sv_a, px_a, w_a = _frames(surf, uva, uvb)
    su_b, sv_b, px_b, w_b = _frames(surf, uvb, uva)
    amp = np.full(k, np.radians(opt.beta_amp))
    nl = np.full(k, int(opt.n_lines))
    ba, bb = beta_a.astype(float).copy(), beta_b.astype(float).copy()
    prev = np.full((k, 2), np.nan)
    seen = np.zeros(k, dtype=bool)
    out = np.full((k, 2), np.nan)
    act = np.arange(k)
    for _ in range(40):
        if act.size == 0:
            break
        m = int(nl[act].max())
        frac = np.minimum(np.arange(m + 1)[None, :], nl[act][:, None]) / nl[act][:, None]  # pads with the end
        ang_a = ba[act][:, None] + amp[act][:, None] * (2 * frac - 1)
        ang_b = bb[act][:, None] + amp[act][:, None] * (2 * frac - 1)
        th_a = _beta_to_theta(su_a[act], sv_a[act], px_a[act], w_a[act], ang_a)
        th_b = _beta_to_theta(su_b[act], sv_b[act], px_b[act], w_b[act], ang_b)
        na = len(act)
        ends = _epp(surf, ds, np.repeat(np.concatenate([uva[act], uvb[act]]), m + 1, axis=0),
                    np.concatenate([th_a, th_b]).ravel(),
                    np.repeat(np.concatenate([ra[act], rb[act]]), m + 1))
        ends = ends.reshape(2 * na, m + 1, 2)
        A, B = ends[:na], ends[na:]
        found, pt, ia, sa, ib, sb = _polyline_intersections(A, B)
        dab = uvb[act] - uva[act]
        dc = pt - uva[act]
        cr = dab[:, 0] * dc[:, 1] - dab[:, 1] * dc[:, 0]
        good = found & (np.sign(cr) == side[act])
        wrong = found & ~good
        lost = ~found & seen[act]
        none = ~found & ~seen[act]
        # case A: re-orient to the intersection, amplitude / NL; converged when the
        # intersection moved by less than aip_tol % of the arc radius (parameter space)
        step = np.linalg.norm(pt - prev[act], axis=1)
        radius = np.linalg.norm(dc, axis=1)
        conv = good & np.isfinite(step) & (step <= opt.aip_tol / 100.0 * radius)
        out[act[conv]] = pt[conv]
        upd = good & ~conv
        stepa = 2 * amp[act] / nl[act]
        ka = act[upd]
        ba[ka] = ang_a[upd, 0] + stepa[upd] * (ia[upd] + sa[upd])
        bb[ka] = ang_b[upd, 0] + stepa[upd] * (ib[upd] + sb[upd])
        prev[ka] = pt[upd]
        seen[ka] = True
        amp[ka] = amp[ka] / nl[ka]
        # cases B, D: amplitude doubled; case C: amplitude and NL doubled
        amp[act[wrong | lost | none]] *= 2.0
        nl[act[none]] *= 2
        keep = upd | ((wrong | lost | none) & (amp[act] <= np.radians(90.0)) & (nl[act] <= 48))
        act = act[keep]
    return out


# ---------------------------------------------------------------------------------------
# hexagon rings (section 5.4) and rescue (5.5)


def _ring(k: int) -> list[tuple[int, int, bool]]:
    """Axial lattice positions of hexagon k, CCW from the right-hand corner, with a corner flag."""
    if k == 0:
        return [(0, 0, True)]
    out = []
    i, j = k, 0
    for side in range(6):
        d = _DIRS[(side + 2) % 6]
        for s in range(k):
            out.append((i, j, s == 0))
            i, j = i + d[0], j + d[1]
    return out


def _hexdist(i, j):
    return max(abs(i), abs(j), abs(i + j))


class _Lattice:
    """The pattern-space vertices computed so far: axial (i, j) -> index, uv, pattern r."""

    def __init__(self, R: float) -> None:
        self.R = R
        self.index: dict[tuple[int, int], int] = {}
        self.uv: list[np.ndarray] = []
        self.ij: list[tuple[int, int]] = []

    def add(self, ij, uv) -> None:
        self.index[ij] = len(self.uv)
        self.uv.append(np.asarray(uv, dtype=float))
        self.ij.append(ij)

    def r(self, ij) -> np.ndarray:
        i, j = ij
        return self.R * np.array([i + 0.5 * j, np.sqrt(3.0) / 2 * j])


def _setup(lat: _Lattice, a, b, c):
    """AIP inputs from pattern positions a, b, c: radii, trial angles and side (Table 2:
    R for side vertices, sqrt(3) R for corners; angles from the pattern, +-60 / +-73.2 deg)."""
    ra_, rb_, rc_ = lat.r(a), lat.r(b), lat.r(c)
    ab, ac, ba, bc = rb_ - ra_, rc_ - ra_, ra_ - rb_, rc_ - rb_
    cross = ab[0] * ac[1] - ab[1] * ac[0]
    beta_a = np.arctan2(ab[0] * ac[1] - ab[1] * ac[0], ab @ ac)
    beta_b = np.arctan2(ba[0] * bc[1] - ba[1] * bc[0], ba @ bc)
    return np.linalg.norm(ac), np.linalg.norm(bc), beta_a, beta_b, np.sign(cross)


def _run_aip(lat: _Lattice, surf, ds, jobs, opt) -> list[np.ndarray]:
    """Solve AIP jobs [(a_ij, b_ij, c_ij)] in one batch; returns uv per job (NaN = failed)."""
    if not jobs:
        return []
    uva = np.array([lat.uv[lat.index[a]] for a, _, _ in jobs])
    uvb = np.array([lat.uv[lat.index[b]] for _, b, _ in jobs])
    par = np.array([_setup(lat, a, b, c) for a, b, c in jobs])
    uv = _aip(surf, ds, uva, uvb, par[:, 0], par[:, 1], par[:, 2], par[:, 3], par[:, 4], opt)
    if opt.chord_polish:
        uv = _chord_polish(surf, uva, uvb, par[:, 0], par[:, 1], uv)
    return list(uv)


def _chord_polish(surf: _Surf, uva, uvb, ra, rb, uv, iters: int = 8):
    """Beyond the paper: Newton from the AIP point to the exact intersection of the two
    spheres |x - x_a| = ra, |x - x_b| = rb on the surface, so that triangle sides (chords) are
    R, not the lengths of the straight parameter paths (which bend in 3D where the
    parametrisation is uneven, shortening the chords). Points that do not converge keep
    the AIP result."""
    ok = np.all(np.isfinite(uv), axis=1)
    if not ok.any():
        return uv
    c = uv[ok].copy()
    xa, _, _ = surf.d1(uva[ok])
    xb, _, _ = surf.d1(uvb[ok])
    ra, rb = ra[ok], rb[ok]
    for _ in range(iters):
        x, su, sv = surf.d1(c)
        da, db = x - xa, x - xb
        f = np.column_stack([np.einsum("ij,ij->i", da, da) - ra**2, np.einsum("ij,ij->i", db, db) - rb**2])
        j11, j12 = 2 * np.einsum("ij,ij->i", da, su), 2 * np.einsum("ij,ij->i", da, sv)
        j21, j22 = 2 * np.einsum("ij,ij->i", db, su), 2 * np.einsum("ij,ij->i", db, sv)
        det = j11 * j22 - j12 * j21
        det = np.where(np.abs(det) > 0, det, np.inf)
        c = c - np.column_stack([(j22 * f[:, 0] - j12 * f[:, 1]) / det, (-j21 * f[:, 0] + j11 * f[:, 1]) / det])
    x, _, _ = surf.d1(c)
    err = np.maximum(np.abs(np.linalg.norm(x - xa, axis=1) - ra) / ra, np.abs(np.linalg.norm(x - xb, axis=1) - rb) / rb)
    moved = np.linalg.norm(c - uv[ok], axis=1) / np.maximum(np.linalg.norm(uv[ok] - uva[ok], axis=1), 1e-300)
    good = np.isfinite(err) & (err < 1e-6) & (moved < 0.25)
    out = uv.copy()
    idx = np.flatnonzero(ok)[good]
    out[idx] = c[good]
    return out


def _surface_vertices(surf: _Surf, ds: _DSMesh, region: np.ndarray, centre: np.ndarray, opt: QitOptions,
                      max_rings: int, rep: QitFaceReport, label: str = "face") -> _Lattice:
    """Hexagonal wave from ``centre`` (section 5.4): a vertex is computed iff one of its base
    vertices lies in ``region`` (u0, u1, v0, v1); the front stops at the first ring with none."""
    R = opt.size
    lat = _Lattice(R)
    lat.add((0, 0), centre)
    e = _epp(surf, ds, centre[None], np.zeros(1), np.array([R]))[0]
    if opt.chord_polish:  # chord |x2 - x1| = R along the same parameter ray (secant steps)
        x1 = surf.d1(centre[None])[0][0]
        t0, t1 = 0.0, e[0] - centre[0]
        f = lambda t: np.linalg.norm(surf.d1(np.array([[centre[0] + t, centre[1]]]))[0][0] - x1) - R  # noqa: E731
        f0, f1 = -R, f(t1)
        for _ in range(30):
            if abs(f1) <= 1e-12 * R or f1 == f0:
                break
            t0, t1, f0 = t1, t1 - f1 * (t1 - t0) / (f1 - f0), f1
            f1 = f(t1)
        if abs(f1) <= 1e-9 * R:
            e = np.array([centre[0] + t1, centre[1]])
    lat.add((1, 0), e)
    ring1 = _ring(1)
    for n in range(1, 6):
        c = ring1[n][:2]
        uv = _run_aip(lat, surf, ds, [(ring1[n - 1][:2], (0, 0), c)], opt)[0]
        if not np.all(np.isfinite(uv)):
            raise QitError(f"{label}: AIP found no vertex of the first hexagon (the face is small or strongly "
                           f"curved for R = {R:g}); use a smaller --size or --mesher gmsh")
        lat.add(c, uv)

    def inside(ij) -> bool:
        k = lat.index.get(ij)
        if k is None:
            return False
        u, v = lat.uv[k]
        return region[0] <= u <= region[1] and region[2] <= v <= region[3]

    rings = 1
    for k in range(2, max_rings + 1):
        todo = []
        for i, j, corner in _ring(k):
            if corner:
                d = np.sign([i, j]).astype(int)  # corner = k * direction
                p = ((k - 1) * d[0], (k - 1) * d[1])
                base = [(p[0] + dd[0], p[1] + dd[1]) for dd in _DIRS if _hexdist(p[0] + dd[0], p[1] + dd[1]) == k - 1]
            else:
                base = [(i + dd[0], j + dd[1]) for dd in _DIRS if _hexdist(i + dd[0], j + dd[1]) == k - 1]
            if len(base) != 2:
                continue
            if inside(base[0]) or inside(base[1]):
                todo.append((base[0], base[1], (i, j)))
        if not todo:
            break
        # rescue base vertices that were not computed (section 5.5)
        missing = sorted({b for a, b2, _ in todo for b in (a, b2) if b not in lat.index})
        rjobs, rfor = [], []
        for q in missing:
            nb = [(q[0] + d[0], q[1] + d[1]) for d in _DIRS]
            have = [x in lat.index for x in nb]
            pair = None
            for gap in (1, 2):  # 60 degrees first, then 120
                for s in range(6):
                    if have[s] and have[(s + gap) % 6]:
                        pair = (nb[s], nb[(s + gap) % 6])
                        break
                if pair:
                    break
            if pair:
                rjobs.append((pair[0], pair[1], q))
                rfor.append(q)
        for q, uv in zip(rfor, _run_aip(lat, surf, ds, rjobs, opt)):
            if np.all(np.isfinite(uv)):
                lat.add(q, uv)
                rep.rescued += 1
        todo = [t for t in todo if t[0] in lat.index and t[1] in lat.index]
        res = _run_aip(lat, surf, ds, todo, opt)
        for (_, _, c), uv in zip(todo, res):
            if np.all(np.isfinite(uv)):
                lat.add(c, uv)
            else:
                rep.aip_failed += 1
        rings = k
    rep.rings = rings
    return lat


# ---------------------------------------------------------------------------------------
# triangulation (section 6)


def _tri_adjacency(tris: np.ndarray) -> dict:
    """Directed edge (a, b) -> triangle index."""
    return {(int(t[i]), int(t[(i + 1) % 3])): n for n, t in enumerate(tris) for i in range(3)}


def _orient2d(a, b, c) -> float:
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


def _segments_cross(p, q, r, s) -> bool:
    """Proper crossing of segments pq and rs (no shared end points)."""
    d1, d2 = _orient2d(p, q, r), _orient2d(p, q, s)
    d3, d4 = _orient2d(r, s, p), _orient2d(r, s, q)
    return d1 * d2 < 0 and d3 * d4 < 0


def _constrained_delaunay(pts: np.ndarray, constraints: list[tuple[int, int]], label: str) -> np.ndarray:
    """Triangles (CCW) of the points inside the constraint loops: scipy Delaunay, each
    missing constraint recovered by flipping the edges that cross it (Sloan 1993), then the
    regions outside the loops removed by an even-odd flood fill from the hull."""
    # four frame points far outside: no real point is on the convex hull, where collinear
    # edge vertices (a straight edge) would give Qhull flat triangles
    n_real = len(pts)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    mid, ext = 0.5 * (lo + hi), 2.0 * float(np.max(hi - lo)) + 1.0
    pts = np.concatenate([pts, mid + ext * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])])
    tri = Delaunay(pts)
    tris = [list(t) for t in tri.simplices]
    for t in tris:
        if _orient2d(pts[t[0]], pts[t[1]], pts[t[2]]) < 0:
            t[1], t[2] = t[2], t[1]
    adj = _tri_adjacency(np.array(tris))

    def flip(a, b) -> tuple[int, int]:
        t1, t2 = adj[(a, b)], adj[(b, a)]
        c = [x for x in tris[t1] if x not in (a, b)][0]
        d = [x for x in tris[t2] if x not in (a, b)][0]
        for t in (t1, t2):
            tt = tris[t]
            for i in range(3):
                adj.pop((tt[i], tt[(i + 1) % 3]), None)
        tris[t1] = [c, d, b] if _orient2d(pts[c], pts[d], pts[b]) > 0 else [d, c, b]
        tris[t2] = [d, c, a] if _orient2d(pts[d], pts[c], pts[a]) > 0 else [c, d, a]
        for t in (t1, t2):
            tt = tris[t]
            for i in range(3):
                adj[(tt[i], tt[(i + 1) % 3])] = t
        return c, d

    cset = {(min(a, b), max(a, b)) for a, b in constraints}
    for a, b in constraints:
        if (a, b) in adj or (b, a) in adj:
            continue
        pa, pb = pts[a], pts[b]
        crossing = [e for e in {(min(x, y), max(x, y)) for (x, y) in adj}
                    if a not in e and b not in e and _segments_cross(pa, pb, pts[e[0]], pts[e[1]])]
        guard = 0
        while crossing:
            guard += 1
            if guard > 20000:
                raise QitError(f"{label}: constraint recovery failed (the edge loop crosses itself in "
                               "pattern space); mesh this face with --mesher gmsh")
            e = crossing.pop(0)
            if (e[0], e[1]) not in adj or (e[1], e[0]) not in adj:
                continue
            x, y = e
            c = [v for v in tris[adj[(x, y)]] if v not in e][0]
            d = [v for v in tris[adj[(y, x)]] if v not in e][0]
            if not _segments_cross(pts[x], pts[y], pts[c], pts[d]):  # quad not convex
                crossing.append(e)
                continue
            c, d = flip(x, y)
            if a not in (c, d) and b not in (c, d) and _segments_cross(pa, pb, pts[c], pts[d]):
                crossing.append((min(c, d), max(c, d)))
    tris_a = np.array(tris)
    # even-odd flood fill: crossing a constraint toggles inside/outside
    n = len(tris_a)
    level = np.full(n, -1)
    nbr = []
    for t in tris_a:
        row = []
        for i in range(3):
            a, b = int(t[i]), int(t[(i + 1) % 3])
            row.append((adj.get((b, a), -1), (min(a, b), max(a, b)) in cset))
        nbr.append(row)
    from collections import deque

    dq = deque()
    for i in np.flatnonzero((tris_a >= n_real).any(axis=1)):  # the frame is outside
        level[i] = 0
        dq.append(i)
    while dq:
        i = dq.popleft()
        for o, c in nbr[i]:
            if o >= 0 and level[o] < 0:
                level[o] = level[i] + (1 if c else 0)
                if c:
                    dq.append(o)
                else:
                    dq.appendleft(o)
    return tris_a[level % 2 == 1]


def _edge_strip_flips(tris: np.ndarray, is_edge: np.ndarray, x: np.ndarray, uv: np.ndarray,
                      constrained: set) -> tuple[np.ndarray, int]:
    """Edge-strip amendment (section 6.4): in each pair of strip triangles (at least one
    edge vertex) forming a convex quadrilateral (in (u, v), so no flip can invert), keep the
    diagonal that is shorter in physical space. Sweeps until none changes (at most 4)."""
    tris = [list(t) for t in tris]
    flips = 0
    for _ in range(4):
        adj = _tri_adjacency(np.array(tris))
        changed = 0
        seen = set()
        for (a, b), t1 in list(adj.items()):
            key = (min(a, b), max(a, b))
            if key in seen or key in constrained:
                continue
            seen.add(key)
            t2 = adj.get((b, a))
            if t2 is None or t1 == t2:
                continue
            if tris[t1] is None or tris[t2] is None:
                continue
            if not (is_edge[tris[t1]].any() or is_edge[tris[t2]].any()):
                continue
            if a not in tris[t1] or b not in tris[t1] or a not in tris[t2] or b not in tris[t2]:
                continue
            c = [v for v in tris[t1] if v not in (a, b)][0]
            d = [v for v in tris[t2] if v not in (a, b)][0]
            if c == d or _orient2d(uv[c], uv[d], uv[b]) <= 0 or _orient2d(uv[d], uv[c], uv[a]) <= 0:
                continue  # reflex quadrilateral (the new pair would fold in (u, v)): not checked
            if np.linalg.norm(x[c] - x[d]) < np.linalg.norm(x[a] - x[b]) * (1 - 1e-12):
                # a-b-c is CCW in t1, so c, d, b and d, c, a are CCW
                tris[t1] = [c, d, b]
                tris[t2] = [d, c, a]
                changed += 1
                # refresh adjacency of the two triangles
                for t in (t1, t2):
                    tt = tris[t]
                    for i in range(3):
                        adj[(tt[i], tt[(i + 1) % 3])] = t
                seen.update({(min(c, d), max(c, d))})
        flips += changed
        if not changed:
            break
    return np.array(tris), flips


def _fix_slivers(tris: np.ndarray, x: np.ndarray, uv: np.ndarray, constrained: set,
                 min_angle: float = np.radians(0.5)) -> tuple[np.ndarray, int]:
    """Beyond the paper: a triangle flatter than ``min_angle`` (three nearly collinear
    vertices; on faces too small for an interior lattice the pattern coordinates of their
    edge vertices are extrapolated and the CDT can join three vertices of one straight edge)
    has its longest edge flipped, if that edge is not a loop segment and the new pair is
    positive in (u, v). Repeats until none is left or none can be flipped."""
    tris = [list(t) for t in tris]
    done = 0
    for _ in range(4 * len(tris) + 4):
        t_arr = np.array(tris)
        p = x[t_arr]
        ang = np.empty((len(t_arr), 3))
        for i in range(3):
            a, b = p[:, (i + 1) % 3] - p[:, i], p[:, (i + 2) % 3] - p[:, i]
            ang[:, i] = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))
        bad = np.flatnonzero(ang.min(axis=1) < min_angle)
        if bad.size == 0:
            break
        adj = _tri_adjacency(t_arr)
        flipped = False
        for t1 in bad:
            tt = tris[t1]
            k = int(np.argmax(ang[t1]))  # the vertex opposite the longest edge
            c, a, b = tt[k], tt[(k + 1) % 3], tt[(k + 2) % 3]
            if (min(a, b), max(a, b)) in constrained or (b, a) not in adj:
                continue
            t2 = adj[(b, a)]
            d = [v for v in tris[t2] if v not in (a, b)][0]
            if _orient2d(uv[c], uv[d], uv[b]) <= 0 and _orient2d(uv[d], uv[c], uv[a]) <= 0:
                continue
            new1, new2 = [c, a, d], [c, d, b]
            if _orient2d(uv[new1[0]], uv[new1[1]], uv[new1[2]]) <= 0 or _orient2d(uv[new2[0]], uv[new2[1]], uv[new2[2]]) <= 0:
                continue
            tris[t1], tris[t2] = new1, new2
            done += 1
            flipped = True
            break
        if not flipped:
            break
    return np.array(tris), done


# ---------------------------------------------------------------------------------------
# edges of the model: boundary curves, matching, discretisation


def _iso_loop(surface) -> list[NurbsCurve]:
    u0, u1, v0, v1 = surface.domain
    c = [(u0, v0), (u1, v0), (u1, v1), (u0, v1)]
    return [NurbsCurve(1, [0, 0, 1, 1], [c[i], c[(i + 1) % 4]]) for i in range(4)]


@dataclass
class _Edge:
    face: int
    loop: int
    curve: NurbsCurve
    x0: np.ndarray
    x1: np.ndarray
    samples: np.ndarray  # (S, 3) dense 3D polyline
    length: float
    owner: int = -1  # index of the edge whose discretisation this one uses
    reversed: bool = False
    t: np.ndarray | None = None  # parameters of the edge vertices (owner only)
    nodes: list = field(default_factory=list)  # global node ids, in this edge's direction
    uv: np.ndarray | None = None  # (n, 2) on this edge's face


def _face_loops(face) -> list[list[NurbsCurve]]:
    s = face.surface
    tr = face.trims
    loops = []
    if tr is None or tr.outer is None:
        loops.append(_iso_loop(s))
    else:
        loops.append(list(tr.outer.curves))
    if tr is not None:
        loops += [list(lp.curves) for lp in tr.inner]
    return loops


def _dist_to_polyline(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    a, b = poly[:-1], poly[1:]
    ab = b - a
    ll = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("kij,ij->ki", p[:, None] - a[None], ab) / np.where(ll > 0, ll, 1)[None], 0, 1)
    q = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(p[:, None] - q, axis=2).min(axis=1)


def _foot_on_curve(surface, curve: NurbsCurve, pts: np.ndarray, iters: int = 30):
    """(u, v) on ``curve`` (a face's edge in its parameter space) of the points of the curve
    S(c(t)) nearest to ``pts`` (M, 3): dense samples, then Newton on t for
    C'(t).(C(t) - p) = 0, t kept in the curve's domain (so the side of a seam the curve is
    on is kept). Returns uv (M, 2) and the distances (M,)."""
    t0, t1 = curve.domain
    ts = np.linspace(t0, t1, 513)
    cs = _edge_derivs(surface, curve, ts)[:, 0]
    t = ts[cKDTree(cs).query(pts)[1]]
    for _ in range(iters):
        d = _edge_derivs(surface, curve, t)
        r = d[:, 0] - pts
        f = np.einsum("ij,ij->i", d[:, 1], r)
        df = np.einsum("ij,ij->i", d[:, 2], r) + np.einsum("ij,ij->i", d[:, 1], d[:, 1])
        step = np.where(np.abs(df) > 0, f / np.where(np.abs(df) > 0, df, 1.0), 0.0)
        t = np.clip(t - step, t0, t1)
        if np.all(np.abs(step) <= 1e-14 * (t1 - t0)):
            break
    d = _edge_derivs(surface, curve, t)
    return curve.evaluate(t)[:, :2], np.linalg.norm(d[:, 0] - pts, axis=1)


def _face_label(model, f: int) -> str:
    face = model.faces[f]
    nm = f" '{face.name}'" if face.name else ""
    return f"face {f} (DE {face.de}{nm})"


def qit_mesh(model, size: float, options: QitOptions | None = None, faces=None, progress=None,
             reports: list | None = None, fallback: bool = False) -> Mesh:
    """QIT of the faces of ``model`` (`cadbridge.cad.model.Model`, or one `Face`) with target edge
    length ``size`` (R, model units).

    faces : indices of the faces to mesh (default all). Adjacent faces whose boundary curves
    coincide in 3D share one discretisation of that edge (same nodes). Returns a `Mesh`
    with one triangle block (CCW about Su x Sv of each face), point_data ``node_face``
    (N,) and ``node_uv`` (N, 2) (the face a node was made on and its parameters there),
    cell_data ``element_face`` (E,). ``reports`` (a list) receives one `QitFaceReport` per face.
    Raises `QitError` naming the face it cannot mesh -- unless ``fallback``: a face QIT
    refuses for its shape (a front that does not fill it, folds, a failed first hexagon or
    constraint recovery) is then meshed by gmsh on QIT's edge vertices
    (`cadbridge.mesh.gmsh.planar`; its report says ``mesher="gmsh"`` and why), so the
    shared edges still conform -- or, for a face that shares no edge or corner with another,
    by gmsh's own mesh of it where that has the larger share of angles within 60 +- 10 deg
    (``mesher="gmsh-face"``); a vanishing Jacobian (`QitJacobianError`) stays an error.
    """
    from cadbridge.cad.model import Face, Model

    if isinstance(model, Face):
        model = Model(faces=[model])
    opt = options or QitOptions(size=size)
    opt.size = float(size)
    if not (np.isfinite(opt.size) and opt.size > 0):
        raise QitError(f"QIT size must be a positive number, got {size!r}")
    R = opt.size
    dx_th = opt.threshold if opt.threshold is not None else R / 3.0
    face_ids = list(range(len(model.faces))) if faces is None else [int(f) for f in faces]
    if not face_ids:
        raise QitError("QIT: no faces to mesh")
    msize = model.size()
    mtol = opt.match_tol if opt.match_tol is not None else 1e-5 * msize

    def stage(text):
        if progress is not None:
            progress.stage(text)

    # --- edges
    edges: list[_Edge] = []
    face_loops: dict[int, list[list[int]]] = {}
    for f in face_ids:
        s = model.faces[f].surface
        u0, u1, v0, v1 = s.domain
        if not all(np.isfinite([u0, u1, v0, v1])):
            raise QitError(f"{_face_label(model, f)}: unbounded parameter domain; QIT cannot mesh it")
        face_loops[f] = []
        for li, loop in enumerate(_face_loops(model.faces[f])):
            ids = []
            for c in loop:
                tt = np.linspace(*c.domain, 65)
                xs = _edge_derivs(s, c, tt)[:, 0]
                ln = float(np.linalg.norm(np.diff(xs, axis=0), axis=1).sum())
                if ln <= 1e-9 * msize:
                    continue  # degenerate piece: its end points merge
                ids.append(len(edges))
                edges.append(_Edge(f, li, c, xs[0], xs[-1], xs, ln))
            face_loops[f].append(ids)
    # --- shared edges: same end points (either way) and every sample within mtol of the other
    ends = cKDTree(np.array([e.x0 for e in edges] + [e.x1 for e in edges]))
    n_e = len(edges)
    for i, e in enumerate(edges):
        if e.owner >= 0:
            continue
        e.owner = i
        cand = set(j % n_e for j in ends.query_ball_point(e.x0, mtol)) & set(j % n_e for j in ends.query_ball_point(e.x1, mtol))
        for j in sorted(cand):
            o = edges[j]
            if j <= i or o.owner >= 0:  # the same face too: the two sides of a seam
                continue
            if _dist_to_polyline(o.samples[::4], e.samples).max() > mtol + 1e-3 * e.length / 16:
                continue
            if _dist_to_polyline(e.samples[::4], o.samples).max() > mtol + 1e-3 * e.length / 16:
                continue
            o.owner = i
            o.reversed = bool(np.linalg.norm(o.x0 - e.x0) > np.linalg.norm(o.x0 - e.x1))
    # --- discretise owners; node registry (end points merged in 3D)
    stage(f"QIT: discretising {sum(e.owner == i for i, e in enumerate(edges))} edges by arc length")
    node_x: list[np.ndarray] = []
    node_face: list[int] = []
    node_uv: list[np.ndarray] = []
    # end points of all edges within mtol of each other are one node (union-find over pairs)
    ends_x = np.array([p for e in edges for p in (e.x0, e.x1)])
    parent = np.arange(len(ends_x))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in cKDTree(ends_x).query_pairs(mtol) if len(ends_x) else []:
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    corner_of: dict[int, int] = {}

    def corner_node(end: int, x, f, uv) -> int:
        r = find(end)
        if r not in corner_of:
            node_x.append(x)
            node_face.append(f)
            node_uv.append(uv)
            corner_of[r] = len(node_x) - 1
        return corner_of[r]

    for i, e in enumerate(edges):
        if e.owner != i:
            continue
        s = model.faces[e.face].surface
        closed = np.linalg.norm(e.x0 - e.x1) <= mtol
        sharers = [o for o in edges if o.owner == i]
        min_seg = 3 if closed and all(len(face_loops[o.face][o.loop]) == 1 for o in sharers) else 1
        t, _ = discretise_edge(s, e.curve, R, opt.edge_tol, opt.max_depth, min_seg)
        e.t = t
        d = _edge_derivs(s, e.curve, t)[:, 0]
        uv = e.curve.evaluate(t)[:, :2]
        ids = [corner_node(2 * i, d[0], e.face, uv[0])]
        for k in range(1, len(t) - 1):
            node_x.append(d[k])
            node_face.append(e.face)
            node_uv.append(uv[k])
            ids.append(len(node_x) - 1)
        ids.append(corner_node(2 * i + 1, d[-1], e.face, uv[-1]))
        e.nodes, e.uv = ids, uv
    for i, e in enumerate(edges):
        if e.owner == i:
            continue
        o = edges[e.owner]
        ids = o.nodes[::-1] if e.reversed else list(o.nodes)
        pts = np.array([node_x[k] for k in ids])
        s = model.faces[e.face].surface
        uv, dist = _foot_on_curve(s, e.curve, pts)
        if not np.all(dist <= 10 * mtol):
            raise QitError(f"{_face_label(model, e.face)}: the edge it shares with {_face_label(model, o.face)} "
                           f"is {float(np.max(dist)):.3g} off its own trim curve; QIT cannot conform them")
        e.nodes, e.uv = ids, uv
    # --- faces
    tri_all, tri_face = [], []
    for f in face_ids:
        label = _face_label(model, f)
        stage(f"QIT: {label}")
        rep = QitFaceReport(face=f)
        loops_f = [[edges[i] for i in lp] for lp in face_loops[f]]
        try:
            tris = _mesh_face(model, f, loops_f, opt, dx_th, label, node_x, node_face, node_uv, rep)
        except QitError as exc:
            if not fallback or isinstance(exc, QitJacobianError):
                raise
            stage(f"QIT: {label} refused ({str(exc).split(';')[0].removeprefix(label + ': ')}); meshing it with gmsh")
            rep = QitFaceReport(face=f, mesher="gmsh", refused=str(exc))
            tris = _refused_face(model, f, loops_f, opt, label, node_x, node_face, node_uv, rep,
                                 alone=_face_alone(f, edges, face_loops))
        rep.triangles = len(tris)
        if reports is not None:
            reports.append(rep)
        tri_all.append(tris)
        tri_face.append(np.full(len(tris), f, dtype=np.int64))
    tris = np.concatenate(tri_all).astype(np.int64)
    m = Mesh(np.array(node_x), [CellBlock("triangle", tris)],
             point_data={"node_face": np.array(node_face, dtype=np.int64), "node_uv": np.array(node_uv)},
             cell_data={"element_face": np.concatenate(tri_face)}, name="qit")
    return m.remove_unused_nodes()[0]


def _mesh_face(model, f: int, loops: list[list[_Edge]], opt: QitOptions, dx_th: float, label: str,
               node_x: list, node_face: list, node_uv: list, rep: QitFaceReport) -> np.ndarray:
    """Surface vertices, classification and triangulation of one face; appends its SI
    vertices to the node registry and returns its triangles (global node ids)."""
    face = model.faces[f]
    s = face.surface
    surf = _Surf(s)
    R = opt.size
    ds = _DSMesh(surf, opt.surface_tol, opt.max_depth, label)
    rep.ds_partitions = len(ds.leaves)
    # edge vertices of this face, loop by loop (global ids, uv here)
    loop_ids, loop_uv = _loop_vertices(loops)
    e_ids = np.array([k for ids in loop_ids for k in ids], dtype=np.int64)
    e_uv = np.concatenate(loop_uv)
    e_x = np.array([node_x[k] for k in e_ids])
    rep.edge_vertices = len(e_ids)
    if len(e_ids) < 3:
        raise QitError(f"{label}: boundary too short for QIT at size {R:g} (fewer than 3 edge vertices)")
    # propagation region and start
    if face.trims is not None and face.trims.outer is not None:
        lo, hi = e_uv.min(axis=0), e_uv.max(axis=0)
        pad = 0.02 * (hi - lo)
        region = np.array([max(lo[0] - pad[0], surf.lo[0]), min(hi[0] + pad[0], surf.hi[0]),
                           max(lo[1] - pad[1], surf.lo[1]), min(hi[1] + pad[1], surf.hi[1])])
    else:
        region = np.array([surf.lo[0], surf.hi[0], surf.lo[1], surf.hi[1]])
    centre = np.array([0.5 * (region[0] + region[1]), 0.5 * (region[2] + region[3])])
    perim = float(np.linalg.norm(np.diff(np.vstack([e_x, e_x[:1]]), axis=0), axis=1).sum())
    lat = _surface_vertices(surf, ds, region, centre, opt, int(perim / R) + 10, rep, label)
    uv = np.array(lat.uv)
    pr = np.array([lat.r(ij) for ij in lat.ij])
    rep.computed = len(uv)
    # SO: outside the face (domain + exact trims); SE: within dx_th of the edge polyline
    inside = face.contains(uv[:, 0], uv[:, 1]) if face.trims is not None else (
        np.all((uv >= surf.lo) & (uv <= surf.hi), axis=1))
    x = np.full((len(uv), 3), np.nan)
    if inside.any():
        x[inside] = s.evaluate(uv[inside, 0], uv[inside, 1])
    seg_a, seg_b = [], []
    for ids in loop_ids:
        arr = np.array([node_x[k] for k in ids])
        seg_a.append(arr)
        seg_b.append(np.roll(arr, -1, axis=0))
    seg_a, seg_b = np.concatenate(seg_a), np.concatenate(seg_b)
    edge_dist = _EdgeDistance(seg_a, seg_b, dx_th)
    dist = np.full(len(uv), np.inf)
    if inside.any():
        dist[inside] = edge_dist(x[inside])
    si = inside & (dist >= dx_th)
    # the front must have reached every edge vertex (else the CDT would bridge the gap with
    # slivers): a long face narrower than a few R can starve the hexagon rings
    xs_all, _, _ = surf.d1(uv)
    gap = cKDTree(xs_all).query(e_x)[0]
    if gap.max() > 2.0 * R:
        k = int(np.argmax(gap))
        raise QitError(f"{label}: the hexagonal front of QIT did not reach the whole face (edge vertex at "
                       f"{np.round(e_x[k], 6).tolist()} is {gap[k]:.3g} from every lattice vertex, R = {R:g}: "
                       "a long face only a few R wide); use a smaller --size or --mesher gmsh")
    rep.so = int((~inside).sum())
    rep.se = int((inside & ~si).sum())
    rep.si = int(si.sum())
    # pattern coordinates of the edge vertices (eqs. 19-20): area coordinates in the lattice's
    # own cells (not a Delaunay of the (u, v), which the distortion folds)
    e_pr = _interpolate_pattern(xs_all, uv, pr, _lattice_cells(lat.ij), e_x, e_uv, R)
    # constrained Delaunay in pattern space
    si_idx = np.flatnonzero(si)
    pts = np.concatenate([pr[si_idx], e_pr])
    if len(si_idx) == 0:
        d = s.derivatives(uv[:, 0].clip(surf.lo[0], surf.hi[0]), uv[:, 1].clip(surf.lo[1], surf.hi[1]), order=1)
        scale = np.array([np.linalg.norm(d[:, 1, 0], axis=1).mean(), np.linalg.norm(d[:, 0, 1], axis=1).mean()])
        # no interior lattice vertex (a face about R wide or smaller): the pattern positions
        # of its edge vertices are all extrapolated, and straight edges can come out bent;
        # the loop is then triangulated in its (u, v) scaled by the metric instead
        pts = e_uv * scale
    n_si = len(si_idx)
    cons = []
    off = n_si
    for ids in loop_ids:
        n = len(ids)
        cons += [(off + k, off + (k + 1) % n) for k in range(n)]
        off += n
    local = _constrained_delaunay(pts, cons, label)
    # node ids: SI vertices become new nodes
    base = len(node_x)
    si_x = x[si_idx]
    for k in range(n_si):
        node_x.append(si_x[k])
        node_face.append(f)
        node_uv.append(uv[si_idx[k]])
    gid = np.concatenate([base + np.arange(n_si), e_ids])
    all_uv = np.concatenate([uv[si_idx], e_uv])
    all_x = np.concatenate([si_x, e_x])
    # orientation: CCW in (u, v) (so along Su x Sv)
    a, bb, c = all_uv[local[:, 0]], all_uv[local[:, 1]], all_uv[local[:, 2]]
    sgn = (bb[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (bb[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    if np.sum(sgn < 0) > np.sum(sgn > 0):  # the pattern->parameter map reverses orientation
        local = local[:, [0, 2, 1]]
    if opt.edge_flips:
        is_edge = np.zeros(len(pts), dtype=bool)
        is_edge[n_si:] = True
        local, rep.flips = _edge_strip_flips(local, is_edge, all_x, all_uv, {(min(p, q), max(p, q)) for p, q in cons})
    local, fixed = _fix_slivers(local, all_x, all_uv, {(min(p, q), max(p, q)) for p, q in cons})
    rep.flips += fixed
    if opt.strip_opt and n_si:
        local, all_uv, all_x = _relax_strip(local, all_uv, all_x, n_si, s, face, opt, edge_dist, dx_th,
                                            {(min(p, q), max(p, q)) for p, q in cons}, rep)
        for k in range(n_si):  # the relaxed SI vertices replace their registry entries
            node_x[base + k] = all_x[k]
            node_uv[base + k] = all_uv[k]
    out = gid[local]
    # two loop vertices may be one node (the two sides of a seam meet in 3D): a triangle on
    # both has two coincident corners, zero area; dropping it joins its neighbours there
    rep_node = (out[:, 0] == out[:, 1]) | (out[:, 1] == out[:, 2]) | (out[:, 2] == out[:, 0])
    rep.seam_dropped = int(rep_node.sum())
    local = local[~rep_node]
    # guard: a triangle whose normal opposes the surface normal at its (u, v) centroid is
    # folded (R too large for the curvature, or a parametrisation so uneven that the lattice
    # left a gap the CDT bridged); a silent fold would poison the Nagata tool
    cuv = surf.clamp(all_uv[local].mean(axis=1))
    d = s.derivatives(cuv[:, 0], cuv[:, 1], order=1)
    nrm = np.cross(d[:, 1, 0], d[:, 0, 1])  # at the (u, v) centroid of each triangle
    p = all_x[local]
    tn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    folded = np.einsum("kj,kj->k", tn, nrm) <= 0
    if folded.any():
        k = int(np.flatnonzero(folded)[0])
        raise QitError(f"{label}: QIT made {int(folded.sum())} folded triangles (normal against the surface's, "
                       f"first near {np.round(p[k].mean(axis=0), 6).tolist()}; R = {R:g} is too large for the "
                       "curvature or the parametrisation too uneven there); use a smaller --size or --mesher gmsh")
    return out[~rep_node]


def _relax_strip(local, all_uv, all_x, n_si, s, face, opt: QitOptions, edge_dist, dx_th, constrained, rep):
    """Beyond the paper (``opt.strip_opt``, docs/qit.md choice 19): two passes of valence
    flips and spring relocation of the SI vertices within 2 mesh edges of the face's edge
    vertices; then (a) the SI vertices of triangles with an angle over ``strip_max_angle``
    relocated again (their largest angles not raised) and the max-angle clean-up, or (b) the
    clean-up alone; the first of (a), (b) that leaves the face no worse than the paper's
    triangulation by smallest angle, largest angle (up to ``strip_max_angle``), angle spread,
    size spread, folds and the face's Q is kept, else the paper's (`cadbridge.mesh.qit.relax`). Local
    vertices 0..n_si-1 are the SI ones; the edge vertices stay. Returns triangles, uv, x."""
    from cadbridge.mesh.qit.relax import max_angle_flips, relax_vertices, tri_angles, valence_flips, vertex_angle_sums
    from cadbridge.mesh.quality import mesh_quality

    local0, uv0, x0 = local, all_uv, all_x
    is_edge = np.zeros(len(all_uv), dtype=bool)
    is_edge[n_si:] = True
    near = is_edge.copy()
    e = np.concatenate([local[:, [0, 1]], local[:, [1, 2]], local[:, [2, 0]]])
    for _ in range(2):
        near[e[near[e[:, 0]] | near[e[:, 1]]].ravel()] = True
    free = near & ~is_edge
    trimmed = face.trims is not None and face.trims.outer is not None
    R = opt.size

    def admissible(uv, x):
        ok = edge_dist(x) >= dx_th
        if trimmed and ok.any():
            ok[ok] = face.contains(uv[ok, 0], uv[ok, 1])
        return ok

    for _ in range(2):
        alpha = vertex_angle_sums(local, all_x, is_edge)
        local, nf = valence_flips(local, all_uv, all_x, alpha, constrained, min_angle=10.0, max_angle=150.0)
        rep.valence_flips += nf
        all_uv, all_x, nm = relax_vertices(local, all_uv, all_x, free, s, R, admissible)
        rep.relaxed = max(rep.relaxed, nm)

    def measures(uv, x, t):
        a = np.degrees(tri_angles(x, t))
        p = x[t]
        area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
        q = mesh_quality(x, t, R).q
        return a.min(), a.max(), a.std(), (area / (R * R * np.sqrt(3) / 4)).std(), _n_folded(s, uv, x, t), q

    m0 = measures(uv0, x0, local0)
    over = np.degrees(tri_angles(all_x, local)).max(axis=1) > opt.strip_max_angle
    fix = np.zeros(len(all_uv), dtype=bool)
    fix[local[over].ravel()] = True
    uv_a, x_a, _ = relax_vertices(local, all_uv, all_x, fix & ~is_edge, s, R, admissible, keep_max=True)
    for uv_c, x_c in ((uv_a, x_a), (all_uv, all_x)):
        t_c, nf = max_angle_flips(local, uv_c, x_c, constrained, opt.strip_max_angle)
        m = measures(uv_c, x_c, t_c)
        if (m[0] >= m0[0] - 1e-9 and m[1] <= max(m0[1], opt.strip_max_angle) + 1e-9 and m[2] <= m0[2] + 1e-9
                and m[3] <= m0[3] + 1e-9 and m[4] <= m0[4] and m[5] >= m0[5] - 1e-9):
            rep.flips += nf
            return t_c, uv_c, x_c
    rep.strip_reverted = True
    return local0, uv0, x0


def _loop_vertices(loops: list[list[_Edge]]) -> tuple[list[list[int]], list[np.ndarray]]:
    """Per loop of a face, its edge vertices in loop order (global ids, each edge's last
    vertex left to the next edge) and their (u, v) on this face, (n, 2)."""
    loop_ids, loop_uv = [], []
    for lp in loops:
        ids, uvs = [], []
        for e in lp:
            ids += list(e.nodes[:-1])
            uvs.append(e.uv[:-1])
        loop_ids.append(ids)
        loop_uv.append(np.concatenate(uvs) if uvs else np.zeros((0, 2)))
    return loop_ids, loop_uv


def _fallback_face(model, f: int, loops: list[list[_Edge]], opt: QitOptions, label: str,
                   node_x: list, node_face: list, node_uv: list, rep: QitFaceReport) -> np.ndarray:
    """A face QIT refused, meshed by gmsh in its metric-scaled (u, v) on QIT's edge vertices
    (`cadbridge.mesh.gmsh.planar`); appends its interior vertices to the node registry and
    returns its triangles (global ids), CCW about Su x Sv."""
    from cadbridge.mesh.gmsh.planar import mesh_loops_in_parameter_space

    s = model.faces[f].surface
    loop_ids, loop_uv = _loop_vertices(loops)
    keep = [i for i, ids in enumerate(loop_ids) if ids]
    loop_ids, loop_uv = [loop_ids[i] for i in keep], [loop_uv[i] for i in keep]
    e_ids = np.array([k for ids in loop_ids for k in ids], dtype=np.int64)
    if len(e_ids) < 3:
        raise QitError(f"{label}: boundary too short for a mesh at size {opt.size:g} (fewer than 3 edge vertices)")
    e_uv = np.concatenate(loop_uv)
    u0, u1, v0, v1 = s.domain
    c = np.clip(e_uv, [u0, v0], [u1, v1])
    d = s.derivatives(c[:, 0], c[:, 1], order=1)
    scale = np.array([np.linalg.norm(d[:, 1, 0], axis=1).mean(), np.linalg.norm(d[:, 0, 1], axis=1).mean()])
    scale = np.maximum(scale, 1e-12 * max(scale.max(), 1e-300))
    try:
        uv, tris = mesh_loops_in_parameter_space(loop_uv, scale, opt.size, label)
    except MeshError as exc:
        raise QitError(f"{rep.refused}; {exc}") from exc
    n_loop = len(e_ids)
    x_in = s.evaluate(uv[n_loop:, 0], uv[n_loop:, 1]) if len(uv) > n_loop else np.zeros((0, 3))
    all_x = np.concatenate([np.array([node_x[k] for k in e_ids]), x_in])
    folded = _n_folded(s, uv, all_x, tris)
    if folded:
        raise QitError(f"{rep.refused}; the gmsh fallback in its (u, v) folded {folded} triangles too; "
                       "mesh this file with --mesher gmsh")
    base = len(node_x)
    for k in range(len(x_in)):
        node_x.append(x_in[k])
        node_face.append(f)
        node_uv.append(uv[n_loop + k])
    gid = np.concatenate([e_ids, base + np.arange(len(x_in))])
    out = gid[tris]
    keep = (out[:, 0] != out[:, 1]) & (out[:, 1] != out[:, 2]) & (out[:, 2] != out[:, 0])  # seams
    rep.edge_vertices = n_loop
    rep.seam_dropped = int((~keep).sum())
    return out[keep]


def angle_share(x: np.ndarray, tris: np.ndarray, tol: float = 10.0) -> float:
    """Share of the triangles' angles within 60 +- ``tol`` degrees (x (N, 3), tris (T, 3))."""
    from cadbridge.mesh.quality import triangle_angles

    return float(np.mean(np.abs(triangle_angles(x, tris) - 60.0) <= tol)) if len(tris) else 0.0


def _face_alone(f: int, edges: list[_Edge], face_loops: dict) -> bool:
    """True if face f shares no edge and no corner with another face being meshed."""
    own = {i for lp in face_loops[f] for i in lp}
    shared = any((i in own) != (e.owner in own) for i, e in enumerate(edges))
    mine = {k for i in own for k in edges[i].nodes}
    others = {k for i, e in enumerate(edges) if i not in own for k in e.nodes}
    return not shared and not (mine & others)


def _refused_face(model, f: int, loops: list[list[_Edge]], opt: QitOptions, label: str,
                  node_x: list, node_face: list, node_uv: list, rep: QitFaceReport, *, alone: bool) -> np.ndarray:
    """A face QIT refused: gmsh on QIT's edge vertices (`_fallback_face`, conformal with its
    neighbours) or, for a face that shares no edge or corner with another (``alone``), also
    gmsh's own mesh of the face at the same size (`_gmsh_own_face`); the one with the larger
    share of angles within 60 +- 10 deg is kept (its name in ``rep.mesher``, both shares in
    ``rep.choice``). Appends the kept interior nodes to the registry; returns triangles."""
    n0 = len(node_x)
    try:
        tris = _fallback_face(model, f, loops, opt, label, node_x, node_face, node_uv, rep)
        fb = angle_share(np.array(node_x), tris)
    except QitError as exc:
        if not alone:
            raise
        tris, fb, why = None, -1.0, exc
    if not alone:
        return tris
    try:
        x, uv, own = _gmsh_own_face(model.faces[f], opt.size)
    except MeshError as exc:
        if tris is None:
            raise QitError(f"{why}; gmsh's own mesh of the face failed too: {exc}") from exc
        rep.choice = f"gmsh's own mesh of the face failed: {exc}"
        return tris
    gm = angle_share(x, own)
    rep.choice = (f"within 60 +- 10 deg: gmsh on QIT's edge vertices "
                  f"{'failed' if fb < 0 else f'{100 * fb:.0f} %'}, gmsh's own mesh of the face {100 * gm:.0f} %")
    if tris is not None and fb >= gm:
        return tris
    del node_x[n0:], node_face[n0:], node_uv[n0:]
    node_x.extend(x)
    node_face.extend([f] * len(x))
    node_uv.extend(uv)
    rep.mesher = "gmsh-face"
    rep.edge_vertices = 0
    return own + n0


def _gmsh_own_face(face, size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """gmsh's own mesh of one face (Frontal-Delaunay on the face through OCC, size ``size``,
    `cadbridge.mesh.generate.mesh_cad`), its nodes moved onto S(u, v) at their feet on the
    surface (`cadbridge.nurbs.project.project_to_surface`). Returns x (N, 3),
    uv (N, 2) and triangles (T, 3), counter-clockwise about Su x Sv."""
    import tempfile
    from pathlib import Path

    from cadbridge.iges import write_iges
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.nurbs.project import project_to_surface

    with tempfile.TemporaryDirectory() as td:
        p = Path(td) / "face.igs"
        write_iges([face], p)
        m = mesh_cad(p, element="tri", size=size, parametric=False)
    if len(m.triangles) == 0:
        raise MeshError("gmsh made no triangles on the face")
    s = face.surface
    pr = project_to_surface(s, m.nodes)
    uv = np.column_stack([pr.u, pr.v])
    x = s.evaluate(uv[:, 0], uv[:, 1])
    tris = m.triangles.astype(np.int64)
    d = s.derivatives(*uv[tris].mean(axis=1).T, order=1)
    tn = np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]])
    if np.sum(np.einsum("kj,kj->k", tn, np.cross(d[:, 1, 0], d[:, 0, 1])) < 0) > len(tris) / 2:
        tris = tris[:, [0, 2, 1]]
    return x, uv, tris


def _n_folded(s, uv: np.ndarray, x: np.ndarray, tris: np.ndarray) -> int:
    """Triangles whose 3D normal is against Su x Sv at their (u, v) centroid."""
    u0, u1, v0, v1 = s.domain
    c = np.clip(uv[tris].mean(axis=1), [u0, v0], [u1, v1])
    d = s.derivatives(c[:, 0], c[:, 1], order=1)
    p = x[tris]
    tn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return int(np.sum(np.einsum("kj,kj->k", tn, np.cross(d[:, 1, 0], d[:, 0, 1])) <= 0))


def _lattice_cells(ij: list[tuple[int, int]]) -> np.ndarray:
    """(T, 3) indices (CCW in the pattern) of the lattice triangles whose three vertices were
    computed: up cells (i, j), (i+1, j), (i, j+1) and down cells (i+1, j), (i+1, j+1), (i, j+1)."""
    idx = {tuple(k): n for n, k in enumerate(ij)}
    out = []
    for (i, j), n in idx.items():
        a, b, c = idx.get((i + 1, j)), idx.get((i, j + 1)), idx.get((i + 1, j + 1))
        if a is not None and b is not None:
            out.append((n, a, b))
            if c is not None:
                out.append((a, c, b))
    return np.array(out, dtype=np.int64).reshape(-1, 3)


def _interpolate_pattern(x: np.ndarray, uv: np.ndarray, r: np.ndarray, cells: np.ndarray, qx: np.ndarray,
                         quv: np.ndarray, R: float, k: int = 6) -> np.ndarray:
    """Eqs. 19-20: pattern coordinates (E, 2) of the edge vertices (3D qx (E, 3), parameters
    quv (E, 2)) by area coordinates, in (u, v), in the lattice cell that contains them
    (``cells`` (T, 3) into the lattice vertices x (N, 3), uv (N, 2), pattern r (N, 2)). The
    cells are the images of the pattern's own triangles, so the map is the lattice's
    piecewise-linear one, one-to-one wherever the lattice is; a triangulation made in
    (u, v) instead (a Delaunay) joins, where the parametrisation is distorted, vertices
    that the pattern orders the other way, and its map folds (on clustered knots the edge
    loop came out folded or self-crossing). A vertex in no cell takes the cell whose least
    area coordinate is largest (linear extrapolation); where cells overlap (a lattice that
    ran over itself), the one nearest the pattern's centre. Candidates: the cells around the
    k lattice vertices nearest in 3D. Area coordinates in (u, v) are still first-order in
    the cell's size, so the point is then refined by trilateration: the lattice was built
    with chords |x_c - x_a| = |r_c - r_a| (AIP with the chord polish), so the pattern point
    whose distances to those k vertices (the ones within 2R of it in the pattern) are their
    3D chords to the edge vertex, weights 1/chord^2 (Gauss-Newton; kept where it fits better)."""
    inc_t = np.repeat(np.arange(len(cells)), 3)
    inc_v = cells.ravel()
    order = np.argsort(inc_v, kind="stable")
    inc_v, inc_t = inc_v[order], inc_t[order]
    start = np.searchsorted(inc_v, np.arange(len(x) + 1))
    used = np.unique(inc_v)
    _, near = cKDTree(x[used]).query(qx, k=min(k, len(used)))
    near = used[np.asarray(near).reshape(len(qx), -1)]
    cand = [np.unique(np.concatenate([inc_t[start[v]:start[v + 1]] for v in row])) for row in near]
    width = max(len(c) for c in cand)
    ct = np.array([np.pad(c, (0, width - len(c)), mode="edge") for c in cand])  # (E, W)
    a = uv[cells[ct, 0]]
    v0, v1, v2 = uv[cells[ct, 1]] - a, uv[cells[ct, 2]] - a, quv[:, None] - a  # (E, W, 2)
    den = v0[..., 0] * v1[..., 1] - v0[..., 1] * v1[..., 0]
    den = np.where(np.abs(den) > 0, den, np.inf)
    l1 = (v2[..., 0] * v1[..., 1] - v2[..., 1] * v1[..., 0]) / den
    l2 = (v0[..., 0] * v2[..., 1] - v0[..., 1] * v2[..., 0]) / den
    lam = np.stack([1 - l1 - l2, l1, l2], axis=-1)  # (E, W, 3)
    # a cell that contains the vertex, nearest the lattice's centre (where the lattice
    # overlaps itself, the part the front made first); else the least-outside one
    least = lam.min(axis=-1)
    ring = np.linalg.norm(r[cells[ct]].mean(axis=2), axis=-1) / R
    best = np.argmax(np.where(least >= -1e-9, 1e6 - ring, least), axis=1)
    rows = np.arange(len(qx))
    q = np.einsum("ki,kij->kj", lam[rows, best], r[cells[ct[rows, best]]])
    # trilateration (Gauss-Newton on |q - r_i| = |qx - x_i|)
    q0 = q
    d = np.linalg.norm(x[near] - qx[:, None], axis=2)  # (E, k)
    rn = r[near]
    w = np.where(np.linalg.norm(rn - q[:, None], axis=2) <= 2.0 * R, 1.0 / np.maximum(d, 1e-3 * R) ** 2, 0.0)
    for _ in range(20):
        dv = q[:, None] - rn
        ln = np.maximum(np.linalg.norm(dv, axis=2), 1e-300)
        J = dv / ln[..., None]  # (E, k, 2)
        res = ln - d
        A = np.einsum("ek,eki,ekj->eij", w, J, J)
        b = np.einsum("ek,eki,ek->ei", w, J, res)
        step = np.linalg.solve(A + 1e-12 * np.eye(2), b[..., None])[..., 0]
        q = q - step
        if np.abs(step).max() < 1e-9 * R:
            break

    def misfit(p):
        return np.einsum("ek,ek->e", w, (np.linalg.norm(p[:, None] - rn, axis=2) - d) ** 2)

    return np.where((misfit(q) <= misfit(q0))[:, None], q, q0)


class _EdgeDistance:
    """Distance in 3D from points to the chords (seg_a[i], seg_b[i]) of a face's edge
    polylines, exact wherever it is below ``dx_th`` (KD-tree of chord midpoints; the 16
    nearest chords, all chords within dx_th + half the longest chord where that is not enough)."""

    def __init__(self, seg_a: np.ndarray, seg_b: np.ndarray, dx_th: float) -> None:
        self.a, self.b, self.dx_th = seg_a, seg_b, dx_th
        self.half = 0.5 * np.linalg.norm(seg_b - seg_a, axis=1).max()
        self.tree = cKDTree(0.5 * (seg_a + seg_b))
        self.kk = min(16, len(seg_a))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """(M,) distances of the points x (M, 3)."""
        kk = self.kk
        dm, nn = self.tree.query(x, k=kk)
        dm, nn = dm.reshape(len(x), kk), nn.reshape(len(x), kk)
        p = x[:, None]
        a, ab = self.a[nn], self.b[nn] - self.a[nn]
        t = np.clip(np.einsum("kij,kij->ki", p - a, ab) / np.maximum(np.einsum("kij,kij->ki", ab, ab), 1e-300), 0, 1)
        dist = np.linalg.norm(p - (a + t[..., None] * ab), axis=2).min(axis=1)
        # a chord within dx_th may be farther than the kk-th midpoint only if that one is near
        for k in np.flatnonzero(dm[:, -1] < self.dx_th + self.half) if kk < len(self.a) else []:
            c = np.array(self.tree.query_ball_point(x[k], self.dx_th + self.half))
            dist[k] = _dist_to_polyline_pairs(x[k], self.a[c], self.b[c])
        return dist


def _dist_to_polyline_pairs(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    ll = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.where(ll > 0, ll, 1.0), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + t[:, None] * ab), axis=1).min())


def mesh_cad_qit(path, *, size: float | None = None, element: str = "tri", structured: bool = False,
                 embed_curves=(), options: QitOptions | None = None, progress=None) -> Mesh:
    """`cadbridge.mesh.generate.mesh_cad` with ``mesher="qit"``: read the IGES file and mesh
    all its faces with QIT (default size: bounding-box diagonal / 20, as gmsh's default).
    Raises `MeshError` (one line) for what QIT does not do: quads, structured meshes,
    crease lines inside faces (``embed_curves``). Faces QIT refuses are meshed by gmsh on
    QIT's edge vertices, or by gmsh's own mesh where that is better on a face alone
    (``qit_mesh(..., fallback=True)``); each such face is named, with the way it went, in a
    warning and in ``mesh.notes`` (the notes the CLI prints)."""
    from pathlib import Path

    from cadbridge.formats import read_cad
    from cadbridge.iges import IgesError
    from cadbridge.step import StepError

    path = Path(path)
    if element != "tri":
        raise MeshError("QIT makes triangles only: --element quad needs --mesher gmsh")
    if structured:
        raise MeshError("QIT makes unstructured meshes: --structured needs --mesher gmsh")
    if not path.is_file():
        raise MeshError(f"{path}: no such file")
    try:
        model = read_cad(path)
    except (IgesError, StepError) as exc:
        raise MeshError(str(exc)) from exc
    if embed_curves:
        raise MeshError(f"{path}: {len(embed_curves)} crease lines inside faces (C0 knots) must become mesh edges; "
                        "QIT does not embed curves: mesh this file with --mesher gmsh")
    if size is None:
        size = model.size() / 20.0
    reports: list = []
    mesh = qit_mesh(model, size, options, progress=progress, fallback=True, reports=reports)
    import warnings

    for r in reports:
        if r.mesher != "qit":
            how = "gmsh on QIT's edge vertices" if r.mesher == "gmsh" else "gmsh's own mesh of the face"
            note = f"{r.refused.split(';')[0]}; meshing it with {how}" + (f" ({r.choice})" if r.choice else "")
            mesh.notes.append(f"mesh: {note}")
            warnings.warn(note, stacklevel=2)
    mesh.name = path.stem
    return mesh
