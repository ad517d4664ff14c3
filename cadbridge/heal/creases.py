"""Crease lines inside CAD faces, and mesh elements that straddle a crease.

A NURBS face whose surface is only C0 along a knot line (a knot of multiplicity >= degree)
can fold there: the normal jumps across the line (`NurbsSurface.crease_knots`). One
quadratic Nagata patch cannot fold inside an element, so

* `crease_lines` gives every such line as an exact 3D curve (`nurbs.edits.isocurve`), for the
  mesher to put mesh edges on it (`mesh.generate.mesh_cad(..., embed_curves=...)`);
* `straddling_elements` finds the elements of a mesh whose interior a crease crosses: a
  crease line of their face (corners strictly on both sides of the knot), or a sharp edge
  between two faces (corners on two faces whose normals differ by more than the crease
  angle, with a corner off the other face). No choice of normals can repair those.

A knot line beside which the face is a sliver band, every point of the band within the node
tolerance (`SLIVER_BAND` x model size) of the line, is no crease inside the face: it is the
face's edge to within that tolerance (`sliver_side`). OCC's NURBS fillets have such bands: on
the production die all 14 C0 knot lines lie 0.0035-0.23 mm from a domain edge of their
fillet faces, 12 of them with a normal jump of 0.03 degrees at most; the fuse of crease 130
(FTR00131: a band 0.014-0.020 mm wide whose normal folds 180 degrees for u > 13 of 17.6)
cut off a 5.17 x 0.014-0.020 mm sliver face, and on the analytic die the slivers gmsh fails
on (surfaces 1131, 1133) at its end.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cadbridge.cad.model import Model
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.edits import isocurve

__all__ = ["CreaseLine", "along_crease_lines", "crease_lines", "inner_crease_knots", "seam_side", "sliver_side",
           "straddling_elements", "SLIVER_BAND"]

SLIVER_BAND = 1e-4
"""A face band narrower than this x model size beside a knot line makes it no crease (the
node tolerance of `cadbridge.normals.cad_normals` and of `straddling_elements`)."""


@dataclass(frozen=True)
class CreaseLine:
    """One crease knot line of a face.

    face       index into ``model.faces``
    direction  "u": the line u = knot (a curve in v); "v": the line v = knot
    knot       the knot value
    curve      exact 3D curve of the line over the surface's domain (`isocurve`)
    """

    face: int
    direction: str
    knot: float
    curve: NurbsCurve


def crease_lines(model: Model, angle: float = 1e-6, band: float | None = None) -> list[CreaseLine]:
    """All crease knot lines of the model's faces (normal jump above ``angle`` radians), but
    those beside a sliver band narrower than ``band`` (model units; default `SLIVER_BAND` x
    model size; `sliver_side`).

    The curves span the whole surface domain; where trims cut the face, the part outside
    the trims is left for the mesher to drop."""
    band = SLIVER_BAND * model.size() if band is None else float(band)
    out = []
    for k, face in enumerate(model.faces):  # loop over faces; most have no crease knots
        ku, kv = inner_crease_knots(face.surface, band, angle)
        for direction, knots in (("u", ku), ("v", kv)):
            for t in knots:
                out.append(CreaseLine(k, direction, float(t), isocurve(face.surface, direction, float(t))))
    return out


def sliver_side(surface, direction: str, knot: float, band: float, samples: int = 17) -> bool:
    """Whether the surface on one side of its knot line ``direction`` = ``knot`` lies within
    ``band`` (model units) of the line: every point of a ``samples`` x 9 grid of that side's
    (untrimmed) domain within ``band`` of the line's point at the same other parameter (an
    upper bound of its distance to the line, so a folded band counts by its true extent)."""
    u0, u1, v0, v1 = surface.domain
    lo, hi, olo, ohi = (u0, u1, v0, v1) if direction == "u" else (v0, v1, u0, u1)
    other = np.linspace(olo, ohi, samples)
    for a, b in ((lo, knot), (knot, hi)):
        across = np.linspace(a, b, 9)
        o, t = (np.repeat(other, 9), np.tile(across, samples))
        uv = (t, o) if direction == "u" else (o, t)
        line = (np.full(samples, knot), other) if direction == "u" else (other, np.full(samples, knot))
        p = surface.evaluate(*uv).reshape(samples, 9, 3)
        if np.linalg.norm(p - surface.evaluate(*line)[:, None, :], axis=2).max() <= band:
            return True
    return False


def inner_crease_knots(surface, band: float, angle: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """`NurbsSurface.crease_knots` (u knots (Ku,), v knots (Kv,)) less the knots beside a
    sliver band narrower than ``band`` (`sliver_side`)."""
    ku, kv = surface.crease_knots(angle)
    return tuple(np.array([t for t in k if not sliver_side(surface, d, float(t), band)], dtype=float)
                 for d, k in (("u", ku), ("v", kv)))


def along_crease_lines(model: Model, face: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(K,) bool: mesh edges from ``a`` to ``b`` (K, 3) that run along a crease line of their
    face ``face`` (K,): both ends on its surface (within `SLIVER_BAND` x model size) at
    one crease knot (`inner_crease_knots`) of one direction, within 1e-9 x the parameter
    range (nodes on an embedded crease line are snapped there by the projection).

    Such an edge is no straddle where its elements carry the crease's two normals at one
    end only: the normal jump along a knot line varies, and where it crosses the crease
    angle between the edge's ends (the fuselage of bug28366: 5.00 degrees at the ends of
    its knot lines, 4.86 between) the edge is the crease fading below that angle, as at
    a sharp edge between faces."""
    from cadbridge.nurbs.project import project_to_surface

    out = np.zeros(len(face), dtype=bool)
    band = SLIVER_BAND * model.size()
    for f in np.unique(face):  # loop over the few faces with such edges
        if f < 0:
            continue
        s = model.faces[int(f)].surface
        ku, kv = inner_crease_knots(s, band)
        if not (len(ku) or len(kv)):
            continue
        sel = np.flatnonzero(face == f)
        pa, pb = project_to_surface(s, a[sel]), project_to_surface(s, b[sel])
        near = (pa.distance <= band) & (pb.distance <= band)
        u0, u1, v0, v1 = s.domain
        on = np.zeros(len(sel), dtype=bool)
        for knots, ta, tb, rng in ((ku, pa.u, pb.u, u1 - u0), (kv, pa.v, pb.v, v1 - v0)):
            if len(knots):
                tol = 1e-9 * rng
                on |= ((np.abs(ta[:, None] - knots[None]) <= tol) & (np.abs(tb[:, None] - knots[None]) <= tol)).any(axis=1)
        out[sel] = near & on
    return out


