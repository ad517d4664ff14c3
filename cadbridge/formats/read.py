"""`read_cad`: a CAD file's `Model`, IGES or STEP, the format told by the file's content.

STEP (ISO 10303-21) files start with ``ISO-10303-21;``; everything else is read as IGES,
whose reader names what is wrong with a file that is neither. The extension does not
decide: ``.igs`` files that hold STEP text, and the reverse, occur in transfers.
"""

from __future__ import annotations

from pathlib import Path

from cadbridge.cad.model import Model

__all__ = ["cad_format", "read_cad"]


def cad_format(path: str | Path) -> str:
    """"step" or "iges": the format of the file at ``path`` by its content."""
    from cadbridge.step.reader import is_step

    return "step" if is_step(path) else "iges"


def read_cad(path: str | Path, progress=None) -> Model:
    """The `Model` of the IGES or STEP file at ``path`` (`cadbridge.iges.read_iges`,
    `cadbridge.step.read_step`): the same faces (exact NURBS surfaces and (u, v) trim loops),
    in the file's units for IGES and in mm for STEP. Raises `cadbridge.iges.IgesError` or
    `cadbridge.step.StepError` (exit 2 in the CLI) for a file that cannot be read."""
    if cad_format(path) == "step":
        from cadbridge.step.reader import read_step

        return read_step(path, progress)
    from cadbridge.iges import read_iges

    return read_iges(str(path))
