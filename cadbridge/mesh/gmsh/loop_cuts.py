"""Trim-loop excursions cut out of the gmsh mesh too (`cadbridge.heal.loop_excursions`).

gmsh meshes the file through OpenCASCADE, which keeps a face's trim loop as the file has it,
excursion included; cadbridge classifies with the healed loop. So that both see one face,
the gmsh surfaces that hold an excursion are cleared after ``generate`` and meshed again by
`cadbridge.mesh.gmsh.empty_faces` on gmsh's boundary nodes, less the nodes on the excursion
(`Excursion.in_stretch`): the loop the fallback mesher sees goes from the last node before X
to the first after Y, as the healed trim does. The excursion's nodes stay on the neighbour
(the edge it shares with the face): a crack no wider than the excursion's chord is left
there, and reported.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["surfaces_with_excursions"]


def surfaces_with_excursions(g, excursions: Sequence, surfaces: list[int], tol: float) -> dict[int, list]:
    """{gmsh surface tag: excursions on it}: the surface whose own parametrisation maps each
    excursion's (u, v) samples onto its model-space points within ``tol`` (OCC keeps a B-spline
    surface's parameters, so the face is found by its surface, not by its position among
    fragments); an excursion no surface reproduces is left out (gmsh meshes that face as
    usual). ``g`` the gmsh module with the model loaded."""
    out: dict[int, list] = {}
    for e in excursions:  # loop over the (few) excursions
        lo, hi = e.stretch_xyz.min(axis=0) - tol, e.stretch_xyz.max(axis=0) + tol
        for s in surfaces:
            bb = np.asarray(g.model.getBoundingBox(2, s), dtype=float)
            if np.any(bb[:3] > hi) or np.any(bb[3:] < lo):
                continue
            p = np.asarray(g.model.getValue(2, s, e.stretch_uv.ravel().tolist()), dtype=float).reshape(-1, 3)
            if len(p) == len(e.stretch_xyz) and float(np.linalg.norm(p - e.stretch_xyz, axis=1).max()) <= tol:
                out.setdefault(s, []).append(e)
                break
    return out


def clear(g, cuts: dict[int, list]) -> None:
    """Remove gmsh's 2D mesh of the surfaces of ``cuts`` (their curves keep their nodes)."""
    if cuts:
        g.model.mesh.clear([(2, s) for s in sorted(cuts)])


def drop_mask(excursions: Sequence, xyz: np.ndarray) -> np.ndarray:
    """Loop nodes (N, 3) that lie on one of ``excursions``' cut stretches, (N,) bool."""
    drop = np.zeros(len(xyz), dtype=bool)
    for e in excursions:
        drop |= e.in_stretch(xyz)
    return drop
