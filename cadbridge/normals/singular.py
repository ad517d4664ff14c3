"""Normals at singular points of CAD faces: cone apexes, sphere poles, degenerated edges.

Where a whole side of a face's parameter domain maps onto one point (`NurbsSurface.
collapsed_sides`: the edge v = v0 of a cone or a sphere written as a NURBS, say), Su x Sv
vanishes and the normal there is a limit that can depend on the direction of approach. Along
the generatrix t (the iso-line leaving the point, u = t on the side v = v0) the surface leaves
the point in the direction d(t) (`NurbsSurface.limit_tangent`) with the limit normal n(t)
(`NurbsSurface.limit_normal`: Suv x Sv on a cone or a sphere, Suvv x Svv where a profile leaves
the axis with zero speed). On a sphere pole n(t) is one normal, the axis; on a cone apex, or
where a profile meets the axis at another angle than 90 degrees, the n(t) form a cone of
directions.

The node there gets one normal, the same in all its elements (no CORNER_NORMALS records): the
normal n0 that keeps every generatrix edge leaving the node straight in the Nagata
patches: the two-normal edge curve (Nagata eq. 15) from n0 at the point to n(t) at the far
end of a straight generatrix d is the segment itself, parametrised from rest (c = d), exactly
when n0 lies in the plane of d(t) and n(t), i.e. n0 . b(t) = 0 with b = d x n. So n0 is the
unit vector least off those planes over the generatrices the node's elements cover: the
eigenvector of the least eigenvalue of B = integral of b b^T dt, on the side of the integral of
n(t) (each element's range of t, between its two edges leaving the node; 16-point
Gauss-Legendre between knots). On a surface of revolution that is its axis, for a whole apex
or a partial one (a corner of a face), and each patch at the apex is then exactly the cone over
its far edge curve (straight rulings from the apex; the generatrices' normals along them). At a
pole, where the limits agree, it is that common limit (the axis). Where the elements cover too
few generatrices to fix n0 (B of rank < 2), the integral of n(t) projected into B's null space;
where some element's own limit normal would not see n0 on its side (n . n0 <= `MIN_COS`: a
collapsed edge that is no apex of revolution), the integral itself.

Measured against the alternative the issue suggests (each element's own limit n(t_c), t_c
through its centroid, as CORNER_NORMALS records): the tool file's rule for an edge with several
normals at one end (the one most orthogonal to the edge) bends the generatrix edges, and on
cone_apex.igs the Nagata surface error grew from 2.7e-3 to 1.4e-2 mm (quad) and the normal
error beyond 0.01 mm of the apex from 4.6 to 30-50 degrees.

A node is at a singular point when it lies within `SINGULAR_TOL` x model size of a collapsed
side's point (the mesher's vertex there, on the CAD to round-off). `reference_normals` gives
error samples at such points the limit from inside their element (the direction a patch
leaves the point in), the CAD normal a patch is measured against there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from cadbridge.cad.model import Model
from cadbridge.cad.search import index_for
from cadbridge.nurbs.project import FAILED, closed_directions
from cadbridge.nurbs.project_many import SurfacePack, project_to_surfaces

__all__ = ["MIN_COS", "SINGULAR_TOL", "SingularNodes", "collapsed_points", "reference_normals",
           "singular_nodes"]

SINGULAR_TOL = 1e-6
"""A point within this x model size of a collapsed side's point is at that singular point."""

MIN_COS = 1e-3
"""The straight-edge normal n0 is used only if every element's limit normal n . n0 exceeds this."""

_GAUSS_T, _GAUSS_W = np.polynomial.legendre.leggauss(16)


