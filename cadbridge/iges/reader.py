"""`read_iges`: IGES 5.3 fixed-format file -> `Model` (faces with exact NURBS, trims, units)."""

from __future__ import annotations

import gc
from collections import Counter
from os import PathLike
from pathlib import Path

import numpy as np

from cadbridge.iges.directory import parse_directory
from cadbridge.iges.entities import (ANALYTIC_TYPES, FACE_TYPES, INTERPRETED_TYPES, SURFACE_TYPES, Affine, Builder,
                                     compose)
from cadbridge.iges.errors import IgesError
from cadbridge.iges.globals import (F_AUTHOR, F_FILE_NAME, F_ORGANIZATION, F_PREPROCESSOR, F_PRODUCT_ID,
                                    F_SYSTEM, parse_global)
from cadbridge.iges.lexer import split_sections
from cadbridge.cad.model import Diagnostic, Face, Model

__all__ = ["curve_preferences", "read_iges", "read_iges_string"]


def read_iges(path: str | PathLike) -> Model:
    """Read an IGES 5.3 file. Raises IgesError for malformed or unsupported content
    (OSError if the file cannot be opened)."""
    path = Path(path)
    data = path.read_bytes()
    return read_iges_string(data.decode("latin-1"), filename=path.name)


def curve_preferences(path: str | PathLike) -> dict[int, int]:
    """The preferred representation (PREF, IGES 5.3 4.32: 0 unspecified, 1 parameter space,
    2 model space, 3 equal) of every 142 curve on a surface in the IGES file, by DE number;
    -1 where the field cannot be read."""
    path = Path(path)
    text = path.read_bytes().decode("latin-1")
    secs = split_sections(text, path.name)
    g = parse_global(secs.global_, path.name)
    entries = parse_directory(secs.directory, path.name)
    b = Builder(entries, secs.parameter, g.pdelim, g.rdelim, path.name, [])
    out = {}
    for e in entries.values():  # loop over the file's entities (a yardstick's read, not the reader's)
        if e.entity_type != 142:
            continue
        try:
            out[e.de] = int(float(b.params(e.de).tokens[5].text or 0))
        except (IgesError, IndexError, ValueError):
            out[e.de] = -1
    return out


def read_iges_string(text: str, filename: str = "<string>") -> Model:
    """Read IGES text (as from a file). Raises IgesError, never another exception type.

    Python's cyclic garbage collector is paused while reading (and restored after): a file
    becomes hundreds of thousands of small acyclic objects (records, tokens, arrays), whose
    allocation would otherwise trigger full collections again and again (about 30 % of the
    read of a 25 MB file); reference counting frees memory as usual meanwhile."""
    holder: list[Builder] = []
    paused = gc.isenabled()
    if paused:
        gc.disable()
    try:
        return _read(text, filename, holder)
    except IgesError:
        raise
    except Exception as exc:  # last resort: keep the location we know
        de = line = etype = None
        if holder:
            de, line, etype = holder[0].current_location()
        raise IgesError(f"unexpected {type(exc).__name__}: {exc}", filename=filename, line=line, de=de,
                        entity_type=etype) from exc
    finally:
        if paused:
            gc.enable()


def _read(text: str, filename: str, holder: list) -> Model:
    secs = split_sections(text, filename)
    g = parse_global(secs.global_, filename)
    entries = parse_directory(secs.directory, filename)
    diagnostics = [Diagnostic(msg, line) for line, msg in secs.notes + g.notes]
    b = Builder(entries, secs.parameter, g.pdelim, g.rdelim, filename, diagnostics)
    b.resolution = g.resolution
    model = Model(
        units=g.units, resolution=g.resolution, filename=g.string(F_FILE_NAME), author=g.string(F_AUTHOR),
        organization=g.string(F_ORGANIZATION), system=g.string(F_SYSTEM), preprocessor=g.string(F_PREPROCESSOR),
        product_id=g.string(F_PRODUCT_ID), global_params=list(g.values),
        entity_counts=dict(Counter(e.entity_type for e in entries.values())), diagnostics=diagnostics,
    )
    holder.append(b)
    model.source = filename
    model.faces = _faces(b)  # trim deltas deferred: `Face.trim_delta`
    _raw(b, model)
    _check_values(b)
    return model


def _check_values(b: Builder) -> None:
    """Every field of every entity type the reader interprets holds an IGES value (integer,
    real, Hollerith string or empty), also fields no face needs (a 504's unused vertex
    pointer): a damaged number or garbage there makes the file malformed, refused with an
    IgesError at that field. The mesher reads every entity of the file through its own IGES
    reader (OpenCASCADE in gmsh), which is not as careful: gmsh 4.15 crashed (SIGSEGV) on a
    "-" in a 504 edge list. Entities whose records cannot be read at all are reported where
    they are used, as before."""
    for e in b.entries.values():
        if e.entity_type not in INTERPRETED_TYPES:
            continue
        try:
            p = b.params(e.de)
        except IgesError:
            continue
        p.check_values()


def _members(b: Builder, de: int) -> list[int]:
    """DEs listed in a 308 subfigure definition (DEPTH, NAME, N, DE(1..N))."""
    p = b.params(de)
    n = p.int(3, "N")
    if n < 0:
        raise p.error(f"N = {n} is negative", 3, "N")
    p.require(3 + n, "N")
    out = []
    for j in range(n):
        m = p.pointer(4 + j, f"DE({j + 1})", allow_zero=False)
        b.entry(m, p, 4 + j, f"DE({j + 1})")
        out.append(m)
    b._own_end[de] = 4 + n
    return out


