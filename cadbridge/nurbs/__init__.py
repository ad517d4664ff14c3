"""Single-surface NURBS math: basis functions, curves, surfaces, knot work and edits, constructions,
curvature, inflections, projection (Newton) and fitting."""

from cadbridge.nurbs.basis import basis_funs, ders_basis_funs, find_span
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["NurbsCurve", "NurbsSurface", "basis_funs", "ders_basis_funs", "find_span"]
