"""Admissible Nagata edges: a quadratic edge curve that a patch can be built on.

The edge curve x(xi) = x0 + (d - c) xi + c xi^2 (Nagata eq. 1) of an edge whose end nodes
lie on a smooth surface is *admissible* when

1. **not inflected**: the chord lies on opposite sides of the two end tangent planes,
   (d . n0)(d . n1) <= 0. Otherwise the surface has an inflection between the nodes, the
   node is outside the "admissible region" of thesis §6.2.2 (Fig. 56), and no quadratic can
   follow it (Fig. 57/58: the irregular patches);
2. **monotone**: the curve runs forward along its chord, d . x'(xi) > 0 on [0, 1], i.e.
   |d . c| < |d|^2 (x'(xi) = d - c + 2 c xi is linear in xi: the ends decide);
3. **no sharp bend**: the angle between the end tangents x'(0) = d - c and x'(1) = d + c is
   at most ``max_bend`` (default 100 degrees; a quarter circle on one edge turns by 90).

Edges with several normals at an end (creases, `NagataMesh.crease_edges`) are built from
the generalized inverse; their condition 1 is not defined and is not tested.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cadbridge.nagata.patch import QUAD_EDGES, TRI_EDGES

__all__ = ["MAX_BEND_DEG", "EdgeAdmissibility", "edge_admissibility"]

MAX_BEND_DEG = 100.0
"""Largest angle between an admissible edge curve's end tangents (condition 3) [degrees]."""


@dataclass
class EdgeAdmissibility:
    """Per global edge (Ne,) of a `NagataMesh`: ``edges`` (Ne, 2) node pairs, ``inflected``,
    ``not_monotone``, ``bend_deg`` (angle between the end tangents), ``admissible``; and per
    element (E,) ``element_ok`` (all its edges admissible)."""

    edges: NDArray
    inflected: NDArray
    not_monotone: NDArray
    bend_deg: NDArray
    admissible: NDArray
    element_ok: NDArray

    def bad_elements(self) -> NDArray:
        """Global ids (K,) of the elements with an inadmissible edge."""
        return np.flatnonzero(~self.element_ok)

    def reasons(self) -> NDArray:
        """Per edge (Ne,) a short reason ('' where admissible)."""
        r = np.full(len(self.edges), "", dtype=object)
        r[self.bend_mask] = "sharp bend"
        r[self.not_monotone] = "not monotone"
        r[self.inflected] = "inflected (node outside the admissible region)"
        return r

    bend_mask: NDArray = None  # type: ignore[assignment]


def edge_admissibility(nm, max_bend: float = MAX_BEND_DEG, eps: float = 1e-10) -> EdgeAdmissibility:
    """Admissibility (module docs) of every edge of the `NagataMesh` ``nm``."""
    topo = nm.edges
    ne = len(topo["edges"])
    first = topo["first_inst"]
    # per instance: local end normals and coefficient, in the instance's own direction
    n0 = np.concatenate([nm.tri_corner_normals[:, TRI_EDGES[:, 0]].reshape(-1, 3),
                         nm.quad_corner_normals[:, QUAD_EDGES[:, 0]].reshape(-1, 3)])
    n1 = np.concatenate([nm.tri_corner_normals[:, TRI_EDGES[:, 1]].reshape(-1, 3),
                         nm.quad_corner_normals[:, QUAD_EDGES[:, 1]].reshape(-1, 3)])
    c = np.concatenate([nm.tri_edge_coefficients.reshape(-1, 3), nm.quad_edge_coefficients.reshape(-1, 3)])
    a = np.concatenate([nm.tri_elements[:, TRI_EDGES[:, 0]].ravel(), nm.quad_elements[:, QUAD_EDGES[:, 0]].ravel()])
    b = np.concatenate([nm.tri_elements[:, TRI_EDGES[:, 1]].ravel(), nm.quad_elements[:, QUAD_EDGES[:, 1]].ravel()])
    d = nm.nodes[b] - nm.nodes[a]
    f = first
    d, c, n0, n1 = d[f], c[f], n0[f], n1[f]
    dd = np.einsum("ij,ij->i", d, d)
    inflected = np.einsum("ij,ij->i", d, n0) * np.einsum("ij,ij->i", d, n1) > eps * dd
    if len(nm.crease_edges):
        inflected[nm.crease_edges] = False
    not_monotone = np.abs(np.einsum("ij,ij->i", d, c)) >= dd
    t0, t1 = d - c, d + c
    cosb = np.einsum("ij,ij->i", t0, t1) / np.maximum(np.linalg.norm(t0, axis=1) * np.linalg.norm(t1, axis=1), 1e-300)
    bend = np.degrees(np.arccos(np.clip(cosb, -1.0, 1.0)))
    bend_bad = bend > max_bend
    ok = ~(inflected | not_monotone | bend_bad)
    elem_ok = np.ones(nm.n_elements, bool)
    bad_inst = ~ok[topo["inst_edge"]]
    elem_ok[topo["inst_elem"][bad_inst]] = False
    return EdgeAdmissibility(topo["edges"], inflected, not_monotone, bend, ok, elem_ok, bend_bad)
