"""A whole mesh of Nagata patches: triangles, quadrilaterals or both, with sharp edges.

``NagataMesh(nodes, elements, normals)`` builds one patch per element (thesis eqs. 4-13).
Edges are identified globally (sorted node pair); an edge whose elements carry different
corner normals at both of its ends (a crease) or that is shared by more than two elements
with differing normals gets one coefficient from *all* those normals through the
generalized inverse (Nagata 2005, eqs. 19-33), so the patches on both sides share the edge
curve. An edge whose elements differ at one end only (it leaves a crease node into one side:
the mesh straddles the crease) takes, at that end, the normal most orthogonal to the edge;
so does, at both ends, a crease edge whose generalized-inverse curve would turn back (an
edge across a hairpin of the crease).
Every other edge uses the two-normal closed form (Nagata eq. 15, with the bounded rules of
`cadbridge.nagata.edge`). docs/toolfile.md states the same rule for readers of tool files.

Edge normals: a mesh edge listed in ``edge_normals`` with a conormal at each end (the
curve's ``t x n``, `cadbridge.nagata.boundary_edges` gives them to the free boundary edges that
follow a curved trim curve) takes the two-normal coefficient plus the sideways part the
conormals ask for (`cadbridge.nagata.edge.edge_coefficient_conormal`): the edge curve keeps
the surface's normal curvature and follows the trim curve's geodesic curvature, instead of
being the straight chord two equal surface normals give on a planar face with a round hole.
On a crease edge the listed conormals are not used.

All of the above is the ``bounded`` edge rule (the default). ``edge_rule="published"`` is
Nagata 2005 as published (`cadbridge.nagata.edge` module docs): eq. (15) without the bounded
cases, the generalized inverse wherever an end carries several distinct normals (one end
too), and the edge normals do not change any coefficient (they are kept, for the tool file).
"""

from __future__ import annotations

from functools import cached_property
from typing import NamedTuple, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cadbridge.nagata.admissibility import MAX_BEND_DEG
from cadbridge.nagata.edge import (
    EPS_RANK,
    EPS_SINGULAR,
    check_edge_rule,
    edge_coefficient,
    edge_coefficient_conormal,
    edge_coefficient_multi,
)
from cadbridge.nagata.patch import (
    QUAD_EDGES,
    TRI_EDGES,
    eval_rows,
    quad_coefficients,
    tri_coefficients,
    unit,
)

SAME_NORMAL = 1e-12
"""Corner normals (unit) whose components differ by no more are one normal: round-off, e.g.
a smooth seam's normal evaluated at u0 and at u1, never a crease."""


class Grid(NamedTuple):
    """Uniform parametric sample of every patch (elements in global order)."""

    points: NDArray  # (M, 3)
    normals: NDArray  # (M, 3) unit, oriented with the element winding
    elem: NDArray  # (M,) global element id
    eta: NDArray  # (M,)
    zeta: NDArray  # (M,)

    # mapping access too: grid["points"], dict(grid)
    def keys(self) -> tuple[str, ...]:
        return self._fields

    def __getitem__(self, key):  # type: ignore[override]
        return getattr(self, key) if isinstance(key, str) else tuple.__getitem__(self, key)


class ClosestPoint(NamedTuple):
    foot: NDArray  # (M, 3)
    elem: NDArray  # (M,)
    eta: NDArray  # (M,)
    zeta: NDArray  # (M,)
    dist: NDArray  # (M,) unsigned distance |point - foot|


def _tri_template(n: int) -> tuple[NDArray, NDArray, NDArray]:
    """(i, j) lattice 0 <= j <= i <= n of a triangle, index i(i+1)/2 + j, and its triangles."""
    i = np.concatenate([np.full(k + 1, k) for k in range(n + 1)])
    j = np.concatenate([np.arange(k + 1) for k in range(n + 1)])
    idx = lambda a, b: a * (a + 1) // 2 + b  # noqa: E731
    tris = []
    for a in range(n):  # loop over template rows (n), not over elements
        b = np.arange(a + 1)
        tris.append(np.stack([idx(a, b), idx(a + 1, b), idx(a + 1, b + 1)], 1))
        b = np.arange(a)
        tris.append(np.stack([idx(a, b), idx(a + 1, b + 1), idx(a, b + 1)], 1))
    return i, j, np.concatenate(tris)


