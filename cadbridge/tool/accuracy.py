"""Errors of a Nagata tool against the CAD model: two honest numbers, and the flat reference.

For sample points x(e, eta, zeta) of the patches (element e):

* **surface error**: signed distance (along the CAD normal) from x to the *underlying*
  surface of e's face, untrimmed: how well the patch follows the surface it was built on.
  The CAD normal is taken on e's side of a crease knot line of that face (one-sided at the
  knot), so a sample on a crease edge is compared with its own side's normal.
* **boundary error**: distance from x to the *trimmed* model (nearest face, trims decided
  on the trim curves); on the tool's free edges also the distance to the face's boundary
  curve (`cadbridge.nagata.boundary_edges.boundary_curve_distance`), so that an edge that leaves a
  trim curve counts on both sides of it: patches bridging into a hole and patch edges that
  bulge back into the material.
* **flat surface error**: the surface error of the flat element (linear triangle, bilinear
  quadrilateral through the same corners) at the same (eta, zeta): what the tool would be
  without Nagata patches. A Nagata surface worse than that is not worth writing.

The normal error is the angle between the patch normal and that one-sided CAD normal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cadbridge.cad.model import Model

__all__ = ["ToolErrors", "flat_points", "tool_errors", "worst_elements"]


@dataclass
class ToolErrors:
    """Per sample point (M,): ``surface`` signed [length], ``normal`` [deg], ``boundary``
    (>= 0) [length], ``flat_surface`` signed [length]; ``face`` (M,) the face measured
    against (-1: none, then the trimmed projection's face is used); ``fallback`` how many
    samples had no foot on their element's face and were measured against the nearest
    trimmed face instead."""

    surface: np.ndarray
    normal: np.ndarray
    boundary: np.ndarray
    flat_surface: np.ndarray
    face: np.ndarray
    fallback: int = 0  # samples measured against the nearest trimmed face (no foot on their own)

    def stats(self) -> dict:
        def mx(a):
            return float(np.max(np.abs(a))) if len(a) else 0.0

        def mean(a):
            return float(np.mean(np.abs(a))) if len(a) else 0.0

        return {
            "max_abs_surface_error": mx(self.surface),
            "mean_abs_surface_error": mean(self.surface),
            "max_boundary_error": mx(self.boundary),
            "mean_boundary_error": mean(self.boundary),
            "max_abs_flat_surface_error": mx(self.flat_surface),
            "max_normal_error_deg": mx(self.normal),
            "mean_normal_error_deg": mean(self.normal),
            "samples_on_nearest_face": int(self.fallback),
        }


def flat_points(nm, elem: np.ndarray, eta: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """Points (M, 3) of the flat elements at (elem, eta, zeta): triangle x00 + (x10 - x00) eta
    + (x11 - x10) zeta (the linear part of thesis eq. 4), quadrilateral bilinear."""
    out = np.empty((len(elem), 3))
    kind = nm.element_kind[elem]
    loc = nm.element_local[elem]
    t = kind == 3
    if np.any(t):
        x = nm.nodes[nm.tri_elements[loc[t]]]  # (m, 3, 3)
        e, z = eta[t, None], zeta[t, None]
        out[t] = x[:, 0] + (x[:, 1] - x[:, 0]) * e + (x[:, 2] - x[:, 1]) * z
    q = ~t
    if np.any(q):
        x = nm.nodes[nm.quad_elements[loc[q]]]  # (m, 4, 3)
        e, z = eta[q, None], zeta[q, None]
        out[q] = (x[:, 0] * (1 - e) * (1 - z) + x[:, 1] * e * (1 - z) + x[:, 2] * e * z + x[:, 3] * (1 - e) * z)
    return out


CREASE_DEG = 5.0
"""A knot line whose normal jump exceeds this is a crease the errors respect (elements are
measured on their own side of it); the same angle decides which elements straddle a crease
(`cadbridge.heal.creases.straddling_elements`). Smaller jumps (a C0 parametrisation of smooth
geometry, 1e-5 rad on the QIT paper's Ex. 7.2) are measured on the whole surface."""

_PIECES: dict = {}


def _crease_pieces(surface) -> list:
    """The surface split along its knot lines with a normal jump above `CREASE_DEG`."""
    hit = _PIECES.get(id(surface))
    if hit is None or hit[0] is not surface:
        u0, u1, v0, v1 = surface.domain
        ku, kv = surface.crease_knots(np.radians(CREASE_DEG))
        eu, ev = np.concatenate([[u0], ku, [u1]]), np.concatenate([[v0], kv, [v1]])
        pieces = ([surface] if len(eu) == 2 and len(ev) == 2 else
                  [surface.with_domain((a, b, c, d)) for a, b in zip(eu[:-1], eu[1:]) for c, d in zip(ev[:-1], ev[1:])])
        hit = _PIECES[id(surface)] = (surface, pieces)
    return hit[1]


COINCIDENT = 1e-12
"""Sample points closer than about this x the model size are one point for the error
measure (a grid cell of that width): neighbouring patches share their corner and edge
samples (on a 2-division grid 2 of a triangle's 6 samples are its own), so each such point
is projected once (`_unique_points`)."""


def _by_face(face: np.ndarray, mask: np.ndarray):
    """(face, indices) for each face of the points ``mask`` (M,) selects, ``face`` (M,) their
    face: one stable sort, so each face's indices ascend as with ``np.flatnonzero``."""
    on = np.flatnonzero(mask)
    order = on[np.argsort(face[on], kind="stable")]
    faces, first = np.unique(face[order], return_index=True)
    return zip(faces.tolist(), np.split(order, first[1:]))


def _unique_points(points: np.ndarray, quantum: float, key: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Representatives of the points (M, 3) that fall into one cell of width ``quantum``
    (and share ``key`` (M,) if given): (rep (K,) indices into points, inverse (M,) with
    points[rep][inverse] ~ points). A projection is a function of the point alone, so the
    representative's result stands for its cell (within ``quantum`` of the exact one)."""
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    cell = np.round(np.asarray(points, dtype=float) / quantum)
    if key is not None:
        cell = np.column_stack([cell, np.asarray(key, dtype=float)])
    cell = np.ascontiguousarray(cell)
    rows = cell.view(np.dtype((np.void, cell.dtype.itemsize * cell.shape[1]))).ravel()
    _, rep, inv = np.unique(rows, return_index=True, return_inverse=True)
    return rep, inv.ravel()


def _expand(result, inverse: np.ndarray):
    """A projection result (dataclass of (K, ...) arrays) taken at ``inverse`` (M,)."""
    import dataclasses

    return dataclasses.replace(result, **{f.name: np.asarray(getattr(result, f.name))[inverse]
                                          for f in dataclasses.fields(result)})


def _project_unique(project, points: np.ndarray, quantum: float, **kw):
    """``project(points, **kw)`` with coincident points (`_unique_points`) projected once."""
    rep, inv = _unique_points(points, quantum)
    if len(rep) == len(points):
        return project(points, **kw)
    return _expand(project(points[rep], **kw), inv)


def _on_faces(model: Model, points: np.ndarray, face: np.ndarray, elem: np.ndarray,
              ref_normals: np.ndarray, piece_uv: np.ndarray | None = None):
    """Project each point onto the untrimmed surface of its face; on a face with crease knot
    lines (jump above `CREASE_DEG`), onto the smooth piece its element lies on (the
    piece holding the element's mean foot parameter, or ``piece_uv`` (M, 2)), with the
    one-sided normal where the foot is on the piece's crease edge.
    Returns signed distance (M,), normal aligned with ``ref_normals`` (M, 3), (u, v) (M, 2)."""
    from cadbridge.nurbs.project import FAILED, project_to_surface

    dist = np.full(len(points), np.nan)
    nrm = np.full((len(points), 3), np.nan)
    uv = np.full((len(points), 2), np.nan)
    from cadbridge.heal.folds import folds_for

    folded = {line.face for line in folds_for(model).lines}
    quantum = COINCIDENT * model.size()
    # the faces' untrimmed surfaces in one compiled call over all (point, face) pairs
    # (`project_to_surfaces`: the result of `project_to_surface` face by face)
    batch = np.flatnonzero((face >= 0) & ~np.isin(face, np.fromiter(folded, dtype=np.int64, count=len(folded))))
    row = np.full(len(points), -1, dtype=np.int64)  # point -> its row of ``feet``
    row[batch] = np.arange(len(batch))
    if len(batch):
        from cadbridge.nurbs.project_many import project_to_surfaces
        from cadbridge.cad.search import index_for

        rep, inv = _unique_points(points[batch], quantum, key=face[batch])
        feet = _expand(project_to_surfaces(index_for(model).surface_pack(model), face[batch][rep],
                                           points[batch][rep]), inv)
    for f, sel in _by_face(face, face >= 0):  # loop over faces, vectorised over points
        s = model.faces[f].surface
        if f in folded:
            # on a folded face the sheets lie close: Newton from the nearest grid sample alone
            # can end on another sheet than the nearest one
            pr = _project_unique(lambda x: project_to_surface(s, x, n_starts=4), points[sel], quantum)
        else:
            pr = _expand(feet, row[sel])
        pieces = _crease_pieces(s)
        if len(pieces) > 1:
            if piece_uv is None:
                _, inv = np.unique(elem[sel], return_inverse=True)
                cnt = np.bincount(inv)
                mu, mv = (np.bincount(inv, weights=pr.u) / cnt)[inv], (np.bincount(inv, weights=pr.v) / cnt)[inv]
            else:
                mu, mv = piece_uv[sel, 0], piece_uv[sel, 1]
            dom = np.array([pc.domain for pc in pieces])  # (P, 4)
            which = np.argmax((mu[:, None] >= dom[None, :, 0]) & (mu[:, None] <= dom[None, :, 1])
                              & (mv[:, None] >= dom[None, :, 2]) & (mv[:, None] <= dom[None, :, 3]), axis=1)
            u0, u1, v0, v1 = s.domain
            for k in np.unique(which):  # loop over the (few) pieces
                m = which == k
                pc = pieces[k]
                q = _project_unique(lambda x: project_to_surface(pc, x), points[sel[m]], quantum)
                a, b, c, d = pc.domain
                fail = np.flatnonzero(q.status == FAILED)
                if len(fail):
                    # Newton stalled next to the piece's crease edge: take the whole surface's
                    # foot clamped into the piece (a foot on the crease line; its distance is
                    # an upper bound of the true one)
                    q.u[fail] = np.clip(pr.u[m][fail], a, b)
                    q.v[fail] = np.clip(pr.v[m][fail], c, d)
                    q.foot[fail] = s.evaluate(q.u[fail], q.v[fail])
                eu, ev = 1e-12 * (u1 - u0), 1e-12 * (v1 - v0)
                lo_u = (np.abs(q.u - a) <= eu) & (a > u0)
                hi_u = (np.abs(q.u - b) <= eu) & (b < u1)
                lo_v = (np.abs(q.v - c) <= ev) & (c > v0)
                hi_v = (np.abs(q.v - d) <= ev) & (d < v1)
                n = q.normal.copy()
                at = lo_u | hi_u | lo_v | hi_v
                if len(fail):
                    n[fail] = s.normal(q.u[fail], q.v[fail])  # interior of the piece, else one-sided below
                if np.any(at):
                    n[at] = s.normal(q.u[at], q.v[at], side_u=np.where(hi_u[at], -1, 1),
                                     side_v=np.where(hi_v[at], -1, 1))
                for name, val in (("u", q.u), ("v", q.v), ("foot", q.foot), ("normal", n)):
                    getattr(pr, name)[m] = val
        n = pr.normal * np.where(np.einsum("ij,ij->i", pr.normal, ref_normals[sel]) < 0, -1.0, 1.0)[:, None]
        uv[sel, 0], uv[sel, 1] = pr.u, pr.v
        dist[sel] = np.einsum("ij,ij->i", points[sel] - pr.foot, n)
        nrm[sel] = n
    return dist, nrm, uv


def tool_errors(nm, elem: np.ndarray, eta: np.ndarray, zeta: np.ndarray, element_face: np.ndarray,
                model: Model, project_trimmed) -> ToolErrors:
    """Surface, normal, boundary and flat surface errors at the patch samples (elem, eta,
    zeta) (M,) of the `NagataMesh` ``nm``.

    element_face    (E,) face index of each element (-1 where unknown)
    project_trimmed callable points (M, 3) -> `cadbridge.cad.search.Projection` on the trimmed
                    model (e.g. `cadbridge.tool.build.CadProjector.project`)
    """
    from cadbridge.nagata.errors import angle_deg

    elem = np.asarray(elem, dtype=np.int64)
    pts, pn = nm.evaluate(elem, eta, zeta)
    face = np.asarray(element_face, dtype=np.int64)[elem].copy()
    # elements without a face: measure against the trimmed projection's face
    nof = np.flatnonzero(face < 0)
    if len(nof):
        face[nof] = np.asarray(project_trimmed(pts[nof]).face, dtype=np.int64)
    surface, ncad, uv = _on_faces(model, pts, face, elem, pn)
    from cadbridge.heal.folds import fold_reference_normals  # on a fold line: the sheets' cusp normal

    ncad = fold_reference_normals(model, pts - surface[:, None] * ncad, ncad, pn)
    from cadbridge.normals.singular import reference_normals  # at a cone apex: the limit into the element

    ncad = reference_normals(model, pts - surface[:, None] * ncad, face, _centroids(nm)[elem], ncad, pn)
    # the flat element lies on the same smooth piece as its Nagata patch
    _, inv = np.unique(elem, return_inverse=True)
    ok = np.isfinite(uv[:, 0])
    cnt = np.maximum(np.bincount(inv, weights=ok.astype(float)), 1.0)
    piece_uv = np.column_stack([(np.bincount(inv, weights=np.where(ok, uv[:, i], 0.0)) / cnt)[inv] for i in (0, 1)])
    flat = flat_points(nm, elem, eta, zeta)
    flat_surface, _, _ = _on_faces(model, flat, face, elem, pn, piece_uv)
    # where Newton found no foot on the element's own face, the nearest trimmed face stands in
    # (counted in ``fallback``; the distance is then an upper bound of the surface error)
    miss = np.flatnonzero(~np.isfinite(surface) | ~np.isfinite(flat_surface))
    # boundary error: where the own face's foot is inside its trims and no other face comes
    # within |surface error|, that foot is the nearest point of the trimmed model; the rest
    # goes through the trimmed projection (the same number, without the global search)
    boundary = np.full(len(pts), np.nan)
    own, own_d = own_face_nearest(model, pts, face, uv)
    own[miss] = False
    boundary[own] = own_d[own]
    rest = np.flatnonzero(~own)
    at = np.full(len(pts), -1, dtype=np.int64)
    at[rest] = np.arange(len(rest))
    if len(rest):
        trimmed = _project_unique(project_trimmed, pts[rest], COINCIDENT * model.size())
        boundary[rest] = np.linalg.norm(pts[rest] - trimmed.foot, axis=1)
    if len(miss):
        n_t = np.asarray(trimmed.normal, dtype=float)[at[miss]]
        n_t = n_t * np.where(np.einsum("ij,ij->i", n_t, pn[miss]) < 0, -1.0, 1.0)[:, None]
        surface[miss] = np.einsum("ij,ij->i", pts[miss] - trimmed.foot[at[miss]], n_t)
        ncad[miss] = n_t
        ft = project_trimmed(flat[miss])
        nf = np.asarray(ft.normal, dtype=float)
        nf = nf * np.where(np.einsum("ij,ij->i", nf, pn[miss]) < 0, -1.0, 1.0)[:, None]
        flat_surface[miss] = np.einsum("ij,ij->i", flat[miss] - ft.foot, nf)
    # free edges: two-sided, the distance to the boundary curve of the element's face
    from cadbridge.nagata.boundary_edges import boundary_curve_distance, free_edge_samples

    on_free = np.flatnonzero(free_edge_samples(nm, elem, eta, zeta) & (face >= 0))
    size = model.size()
    for f in np.unique(face[on_free]):  # loop over the faces owning free edges
        sel = on_free[face[on_free] == f]
        boundary[sel] = np.maximum(boundary[sel], boundary_curve_distance(model.faces[int(f)], pts[sel], size))
    normal = angle_deg(pn, ncad)
    for name, a in (("surface", surface), ("flat surface", flat_surface), ("normal", normal), ("boundary", boundary)):
        if not np.all(np.isfinite(a)):
            bad = np.flatnonzero(~np.isfinite(a))
            from cadbridge.common.errors import CheckFailed

            x = pts[bad[0]]
            raise CheckFailed(f"the {name} error could not be measured at {len(bad)} sample points of the Nagata "
                              f"patches (no foot on the CAD found there), e.g. on element {int(elem[bad[0]]) + 1} "
                              f"(1-based) at ({x[0]:.6g}, {x[1]:.6g}, {x[2]:.6g})")
    return ToolErrors(surface, normal, boundary, flat_surface, face, len(miss))


def _centroids(nm) -> np.ndarray:
    """(E, 3) corner centroids of the elements of the `NagataMesh` ``nm`` (global numbering)."""
    out = np.empty((nm.n_elements, 3))
    out[nm.tri_global] = nm.nodes[nm.tri_elements].mean(axis=1)
    out[nm.quad_global] = nm.nodes[nm.quad_elements].mean(axis=1)
    return out


def own_face_nearest(model: Model, pts: np.ndarray, face: np.ndarray, uv: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Points (M, 3) whose foot (u, v) (M, 2) on the untrimmed surface of ``face`` (M,) (the
    nearest point of that surface, `_on_faces`) is also their nearest point of the trimmed
    model: the foot lies inside the face's trims (decided on the trim curves,
    `Face.contains`) and no sub-patch box or slab of another face (`cadbridge.cad.search`'s
    index, which holds the surfaces) comes within the foot's distance d of the point.
    Faces with crease knot lines (measured on one smooth piece) are left out.
    Returns (ok (M,) bool, d (M,) = |x - S(u, v)|, NaN where not computed)."""
    from cadbridge.cad.search import candidate_pairs, index_for

    rep, inv = _unique_points(pts, COINCIDENT * model.size(), key=face)  # shared samples once
    if len(rep) < len(pts):
        ok, dist = own_face_nearest(model, pts[rep], face[rep], uv[rep])
        return ok[inv], dist[inv]
    ok = (face >= 0) & np.all(np.isfinite(uv), axis=1)
    dist = np.full(len(pts), np.nan)
    for f, sel in _by_face(face, ok):  # loop over faces, vectorised over points
        fc = model.faces[f]
        if len(_crease_pieces(fc.surface)) > 1:
            ok[sel] = False
            continue
        ok[sel] = fc.contains(uv[sel, 0], uv[sel, 1])
        dist[sel] = np.linalg.norm(pts[sel] - fc.surface.evaluate(uv[sel, 0], uv[sel, 1]), axis=1)
    ok &= np.isfinite(dist)
    sel = np.flatnonzero(ok)
    if len(sel):
        d = dist[sel]
        bound = d + 1e-9 * d + 1e-12 * model.size()
        cp, _ = candidate_pairs(index_for(model), pts[sel], bound, exclude=face[sel])
        ok[sel[cp]] = False
    return ok, dist


def worst_elements(err: ToolErrors, elem: np.ndarray, n_elements: int, floor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Elements whose Nagata surface error exceeds their flat element's (beyond ``floor``),
    worst first: (element ids (K,), their max |surface error|, their max |flat error|)."""
    nag = np.zeros(n_elements)
    flat = np.zeros(n_elements)
    np.maximum.at(nag, elem, np.abs(err.surface))
    np.maximum.at(flat, elem, np.abs(err.flat_surface))
    worse = np.flatnonzero(nag > np.maximum(flat, floor))
    order = worse[np.argsort(-nag[worse], kind="stable")]
    return order, nag[order], flat[order]
