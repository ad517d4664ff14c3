"""The number of elements a mesh of a model at a given element size will have, before meshing.

The trimmed area of each face comes from a midpoint rule on an n x n grid of its (u, v)
domain (|Su x Sv| du dv over the cells whose centre lies inside the trims); one element of
edge ``size`` covers an equilateral triangle (sqrt(3)/4 size^2) or a square (size^2). The
mesher's size bounds its element edges from above (gmsh's ``Mesh.MeshSizeMax``; curvature
and small features make elements smaller), so the count is an estimate from below: a run
refused on it would have made at least about that many elements.

`check_element_count` refuses a size that would make more than `MAX_ELEMENTS` elements, up
front, with the number and the face that would hold most of them (a ``--size`` far too small
for the model, or a model made far larger by a damaged number).
"""

from __future__ import annotations

import math

import numpy as np

from cadbridge.cad.model import Model
from cadbridge.mesh.mesh import MeshError

__all__ = ["MAX_ELEMENTS", "check_element_count", "estimated_elements", "face_areas"]

MAX_ELEMENTS = 5_000_000
"""Meshes above this many elements are refused before meshing: gmsh needs about 1 kB per
element while meshing, and the tool chain several times that; the largest tool of the
production dies has about 140 000 nodes."""

_ELEMENT_AREA = {"tri": math.sqrt(3.0) / 4.0, "quad": 1.0}  # x size^2


def face_areas(model: Model, n: int = 32) -> np.ndarray:
    """Trimmed area of each face (F,), in model units squared: midpoint rule on an ``n`` x
    ``n`` grid of the face's (u, v) domain, cells counted where their centre is inside."""
    out = np.zeros(len(model.faces))
    t = (np.arange(n) + 0.5) / n
    for i, f in enumerate(model.faces):  # loop over faces, vectorised over the grid
        u0, u1, v0, v1 = f.surface.domain
        uu, vv = np.meshgrid(u0 + (u1 - u0) * t, v0 + (v1 - v0) * t, indexing="ij")
        u, v = uu.ravel(), vv.ravel()
        d = f.surface.derivatives(u, v, order=1)
        jac = np.linalg.norm(np.cross(d[:, 1, 0], d[:, 0, 1]), axis=1)
        inside = f.contains(u, v)
        cell = (u1 - u0) * (v1 - v0) / (n * n)
        out[i] = float(np.sum(np.where(inside & np.isfinite(jac), jac, 0.0))) * cell
    return out


def estimated_elements(model: Model, size: float, element: str = "quad") -> np.ndarray:
    """Elements (F,) a mesh of edge ``size`` (model units) puts on each face, from below:
    face area / the area of one element ("tri": equilateral, "quad": square)."""
    return face_areas(model) / (_ELEMENT_AREA[element] * size * size)


def check_element_count(model: Model, size: float, element: str = "quad", limit: int = MAX_ELEMENTS) -> None:
    """Raise `MeshError` when a mesh of edge ``size`` would have more than ``limit`` elements
    (`estimated_elements`): the message gives the estimate, the face holding most and the
    smallest size within the limit."""
    per_face = estimated_elements(model, size, element)
    total = float(per_face.sum())
    if not total > limit:
        return
    k = int(np.argmax(per_face))
    f = model.faces[k]
    least = size * math.sqrt(total / limit)
    raise MeshError(f"element size {size:g} would make about {total:.2g} elements, more than {limit:.0e}; most "
                    f"({per_face[k]:.2g}) on face {k} ({f.name or 'unnamed'}, DE {f.de}), area about "
                    f"{per_face[k] * _ELEMENT_AREA[element] * size * size:.3g}: choose a size of at least {least:.3g}")
