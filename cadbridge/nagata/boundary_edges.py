"""Conormals of a tool mesh's free boundary edges, from the exact trim curves of its faces.

A Nagata edge with the same surface normal at both ends is a straight chord on a plane: the
normals carry the normal curvature of a surface curve, not its geodesic curvature. Along a
round hole in a flat die face the chord cuts the hole's circle (0.34 mm of boundary error on
the ``trimmed_hole`` sample's R 10 hole), and on any curved trim the patch boundary leaves the
trimmed face. The edge curve follows the trim curve if, at each end, it is also orthogonal to
the curve's *conormal* ``b = t x n`` (``t`` the trim curve's tangent on the surface, ``n`` the
corner normal the patch uses there): ``n . (d - c) = b . (d - c) = 0`` makes the end tangent
``d - c`` parallel to ``t``. The surface normals keep fixing the edge's normal curvature
(eq. 15) and the conormals add the sideways part in least squares
(`cadbridge.nagata.edge.edge_coefficient_conormal`); the tool file carries the conormals
(docs/toolfile.md, EDGE_NORMALS, rule 4b) so that its reader rebuilds the same curve.

For every free edge (one element) of a face with trim curves (or of an untrimmed face, whose
boundary is its parameter domain's border): the trim curve nearest the edge's midpoint is the
curve it follows, both end nodes are projected onto that curve exactly (Newton on
``(S(c(t)) - x) . C'(t) = 0``, the compiled kernel of `cadbridge.cad.trims`), and ``t = C'(t)``
there, evaluated a hair inside the edge (one-sided at a kink of the curve or at a C0 knot of
the surface). An edge is left to the two-normal formula (a chord) when it does not lie along a
curve or a quadratic cannot follow the curve there: an end node farther than ``1e-3 |d|``
(plus 1e-9 x model size) from the curve, the midpoint farther than ``|d| / 4``, an end tangent
more than 45 degrees from the chord, or a solution with ``|c| > |d|`` or an end tangent
``d -+ c`` more than 20 degrees from the curve's (an S-shaped, twisted or kinked stretch), or
one that does not halve the two-normal chord's distance to the curve (at 1/4, 1/2 and 3/4 of
the edge): where the surface normals already give the curve, nothing is added.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from cadbridge.nagata.edge import edge_coefficient, edge_coefficient_conormal
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.mesh.topology import edge_table
from cadbridge.cad.trims import curve_ders, curve_newton

MAX_TANGENT_DEG = 45.0
"""An end tangent further than this from the chord: the edge does not follow the curve."""

MATCH_DEG = 20.0
"""The edge curve's end tangent must be this close to the trim curve's (else: the chord)."""


@dataclass
class BoundaryConormals:
    """Extra edge normals for `cadbridge.nagata.NagataMesh` (``edge_normals``)."""

    pairs: NDArray  # (B, 2) node ids of the free edges that follow a trim curve
    p: NDArray  # (B, 3) unit conormal at pairs[:, 0]
    q: NDArray  # (B, 3) unit conormal at pairs[:, 1]
    free: int  # number of free edges in the mesh
    skipped: int  # free edges left as chords (no face curve they follow)

    def as_edge_normals(self) -> tuple[NDArray, NDArray, NDArray]:
        return self.pairs, self.p, self.q


def _face_curves(face) -> list[NurbsCurve]:
    """The (u, v) boundary curves of a face: its trim loops, or its domain's four sides."""
    tr = face.trims
    curves: list[NurbsCurve] = []
    if tr is not None:
        for loop in ([tr.outer] if tr.outer is not None else []) + list(tr.inner):
            curves += [c for c in loop.curves if getattr(c, "dim", 2) == 2]
    if tr is None or tr.outer is None:
        u0, u1, v0, v1 = face.surface.domain
        for p0, p1 in (((u0, v0), (u1, v0)), ((u1, v0), (u1, v1)), ((u1, v1), (u0, v1)), ((u0, v1), (u0, v0))):
            curves.append(NurbsCurve(1, [0.0, 0.0, 1.0, 1.0], [p0, p1]))
    return curves


def _curve_feet(surf, curve: NurbsCurve, pts: NDArray, size: float, samples: int = 16):
    """Nearest points of ``S(curve(t))`` to (M, 3) points: (distance (M,), parameter t (M,)).

    Start at the nearest of ``samples`` points per knot span, then `cadbridge.cad.trims.curve_newton`."""
    u0, u1, v0, v1 = surf.domain
    ts = curve.sample_parameters(samples)
    c = curve_ders(curve, ts, 0)[:, 0]
    xs = surf.evaluate(np.clip(c[:, 0], u0, u1), np.clip(c[:, 1], v0, v1))
    _, k = cKDTree(xs).query(pts)
    t = np.ascontiguousarray(ts[np.asarray(k)], dtype=float)
    closed = float(np.linalg.norm(xs[0] - xs[-1])) <= 1e-9 * size
    curve_newton(surf, curve, pts, t, closed, 1e-12 * size)
    c = curve_ders(curve, t, 0)[:, 0]
    x = surf.evaluate(np.clip(c[:, 0], u0, u1), np.clip(c[:, 1], v0, v1))
    return np.linalg.norm(x - pts, axis=1), t