def _referenced_surfaces(b: Builder) -> set[int]:
    """Surface DEs used by a trimmed/bounded surface or B-rep face (not faces of their own)."""
    out = set()
    for e in b.entries.values():
        k = {144: 1, 143: 2, 510: 1}.get(e.entity_type)
        if k is None:
            continue
        try:
            p = b.params(e.de)
            out.add(p.pointer(k, "surface"))
        except IgesError:
            continue  # reported when the face itself is built
    return out


def _orphan_brep(b: Builder) -> set[int]:
    """510 faces and 514 shells flagged physically dependent that no 514 / 186 references.
    OpenCASCADE's B-rep writer emits such faces (status 01) when a shape is a bare face;
    OCC's reader takes every unreferenced entity as a root, and so do we for these."""
    in_shell: set[int] = set()
    in_solid: set[int] = set()
    for e in b.entries.values():
        try:
            if e.entity_type == 514:
                p = b.params(e.de)
                n = p.int(1, "N", 0)
                in_shell.update(p.pointer(2 + 2 * j, "FACE", default=0) for j in range(max(n, 0))
                                if p.has(2 + 2 * j))
            elif e.entity_type == 186:
                p = b.params(e.de)
                in_solid.add(p.pointer(1, "SHELL", default=0))
                n = p.int(3, "N", 0)
                in_solid.update(p.pointer(4 + 2 * j, "VOID", default=0) for j in range(max(n, 0)) if p.has(4 + 2 * j))
        except IgesError:
            continue  # reported when the shell or solid itself is built
    return {e.de for e in b.entries.values() if e.physically_dependent
            and ((e.entity_type == 510 and e.de not in in_shell) or (e.entity_type == 514 and e.de not in in_solid))}


def _faces(b: Builder) -> list[Face]:
    entries = b.entries
    in_subfigure: set[int] = set()
    for e in entries.values():
        if e.entity_type == 308:
            in_subfigure.update(_members(b, e.de))
    used = _referenced_surfaces(b)
    orphans = _orphan_brep(b)
    faces: list[Face] = []
    seen: set[int] = set()  # surface DEs already made faces (outside instances)
    for e in entries.values():
        t = e.entity_type
        if (e.physically_dependent and e.de not in orphans) or e.de in in_subfigure:
            continue
        if t in SURFACE_TYPES and e.de in used:
            continue
        if t == 108 and e.form != 1:  # a 108 under a 144/143/510 is made a face there (in `used`)
            b.note("unbounded plane (108 form 0) is not a face", e.de)
            continue
        if t in ANALYTIC_TYPES:  # likewise: 190-198 are faces only under a 510/144/143
            b.note(f"unbounded analytic surface ({t}) referenced by no face is not a face", e.de)
            continue
        for f in _expand(b, e.de, None):
            key = f.surface_de
            if key in seen and t != 408:
                b.note(f"surface DE {key} already used by another face: skipped", e.de)
                continue
            if t != 408:
                seen.add(key)
            faces.append(f)
    return faces


def _expand(b: Builder, de: int, placement: Affine | None) -> list[Face]:
    """Faces reached from entity ``de`` (surface, 143/144, 510, 514, 186, 408)."""
    t = b.entries[de].entity_type
    if t in FACE_TYPES or t == 510:
        f = b.face(de, placement)
        return [] if f is None else [f]
    out: list[Face] = []
    if t in (186, 514, 408):
        with b.visiting(de):
            if t == 186:
                for s in b.msbo_shells(de):
                    out.extend(_expand(b, s, placement))
            elif t == 514:
                for f in b.shell_faces(de):
                    out.extend(_expand(b, f, placement))
            else:
                out.extend(_instance(b, de, placement))
    return out


def _instance(b: Builder, de: int, placement: Affine | None) -> list[Face]:
    """408: DE (308), X, Y, Z, S -> the definition's faces under x -> M(S x + (X, Y, Z)),
    M the instance's own transformation, then the enclosing placement."""
    p = b.params(de)
    d = p.pointer(1, "DE", allow_zero=False)
    b.entry(d, p, 1, "DE", types=(308,))
    xyz = np.array([p.real(2, "X", 0.0), p.real(3, "Y", 0.0), p.real(4, "Z", 0.0)])
    s = p.real(5, "S", 1.0) if p.has(5) and p.tokens[5].text else 1.0
    if not s > 0:
        raise p.error(f"scale factor S = {s!r} must be positive", 5, "S")
    b._own_end[de] = 6
    local = (np.eye(3) * s, xyz)
    own = compose(b.transform(de), local)
    total = compose(placement, own)
    inst_name = b.name(de) if b.properties(de) else None
    faces: list[Face] = []
    with b.visiting(d):
        for m in _members(b, d):
            sub = _expand(b, m, total)
            for f in sub:
                if f.name is None or f.name == b.entries[f.de].label:
                    f.name = inst_name or f.name
            faces.extend(sub)
    return faces


def _raw(b: Builder, model: Model) -> None:
    """Keep entities the reader does not interpret in ``model.raw`` (type, form, parameters)."""
    for e in b.entries.values():
        if e.entity_type in INTERPRETED_TYPES:
            continue
        try:
            params = [t.text for t in b.params(e.de).tokens[1:]]
        except IgesError as err:
            b.note(f"parameters of uninterpreted entity unreadable: {err.message}", e.de)
            params = None
        model.raw[e.de] = (e.entity_type, e.form, params)
