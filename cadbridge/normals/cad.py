"""Exact normals at mesh nodes from the CAD model (thesis ch. 5, Fig. 47).

Every node is projected onto the model (global box search, then Newton); its normal is the
exact NURBS normal at the foot point. Where faces meet at a sharp edge (normals of the faces
on either side differ by more than ``crease_angle``), a node gets one normal per adjacent
face, stored per element corner, so Nagata patches can keep the crease.

Normals are oriented with the element winding: each corner normal points to the side of
its element's (polyhedral) normal, and a node normal to the side of the summed normals of
the elements around it.

Mesh checks before projecting: inconsistent element orientation (two elements traversing a
shared edge in the same direction) raises `MeshError` naming the pair, unless ``orient=True``
re-orients the mesh first (`orient_consistently`; the result carries the mesh the corner
normals refer to). Non-manifold edges (three or more elements on an edge, e.g. a rib standing
on a plate) are accepted with a `MeshWarning` naming the first edge's nodes and elements:
every corner takes the normal of its own element's face, which is what Nagata patches need
there, and the node normal is oriented by the summed element normals as elsewhere.
"""

from __future__ import annotations

import threading
import warnings
from dataclasses import dataclass

import numba
import numpy as np

from cadbridge.mesh.io import MeshWarning
from cadbridge.mesh.mesh import Mesh, MeshError
from cadbridge.mesh.topology import edge_table, non_manifold_edges, orient_consistently, orientation_conflicts
from cadbridge.cad.model import Model
from cadbridge.nurbs.project_many import project_to_surfaces
from cadbridge.cad.search import BEYOND_TOLERANCE, CONVERGED, FAILED, ON_BOUNDARY, Projection, index_for, project_points
from cadbridge.normals.singular import singular_nodes

__all__ = ["CadNormals", "NODE_TOLERANCE", "ProjectionError", "cad_normals", "check_far"]

NODE_TOLERANCE = 1e-4
"""`cad_normals`' default node-to-CAD tolerance, x model size."""


class ProjectionError(ValueError):
    """Mesh nodes that could not be given an exact CAD normal (too far, or failed)."""

    def __init__(self, message: str, nodes: np.ndarray, distances: np.ndarray) -> None:
        super().__init__(message)
        self.nodes = nodes
        self.distances = distances


@dataclass
class CadNormals:
    """Result of `cad_normals`.

    normals         (N, 3) unit node normals (one per node)
    corner_normals  list of (E_b, k_b, 3) per cell block of the mesh: the normal each element
                    corner uses (equal to the node normal except on creases)
    face, u, v      (N,) the face index (into model.faces) and parameters of each node's foot
    distance        (N,) node-to-CAD distance (model units)
    status          (N,) projection status (CONVERGED, ON_BOUNDARY, BEYOND_TOLERANCE, FAILED)
    crease          (N,) bool, node sits on a sharp edge (has several corner normals)
    element_face    list of (E_b,) face index of each element (from its centroid)
    singular        (N,) bool, node at a singular point of a face (cone apex, sphere pole,
                    degenerated edge): its normal comes from the face's limit normals there
                    (`cadbridge.normals.singular`), one for all its elements
    mesh            the mesh the corner normals refer to (re-oriented if ``orient=True``)
    flipped         (E,) bool, elements whose winding ``orient=True`` reversed (all False
                    otherwise)
    non_manifold    (K, 2) node pairs of the non-manifold edges found (a warning was issued)
    """

    normals: np.ndarray
    corner_normals: list[np.ndarray]
    face: np.ndarray
    u: np.ndarray
    v: np.ndarray
    distance: np.ndarray
    status: np.ndarray
    crease: np.ndarray
    element_face: list[np.ndarray]
    projection: Projection
    mesh: Mesh | None = None
    flipped: np.ndarray | None = None
    non_manifold: np.ndarray | None = None
    singular: np.ndarray | None = None

    @property
    def has_creases(self) -> bool:
        return bool(self.crease.any())

    def far_nodes(self) -> np.ndarray:
        """Indices of nodes beyond tolerance or failed."""
        return np.flatnonzero((self.status == BEYOND_TOLERANCE) | (self.status == FAILED))


