"""Nagata patches: edge coefficient, triangular/quadrilateral patches, error analysis."""

from cadbridge.nagata.edge import (
    EDGE_RULES,
    EPS_RANK,
    EPS_SINGULAR,
    check_edge_rule,
    edge_coefficient,
    edge_coefficient_multi,
)
from cadbridge.nagata.errors import (
    Cylinder,
    ErrorReport,
    Plane,
    Sphere,
    Torus,
    cad_errors,
    normal_error,
    patch_errors,
    radial_error,
)
from cadbridge.nagata.mesh import ClosestPoint, Grid, NagataMesh
from cadbridge.nagata.patch import quad_coefficients, quad_eval, tri_coefficients, tri_eval

__all__ = [
    "EDGE_RULES",
    "EPS_RANK",
    "EPS_SINGULAR",
    "ClosestPoint",
    "Cylinder",
    "ErrorReport",
    "Grid",
    "NagataMesh",
    "Plane",
    "Sphere",
    "Torus",
    "cad_errors",
    "check_edge_rule",
    "edge_coefficient",
    "edge_coefficient_multi",
    "normal_error",
    "patch_errors",
    "quad_coefficients",
    "quad_eval",
    "radial_error",
    "tri_coefficients",
    "tri_eval",
]