def _quad_template(n: int) -> tuple[NDArray, NDArray, NDArray]:
    """(i, j) lattice of a quadrilateral, index i(n+1) + j, and its triangles."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    a, b = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a, b = a.ravel(), b.ravel()
    idx = lambda p, q: p * (n + 1) + q  # noqa: E731
    t1 = np.stack([idx(a, b), idx(a + 1, b), idx(a + 1, b + 1)], 1)
    t2 = np.stack([idx(a, b), idx(a + 1, b + 1), idx(a, b + 1)], 1)
    return i, j, np.concatenate([t1, t2])


def _template_location(kind: int, i: NDArray, j: NDArray, n: int) -> tuple[NDArray, NDArray, NDArray]:
    """Classify lattice points: local corner (or -1), local edge (or -1), index k along
    the local edge from its first to its second corner."""
    corner = np.full(i.shape, -1)
    edge = np.full(i.shape, -1)
    k = np.zeros(i.shape, dtype=int)
    if kind == 3:
        conds = [(j == 0, i), (i == n, j), (i == j, i)]
        corners = [((i == 0) & (j == 0)), ((i == n) & (j == 0)), ((i == n) & (j == n))]
    else:
        conds = [(j == 0, i), (i == n, j), (j == n, i), (i == 0, j)]
        corners = [((i == 0) & (j == 0)), ((i == n) & (j == 0)), ((i == n) & (j == n)), ((i == 0) & (j == n))]
    for le, (m, kk) in enumerate(conds):
        edge = np.where(m & (edge < 0), le, edge)
        k = np.where(edge == le, kk, k)
    for lc, m in enumerate(corners):
        corner[m] = lc
    edge[corner >= 0] = -1
    return corner, edge, k


def _edge_params(kind: NDArray, ledge: NDArray, xi: NDArray) -> tuple[NDArray, NDArray]:
    """(eta, zeta) of the point xi on local edge ``ledge`` (per point kind 3|4)."""
    one = np.ones_like(xi)
    zero = np.zeros_like(xi)
    tri_e = np.select([ledge == 0, ledge == 1, ledge == 2], [xi, one, xi], xi)
    tri_z = np.select([ledge == 0, ledge == 1, ledge == 2], [zero, xi, xi], zero)
    q_e = np.select([ledge == 0, ledge == 1, ledge == 2, ledge == 3], [xi, one, xi, zero], xi)
    q_z = np.select([ledge == 0, ledge == 1, ledge == 2, ledge == 3], [zero, xi, one, xi], zero)
    return np.where(kind == 3, tri_e, q_e), np.where(kind == 3, tri_z, q_z)


def _edge_xi(kind: NDArray, ledge: NDArray, eta: NDArray, zeta: NDArray) -> NDArray:
    """Edge parameter xi (first -> second corner) of a point lying on local edge ``ledge``."""
    use_zeta = (ledge == 1) | ((kind == 4) & (ledge == 3))
    return np.where(use_zeta, zeta, eta)


def _edge_normals(given, n_nodes: int) -> tuple[NDArray, NDArray, NDArray]:
    """Validated ``(pairs (B, 2) int64, p (B, 3), q (B, 3))`` of the extra edge normals."""
    if given is None:
        return np.zeros((0, 2), np.int64), np.zeros((0, 3)), np.zeros((0, 3))
    pairs, p, q = given
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    p = np.asarray(p, dtype=float).reshape(-1, 3)
    q = np.asarray(q, dtype=float).reshape(-1, 3)
    if not len(pairs) == len(p) == len(q):
        raise ValueError(f"edge_normals: {len(pairs)} edges but {len(p)} and {len(q)} normals")
    if pairs.size and (pairs.min() < 0 or pairs.max() >= n_nodes):
        raise ValueError(f"edge_normals: node ids outside 0..{n_nodes - 1}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        raise ValueError("edge_normals: normals must be finite")
    return pairs, p, q


def _distinct(n: NDArray, mask: NDArray) -> NDArray:
    """(K, P) bool: the rows of ``mask`` whose normal ``n`` (K, P, 3) differs by more than
    `SAME_NORMAL` from every earlier present row of its edge (each distinct normal once)."""
    p = n.shape[1]
    close = np.abs(n[:, :, None] - n[:, None, :]).max(axis=3) <= SAME_NORMAL  # (K, P, P)
    earlier = np.tri(p, k=-1, dtype=bool)  # [i, j]: j < i
    return mask & ~np.any(close & mask[:, None, :] & earlier, axis=2)


class NagataMesh:
    """Nagata patches over a triangle, quadrilateral or mixed mesh.

    Parameters
    ----------
    nodes : (N, 3)
    elements : (E, 3) triangles, (E, 4) quadrilaterals, or a list of such blocks
        (global element numbering follows the blocks in the order given).
    normals : (N, 3) unit normals per node, or per element corner (E, 3|4, 3)
        (a list of per-block arrays for a list of blocks).
    eps : threshold of the two-normal formula (Nagata eq. 15).
    eps_rank : threshold on the dimensionless ``D^(k)`` (Nagata eq. 31).
    edge_normals : optional ``(pairs (B, 2) node ids, p (B, 3) at pairs[:, 0], q (B, 3) at
        pairs[:, 1])``: a conormal at each end of each listed mesh edge (module docs).
    edge_rule : "bounded" (default) or "published" (module docs, `cadbridge.nagata.edge.EDGE_RULES`).
    """

    def __init__(
        self,
        nodes: ArrayLike,
        elements: ArrayLike | Sequence[ArrayLike],
        normals: ArrayLike | Sequence[ArrayLike],
        eps: float = EPS_SINGULAR,
        eps_rank: float = EPS_RANK,
        edge_normals: tuple[ArrayLike, ArrayLike, ArrayLike] | None = None,
        edge_rule: str = "bounded",
    ) -> None:
        self.nodes = np.ascontiguousarray(nodes, dtype=float)
        if self.nodes.ndim != 2 or self.nodes.shape[1] != 3:
            raise ValueError(f"nodes must be (N, 3), got {self.nodes.shape}")
        self.eps = eps
        self.eps_rank = eps_rank
        self.edge_rule = check_edge_rule(edge_rule)
        if isinstance(elements, np.ndarray) or (
            isinstance(elements, Sequence) and len(elements) > 0 and np.ndim(elements[0]) == 1
        ):
            blocks = [np.asarray(elements)]
            nblocks = None if np.ndim(normals) == 2 else [np.asarray(normals)]
        else:
            blocks = [np.asarray(b) for b in elements]
            try:
                per_node_arr = np.ndim(normals) == 2 and np.shape(normals)[1] == 3
            except ValueError:  # ragged list of per-block corner normals
                per_node_arr = False
            nblocks = None if per_node_arr else [np.asarray(b, dtype=float) for b in normals]
        per_node = nblocks is None
        nn = self.nodes.shape[0]
        kinds, locs, tri_c, quad_c, tri_n, quad_n = [], [], [], [], [], []
        ntri = nquad = 0
        for b, blk in enumerate(blocks):
            blk = blk.astype(np.int64).reshape(-1, blk.shape[-1] if blk.ndim == 2 else 3)
            k = blk.shape[1]
            if k not in (3, 4):
                raise ValueError(f"element block {b} has {k} nodes per element; expected 3 or 4")
            if blk.size and (blk.min() < 0 or blk.max() >= nn):
                raise ValueError(f"element block {b} references nodes outside 0..{nn - 1}")
            kinds.append(np.full(len(blk), k, dtype=np.int8))
            if k == 3:
                locs.append(np.arange(ntri, ntri + len(blk)))
                ntri += len(blk)
                tri_c.append(blk)
            else:
                locs.append(np.arange(nquad, nquad + len(blk)))
                nquad += len(blk)
                quad_c.append(blk)
            if not per_node:
                nb = nblocks[b]
                if nb.shape != (len(blk), k, 3):
                    raise ValueError(f"corner normals of block {b} must be {(len(blk), k, 3)}, got {nb.shape}")
                (tri_n if k == 3 else quad_n).append(nb)
        self.element_kind: NDArray = np.concatenate(kinds) if kinds else np.zeros(0, np.int8)
        """(E,) 3 for triangles, 4 for quadrilaterals (global numbering)."""
        self.element_local: NDArray = np.concatenate(locs) if locs else np.zeros(0, int)
        """(E,) row of each element in ``tri_*`` or ``quad_*`` arrays."""
        self.tri_elements = np.concatenate(tri_c) if tri_c else np.zeros((0, 3), np.int64)
        self.quad_elements = np.concatenate(quad_c) if quad_c else np.zeros((0, 4), np.int64)
        self.tri_global = np.flatnonzero(self.element_kind == 3)
        self.quad_global = np.flatnonzero(self.element_kind == 4)
        if per_node:
            nrm = np.asarray(normals, dtype=float)
            if nrm.shape != self.nodes.shape:
                raise ValueError(f"node normals must be {self.nodes.shape}, got {nrm.shape}")
            self.normals_per_node: NDArray | None = nrm
            self.tri_corner_normals = nrm[self.tri_elements]
            self.quad_corner_normals = nrm[self.quad_elements]
        else:
            self.normals_per_node = None
            self.tri_corner_normals = np.concatenate(tri_n) if tri_n else np.zeros((0, 3, 3))
            self.quad_corner_normals = np.concatenate(quad_n) if quad_n else np.zeros((0, 4, 3))
        self.crease_edges: NDArray = np.zeros(0, dtype=np.int64)
        """Global ids of the edges whose elements give different corner normals (see ``edges``):
        solved with the generalized inverse where both ends carry several normals."""
        self.half_crease_edges: NDArray = np.zeros(0, dtype=np.int64)
        """Global ids of crease edges with several normals at one end only (a mesh that
        straddles a crease): at that end the normal most orthogonal to the edge is used."""
        self.edge_normals = _edge_normals(edge_normals, nn)
        """(pairs (B, 2), p (B, 3), q (B, 3)): the extra edge normals given (module docs)."""
        bounded = self.edge_rule == "bounded"
        tri_ec, quad_ec = self._edge_coefficients(per_node and (len(self.edge_normals[0]) == 0 or not bounded))
        self.tri_edge_coefficients = tri_ec  # (Et, 3, 3) c1 c2 c3
        self.quad_edge_coefficients = quad_ec  # (Eq, 4, 3) c1 c2 c3 c4
        self.tri_coefficients = tri_coefficients(self.nodes[self.tri_elements], tri_ec)
        self.quad_coefficients = quad_coefficients(self.nodes[self.quad_elements], quad_ec)

    # ------------------------------------------------------------------ construction
    @property
    def n_elements(self) -> int:
        return int(self.element_kind.shape[0])

    @property
    def coefficients(self) -> NDArray:
        """(E, 6, 3) for a triangle mesh or (E, 8, 3) for a quadrilateral mesh.

        Mixed meshes: use ``tri_coefficients`` / ``quad_coefficients`` with
        ``element_kind`` / ``element_local``."""
        if len(self.quad_elements) == 0:
            return self.tri_coefficients
        if len(self.tri_elements) == 0:
            return self.quad_coefficients
        raise ValueError("mixed mesh: use tri_coefficients / quad_coefficients and element_kind/element_local")

    def _edge_coefficients(self, per_node: bool) -> tuple[NDArray, NDArray]:
        x, t, q = self.nodes, self.tri_elements, self.quad_elements
        bounded = self.edge_rule == "bounded"
        if per_node:
            # one normal per node: no creases possible, two-normal formula on every element edge
            def per_elem(conn: NDArray, nrm: NDArray, le: NDArray) -> NDArray:
                a, b = conn[:, le[:, 0]], conn[:, le[:, 1]]
                return edge_coefficient(x[a], x[b], nrm[:, le[:, 0]], nrm[:, le[:, 1]], self.eps, bounded)

            return per_elem(t, self.tri_corner_normals, TRI_EDGES), per_elem(q, self.quad_corner_normals, QUAD_EDGES)
        topo = self.edges
        inst_n0 = np.concatenate(
            [
                self.tri_corner_normals[:, TRI_EDGES[:, 0]].reshape(-1, 3),
                self.quad_corner_normals[:, QUAD_EDGES[:, 0]].reshape(-1, 3),
            ]
        )
        inst_n1 = np.concatenate(
            [
                self.tri_corner_normals[:, TRI_EDGES[:, 1]].reshape(-1, 3),
                self.quad_corner_normals[:, QUAD_EDGES[:, 1]].reshape(-1, 3),
            ]
        )
        flip = topo["inst_flip"]
        n_lo = np.where(flip[:, None], inst_n1, inst_n0)
        n_hi = np.where(flip[:, None], inst_n0, inst_n1)
        eid = topo["inst_edge"]
        ne = len(topo["edges"])
        first = topo["first_inst"]  # (Ne,) first instance of each edge
        diff = np.maximum(np.abs(n_lo - n_lo[first[eid]]).max(1), np.abs(n_hi - n_hi[first[eid]]).max(1))
        # normals that differ by round-off only are one normal (a smooth seam evaluated from its
        # two sides: 1e-17 apart; taken as a crease, the edge read as half a crease, a straddle)
        crease = np.bincount(eid, weights=(diff > SAME_NORMAL).astype(float), minlength=ne) > 0
        lo, hi = topo["edges"][:, 0], topo["edges"][:, 1]
        c_edge = edge_coefficient(x[lo], x[hi], n_lo[first], n_hi[first], self.eps, bounded)
        ce = np.flatnonzero(crease)
        self.crease_edges = ce
        if ce.size:
            sel = np.flatnonzero(crease[eid])
            order = sel[np.argsort(eid[sel], kind="stable")]
            e_sorted = eid[order]
            cmap = np.full(ne, -1)
            cmap[ce] = np.arange(ce.size)
            row = cmap[e_sorted]
            counts = np.bincount(row, minlength=ce.size)
            start = np.concatenate([[0], np.cumsum(counts)[:-1]])
            col = np.arange(order.size) - start[row]
            p = int(counts.max())
            n0 = np.zeros((ce.size, p, 3))
            n1 = np.zeros((ce.size, p, 3))
            mask = np.zeros((ce.size, p), bool)
            n0[row, col] = n_lo[order]
            n1[row, col] = n_hi[order]
            mask[row, col] = True
            d = x[hi[ce]] - x[lo[ce]]
            multi0 = np.any(mask & (np.abs(n0 - n0[:, :1]).max(axis=2) > SAME_NORMAL), axis=1)
            multi1 = np.any(mask & (np.abs(n1 - n1[:, :1]).max(axis=2) > SAME_NORMAL), axis=1)
            full = multi0 & multi1
            half = np.flatnonzero(~full)
            self.half_crease_edges = ce[half]
            if not bounded:  # published: eqs. 19-33 with the distinct normals of each end, at every crease edge
                c_edge[ce] = edge_coefficient_multi(d, n0, n1, _distinct(n0, mask), _distinct(n1, mask), self.eps_rank)
                half = half[:0]
                full[:] = False
            if np.any(full):  # a crease edge: one curve orthogonal to every normal (eqs. 19-33)
                f = np.flatnonzero(full)
                cf = edge_coefficient_multi(d[f], n0[f], n1[f], mask[f], mask[f], self.eps_rank)
                c_edge[ce[f]] = cf
                # An edge across a hairpin of the crease (its chord along a normal of both ends,
                # both ends on the crease line: a notch narrower than the mesh) has no curve
                # orthogonal to every normal that runs forward: eqs. 19-33 give c of size
                # 1e3 |d| (a bulge of 33 mm on a 0.11 mm edge, on a real mesh). Such an edge,
                # not monotone (|c . d| >= |d|^2, `cadbridge.nagata.admissibility`), takes at
                # each end the normal most orthogonal to it, as a half-crease edge does. So does
                # an edge bent sharply (its end tangents d - c, d + c more than `MAX_BEND_DEG`
                # apart, `cadbridge.nagata.admissibility` condition 3): where the two ends carry
                # nearly the same normal (5.6e-5 rad apart) and the chord runs along it (an
                # element standing on its face), n . (d - c) = 0 at one end and n' . (d + c) = 0
                # at the other contradict each other and the least-squares c runs across d, as
                # (n - n') / |n - n'|^2: |c| = 3.3e4 on a 0.96 edge of trj8_b1 (STEP), where
                # |c . d| stays below |d|^2.
                dd_f = np.einsum("ki,ki->k", d[f], d[f])
                t0, t1 = d[f] - cf, d[f] + cf
                cos_bend = np.einsum("ki,ki->k", t0, t1) / np.maximum(
                    np.linalg.norm(t0, axis=1) * np.linalg.norm(t1, axis=1), 1e-300)
                turns_back = ((np.abs(np.einsum("ki,ki->k", cf, d[f])) >= dd_f)
                              | (cos_bend < np.cos(np.radians(MAX_BEND_DEG))))
                half = np.union1d(half, f[turns_back])
            if half.size:
                # several normals at one end only: the edge leaves a crease node into one side
                # (elements on both sides of it straddle the crease). Eqs. 19-33 would make its
                # curve tangent to the crease there (c of size 1e3 |d| on a real mesh); the
                # normal of the side the edge runs in is the one most orthogonal to it
                dh = d[half] / np.linalg.norm(d[half], axis=1, keepdims=True)
                def pick(nn, mk):  # (H, P, 3) -> (H, 3): min |n . d^| over the present rows
                    score = np.where(mk, np.abs(np.einsum("hpi,hi->hp", nn, dh)), np.inf)
                    return nn[np.arange(len(nn)), np.argmin(score, axis=1)]
                c_edge[ce[half]] = edge_coefficient(x[lo[ce[half]]], x[hi[ce[half]]], pick(n0[half], mask[half]),
                                                    pick(n1[half], mask[half]), self.eps)
        pairs, p_extra, q_extra = self.edge_normals
        if len(pairs):  # boundary edges along a curve: two-normal c plus the conormals' sideways part (bounded)
            key = topo["edges"][:, 0] * np.int64(x.shape[0]) + topo["edges"][:, 1]
            kx = np.minimum(pairs[:, 0], pairs[:, 1]) * np.int64(x.shape[0]) + np.maximum(pairs[:, 0], pairs[:, 1])
            pos = np.minimum(np.searchsorted(key, kx), ne - 1)
            if np.any(key[pos] != kx):
                bad = int(np.flatnonzero(key[pos] != kx)[0])
                raise ValueError(f"edge_normals: nodes {pairs[bad].tolist()} are not an edge of the mesh")
            use = ~crease[pos] & bounded  # a crease edge keeps the generalized inverse of its elements' normals
            e, sw = pos[use], (pairs[:, 0] > pairs[:, 1])[use]
            p_lo = np.where(sw[:, None], q_extra[use], p_extra[use])
            p_hi = np.where(sw[:, None], p_extra[use], q_extra[use])
            c_edge[e] = edge_coefficient_conormal(x[lo[e]], x[hi[e]], n_lo[first[e]], n_hi[first[e]], p_lo, p_hi,
                                                  self.eps)
        c_inst = c_edge[eid]  # c is invariant under edge reversal
        nt = 3 * len(t)
        return c_inst[:nt].reshape(-1, 3, 3), c_inst[nt:].reshape(-1, 4, 3)

    @cached_property
    def edges(self) -> dict[str, NDArray]:
        """Global edge topology.

        ``edges`` (Ne, 2) sorted node pairs; per element-edge instance (all triangle edges
        then all quadrilateral edges, 3 resp. 4 per element in local edge order):
        ``inst_elem`` global element, ``inst_ledge`` local edge, ``inst_edge`` global edge,
        ``inst_flip`` True if the local direction is hi -> lo, ``inst_nbr`` the instance on
        the other side of a manifold edge (or -1); ``first_inst`` (Ne,); ``count`` (Ne,).
        """
        t, q = self.tri_elements, self.quad_elements
        a = np.concatenate([t[:, TRI_EDGES[:, 0]].ravel(), q[:, QUAD_EDGES[:, 0]].ravel()])
        b = np.concatenate([t[:, TRI_EDGES[:, 1]].ravel(), q[:, QUAD_EDGES[:, 1]].ravel()])
        inst_elem = np.concatenate([np.repeat(self.tri_global, 3), np.repeat(self.quad_global, 4)])
        inst_ledge = np.concatenate([np.tile(np.arange(3), len(t)), np.tile(np.arange(4), len(q))])
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        key = lo * np.int64(self.nodes.shape[0]) + hi
        uk, first, eid, count = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
        eid = eid.ravel()
        order = np.argsort(eid, kind="stable")
        nbr = np.full(eid.size, -1)
        two = count[eid[order]] == 2
        pos = np.arange(order.size)
        # within sorted order, manifold pairs are consecutive; first of pair has same edge as next
        is_first = two & (pos + 1 < order.size) & (np.r_[eid[order][1:], -1] == eid[order])
        f = order[is_first]
        s = order[np.flatnonzero(is_first) + 1]
        nbr[f] = s
        nbr[s] = f
        return {
            "edges": np.stack([lo[first], hi[first]], 1),
            "inst_elem": inst_elem,
            "inst_ledge": inst_ledge,
            "inst_edge": eid,
            "inst_flip": a > b,
            "inst_nbr": nbr,
            "first_inst": first,
            "count": count,
        }

    @cached_property
    def _elem_inst(self) -> NDArray:
        """(E, 4) instance index of each local edge of each global element (-1 padding)."""
        out = np.full((self.n_elements, 4), -1)
        topo = self.edges
        out[topo["inst_elem"], topo["inst_ledge"]] = np.arange(topo["inst_elem"].size)
        return out

    # ------------------------------------------------------------------ evaluation
    def _eval(self, elem: ArrayLike, eta: ArrayLike, zeta: ArrayLike, order: int) -> tuple[NDArray, ...]:
        elem = np.asarray(elem, dtype=np.int64).ravel()
        eta = np.asarray(eta, dtype=float).ravel()
        zeta = np.asarray(zeta, dtype=float).ravel()
        eta, zeta, elem = np.broadcast_arrays(eta, zeta, elem)
        nout = 1 + 2 * (order >= 1) + 3 * (order >= 2)
        out = tuple(np.empty((elem.size, 3)) for _ in range(nout))
        kind = self.element_kind[elem]
        loc = self.element_local[elem]
        for k, cf in ((3, self.tri_coefficients), (4, self.quad_coefficients)):
            m = np.flatnonzero(kind == k)
            if m.size:
                eval_rows(cf, loc, eta, zeta, m, out)
        return out

    def evaluate(self, elem: ArrayLike, eta: ArrayLike, zeta: ArrayLike) -> tuple[NDArray, NDArray]:
        """Points and unit normals (x_eta x x_zeta, element winding) at (elem, eta, zeta) (M,) -> (M, 3), (M, 3).

        Where a tangent vanishes (an edge whose normals force c = -d or c = d: the edge is
        straight but its parametrisation stops at one end, Nagata's singular case) the
        normal is the limit approached from inside the patch: with x_eta = 0 it is
        +-x_eta_eta x x_zeta, with x_zeta = 0 it is +-x_eta x x_zeta_zeta. Where both
        tangents are non-zero but parallel (a 180-degree corner of a degenerate element), or
        both vanish (to round-off of the element's size: a cone apex, whose patches start
        from rest along its generatrices), it is the normal a step of 1e-7 inside the patch,
        towards its centroid.
        """
        x, xe, xz = self._eval(elem, eta, zeta, 1)
        n = np.cross(xe, xz)
        ln = np.linalg.norm(n, axis=1)
        le, lz = np.linalg.norm(xe, axis=1), np.linalg.norm(xz, axis=1)
        # both tangents at round-off of the element's size: a corner where both edges start
        # from rest (a cone apex whose edges are its straight generatrices, c = d)
        size = self._element_size[np.broadcast_to(np.asarray(elem, dtype=np.int64).ravel(), (len(n),))]
        bad = (ln <= 1e-10 * np.maximum(le, lz) ** 2) | (np.maximum(le, lz) <= 1e-12 * size)
        if np.any(bad):
            el = np.broadcast_to(np.asarray(elem, dtype=np.int64).ravel(), (len(n),))[bad]
            et = np.broadcast_to(np.asarray(eta, dtype=float).ravel(), (len(n),))[bad]
            ze = np.broadcast_to(np.asarray(zeta, dtype=float).ravel(), (len(n),))[bad]
            _, xe_b, xz_b, xee, _, xzz = self._eval(el, et, ze, 2)
            # direction into the patch: towards its parametric centroid
            tri = self.element_kind[el] == 3
            ce, cz = np.where(tri, 2.0 / 3.0, 0.5), np.where(tri, 1.0 / 3.0, 0.5)
            se = np.where(ce - et >= 0, 1.0, -1.0)[:, None]
            sz = np.where(cz - ze >= 0, 1.0, -1.0)[:, None]
            rest = (np.maximum(le, lz) <= 1e-12 * size)[bad][:, None]
            eta_vanishes = (le[bad] <= 1e-6 * lz[bad])[:, None] | rest
            zeta_vanishes = (lz[bad] <= 1e-6 * le[bad])[:, None] | rest
            lim = np.where(eta_vanishes, se * np.cross(xee, xz_b), sz * np.cross(xe_b, xzz))
            lim[~(eta_vanishes | zeta_vanishes)[:, 0] | rest[:, 0]] = 0.0
            still = np.linalg.norm(lim, axis=1) <= 1e-300
            if np.any(still):
                # both tangents vanish, or they are parallel (a flat 180-degree corner of a
                # badly shaped element): the normal is the one just inside the patch
                t = 1e-7
                _, a, b = self._eval(el[still], et[still] + t * (ce[still] - et[still]), ze[still] + t * (cz[still] - ze[still]), 1)
                lim[still] = np.cross(a, b)
            n[bad] = lim
        return x, unit(n)

    @cached_property
    def _element_size(self) -> NDArray:
        """(E,) largest distance of an element's corners from its first corner (global numbering)."""
        out = np.zeros(self.n_elements)
        for conn, glob in ((self.tri_elements, self.tri_global), (self.quad_elements, self.quad_global)):
            if len(conn):
                x = self.nodes[conn]
                out[glob] = np.linalg.norm(x - x[:, :1], axis=2).max(axis=1)
        return out

    def derivatives(self, elem: ArrayLike, eta: ArrayLike, zeta: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
        """Points and first derivatives (thesis eqs. 7-8, 12-13): (M, 3) each."""
        return self._eval(elem, eta, zeta, 1)

    def second_derivatives(self, elem: ArrayLike, eta: ArrayLike, zeta: ArrayLike) -> tuple[NDArray, ...]:
        """x, x_eta, x_zeta, x_eta_eta, x_eta_zeta, x_zeta_zeta, each (M, 3)."""
        return self._eval(elem, eta, zeta, 2)

    # ------------------------------------------------------------------ sampling
    def grid_parameters(self, n: int) -> tuple[NDArray, NDArray, NDArray]:
        """Uniform parametric grid with n divisions per parameter on every patch, elements
        in global order: (elem, eta, zeta) each (M,)."""
        ti, tj, _ = _tri_template(n)
        qi, qj, _ = _quad_template(n)
        nt, nq = ti.size, qi.size
        per = np.where(self.element_kind == 3, nt, nq)
        start = np.concatenate([[0], np.cumsum(per)[:-1]])
        elem = np.repeat(np.arange(self.n_elements), per)
        local = np.arange(elem.size) - start[elem]
        is_t = self.element_kind[elem] == 3
        i = np.where(is_t, ti[np.minimum(local, nt - 1)], qi[np.minimum(local, nq - 1)])
        j = np.where(is_t, tj[np.minimum(local, nt - 1)], qj[np.minimum(local, nq - 1)])
        return elem, i / n, j / n

    def sample_grid(self, n: int) -> Grid:
        """Uniform parametric grid with ``n`` divisions per parameter on each patch
        ((n+1)(n+2)/2 points per triangle, (n+1)^2 per quadrilateral)."""
        elem, eta, zeta = self.grid_parameters(n)
        pts, nrm = self.evaluate(elem, eta, zeta)
        return Grid(pts, nrm, elem, eta, zeta)

    def refined_triangulation(self, n: int, return_params: bool = False):
        """Watertight triangulation of the Nagata surface, ``n`` divisions per patch edge.

        Points on shared mesh edges and nodes are merged by topology (global node / edge
        ids), so neighbouring patches share vertices exactly.
        Returns vertices (V, 3) and triangles (T, 3) oriented with the element winding;
        with ``return_params`` also (elem, eta, zeta) (V,) of one patch each vertex lies on.
        """
        if n < 1:
            raise ValueError("n must be >= 1")
        topo = self.edges
        nn = self.nodes.shape[0]
        ne = len(topo["edges"])
        elem, eta, zeta = self.grid_parameters(n)
        pts, _ = self.evaluate(elem, eta, zeta)
        keys = np.empty(elem.size, dtype=np.int64)
        tris = []
        offsets = np.zeros(self.n_elements, dtype=np.int64)
        per = np.where(self.element_kind == 3, (n + 1) * (n + 2) // 2, (n + 1) ** 2)
        offsets[1:] = np.cumsum(per)[:-1]
        conn = np.full((self.n_elements, 4), -1, dtype=np.int64)
        conn[self.tri_global, :3] = self.tri_elements
        conn[self.quad_global] = self.quad_elements
        inst = self._elem_inst
        interior_base = nn + ne * max(n - 1, 0)
        for kind, tmpl in ((3, _tri_template(n)), (4, _quad_template(n))):
            els = self.tri_global if kind == 3 else self.quad_global
            if els.size == 0:
                continue
            i, j, ttri = tmpl
            corner, ledge, k = _template_location(kind, i, j, n)
            npt = i.size
            gidx = offsets[els][:, None] + np.arange(npt)[None, :]  # (Ek, P)
            kk = np.zeros(gidx.shape, dtype=np.int64)
            cm = corner >= 0
            kk[:, cm] = conn[els][:, corner[cm]]
            em = ledge >= 0
            if em.any():
                ins = inst[els][:, ledge[em]]  # (Ek, Pe)
                flip = topo["inst_flip"][ins]
                kc = np.where(flip, n - k[em][None, :], k[em][None, :])
                kk[:, em] = nn + topo["inst_edge"][ins] * (n - 1) + (kc - 1)
            im = ~cm & ~em
            kk[:, im] = interior_base + gidx[:, im]  # unique per patch point
            keys[gidx.ravel()] = kk.ravel()
            tris.append((offsets[els][:, None, None] + ttri[None]).reshape(-1, 3))
        uk, first, inv = np.unique(keys, return_index=True, return_inverse=True)
        verts = pts[first]
        isnode = uk < nn
        verts[isnode] = self.nodes[uk[isnode]]
        triangles = inv.ravel()[np.concatenate(tris)]
        if return_params:
            return verts, triangles, (elem[first], eta[first], zeta[first])
        return verts, triangles

    # ------------------------------------------------------------------ projection
    @staticmethod
    def _clamp(kind: NDArray, eta: NDArray, zeta: NDArray) -> tuple[NDArray, NDArray]:
        e = np.clip(eta, 0.0, 1.0)
        z = np.clip(zeta, 0.0, 1.0)
        over = (kind == 3) & (z > e)
        t = 0.5 * (e + z)
        return np.where(over, t, e), np.where(over, t, z)

    @staticmethod
    def _violation(kind: NDArray, eta: NDArray, zeta: NDArray) -> tuple[NDArray, NDArray]:
        """Most violated local edge of an unclamped parameter point and the violation (>0 outside)."""
        tri = np.stack([-zeta, eta - 1.0, (zeta - eta) / np.sqrt(2.0), np.full_like(eta, -np.inf)], 1)
        quad = np.stack([-zeta, eta - 1.0, zeta - 1.0, -eta], 1)
        v = np.where((kind == 3)[:, None], tri, quad)
        e = np.argmax(v, 1)
        return e, v[np.arange(e.size), e]

    @staticmethod
    def _on_edge(kind: NDArray, ledge: NDArray, eta: NDArray, zeta: NDArray, tol: float = 1e-12) -> NDArray:
        dist_t = np.select([ledge == 0, ledge == 1, ledge == 2], [zeta, 1.0 - eta, eta - zeta], np.inf)
        dist_q = np.select([ledge == 0, ledge == 1, ledge == 2, ledge == 3], [zeta, 1.0 - eta, 1.0 - zeta, eta], np.inf)
        return np.abs(np.where(kind == 3, dist_t, dist_q)) <= tol

    @cached_property
    def _seed_tree(self):  # noqa: ANN202
        from scipy.spatial import cKDTree

        g = self.grid_parameters(self._seed_n)
        pts, _ = self.evaluate(*g)
        return cKDTree(pts), g

    _seed_n = 6

    def closest_point(self, points: ArrayLike, max_iter: int = 50, tol: float = 1e-13, max_hops: int = 10
                      ) -> ClosestPoint:
        """Closest point on the Nagata surface to each point (M, 3).

        Newton iterations on the squared distance (full Hessian, Gauss-Newton fallback)
        from the nearest sample of a coarse parametric grid, clamped to the parameter
        domain; a point pushed out through a patch edge continues on the neighbouring
        patch.  Iterations are bounded and the best point found is returned.
        """
        p = np.atleast_2d(np.asarray(points, dtype=float))
        tree, (ge, gn, gz) = self._seed_tree
        _, idx = tree.query(p)
        elem, eta, zeta = ge[idx].copy(), gn[idx].copy(), gz[idx].copy()
        topo = self.edges
        inst = self._elem_inst
        best_d = np.full(len(p), np.inf)
        best = [np.zeros((len(p), 3)), elem.copy(), eta.copy(), zeta.copy()]
        active = np.arange(len(p))
        hops = np.zeros(len(p), dtype=int)
        for _ in range(max_iter):  # bounded Newton loop, vectorised over points
            if active.size == 0:
                break
            el, e, z, pp = elem[active], eta[active], zeta[active], p[active]
            x, xe, xz, xee, xez, xzz = self.second_derivatives(el, e, z)
            r = x - pp
            d = np.linalg.norm(r, axis=1)
            better = d <= best_d[active] * (1 + 1e-12) + 1e-300
            ai = active[better]
            best_d[ai] = d[better]
            best[0][ai], best[1][ai], best[2][ai], best[3][ai] = x[better], el[better], e[better], z[better]
            g0 = np.einsum("ij,ij->i", xe, r)
            g1 = np.einsum("ij,ij->i", xz, r)
            a00 = np.einsum("ij,ij->i", xe, xe)
            a01 = np.einsum("ij,ij->i", xe, xz)
            a11 = np.einsum("ij,ij->i", xz, xz)
            h00 = a00 + np.einsum("ij,ij->i", xee, r)
            h01 = a01 + np.einsum("ij,ij->i", xez, r)
            h11 = a11 + np.einsum("ij,ij->i", xzz, r)
            det = h00 * h11 - h01 * h01
            pd = (h00 > 0) & (det > 1e-12 * (a00 * a11))
            h00, h01, h11 = np.where(pd, h00, a00), np.where(pd, h01, a01), np.where(pd, h11, a11)
            det = h00 * h11 - h01 * h01
            det = np.where(det == 0, 1.0, det)
            de = -(h11 * g0 - h01 * g1) / det
            dz = -(-h01 * g0 + h00 * g1) / det
            step = np.hypot(de, dz)
            scale = np.minimum(1.0, 0.5 / np.maximum(step, 1e-300))
            de, dz = de * scale, dz * scale
            kind = self.element_kind[el]
            vedge, viol = self._violation(kind, e + de, z + dz)
            ce, cz = self._clamp(kind, e + de, z + dz)
            # already on the edge the step leaves through: 1D Newton along that edge
            on = (viol > 1e-14) & self._on_edge(kind, vedge, e, z)
            if on.any():
                o = np.flatnonzero(on)
                ko, vo = kind[o], vedge[o]
                te = np.where((vo == 1) | ((ko == 4) & (vo == 3)), 0.0, 1.0)
                tz = np.where((vo == 0) | ((ko == 4) & (vo == 2)), 0.0, 1.0)
                gt = g0[o] * te + g1[o] * tz
                ht = h00[o] * te * te + 2 * h01[o] * te * tz + h11[o] * tz * tz
                at = a00[o] * te * te + 2 * a01[o] * te * tz + a11[o] * tz * tz
                ht = np.where(ht > 1e-12 * at, ht, at)
                st = -gt / np.where(ht > 0, ht, 1.0)
                st = np.clip(st, -0.5, 0.5)
                ce[o], cz[o] = self._clamp(kind[o], e[o] + st * te, z[o] + st * tz)
                stalled = np.zeros(on.shape, bool)
                stalled[o] = np.hypot(ce[o] - e[o], cz[o] - z[o]) < 1e-10
            else:
                stalled = on
            # stalled on the edge it wants to leave -> continue on the neighbouring patch
            hop = stalled & (hops[active] < max_hops)
            ins = inst[el, vedge]
            nb = np.where(hop & (ins >= 0), topo["inst_nbr"][np.maximum(ins, 0)], -1)
            hop &= nb >= 0
            if hop.any():
                h = np.flatnonzero(hop)
                xi = _edge_xi(kind[h], vedge[h], e[h], z[h])
                same = topo["inst_flip"][ins[h]] == topo["inst_flip"][nb[h]]
                xi = np.where(same, xi, 1.0 - xi)
                nel = topo["inst_elem"][nb[h]]
                nle = topo["inst_ledge"][nb[h]]
                ce[h], cz[h] = _edge_params(self.element_kind[nel], nle, xi)
                el = el.copy()
                el[h] = nel
                hops[active[h]] += 1
            moved = np.hypot(ce - e, cz - z)
            elem[active], eta[active], zeta[active] = el, ce, cz
            done = (moved < tol) & ~hop
            active = active[~done]
        # final evaluation of the last iterates still active
        if active.size:
            x, _ = self.evaluate(elem[active], eta[active], zeta[active])
            d = np.linalg.norm(x - p[active], axis=1)
            better = d <= best_d[active] * (1 + 1e-12) + 1e-300
            ai = active[better]
            best_d[ai] = d[better]
            best[0][ai], best[1][ai], best[2][ai], best[3][ai] = (
                x[better], elem[active][better], eta[active][better], zeta[active][better])
        return ClosestPoint(best[0], best[1], best[2], best[3], best_d)
