"""cadbridge: IGES/NURBS CAD to Nagata-patch tool files for sheet metal forming simulation."""

from cadbridge.model import Diagnostic, Face, Model, Trim, TrimLoop, Units
from cadbridge.nurbs import NurbsCurve, NurbsSurface

__version__ = "0.1.0"

__all__ = ["Diagnostic", "Face", "Model", "NurbsCurve", "NurbsSurface", "Trim", "TrimLoop", "Units"]