def collapsed_points(model: Model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The singular points of the model's faces: points (P, 3), face (P,) and side (P,) (0..3 for
    u = u0, u = u1, v = v0, v = v1) of every collapsed domain side (`NurbsSurface.collapsed_sides`)."""
    pts, faces, sides = [], [], []
    for f, face in enumerate(model.faces):  # loop over faces: one cached test each
        s = face.surface
        flags = s.collapsed_sides()
        if not any(flags):
            continue
        u0, u1, v0, v1 = s.domain
        um, vm = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
        for side, (uu, vv) in enumerate(((u0, vm), (u1, vm), (um, v0), (um, v1))):
            if flags[side]:
                pts.append(s.evaluate([uu], [vv])[0])
                faces.append(f)
                sides.append(side)
    return (np.array(pts, dtype=float).reshape(-1, 3), np.array(faces, dtype=np.int64),
            np.array(sides, dtype=np.int64))


def _near_points(model: Model, x: np.ndarray) -> np.ndarray:
    """(M,) bool: which of the points x (M, 3) lie within `SINGULAR_TOL` x model size of some
    face's singular point (a box test first, then a tree of the few singular points)."""
    pts = collapsed_points(model)[0]
    out = np.zeros(len(x), dtype=bool)
    if not len(pts) or not len(x):
        return out
    tol = SINGULAR_TOL * model.size()
    lo, hi = pts.min(axis=0) - tol, pts.max(axis=0) + tol
    box = np.flatnonzero(np.all((x >= lo) & (x <= hi), axis=1))
    d, _ = cKDTree(pts).query(x[box], distance_upper_bound=tol)
    out[box[np.isfinite(d)]] = True
    return out