def _curve_tangent(surf, curve: NurbsCurve, t: NDArray) -> NDArray:
    """(M, 3) tangent ``C'(t) = Su u' + Sv v'`` of ``S(curve(t))``."""
    u0, u1, v0, v1 = surf.domain
    t0, t1 = curve.domain
    c = curve_ders(curve, np.clip(t, t0, t1), 1)  # (M, 2, 2): uv, uv'
    d = surf.derivatives(np.clip(c[:, 0, 0], u0, u1), np.clip(c[:, 0, 1], v0, v1), order=1)
    return d[:, 1, 0] * c[:, 1, 0:1] + d[:, 0, 1] * c[:, 1, 1:2]


def boundary_curve_distance(face, points: NDArray, size: float) -> NDArray:
    """Distance (M,) of (M, 3) points to the nearest boundary curve of ``face`` (trim loops,
    or the domain's four sides), exact (Newton on each curve on the surface)."""
    best = np.full(len(points), np.inf)
    if len(points):
        for cv in _face_curves(face):  # the face's few boundary curves
            dist, _ = _curve_feet(face.surface, cv, points, size)
            np.minimum(best, dist, out=best)
    return best


def free_edge_samples(nm, elem: NDArray, eta: NDArray, zeta: NDArray) -> NDArray:
    """(M,) bool: which samples (elem, eta, zeta) of the `NagataMesh` ``nm`` lie on a free
    edge (an edge of one element only), corners included."""
    topo = nm.edges
    free_inst = topo["count"][topo["inst_edge"]] == 1
    inst = nm._elem_inst[elem]  # (M, 4) instance of each local edge, -1 padding
    tri = nm.element_kind[elem] == 3
    e0, e1 = np.isclose(eta, 0.0, atol=1e-12), np.isclose(eta, 1.0, atol=1e-12)
    z0, z1 = np.isclose(zeta, 0.0, atol=1e-12), np.isclose(zeta, 1.0, atol=1e-12)
    on = np.stack([z0, e1, np.where(tri, np.isclose(eta, zeta, atol=1e-12), z1), ~tri & e0], 1)  # local edges c1..c4
    free = np.where(inst >= 0, free_inst[np.maximum(inst, 0)], False)
    return np.any(on & free, axis=1)


