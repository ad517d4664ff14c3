"""NUMISHEET'93 U-shape (2D draw bending) benchmark: tool contact surfaces, blank mesh, IGES export.

This package builds geometry with OpenCASCADE (OCP); like `cadbridge.verify` it is outside the
core and is never imported by it.
"""

from cadbridge.ushape.geometry import (
    FACE_LABELS,
    UShapeParams,
    blank_mesh,
    build_tools,
    export_iges,
    tool_faces,
)

__all__ = ["FACE_LABELS", "UShapeParams", "blank_mesh", "build_tools", "export_iges", "tool_faces"]