def seam_side(pc: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Corner parameters (S, k) across a closed direction [lo, hi], with each corner that lies
    on the seam (at lo or hi, within 1e-9 x the range: the projection gives either) moved to
    the end its element's other corners are nearer to."""
    tol = 1e-9 * (hi - lo)
    on = (np.abs(pc - lo) <= tol) | (np.abs(pc - hi) <= tol)
    if not on.any():
        return pc
    n_off = np.maximum(np.count_nonzero(~on, axis=1), 1)
    mean_off = np.where(on, 0.0, pc).sum(axis=1) / n_off  # the mean of the element's other corners
    end = np.where(mean_off > 0.5 * (lo + hi), hi, lo)[:, None]
    return np.where(on & (np.count_nonzero(~on, axis=1) > 0)[:, None], end, pc)


def straddling_elements(
    blocks: list[np.ndarray],
    model: Model,
    node_face: np.ndarray,
    node_u: np.ndarray,
    node_v: np.ndarray,
    nodes: np.ndarray | None = None,
    node_normal: np.ndarray | None = None,
    crease_angle: float = 5.0,
    element_face: list[np.ndarray] | None = None,
) -> np.ndarray:
    """Global ids (over ``blocks`` in order) of elements that straddle a crease, (K,).

    blocks       element connectivity per block, (E_b, k)
    node_face    (N,) face index of each node's foot (-1: none); node_u, node_v (N,)
    nodes, node_normal  (N, 3) coordinates and unit CAD normals: with them, elements over a
                 sharp edge between two faces are found too (else only crease lines inside
                 one face)
    crease_angle degrees, for sharp edges between faces (as in `cad_normals`)
    element_face per block (E_b,): the face each element lies on (`CadNormals.element_face`);
                 a candidate too, so an element of a narrow face whose corners all sit on its
                 neighbours' edges is not taken for a straddling one

    Inside one face: all corners on face f and, for a crease knot k of f (but one beside a
    sliver band narrower than 1e-4 x model size, `sliver_side`), some corner has
    u < k and another u > k beyond 1e-9 x the parameter range (corners on the line are
    snapped there by the projection), and the normal jumps across k by more than
    ``crease_angle`` at the corners' mean v (`NurbsSurface.knot_jump`). Between faces: the corners' feet lie on several faces,
    none of those faces' surfaces holds every corner (within 1e-4 x model size, the node
    tolerance of `cad_normals`: sewn CAD edges leave gaps), and two corner normals differ by
    more than ``crease_angle`` (orientation-free).
    """
    from cadbridge.nurbs.project import project_to_surface

    out = []
    offset = 0
    tol3 = 1e-4 * model.size()
    cos_c = np.cos(np.radians(crease_angle))
    for bi, conn in enumerate(blocks):  # loop over blocks (one or two), vectorised over elements
        conn = np.asarray(conn)
        f = node_face[conn]
        same = np.all(f == f[:, :1], axis=1) & (f[:, 0] >= 0)
        bad = np.zeros(len(conn), dtype=bool)
        for fk in np.unique(f[same, 0]):  # loop over faces with elements
            sel = np.flatnonzero(same & (f[:, 0] == fk))
            s = model.faces[fk].surface
            u0, u1, v0, v1 = s.domain
            ku, kv = inner_crease_knots(s, tol3)
            closed = dict(zip("uv", s.closed_directions()))
            for d, knots, par, other, rng in (("u", ku, node_u, node_v, u1 - u0), ("v", kv, node_v, node_u, v1 - v0)):
                if len(knots) == 0:
                    continue
                pc = par[conn[sel]]  # (S, k)
                if closed[d]:  # a corner on the seam belongs to the element's side of it
                    pc = seam_side(pc, *((u0, u1) if d == "u" else (v0, v1)))
                lo, hi = pc.min(axis=1), pc.max(axis=1)
                tol = 1e-9 * rng
                cross = (lo[:, None] < knots[None, :] - tol) & (hi[:, None] > knots[None, :] + tol)
                # ... where the knot line is a crease of more than crease_angle there (a crease
                # of 0.0015 degrees on the production die harms no patch; the flat-vs-Nagata
                # guard still sees any error it causes)
                for j in np.flatnonzero(cross.any(axis=0)):
                    e = np.flatnonzero(cross[:, j])
                    at = other[conn[sel[e]]].mean(axis=1)
                    sharp = s.knot_jump(d, float(knots[j]), at) > np.radians(crease_angle)
                    bad[sel[e[sharp]]] = True
        two = np.flatnonzero(~same & np.all(f >= 0, axis=1))
        if nodes is not None and node_normal is not None and len(two):
            k = conn.shape[1]
            fc = f[two]  # candidate faces: the corners' faces and the element's own
            if element_face is not None:
                fc = np.column_stack([fc, np.asarray(element_face[bi])[two]])
                fc = np.where(fc >= 0, fc, fc[:, :1])
            nc = fc.shape[1]
            # (element, candidate face, corner) triples
            cand = np.repeat(fc, k, axis=1).ravel()  # candidate face of each triple
            corner = np.tile(conn[two], (1, nc)).ravel()  # every corner against each candidate
            dist = np.empty(len(cand))
            for fk in np.unique(cand):  # loop over faces, vectorised over corners
                m = cand == fk
                dist[m] = project_to_surface(model.faces[fk].surface, nodes[corner[m]]).distance
            on_all = (dist.reshape(len(two), nc, k) <= tol3).all(axis=2).any(axis=1)
            nrm = node_normal[conn[two]]  # (T, k, 3)
            cos = np.abs(np.einsum("tai,tbi->tab", nrm, nrm)).min(axis=(1, 2))
            bad[two[~on_all & (cos < cos_c)]] = True
        out.append(offset + np.flatnonzero(bad))
        offset += len(conn)
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)