def boundary_conormals(mesh, corner_normals: list[NDArray], element_face: NDArray, model) -> BoundaryConormals:
    """Conormals at both ends of the free edges that follow a face's boundary curve.

    mesh: `cadbridge.mesh.Mesh` (its blocks in global element order); corner_normals per
    block (E_b, k, 3); element_face (E,) face index of each element. The free edges come from
    `cadbridge.mesh.topology.edge_table`; the loop runs over the faces that own free edges and
    their boundary curves, vectorised over those edges."""
    nodes = mesh.nodes
    t = edge_table(mesh)
    free = np.flatnonzero(t.counts == 1)
    first = t.ptr[free]
    el, side = t.elems[first], t.side[first]
    e = t.edges[free]
    fwd = t.forward[first]
    a, b = np.where(fwd, e[:, 0], e[:, 1]), np.where(fwd, e[:, 1], e[:, 0])  # in the element's winding
    size = model.size()
    nb = len(a)
    pairs, ps, qs = [np.zeros((0, 2), np.int64)], [np.zeros((0, 3))], [np.zeros((0, 3))]
    if nb == 0:
        return BoundaryConormals(pairs[0], ps[0], qs[0], 0, 0)
    starts = np.concatenate([[0], np.cumsum([len(c) for c in corner_normals])])
    blk_of = np.searchsorted(starts, el, side="right") - 1
    n_a = np.empty((nb, 3))
    n_b = np.empty((nb, 3))
    for i, cn in enumerate(corner_normals):  # per block
        m = blk_of == i
        k = cn.shape[1]
        ei = el[m] - starts[i]
        n_a[m] = cn[ei, side[m]]
        n_b[m] = cn[ei, (side[m] + 1) % k]
    ef = np.asarray(element_face, dtype=np.int64)[el]
    kept = 0
    cos_max = np.cos(np.radians(MAX_TANGENT_DEG))
    for f in np.unique(ef[ef >= 0]):  # per face owning free edges
        sel = np.flatnonzero(ef == f)
        face = model.faces[int(f)]
        surf = face.surface
        x0, x1 = nodes[a[sel]], nodes[b[sel]]
        d = x1 - x0
        ld = np.linalg.norm(d, axis=1)
        mid = 0.5 * (x0 + x1)
        curves = _face_curves(face)
        best = np.full(len(sel), np.inf)
        which = np.full(len(sel), -1)
        for k, cv in enumerate(curves):  # the face's few boundary curves
            dist, _ = _curve_feet(surf, cv, mid, size)  # noqa: F841 (t unused)
            better = dist < best
            best[better], which[better] = dist[better], k
        ok = best <= 0.25 * ld
        ta = np.zeros(len(sel))
        tb = np.zeros(len(sel))
        tans = [np.zeros((len(sel), 3)), np.zeros((len(sel), 3))]
        for k in np.unique(which[ok]):
            m = np.flatnonzero(ok & (which == k))
            cv = curves[int(k)]
            da, ta[m] = _curve_feet(surf, cv, x0[m], size)
            db, tb[m] = _curve_feet(surf, cv, x1[m], size)
            ok[m] &= (da <= 1e-3 * ld[m] + 1e-9 * size) & (db <= 1e-3 * ld[m] + 1e-9 * size)
            # tangents a hair inside the edge: one-sided at a kink of the curve or a C0 knot of
            # the surface (a crease node), from the side the edge runs on
            tans[0][m] = _curve_tangent(surf, cv, ta[m] + 1e-7 * (tb[m] - ta[m]))
            tans[1][m] = _curve_tangent(surf, cv, tb[m] + 1e-7 * (ta[m] - tb[m]))
        dh = d / np.maximum(ld, 1e-300)[:, None]
        cons = []
        for tan, nrm in zip(tans, (n_a[sel], n_b[sel])):
            lt = np.linalg.norm(tan, axis=1)
            ok &= np.abs(np.einsum("ij,ij->i", tan, dh)) >= cos_max * lt
            con = np.cross(tan, nrm)
            lc = np.linalg.norm(con, axis=1)
            ok &= lc > 1e-6 * lt
            cons.append(con / np.maximum(lc, 1e-300)[:, None])
        # the quadratic must be able to hold both end tangents: an S-shaped stretch of trim
        # curve (tangents on the same side of the chord), a twisted one or a kink makes the
        # least-squares c of eqs. 19-33 large or degenerate (c = -d, c = -2 d on a real
        # sample); such an edge keeps its chord (two-normal formula). Accepted: |c| <= |d|
        # (a circular arc turning 45 degrees at each end, the tangent limit above), and each
        # end tangent d -+ c within 20 degrees of the curve's tangent there.
        if np.any(ok):
            o = np.flatnonzero(ok)
            c = edge_coefficient_conormal(x0[o], x1[o], n_a[sel[o]], n_b[sel[o]], cons[0][o], cons[1][o])
            good = np.linalg.norm(c, axis=1) <= ld[o]
            for end, tan in ((d[o] - c, tans[0][o]), (d[o] + c, tans[1][o])):
                cos = np.einsum("ij,ij->i", end, tan) * np.sign(np.einsum("ij,ij->i", d[o], tan))
                good &= cos >= np.cos(np.radians(MATCH_DEG)) * np.linalg.norm(end, axis=1) * np.linalg.norm(tan, axis=1)
            # and it must follow the curve better than the two-normal chord does (at 1/4, 1/2,
            # 3/4 of the edge, distance to the exact curve): where the surface normals already
            # give the curve (a normal section, e.g. a cylinder's end circle) nothing is added
            c2 = edge_coefficient(x0[o], x1[o], n_a[sel[o]], n_b[sel[o]])
            gain = np.zeros(len(o))
            worse = np.zeros(len(o))
            for xi in (0.25, 0.5, 0.75):
                for cc, acc in ((c, gain), (c2, worse)):
                    pt = x0[o] + (d[o] - cc) * xi + cc * xi * xi
                    dist = np.full(len(o), np.inf)
                    for k in np.unique(which[o]):
                        m = which[o] == k
                        dist[m], _ = _curve_feet(surf, curves[int(k)], pt[m], size)
                    np.maximum(acc, dist, out=acc)
            ok[o] = good & (gain < 0.5 * worse)
        kept += int(ok.sum())
        pairs.append(np.stack([a[sel[ok]], b[sel[ok]]], 1))
        ps.append(cons[0][ok])
        qs.append(cons[1][ok])
    return BoundaryConormals(np.concatenate(pairs), np.concatenate(ps), np.concatenate(qs), nb, nb - kept)
