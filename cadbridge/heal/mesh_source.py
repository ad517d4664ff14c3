"""The CAD file the mesher should read: the file itself, or a copy that says what cadbridge read.

gmsh meshes the file through OpenCASCADE's IGES reader, cadbridge projects the nodes onto
its own reading. Where the two readings differ the mesh lies off the CAD. cadbridge's
reader marks the faces it read otherwise than the file's preferred trim curves say
(`Diagnostic.kind == "reread"`, e.g. `cadbridge.iges.arc_convention`: parameter-space curves
that measure a generatrix arc from its start); for those faces the model-space curves of
the file agree with cadbridge's reading (that is what decided it). So the mesher's copy sets
the preferred representation (PREF, field 5) of those faces' 142 curves from 1 (parameter
space) to 2 (model space), IGES 5.3 4.32, which OCC honours: it then builds the edges from
the model-space curves. The copy differs from the file in those digits only (same length,
same line structure), and lives in a temporary folder for the time of the meshing.

The copy also makes trim curves C1 at C0 knots beside short pieces (`cadbridge.heal.trim_knots`):
OCC's reader would cut the curves there, and gmsh put a node on every cut.
"""

from __future__ import annotations

import re
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from cadbridge.cad.model import Model

__all__ = ["reread_faces", "mesh_source", "prefer_model_space", "write_mesh_source"]


def reread_faces(model: Model) -> list[int]:
    """DE numbers of the top-level faces the reader read otherwise than the file says, sorted."""
    return sorted({d.de for d in model.diagnostics if d.kind == "reread" and d.de is not None})


def prefer_model_space(text: str, faces: list[int]) -> tuple[str, list[int]]:
    """``text`` (an IGES file) with PREF = 2 on the 142s that the 144s ``faces`` (DE numbers)
    point to; returns the new text and the 142 DEs changed. A 142 whose PREF field is not
    the single digit 1 or whose entity is not found is left as it is.

    Columns (IGES 5.3, 2.2.4): 1-72 data, 73 the section letter, 74-80 the sequence number;
    a directory entry's field 2 is its first P line, field 14 (second record, columns 25-32)
    the number of its P lines; P lines carry data in columns 1-64."""
    lines = text.split("\n")
    sec = [ln[72] if len(ln) > 72 else "" for ln in lines]
    d_lines = [i for i, s in enumerate(sec) if s == "D"]
    p_first = next((i for i, s in enumerate(sec) if s == "P"), None)
    g = "".join(lines[i][:72] for i, s in enumerate(sec) if s == "G")
    pdelim, rdelim = ",", ";"
    m = re.match(r"\s*1H(.)", g)
    if m:
        pdelim = m.group(1)
        m2 = re.match(r"\s*1H.\s*" + re.escape(pdelim) + r"\s*1H(.)", g)
        if m2:
            rdelim = m2.group(1)
    if p_first is None or not d_lines:
        return text, []

    def entry(de: int) -> tuple[int, int, int] | None:
        k = de - 1  # D sequence numbers are 1-based: DE n is the n-th D line
        if not 0 <= k + 1 < len(d_lines):
            return None
        a, b = lines[d_lines[k]], lines[d_lines[k + 1]]
        try:
            return int(a[0:8]), int(a[8:16]), int(b[24:32])  # type, first P line, P line count
        except ValueError:
            return None

    def body(first: int, count: int) -> list[int]:
        return list(range(p_first + first - 1, p_first + first - 1 + count))

    def fields(idx: list[int]) -> list[str]:
        s = "".join(lines[i][:64] for i in idx)
        return s.split(rdelim)[0].split(pdelim)

    changed = []
    for fde in faces:
        e = entry(fde)
        if e is None or e[0] != 144:
            continue
        f = [x.strip() for x in fields(body(e[1], e[2]))]
        try:  # 144: PTS, N1, N2, PTO, PTI(1..N2)
            n1, n2 = int(f[2]), int(f[3])
            cos = ([int(f[4])] if n1 == 1 else []) + [int(x) for x in f[5 : 5 + n2]]
        except (ValueError, IndexError):
            continue
        for cde in cos:
            c = entry(cde)
            if c is None or c[0] != 142:
                continue
            idx = body(c[1], c[2])
            # the 6th field (PREF) is the text between the 5th delimiter and the record delimiter
            flat = "".join(lines[i][:64] for i in idx)
            end = flat.find(rdelim)
            starts = [j for j, ch in enumerate(flat[: max(end, 0)]) if ch == pdelim]
            if end < 0 or len(starts) < 5:
                continue
            a = starts[4] + 1
            b = starts[5] if len(starts) > 5 else end
            if flat[a:b].strip() != "1":
                continue
            j = a + flat[a:b].index("1")
            li, col = idx[j // 64], j % 64
            lines[li] = lines[li][:col] + "2" + lines[li][col + 1 :]
            changed.append(cde)
    return "\n".join(lines), changed


def _occ_step_brep(cad: Path, folder: str | Path) -> Path:
    """OCC's reading of the STEP file ``cad`` (`cadbridge.step.occ_step_shape`) written as an
    OCC ``.brep`` into ``folder``: what gmsh meshes for "the file as OCC reads it" (gmsh's own
    STEP import finds no surface in some files OCC reads, e.g. NIST's CTC-05)."""
    from OCP.BRepTools import BRepTools

    from cadbridge.step.reader import occ_step_shape

    shape = occ_step_shape(cad)
    if shape is None:
        return cad  # gmsh's own import then says what is wrong
    out = Path(folder) / f"{cad.stem}.brep"
    if not BRepTools.Write_s(shape, str(out)):
        raise OSError(f"could not write OCC's reading of {cad.name} to {out}")
    return out


def write_mesh_source(cad: str | Path, model: Model, folder: str | Path, smooth: bool = True) -> Path:
    """The file the mesher should read for ``cad`` as ``model`` says: ``cad`` itself unless the
    reader re-read faces or (``smooth``) a trim curve has short C0 pieces, else a copy written
    into ``folder`` (same file name; the caller owns the folder) with those faces preferring
    their model-space curves (`prefer_model_space`) and those curves smoothed
    (`cadbridge.heal.trim_knots.smooth_short_knots`). ``smooth`` False: the re-read faces only (what
    an independent reference of the CAD should read)."""
    from cadbridge.formats import cad_format
    from cadbridge.heal.trim_knots import JOIN_SHORTER, has_c0_knots, smooth_short_knots

    cad = Path(cad)
    if cad_format(cad) == "step":
        return _occ_step_brep(cad, folder)
    faces = reread_faces(model)
    shorter = JOIN_SHORTER * model.size() if smooth and model.faces else 0.0
    smooth = shorter > 0 and has_c0_knots(model)
    if not faces and not smooth:
        return cad
    text = cad.read_bytes().decode("latin-1")
    changed, joined = [], 0
    if faces:
        text, changed = prefer_model_space(text, faces)
    if smooth:
        text, joined = smooth_short_knots(text, shorter, filename=cad.name)
    if not changed and not joined:
        return cad
    copy = Path(folder) / cad.name
    copy.write_bytes(text.encode("latin-1"))
    return copy


@contextmanager
def mesh_source(cad: str | Path, model: Model) -> Iterator[Path]:
    """Path of the file the mesher should read for ``cad`` as ``model`` (its reading by
    `cadbridge.read_iges`) says: ``cad`` itself, or a temporary copy (`write_mesh_source`),
    removed on exit."""
    with tempfile.TemporaryDirectory(prefix="cadbridge-mesh-") as tmp:
        yield write_mesh_source(cad, model, tmp)