def _element_normals(nodes: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Polyhedral element normals from the winding, (E, 3), unit (quads: diagonal cross)."""
    cells = np.ascontiguousarray(cells, dtype=np.int64)
    out = np.empty((len(cells), 3))
    if len(cells):
        _element_normals_kernel(np.ascontiguousarray(nodes, dtype=float), cells, out)
    return out


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _element_normals_kernel(x, cells, out):  # pragma: no cover - compiled
    """Triangles (x1 - x0) x (x2 - x0), quads (x2 - x0) x (x3 - x1), divided by their length
    (left as they are where it is 0); the arithmetic of np.cross and np.linalg.norm."""
    quad = cells.shape[1] == 4
    for e in range(cells.shape[0]):
        if quad:
            a, b, c, d = cells[e, 0], cells[e, 2], cells[e, 1], cells[e, 3]
        else:
            a, b, c, d = cells[e, 0], cells[e, 1], cells[e, 0], cells[e, 2]
        ux, uy, uz = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        vx, vy, vz = x[d, 0] - x[c, 0], x[d, 1] - x[c, 1], x[d, 2] - x[c, 2]
        nx = uy * vz - uz * vy
        ny = uz * vx - ux * vz
        nz = ux * vy - uy * vx
        ln = np.sqrt(nx * nx + ny * ny + nz * nz)
        if not ln > 0:
            ln = 1.0
        out[e, 0], out[e, 1], out[e, 2] = nx / ln, ny / ln, nz / ln


@numba.njit(cache=True, error_model="numpy")
def _corner_mean_kernel(cells, face, status, u, v, out_face, out_u, out_v, converged):  # pragma: no cover - compiled
    """Per element: its face if all corners project `converged` onto one face (else -1), and
    the mean of the corners' u and v (sums in corner order, as ndarray.mean)."""
    k = cells.shape[1]
    for e in range(cells.shape[0]):
        f0 = face[cells[e, 0]]
        ok = True
        su = u[cells[e, 0]]
        sv = v[cells[e, 0]]
        for j in range(k):
            n = cells[e, j]
            if face[n] != f0 or status[n] != converged:
                ok = False
            if j > 0:
                su += u[n]
                sv += v[n]
        out_face[e] = f0 if ok else -1
        out_u[e] = su / k
        out_v[e] = sv / k


def _element_faces(nodes: np.ndarray, blocks: list[np.ndarray], model: Model, proj: Projection,
                   meshed_on: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Face index and centroid (u, v) of every element (all blocks, global order), (E,) each.

    ``meshed_on`` (E,): the model face the mesher meshed each element on, -1 where not known
    (``cell_data["element_face"]``: gmsh on the model's own B-rep, QIT). Where it is known
    and the element's corners lie on that face's surface (`_off_surface`), it is the
    element's face, its centroid projected onto that surface: no nearest-face rule can tell
    an element across a face narrower than its chord sag from the face beside it.

    Otherwise, an element whose corners all project CONVERGED onto one face lies on that
    face: its centroid parameters are the mean of the corners' (exact for the side of a knot
    line, which is all they are used for). The other elements get their centroid projected
    (`_faces_holding_the_corners`).
    """
    if not blocks:
        return np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0)
    face = np.empty(sum(len(c) for c in blocks), dtype=np.int64)
    u = np.empty(len(face))
    v = np.empty(len(face))
    offset = 0
    pf = np.ascontiguousarray(proj.face, dtype=np.int64)
    ps = np.ascontiguousarray(proj.status)
    pu, pv = np.ascontiguousarray(proj.u, dtype=float), np.ascontiguousarray(proj.v, dtype=float)
    for c in blocks:
        sl = slice(offset, offset + len(c))
        if len(c):
            _corner_mean_kernel(np.ascontiguousarray(c, dtype=np.int64), pf, ps, pu, pv, face[sl], u[sl], v[sl],
                                CONVERGED)
        offset += len(c)
    starts = np.cumsum([0] + [len(c) for c in blocks])
    if meshed_on is not None:
        _faces_meshed_on(nodes, blocks, starts, np.asarray(meshed_on, dtype=np.int64), pf, model, face, u, v)
    todo = np.flatnonzero(face < 0)
    if len(todo):
        # the centroids of those elements only, block by block (no copy of the whole cell arrays)
        cent = np.concatenate([nodes[c[todo[(todo >= a) & (todo < a + len(c))] - a]].mean(axis=1)
                               for a, c in zip(starts[:-1], blocks)])
        cp = project_points(cent, model, max_distance=None)
        face[todo], u[todo], v[todo] = cp.face, cp.u, cp.v
        _faces_holding_the_corners(nodes, blocks, starts, todo, cent, pf, model, face, u, v)
    _seam_means(blocks, model, face, pu, pv, u, v)
    return face, u, v


def _corners_of(blocks: list[np.ndarray], starts: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Corner nodes (R, k) of the elements ``rows`` (global numbering, ascending), -1 padded."""
    k = max(c.shape[1] for c in blocks)
    corners = np.full((len(rows), k), -1, dtype=np.int64)
    for a, c in zip(starts[:-1], blocks):
        sel = (rows >= a) & (rows < a + len(c))
        corners[sel, :c.shape[1]] = c[rows[sel] - a]
    return corners


def _off_surface(model: Model, f: int, x: np.ndarray) -> np.ndarray:
    """(len(x),) whether each point (M, 3) lies farther from face f's surface than the face's
    tolerance (2 x its trim delta, at least 1e-7 x the model's size)."""
    from cadbridge.nurbs.project import project_to_surface

    size = model.size()
    d = project_to_surface(model.faces[f].surface, x).distance
    out = d > 1e-7 * size  # within the floor of tol: no need for the trim delta
    if np.any(out):  # (its first read computes the deltas of all faces of the file)
        tol = max(2.0 * float(getattr(model.faces[f], "trim_delta", 0.0) or 0.0), 1e-7 * size)
        out = d > tol
    return out


def _faces_meshed_on(nodes, blocks, starts, meshed_on, pf, model, face, u, v) -> None:
    """Elements whose mesher's face (``meshed_on`` (E,), -1: not known) is not the one face all
    their corners project onto take it, where their corners lie on its surface, with their
    centroid's (u, v) projected onto it (in place; the others keep ``face``, -1 included).
    One projection per face of the corners that projected elsewhere and of the centroids."""
    from cadbridge.nurbs.project import project_to_surface

    rows = np.flatnonzero((meshed_on >= 0) & (meshed_on != face))
    if not len(rows):
        return
    corners = _corners_of(blocks, starts, rows)
    want = meshed_on[rows]
    off = (corners >= 0) & (pf[np.maximum(corners, 0)] != want[:, None])
    for f in np.unique(want):  # loop over faces, vectorised over their elements
        mine = np.flatnonzero(want == f)
        r, j = np.nonzero(off[mine])
        bad = np.unique(r[_off_surface(model, int(f), nodes[corners[mine[r], j]])])
        mine = np.delete(mine, bad)
        if not len(mine):
            continue
        cn = corners[mine]
        cent = np.where((cn >= 0)[..., None], nodes[np.maximum(cn, 0)], 0.0).sum(axis=1) / (cn >= 0).sum(axis=1)[:, None]
        p = project_to_surface(model.faces[int(f)].surface, cent)
        face[rows[mine]], u[rows[mine]], v[rows[mine]] = f, p.u, p.v


def _closed_face_corners(model: Model, c: np.ndarray, ef: np.ndarray, node_u: np.ndarray, node_v: np.ndarray):
    """For each closed face (`NurbsSurface.closed_directions`) holding elements of ``c``
    (E, k) (faces ``ef`` (E,)): (surface, rows (S,) of those elements, corner parameters
    pu, pv (S, k), and su, sv: the same with each corner on the seam at the end of its
    element's side, `cadbridge.heal.creases.seam_side`; unchanged across an open direction)."""
    from cadbridge.heal.creases import seam_side

    for f in np.unique(ef[ef >= 0]):  # loop over the faces with elements, vectorised over those
        srf = model.faces[int(f)].surface
        closed = srf.closed_directions()
        if not any(closed):
            continue
        rows = np.flatnonzero(ef == f)
        u0, u1, v0, v1 = srf.domain
        pu, pv = node_u[c[rows]], node_v[c[rows]]
        yield (srf, rows, pu, pv, seam_side(pu, u0, u1) if closed[0] else pu,
               seam_side(pv, v0, v1) if closed[1] else pv)


def _seam_means(blocks: list[np.ndarray], model: Model, face: np.ndarray, pu: np.ndarray, pv: np.ndarray,
                u: np.ndarray, v: np.ndarray) -> None:
    """On a closed face, the corner mean of an element with a corner on the seam is taken with
    that corner at the seam end of the element's side (`cadbridge.heal.creases.seam_side`):
    a corner at v = 0 of an element beside v = 1 would pull its mean across the face and put
    it on the wrong side of a crease knot line. u, v (E,) updated in place."""
    offset = 0
    for c in blocks:  # loop over blocks, then over the few closed faces
        ef = face[offset : offset + len(c)]
        for srf, rows, _, _, su, sv in _closed_face_corners(model, c, ef, pu, pv):
            closed = srf.closed_directions()
            if closed[0]:
                u[offset + rows] = su.mean(axis=1)
            if closed[1]:
                v[offset + rows] = sv.mean(axis=1)
        offset += len(c)


def _faces_holding_the_corners(nodes, blocks, starts, todo, cent, pf, model, face, u, v) -> None:
    """Where a centroid's nearest face is none of its corners' faces and does not hold the
    corners (each within 2 x the face's trim delta of its surface, `_off_surface`), the
    element takes the nearest to the centroid of its corners' faces that holds them all (in
    place). Surfaces in contact need it: the Inventor spring's end coil rests on the next
    turn, and an element of the coil had its centroid 0.030 from the turn's face and 0.038
    (its chord sag) from its own. Such elements are few: a loop over them.

    (Asked of every element whose nearest face does not hold its corners, the rule took
    faces of the neighbouring solid in contact on the Alibre assembly trj4_s1 as OCC reads
    it: 44 elements then measured 1.01 against the flat mesh's 1.0. A face narrower than the
    chord sag is the mesher's to say, `_faces_meshed_on`.)"""
    from cadbridge.nurbs.project import project_to_surface

    corners = _corners_of(blocks, starts, todo)
    cf = np.where(corners >= 0, pf[np.maximum(corners, 0)], -1)
    for i in np.flatnonzero(~(cf == face[todo][:, None]).any(axis=1)):  # rare: faces in contact
        x = nodes[corners[i][corners[i] >= 0]]
        if not np.any(_off_surface(model, int(face[todo[i]]), x)):
            continue
        best = None
        for f in sorted(set(cf[i].tolist()) - {-1}):
            if not np.any(_off_surface(model, f, x)):
                r = project_to_surface(model.faces[f].surface, cent[i:i + 1])
                if best is None or r.distance[0] < best[0]:
                    best = (r.distance[0], f, r.u[0], r.v[0])
        if best is not None:
            face[todo[i]], u[todo[i]], v[todo[i]] = best[1], best[2], best[3]


def _summed_normals(n: int, blocks: list[np.ndarray], elem_normals: list[np.ndarray]) -> np.ndarray:
    """(n, 3) sum of the element normals around every node, added in the order block, corner
    k, element (the order of a loop of ``np.add.at``, so the same sums to the last bit)."""
    acc = np.zeros((n, 3))
    for c, en in zip(blocks, elem_normals):
        if len(c):
            _add_corners_kernel(np.ascontiguousarray(c, dtype=np.int64), np.ascontiguousarray(en), acc)
    return acc


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _add_corners_kernel(cells, en, acc):  # pragma: no cover - compiled
    for k in range(cells.shape[1]):
        for e in range(cells.shape[0]):
            i = cells[e, k]
            acc[i, 0] += en[e, 0]
            acc[i, 1] += en[e, 1]
            acc[i, 2] += en[e, 2]


def _on_c0_knot_lines(model: Model, proj: Projection) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nodes whose foot lies on a crease knot line (constant u / constant v) of its face
    (`NurbsSurface.crease_knots`: a C0 knot across which the normal jumps).

    Returns (on_u, on_v) (N,) bools and the feet's (u, v) (N,) with the parameters on such a
    line snapped exactly onto the knot (a foot at 2 - 1e-15 must evaluate both sides of 2).
    """
    on_u = np.zeros(len(proj.face), dtype=bool)
    on_v = np.zeros(len(proj.face), dtype=bool)
    uu, vv = np.array(proj.u, dtype=float), np.array(proj.v, dtype=float)
    fc = np.asarray(proj.face)
    order = np.argsort(fc, kind="stable")
    fs = fc[order]
    for f in np.unique(fs[fs >= 0]):
        s = model.faces[f].surface
        if not any(len(k) for k in s.crease_knots()):
            continue
        u0, u1, v0, v1 = s.domain
        sel = order[np.searchsorted(fs, f, side="left") : np.searchsorted(fs, f, side="right")]
        for k, lo, hi, par, out in zip(s.crease_knots(), (u0, v0), (u1, v1), (uu, vv), (on_u, on_v)):
            if len(k):
                gap = np.abs(par[sel, None] - k[None, :])
                near = np.min(gap, axis=1) <= 1e-9 * (hi - lo)
                out[sel] = near
                par[sel[near]] = k[np.argmin(gap[near], axis=1)]
    return on_u, on_v, uu, vv


class _MeshTopology(threading.Thread):
    """The mesh-only part of `cad_normals` on its own thread: edge table, orientation check
    (`MeshError` unless ``orient``; then `orient_consistently`), non-manifold edges, element
    normals (E, 3) per block of ``nodes`` (N, 3) and their sums (N, 3) around the nodes.
    `result` gives (mesh, flipped, non-manifold report, cell blocks, element normals, sums)
    and re-raises what the thread raised."""

    def __init__(self, mesh: Mesh, nodes: np.ndarray, orient: bool) -> None:
        super().__init__(name="cadbridge-mesh-topology", daemon=True)
        self.mesh, self.nodes, self.orient = mesh, nodes, orient
        self._out: tuple | None = None
        self._exc: BaseException | None = None

    def run(self) -> None:
        try:
            mesh = self.mesh
            table = edge_table(mesh)
            flipped = np.zeros(mesh.n_elements, dtype=bool)
            bad = orientation_conflicts(mesh, table)
            if len(bad):
                if not self.orient:
                    raise MeshError(
                        f"inconsistent element orientation: elements {int(bad[0, 0])} and {int(bad[0, 1])} "
                        f"traverse their shared edge in the same direction ({len(bad)} such pairs); pass "
                        f"orient=True to re-orient the mesh"
                    )
                mesh, flipped = orient_consistently(mesh)
                table = edge_table(mesh)
            nm = non_manifold_edges(mesh, table)
            nodes = self.nodes  # (N, 3) float: orientation flips cells only
            blocks = [np.asarray(b.data) for b in mesh.cells]
            elem_normals = [_element_normals(nodes, c) for c in blocks]
            acc = _summed_normals(len(nodes), blocks, elem_normals)
            self._out = (mesh, flipped, nm, blocks, elem_normals, acc)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            self._exc = exc

    def result(self) -> tuple:
        if self._exc is not None:
            raise self._exc
        return self._out


def _project_with_topology(mesh: Mesh, model: Model, nodes: np.ndarray, tol: float, orient: bool
                           ) -> tuple[Projection, tuple]:
    """The nodes (N, 3) projected onto the model (`project_points`, max_distance ``tol``) while
    `_MeshTopology` runs on a second thread (compiled kernels that release the GIL; it needs
    only the node coordinates). Returns (projection, `_MeshTopology.result()`). The mesh's
    errors come first, as when the topology ran before the projection."""
    topo = _MeshTopology(mesh, nodes, orient)
    topo.start()
    try:
        proj = project_points(nodes, model, max_distance=tol)
    except BaseException:
        topo.join()
        topo.result()  # the mesh's error first, as before
        raise
    topo.join()
    return proj, topo.result()


def _warn_non_manifold(nm) -> None:
    """`MeshWarning` naming the first non-manifold edge of report ``nm`` (if any), at the caller
    of `cad_normals`."""
    if nm:
        (a, b), el = nm.edges[0].tolist(), nm.elements[0].tolist()
        more = f" (and {len(nm) - 1} more)" if len(nm) > 1 else ""
        warnings.warn(
            f"non-manifold edge between nodes {a} and {b}: shared by elements {el}{more}; every corner "
            f"there takes its own element's face normal",
            MeshWarning,
            stacklevel=3,
        )


def _check_far(nodes: np.ndarray, proj: Projection, status: np.ndarray, tol: float) -> None:
    """`ProjectionError` naming (up to 10 of) the nodes (N, 3) beyond tolerance or failed."""
    far = np.flatnonzero((status == BEYOND_TOLERANCE) | (status == FAILED))
    if not len(far):
        return
    worst = far[np.argsort(-np.nan_to_num(proj.distance[far], nan=np.inf))][:10]
    lines = ", ".join(
        f"node {i} at ({nodes[i, 0]:.6g}, {nodes[i, 1]:.6g}, {nodes[i, 2]:.6g}) "
        + (f"distance {proj.distance[i]:.6g}" if status[i] != FAILED else
           f"projection failed (face {int(proj.face[i])})" if proj.face[i] >= 0 else "projection failed")
        for i in worst
    )
    raise ProjectionError(
        f"{len(far)} of {len(nodes)} mesh nodes are further than {tol:.3g} from the CAD "
        f"(or could not be projected): {lines}",
        far,
        proj.distance[far],
    )


def check_far(nodes: np.ndarray, cn: "CadNormals", tol: float) -> None:
    """The `ProjectionError` `cad_normals` raises without ``allow_far``, for a result ``cn``
    made with it: the nodes (N, 3) beyond ``tol`` or failed (their projection's status)."""
    _check_far(nodes, cn.projection, np.asarray(cn.projection.status), tol)


@dataclass
class _Corners:
    """What the corner-normal stages of `cad_normals` share, for N nodes."""

    model: Model
    nodes: np.ndarray  # (N, 3) node coordinates
    node_face: np.ndarray  # (N,) face of each node's foot point
    node_n: np.ndarray  # (N, 3) oriented unit node normals
    sign: float  # -1.0 with ``flip``, else 1.0
    cos_crease: float  # cosine of the crease angle
    kink_u: np.ndarray  # (N,) bool: the foot lies on a C0 knot line u = const of its face
    kink_v: np.ndarray  # (N,) bool: ... v = const
    knot_u: np.ndarray  # (N,) foot parameters, snapped onto such a knot line
    knot_v: np.ndarray
    nm_node: np.ndarray  # (N,) bool: node on a non-manifold edge
    crease: np.ndarray  # (N,) bool, set by the stages: node with several corner normals


def _corners_on_other_faces(cx: _Corners, c: np.ndarray, ef: np.ndarray, en: np.ndarray, cn: np.ndarray,
                            uc: np.ndarray | None = None, vc: np.ndarray | None = None) -> None:
    """Corners whose element lies on another face than the node's foot point take that face's
    normal at the node where it differs by more than the crease angle. c (E, k) node ids, ef
    (E,) element faces, en (E, 3) element normals; cn (E, k, 3) corner normals, updated.
    uc, vc (E,): the element centroids' parameters; with them, a foot on a crease knot line
    or the seam of the element's face takes the normal on the element's side of it
    (`_one_sided`), not whichever side the projection reports."""
    other = (ef[:, None] != cx.node_face[c]) & (ef[:, None] >= 0)
    if np.any(other):
        ei, ki = np.nonzero(other)
        nid = c[ei, ki]
        fids = ef[ei]
        # all (corner, element face) pairs in one compiled pass (`project_to_surfaces`)
        pr = project_to_surfaces(index_for(cx.model).surface_pack(cx.model), fids, cx.nodes[nid])
        nrm = pr.normal
        if uc is not None and vc is not None:
            _one_sided(cx.model, fids, pr.u, pr.v, uc[ei], vc[ei], nrm)
        nrm *= np.where(np.einsum("ij,ij->i", nrm, en[ei]) < 0, -1.0, 1.0)[:, None] * cx.sign
        sharp = np.einsum("ij,ij->i", nrm, cx.node_n[nid]) < cx.cos_crease
        cn[ei[sharp], ki[sharp]] = nrm[sharp]
        cx.crease[nid[sharp]] = True


def _at_poles(s, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Whether feet (u, v) (same shape) lie on a collapsed side of ``s`` (a pole or an apex,
    `NurbsSurface.collapsed_sides`), within 1e-9 x the parameter range."""
    u0, u1, v0, v1 = s.domain
    cu0, cu1, cv0, cv1 = s.collapsed_sides()
    tu, tv = 1e-9 * (u1 - u0), 1e-9 * (v1 - v0)
    return ((cu0 & (np.abs(u - u0) <= tu)) | (cu1 & (np.abs(u - u1) <= tu))
            | (cv0 & (np.abs(v - v0) <= tv)) | (cv1 & (np.abs(v - v1) <= tv)))


def _one_sided(model: Model, fids: np.ndarray, u: np.ndarray, v: np.ndarray, uc: np.ndarray, vc: np.ndarray,
               nrm: np.ndarray) -> None:
    """Normals (M, 3) at feet (u, v) on faces ``fids`` (M,), made one-sided towards the
    element centroids (uc, vc) where a foot lies on a crease knot line of its face
    (`NurbsSurface.crease_knots`) or on its seam (`NurbsSurface.closed_directions`; the foot
    moved to the seam end nearer the centroid), within 1e-9 x the parameter range. In place."""
    for f in np.unique(fids):  # loop over the faces, vectorised over their feet
        s = model.faces[int(f)].surface
        ku, kv = s.crease_knots()
        closed = s.closed_directions()
        if not (len(ku) or len(kv) or any(closed)):
            continue
        sel = np.flatnonzero(fids == f)
        u0, u1, v0, v1 = s.domain
        pu, pv = u[sel].copy(), v[sel].copy()
        side = []
        hit = np.zeros(len(sel), dtype=bool)
        for p, cen, knots, lo, hi, shut in ((pu, uc[sel], ku, u0, u1, closed[0]), (pv, vc[sel], kv, v0, v1, closed[1])):
            tol = 1e-9 * (hi - lo)
            on = np.zeros(len(sel), dtype=bool)
            for k in knots:  # loop over the (few) crease knots
                at = np.abs(p - k) <= tol
                p[at], on = k, on | at
            if shut:
                seam = (np.abs(p - lo) <= tol) | (np.abs(p - hi) <= tol)
                p[seam] = np.where(cen[seam] > 0.5 * (lo + hi), hi, lo)
                on |= seam
            side.append(np.where(cen >= p, 1, -1))
            hit |= on
        hit &= ~_at_poles(s, u[sel], v[sel])  # a pole or apex has its limit normal (`singular_nodes`)
        if hit.any():
            h = sel[hit]
            nrm[h] = s.normal(pu[hit], pv[hit], side_u=side[0][hit], side_v=side[1][hit])


def _corners_on_knot_lines(cx: _Corners, c: np.ndarray, ef: np.ndarray, uc: np.ndarray, vc: np.ndarray,
                           en: np.ndarray, cn: np.ndarray) -> None:
    """Corners at nodes on a C0 knot line inside their own face (a crease within one NURBS
    surface) take the one-sided normal from the element's side of the knot (uc, vc (E,): the
    element centroids' parameters); arguments otherwise as `_corners_on_other_faces`."""
    kink = (cx.kink_u[c] | cx.kink_v[c]) & (ef[:, None] == cx.node_face[c])
    if np.any(kink):
        ei, ki = np.nonzero(kink)
        nid = c[ei, ki]
        side_u = np.where(uc[ei] >= cx.knot_u[nid], 1, -1)
        side_v = np.where(vc[ei] >= cx.knot_v[nid], 1, -1)
        nrm = np.empty((len(nid), 3))
        fids = ef[ei]
        for f in np.unique(fids):  # loop over faces, vectorised over corners
            sel = fids == f
            nrm[sel] = cx.model.faces[f].surface.normal(cx.knot_u[nid[sel]], cx.knot_v[nid[sel]],
                                                        side_u=side_u[sel], side_v=side_v[sel])
        nrm *= np.where(np.einsum("ij,ij->i", nrm, en[ei]) < 0, -1.0, 1.0)[:, None] * cx.sign
        sharp = np.einsum("ij,ij->i", nrm, cx.node_n[nid]) < cx.cos_crease
        cn[ei[sharp], ki[sharp]] = nrm[sharp]
        cx.crease[nid[sharp]] = True


def _corners_on_seams(cx: _Corners, c: np.ndarray, ef: np.ndarray, node_u: np.ndarray, node_v: np.ndarray,
                      en: np.ndarray, cn: np.ndarray) -> None:
    """Corners at nodes on the seam of a closed face (`NurbsSurface.closed_directions`: the
    foot at u0 or u1, v0 or v1, the projection giving either) take the normal at the seam end
    on their element's side (`cadbridge.heal.creases.seam_side`), where it differs from the
    node normal by more than the crease angle: a seam that is a sharp edge (a tube of
    polygonal section closed at a corner, OCC17026-2). node_u, node_v (N,) the feet's
    parameters; arguments otherwise as `_corners_on_other_faces`."""
    own = (ef[:, None] == cx.node_face[c]) & (ef[:, None] >= 0)
    for s, rows, pu, pv, su, sv in _closed_face_corners(cx.model, c, ef, node_u, node_v):
        moved = ((su != pu) | (sv != pv)) & own[rows] & ~_at_poles(s, pu, pv)  # poles: `singular_nodes`
        if not moved.any():
            continue
        ri, ki = np.nonzero(moved)
        ei, nid = rows[ri], c[rows[ri], ki]
        nrm = s.normal(su[ri, ki], sv[ri, ki])
        nrm *= np.where(np.einsum("ij,ij->i", nrm, en[ei]) < 0, -1.0, 1.0)[:, None] * cx.sign
        sharp = np.einsum("ij,ij->i", nrm, cx.node_n[nid]) < cx.cos_crease
        cn[ei[sharp], ki[sharp]] = nrm[sharp]
        cx.crease[nid[sharp]] = True


def _corners_at_non_manifold(cx: _Corners, c: np.ndarray, en: np.ndarray, cn: np.ndarray) -> None:
    """At non-manifold nodes the elements of one face may be wound either way (a fin on both
    sides of a plate): each corner follows its own element's winding."""
    at = cx.nm_node[c]
    turn = at & (cx.sign * np.einsum("ekj,ej->ek", cn, en) < 0)
    cn[turn] = -cn[turn]
    cx.crease[c[turn]] = True


def _corners_with_their_element(cx: _Corners, c: np.ndarray, en: np.ndarray, cn: np.ndarray) -> None:
    """A corner normal against its own element's winding, where most corners of that element
    agree, follows its element: its node's sign, from the summed windings around it, is
    ill-determined where those cancel (the apex node of SolidEdge face 0, DE 101) or belongs
    to another sheet (a knife edge, two faces at 180 degrees). Elements against all their
    corners are left as they are: a mesh that folds over itself, which the pipeline's guard
    reports."""
    agree = cx.sign * np.einsum("ekj,ej->ek", cn, en) >= 0
    minority = ~agree & (2 * agree.sum(axis=1) > c.shape[1])[:, None]
    if np.any(minority):
        cn[minority] = -cn[minority]
        cx.crease[c[minority]] = True


def cad_normals(
    mesh: Mesh,
    model: Model,
    *,
    tolerance: float | None = None,
    crease_angle: float = 5.0,
    flip: bool = False,
    allow_far: bool = False,
    orient: bool = False,
) -> CadNormals:
    """Exact CAD normals at the nodes of ``mesh``.

    tolerance     maximum node-to-CAD distance (model units); default 1e-4 x model size.
    crease_angle  degrees; faces meeting at a node with normals further apart than this
                  make the node a crease node with per-corner normals.
    flip          reverse all normals (choose the other side of the tool).
    allow_far     return nodes beyond tolerance with their status instead of raising.
    orient        re-orient inconsistently wound elements first (`orient_consistently`)
                  instead of raising; ``result.mesh`` is the re-oriented mesh.

    Raises `ProjectionError` naming the nodes beyond tolerance or failed (unless
    ``allow_far``; a FAILED node is reported even then, by its status), `MeshError` (a
    ValueError) naming the first pair of inconsistently oriented elements (unless
    ``orient``), and ValueError for an empty model or mesh. Warns (`MeshWarning`) about
    non-manifold edges, naming the first edge's nodes and elements.
    """
    if not model.faces:
        raise ValueError("the CAD model has no faces: nothing to project onto")
    nodes = np.asarray(mesh.nodes, dtype=float)
    if len(nodes) == 0:
        raise ValueError("the mesh has no nodes")
    size = model.size()
    tol = NODE_TOLERANCE * size if tolerance is None else float(tolerance)

    proj, (mesh, flipped, nm, blocks, elem_normals, acc) = _project_with_topology(mesh, model, nodes, tol, orient)
    _warn_non_manifold(nm)
    status = np.asarray(proj.status).copy()
    if not allow_far:
        _check_far(nodes, proj, status, tol)

    node_n = np.array(proj.normal, dtype=float)
    sign = -1.0 if flip else 1.0

    # element faces and the (u, v) of their centroids: from the nodes where all corners lie
    # inside one face (CONVERGED on it); elsewhere (elements at face borders) by projecting
    # the element centroid
    meshed_on = mesh.cell_data.get("element_face")
    elem_face_all, elem_u, elem_v = _element_faces(nodes, blocks, model, proj, meshed_on)

    # orient node normals with the winding: sum of element normals around each node (acc)
    dots = np.einsum("ij,ij->i", node_n, acc)
    node_n = node_n * np.where(dots < 0, -1.0, 1.0)[:, None] * sign

    kink_u, kink_v, knot_u, knot_v = _on_c0_knot_lines(model, proj)

    # nodes at a cone apex, a sphere pole, on a degenerated edge: the normal from the face's
    # limit normals there (`cadbridge.normals.singular`), in all their elements
    starts = np.cumsum([0] + [len(c) for c in blocks])
    sn = singular_nodes(model, nodes, np.asarray(proj.face), np.asarray(proj.u), np.asarray(proj.v), blocks,
                        [elem_face_all[a:b] for a, b in zip(starts[:-1], starts[1:])], elem_normals,
                        index_for(model).surface_pack(model), sign)
    if sn is not None:
        node_n[np.flatnonzero(sn.node)] = sn.normal

    nm_node = np.zeros(len(nodes), dtype=bool)
    nm_node[nm.edges.ravel()] = True
    cx = _Corners(model, nodes, proj.face, node_n, sign, np.cos(np.radians(crease_angle)), kink_u, kink_v, knot_u,
                  knot_v, nm_node, np.zeros(len(nodes), dtype=bool))
    corner_normals: list[np.ndarray] = []
    element_face: list[np.ndarray] = []
    offset = 0
    for c, en in zip(blocks, elem_normals):
        ef = elem_face_all[offset : offset + len(c)]
        uc, vc = elem_u[offset : offset + len(c)], elem_v[offset : offset + len(c)]
        offset += len(c)
        element_face.append(ef)
        cn = node_n[c]  # (E, k, 3): fancy indexing gives a fresh array (no second copy)
        _corners_on_other_faces(cx, c, ef, en, cn, uc, vc)
        _corners_on_knot_lines(cx, c, ef, uc, vc, en, cn)
        _corners_on_seams(cx, c, ef, np.asarray(proj.u), np.asarray(proj.v), en, cn)
        if len(nm):
            _corners_at_non_manifold(cx, c, en, cn)
        _corners_with_their_element(cx, c, en, cn)
        corner_normals.append(cn)

    # every corner at a crease node takes its own element's face normal, including the
    # elements on the node's own face (their value is the node normal, already in place)
    return CadNormals(
        normals=node_n,
        corner_normals=corner_normals,
        face=np.asarray(proj.face),
        u=np.asarray(proj.u),
        v=np.asarray(proj.v),
        distance=np.asarray(proj.distance),
        status=status,
        crease=cx.crease,
        element_face=element_face,
        projection=proj,
        mesh=mesh,
        flipped=flipped,
        non_manifold=nm.edges,
        singular=np.zeros(len(nodes), dtype=bool) if sn is None else sn.node,
    )