def _at_points(model: Model, x: np.ndarray, face: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which of the points x (M, 3) lie at a singular point of their face ``face`` (M,): the
    rows (K,) and the collapsed side (K,) of each."""
    pts, pface, pside = collapsed_points(model)
    near = np.flatnonzero(_near_points(model, x) & np.isin(face, pface))
    if not len(near):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    hits = cKDTree(pts).query_ball_point(x[near], SINGULAR_TOL * model.size())
    rows, sides = [], []
    for r, h in zip(near, hits):  # loop over the few points at a singular point
        for k in h:
            if pface[k] == face[r]:
                rows.append(r)
                sides.append(pside[k])
                break
    return np.array(rows, dtype=np.int64), np.array(sides, dtype=np.int64)


def _ray(surface, side: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, ...]:
    """(u, v, du, dv) (K,) each: the point on the collapsed ``side`` (K,) of ``surface`` at the
    generatrix t (K,) (the other parameter) and the direction into the domain across it."""
    u0, u1, v0, v1 = surface.domain
    u = np.select([side == 0, side == 1], [u0, u1], t)
    v = np.select([side == 2, side == 3], [v0, v1], t)
    du = np.select([side == 0, side == 1], [1.0, -1.0], 0.0)
    dv = np.select([side == 2, side == 3], [1.0, -1.0], 0.0)
    return u, v, du, dv


def _limits(surface, side: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Limit normals (K, 3) at the generatrices t (K,) of the collapsed ``side`` (K,)."""
    return surface.limit_normal(*_ray(surface, side, t))


def _moments(surface, side: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(K, 12): the limit normal n (3) and b b^T (9, b = d x n, d the generatrix's tangent
    leaving the point) at the generatrices t (K,) of the collapsed ``side`` (K,)."""
    ray = _ray(surface, side, t)
    n = surface.limit_normal(*ray)
    b = np.cross(surface.limit_tangent(*ray), n)
    b = np.where(np.isfinite(b), b, 0.0)
    return np.concatenate([n, (b[:, :, None] * b[:, None, :]).reshape(-1, 9)], axis=1)


def _integrals(surface, side: np.ndarray, a: np.ndarray, b: np.ndarray, wrap: np.ndarray) -> np.ndarray:
    """Integrals (K, 12) of `_moments` on the collapsed ``side`` (K,) of ``surface`` over the
    generatrices t in [a, b] (K,) each (unwrapped: on a closed side, ``wrap``, t is taken
    modulo the domain): Gauss-Legendre (16 points) between the knots, where they are smooth."""
    u0, u1, v0, v1 = surface.domain
    ts, sq, owner, wq = [], [], [], []
    for i in range(len(side)):  # loop over the few corners at singular points
        along_u = side[i] >= 2
        lo, hi = (u0, u1) if along_u else (v0, v1)
        per = hi - lo
        k = np.unique(surface.knots_u if along_u else surface.knots_v)
        k = k[(k > lo) & (k < hi)]
        if wrap[i]:
            shift = per * np.arange(np.floor((a[i] - lo) / per) - 1, np.ceil((b[i] - lo) / per) + 1)
            k = (k[None, :] + shift[:, None]).ravel()
        breaks = np.concatenate([[a[i]], np.sort(k[(k > a[i]) & (k < b[i])]), [b[i]]])
        m, h = 0.5 * (breaks[1:] + breaks[:-1]), 0.5 * np.diff(breaks)
        t = (m[:, None] + h[:, None] * _GAUSS_T[None, :]).ravel()
        ts.append(lo + np.mod(t - lo, per) if wrap[i] else t)
        wq.append((h[:, None] * _GAUSS_W[None, :]).ravel())
        sq.append(np.full(t.size, side[i]))
        owner.append(np.full(t.size, i))
    t, sq, owner, wq = (np.concatenate(x) for x in (ts, sq, owner, wq))
    out = np.zeros((len(side), 12))
    np.add.at(out, owner, wq[:, None] * _moments(surface, sq, t))
    return out


def _node_normal(mean: np.ndarray, bb: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """The straight-edge normal of one node (module docs) from the integrals of n (3,) and of
    b b^T (3, 3) over its generatrices; ``limits`` (K, 3) its elements' own limit normals, all
    of which it must see on their side (else the mean)."""
    m = mean / np.linalg.norm(mean)
    w, e = np.linalg.eigh(bb)
    null = w <= 1e-12 * max(float(w[-1]), 1e-300)
    if null.sum() >= 2:  # too few generatrices: the mean, off the b directions there are
        n0 = e[:, null] @ (e[:, null].T @ m)
        if np.linalg.norm(n0) <= 1e-12:
            return m
    else:
        n0 = e[:, 0]
    n0 = n0 / np.linalg.norm(n0)
    n0 = n0 if n0 @ m >= 0 else -n0
    return n0 if np.all(limits @ n0 > MIN_COS) else m


@dataclass
class SingularNodes:
    """Nodes of one mesh at singular points of the faces they have elements on.

    node     (N,) bool: the node lies at a singular point (cone apex, pole, degenerated edge)
    normal   (S, 3) the unit node normal of each, in ``np.flatnonzero(node)`` order (module
             docs), on the side of its elements' windings
    """

    node: np.ndarray
    normal: np.ndarray


def singular_nodes(model: Model, nodes: np.ndarray, node_face: np.ndarray, node_u: np.ndarray, node_v: np.ndarray,
                   blocks: list[np.ndarray], element_face: list[np.ndarray], element_normals: list[np.ndarray],
                   pack: SurfacePack, sign: float = 1.0) -> SingularNodes | None:
    """The nodes (N, 3) of a mesh at singular points and their normals (module docs).

    node_face, node_u, node_v (N,): the nodes' feet (their projection); blocks: element
    connectivity (E_b, k) per block, element_face (E_b,) the face of each element,
    element_normals (E_b, 3) their winding normals, which orient the limits (times ``sign``,
    -1 for flipped normals); pack: the model's `SurfacePack`. None when no node of an element
    lies at a singular point of that element's face."""
    near = _near_points(model, nodes)
    if not np.any(near):
        return None
    parts = []  # per block: block, element, corner, face, node of the corners near a singular point
    for b, (c, ef) in enumerate(zip(blocks, element_face)):
        ei, ki = np.nonzero(near[c])
        parts.append((np.full(len(ei), b), ei, ki, ef[ei], c[ei, ki]))
    block, elem, corner, face, nid = (np.concatenate(x) for x in zip(*parts))
    rows, side = _at_points(model, nodes[nid], face)
    if not len(rows):
        return None
    block, elem, corner, face, nid = (a[rows] for a in (block, elem, corner, face, nid))
    conn = [blocks[b][e] for b, e in zip(block, elem)]  # the (few) elements at singular points
    cent = np.array([nodes[c_].mean(axis=0) for c_ in conn])
    en = np.array([element_normals[b][e] for b, e in zip(block, elem)])
    # the generatrix through each element's centroid (the direction it leaves the point in)
    cp = project_to_surfaces(pack, face, cent)
    keep = cp.status != FAILED  # (an element whose centroid has no foot does not count)
    if not np.any(keep):
        return None
    corner, face, nid, side, en = (a[keep] for a in (corner, face, nid, side, en))
    tc = np.where(side >= 2, cp.u, cp.v)[keep]
    conn = [c_ for c_, kp in zip(conn, keep) if kp]
    # each element's range of generatrices: between its two edges leaving the point (the
    # neighbouring corners' feet on the same face), unwrapped about tc on a closed side
    prev = np.array([c_[(j - 1) % len(c_)] for c_, j in zip(conn, corner)])
    nxt = np.array([c_[(j + 1) % len(c_)] for c_, j in zip(conn, corner)])
    centre = np.empty((len(nid), 3))
    mom = np.zeros((len(nid), 12))
    for f in np.unique(face):  # loop over faces with singular points, vectorised over corners
        sel = np.flatnonzero(face == f)
        s = model.faces[int(f)].surface
        centre[sel] = _limits(s, side[sel], tc[sel])
        u0, u1, v0, v1 = s.domain
        closed = closed_directions(s)
        along_u = side[sel] >= 2  # the generatrix parameter is u
        per = np.where(along_u, u1 - u0, v1 - v0)
        wrap = np.where(along_u, closed[0], closed[1])
        ends = []
        for nb in (prev[sel], nxt[sel]):
            t = np.where(along_u, node_u[nb], node_v[nb])
            t = np.where(wrap, tc[sel] + np.mod(t - tc[sel] + 0.5 * per, per) - 0.5 * per, t)
            ends.append(np.where(node_face[nb] == f, t, np.nan))
        a, b = np.fmin(ends[0], ends[1]), np.fmax(ends[0], ends[1])
        ok = np.isfinite(a) & np.isfinite(b) & (a <= tc[sel]) & (tc[sel] <= b)
        if np.any(ok):
            mom[sel[ok]] = _integrals(s, side[sel][ok], a[ok], b[ok], wrap[ok])
        bad = sel[~ok]  # range unknown: the centroid's generatrix, weighted by the angle at the node
        if len(bad):
            x0 = nodes[nid[bad]]
            e1, e2 = nodes[prev[bad]] - x0, nodes[nxt[bad]] - x0
            ang = np.arctan2(np.linalg.norm(np.cross(e1, e2), axis=1), np.einsum("ij,ij->i", e1, e2))
            mom[bad] = ang[:, None] * _moments(s, side[bad], tc[bad])
    flip = np.where(np.einsum("ij,ij->i", centre, en) < 0, -1.0, 1.0) * sign
    centre *= flip[:, None]
    mom[:, :3] *= flip[:, None]  # b b^T does not depend on the side
    sing = np.unique(nid)
    row = np.searchsorted(sing, nid)
    acc = np.zeros((len(sing), 12))
    np.add.at(acc, row, mom)
    first = np.unique(row, return_index=True)[1]  # one corner of each node
    normal = np.empty((len(sing), 3))
    for i in range(len(sing)):  # loop over the singular nodes (a few per apex or pole)
        mean = acc[i, :3] if np.linalg.norm(acc[i, :3]) > 0 else centre[first[i]]
        normal[i] = _node_normal(mean, acc[i, 3:].reshape(3, 3), centre[row == i])
    node = np.zeros(len(nodes), dtype=bool)
    node[sing] = True
    return SingularNodes(node, normal)


def reference_normals(model: Model, points: np.ndarray, face: np.ndarray, centroids: np.ndarray,
                      normals: np.ndarray, orient: np.ndarray) -> np.ndarray:
    """``normals`` (M, 3), the CAD normals at ``points`` (M, 3) on faces ``face`` (M,), with the
    points at a singular point of their face given the limit normal along the generatrix
    through ``centroids`` (M, 3) (their element's: the direction it leaves the point in),
    on the side of ``orient`` (M, 3) there. A new array."""
    out = np.array(normals, dtype=float)
    rows, side = _at_points(model, np.asarray(points, dtype=float), np.asarray(face, dtype=np.int64))
    if not len(rows):
        return out
    cp = project_to_surfaces(index_for(model).surface_pack(model), face[rows], centroids[rows])
    ok = cp.status != FAILED
    rows, side, tc = rows[ok], side[ok], np.where(side >= 2, cp.u, cp.v)[ok]
    for f in np.unique(face[rows]):  # loop over faces with singular points
        sel = face[rows] == f
        n = _limits(model.faces[int(f)].surface, side[sel], tc[sel])
        r = rows[sel]
        out[r] = n * np.where(np.einsum("ij,ij->i", n, orient[r]) < 0, -1.0, 1.0)[:, None]
    return out
