"""Crease lines inside CAD faces, and mesh elements that straddle a crease.

A NURBS face whose surface is only C0 along a knot line (a knot of multiplicity >= degree)
can fold there: the normal jumps across the line (`NurbsSurface.crease_knots`). One
quadratic Nagata patch cannot fold inside an element, so

* `crease_lines` gives every such line as an exact 3D curve (`nurbs.ops.isocurve`), for the
  mesher to put mesh edges on it (`mesh.generate.mesh_cad(..., embed_curves=...)`);
* `straddling_elements` finds the elements of a mesh whose interior a crease crosses: a
  crease line of their face (corners strictly on both sides of the knot), or a sharp edge
  between two faces (corners on two faces whose normals differ by more than the crease
  angle, with a corner off the other face). No choice of normals can repair those.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cadbridge.model import Model
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.ops import isocurve

__all__ = ["CreaseLine", "crease_lines", "straddling_elements"]


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


def crease_lines(model: Model, angle: float = 1e-6) -> list[CreaseLine]:
    """All crease knot lines of the model's faces (normal jump above ``angle`` radians).

    The curves span the whole surface domain; where trims cut the face, the part outside
    the trims is left for the mesher to drop."""
    out = []
    for k, face in enumerate(model.faces):  # loop over faces; most have no crease knots
        ku, kv = face.surface.crease_knots(angle)
        for direction, knots in (("u", ku), ("v", kv)):
            for t in knots:
                out.append(CreaseLine(k, direction, float(t), isocurve(face.surface, direction, float(t))))
    return out


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

    Inside one face: all corners on face f and, for a crease knot k of f, some corner has
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
            ku, kv = s.crease_knots()
            for d, knots, par, other, rng in (("u", ku, node_u, node_v, u1 - u0), ("v", kv, node_v, node_u, v1 - v0)):
                if len(knots) == 0:
                    continue
                pc = par[conn[sel]]  # (S, k)
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
