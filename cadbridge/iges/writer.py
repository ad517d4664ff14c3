"""`write_iges`: faces (exact NURBS + trims) -> IGES 5.3 file with entities 128, 126, 102,
142, 144, 314 (colours) and 406 form 15 (names). Reals are written with round-trip
precision, so reading the file back reproduces every surface and every NURBS trim curve bit
for bit.

Trim curves that are not NURBS -- the exact `MappedCurve` / `InvertedCurve` trims the reader
builds over analytic surfaces (the ArcMap / inversion of a NURBS is not rational, so no exact
126 exists) -- are written as their `to_nurbs` cubic: the C1 (C0 at corners) Hermite
interpolant on the same parameter, exact points and first derivatives at its knots, within
``TRIM_REL_TOL`` x the diagonal of the face's (u, v) domain of the exact curve (checked at 1/4,
1/2, 3/4 of every interval). Their model-space curves, when the loop has them, are NURBS and
written exactly."""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from cadbridge.common.atomic import atomic_write
from cadbridge.cad.model import Face, Model, Units
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["write_iges", "iges_text", "bezier_iges_text", "format_real", "curve_params", "pack_lines", "TRIM_REL_TOL"]

TRIM_REL_TOL = 1e-10  # non-NURBS trim curves: cubic deviation / (u, v) domain diagonal

# status numbers (blank, subordinate, entity use, hierarchy)
ST_INDEPENDENT = "00000000"
ST_DEPENDENT = "00010000"  # physically dependent geometry
ST_PARAMETRIC = "00010500"  # physically dependent, 2D parametric (pcurves)
ST_DEFINITION = "00000200"  # colour/name definitions


def format_real(x: float) -> str:
    """A real in IGES syntax with round-trip precision (``repr``, 'e' -> 'E')."""
    x = float(x)
    if not np.isfinite(x):
        raise ValueError(f"cannot write non-finite real {x!r}")
    s = repr(x).replace("e", "E")
    if "." not in s and "E" not in s:
        s += "."
    return s


def _hollerith(s: str) -> str:
    s = s.encode("latin-1", "replace").decode("latin-1")
    return f"{len(s)}H{s}"


@dataclass
class _Entity:
    etype: int
    params: list  # str tokens, already formatted
    form: int = 0
    status: str = ST_INDEPENDENT
    label: str = ""
    color: int = 0
    de: int = 0
    subscript: int = 0


@dataclass
class _File:
    entities: list[_Entity] = field(default_factory=list)
    colors: dict[tuple, int] = field(default_factory=dict)

    def add(self, ent: _Entity) -> int:
        ent.de = 2 * len(self.entities) + 1
        self.entities.append(ent)
        return ent.de


def _reals(a: Iterable[float]) -> list[str]:
    """`format_real` of every value, vectorised (a Nagata export writes millions)."""
    arr = np.ravel(np.asarray(a, dtype=float))
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"cannot write non-finite real {arr[~np.isfinite(arr)][0]!r}")
    if arr.size == 0:
        return []
    # repr of a finite float always has a '.' or an exponent: only 'e' -> 'E' is left to do
    return ",".join(map(repr, arr.tolist())).replace("e", "E").split(",")


def _surface_params(s: NurbsSurface) -> list[str]:
    nu, nv = s.shape
    k1, k2, m1, m2 = nu - 1, nv - 1, s.degree_u, s.degree_v
    poly = 0 if s.rational else 1
    out = [str(v) for v in (k1, k2, m1, m2, 0, 0, poly, 0, 0)]
    # knots u, knots v, weights, control points (IGES order: first index (u) fastest), domain
    out += _reals(np.concatenate([np.ravel(s.knots_u), np.ravel(s.knots_v), np.ravel(s.weights.T),
                                  np.ravel(s.control_points.transpose(1, 0, 2)), np.ravel(s.domain)]))
    return out


def curve_params(c: NurbsCurve) -> list[str]:
    n = len(c.control_points)
    cp = c.control_points
    planar = c.dim == 2
    if planar:
        cp = np.column_stack([cp, np.zeros(n)])
    out = [str(v) for v in (n - 1, c.degree, 1 if planar else 0, 0, 0 if c.rational else 1, 0)]
    out += _reals(c.knots) + _reals(c.weights) + _reals(cp) + _reals(c.domain)
    out += ["0.", "0.", "1."] if planar else ["0.", "0.", "0."]
    return out


def _curve_entity(f: _File, pieces: list[NurbsCurve], status: str) -> int:
    des = [f.add(_Entity(126, curve_params(c), form=0, status=status)) for c in pieces]
    if len(des) == 1:
        return des[0]
    return f.add(_Entity(102, [str(len(des))] + [str(d) for d in des], status=status))


def _properties(name_de: int) -> list[str]:
    return ["0", "1", str(name_de)] if name_de else []


def _add_face(f: _File, face: Face, label: str = "", subscript: int = 0) -> None:
    color = 0
    if face.color is not None:
        rgb = tuple(float(c) for c in face.color)
        if rgb not in f.colors:
            f.colors[rgb] = f.add(_Entity(314, _reals(np.asarray(rgb) * 100.0), status=ST_DEFINITION))
        color = -f.colors[rgb]
    name_de = 0
    if face.name:
        name_de = f.add(_Entity(406, ["1", _hollerith(face.name)], form=15, status=ST_DEFINITION))
    trims = face.trims
    loops = [] if trims is None else ([trims.outer] if trims.outer is not None else []) + list(trims.inner)
    if not loops:
        f.add(_Entity(128, _surface_params(face.surface) + _properties(name_de), status=ST_INDEPENDENT,
                      color=color, label=label, subscript=subscript))
        return
    sde = f.add(_Entity(128, _surface_params(face.surface), status=ST_DEPENDENT, color=color))
    cos = []
    for loop in loops:
        bptr = _curve_entity(f, [_as_2d(c, face.surface) for c in loop.curves], ST_PARAMETRIC)
        cptr = _curve_entity(f, list(loop.model_curves), ST_DEPENDENT) if loop.model_curves else 0
        cos.append(f.add(_Entity(142, ["0", str(sde), str(bptr), str(cptr), "1"], status=ST_DEPENDENT)))
    has_outer = trims.outer is not None
    n2 = len(loops) - has_outer
    params = [str(sde), "1" if has_outer else "0", str(n2), str(cos[0]) if has_outer else "0"]
    params += [str(c) for c in cos[1 if has_outer else 0 :]]
    f.add(_Entity(144, params + _properties(name_de), status=ST_INDEPENDENT, color=color, label=label,
                  subscript=subscript))


def _as_2d(c, surface: NurbsSurface) -> NurbsCurve:
    """A loop piece as a 2D NurbsCurve: NURBS as they are (z dropped), other trim curves as
    their cubic within TRIM_REL_TOL x the (u, v) domain diagonal of ``surface``."""
    if not isinstance(c, NurbsCurve):
        u0, u1, v0, v1 = surface.domain
        return c.to_nurbs(tol=TRIM_REL_TOL * float(np.hypot(u1 - u0, v1 - v0)))
    if c.dim == 2:
        return c
    return NurbsCurve(c.degree, c.knots, c.control_points[:, :2], c.weights, c.domain)


def pack_lines(tokens: list[str], width: int) -> list[str]:
    """Free-format lines of at most ``width`` characters; only strings are split across lines.

    Greedy: a line takes whole tokens, each with its delimiter, while they fit. Where no token
    holds a delimiter and none is longer than a line (numbers; every entity of a Nagata
    export), the same lines come from one regular-expression pass over the joined text: each
    match is the longest run of at most ``width`` characters ending with a delimiter."""
    if not tokens:
        return []
    text = ",".join(tokens) + ";"
    if max(map(len, tokens)) < width and text.count(",") == len(tokens) - 1 and text.count(";") == 1 \
            and "\n" not in text:
        return _WHOLE_TOKENS[width].findall(text)
    lines: list[str] = []
    cur = ""
    for k, tok in enumerate(tokens):
        piece = tok + (";" if k == len(tokens) - 1 else ",")
        if len(cur) + len(piece) <= width:
            cur += piece
            continue
        if cur:
            lines.append(cur)
            cur = ""
        while len(piece) > width:
            lines.append(piece[:width])
            piece = piece[width:]
        cur = piece
    if cur:
        lines.append(cur)
    return lines


_WHOLE_TOKENS = {w: re.compile(r".{0,%d}[,;]" % (w - 1)) for w in (64, 72)}


def _global(model: Model | None, units: Units, author: str | None, filename: str, max_coord: float) -> list[str]:
    now = time.strftime("%Y%m%d.%H%M%S")
    res = model.resolution if (model is not None and model.resolution) else 1e-8
    g = ["1H,", "1H;",
         _hollerith((model.product_id if model and model.product_id else Path(filename).stem) or "cadbridge"),
         _hollerith(filename), _hollerith("cadbridge"), _hollerith("cadbridge IGES writer 1.0"),
         "32", "38", "6", "308", "15",
         _hollerith((model.product_id if model and model.product_id else Path(filename).stem) or "cadbridge"),
         "1.", str(units.flag), _hollerith(units.name), "1", "1.", _hollerith(now), format_real(res),
         format_real(max_coord), _hollerith(author or (model.author if model and model.author else "") or ""),
         _hollerith(model.organization if model and model.organization else ""), "11", "0", _hollerith(now)]
    g = [x if x != "0H" else "" for x in g]
    return pack_lines(g, 72)


def _check_labels(labels, n: int):
    if labels is None:
        return None
    labels = list(labels)
    if len(labels) != n:
        raise ValueError(f"{len(labels)} labels for {n} faces")
    for lab, _ in labels:
        if len(lab) > 8 or not lab.isascii() or not lab.isprintable():
            raise ValueError(f"IGES entity labels are at most 8 printable ASCII characters: {lab!r}")
    return labels


def iges_text(faces: list[Face], model: Model | None = None, *, units: Units | None = None,
              author: str | None = None, filename: str = "model.igs",
              labels: Sequence[tuple[str, int]] | None = None, description: str | None = None) -> str:
    """The IGES file text for ``faces`` (see `write_iges`)."""
    units = units or (model.units if model is not None else Units())
    labels = _check_labels(labels, len(faces))
    f = _File()
    for k, face in enumerate(faces):
        _add_face(f, face, *(labels[k] if labels is not None else ("", 0)))
    max_coord = 0.0
    for face in faces:
        max_coord = max(max_coord, float(np.max(np.abs(face.surface.bbox()))))
    return _file_text(f, description or "cadbridge IGES 5.3 export",
                      _global(model, units, author, filename, max_coord))


def bezier_iges_text(nets: np.ndarray, *, units: Units, labels: Sequence[tuple[str, int]],
                     filename: str = "model.igs", description: str | None = None) -> str:
    """The IGES text of polynomial Bézier patches, one independent 128 each, on [0, 1]^2:
    the same text as `iges_text` of the faces ``NurbsSurface(p, q, clamped knots, net)``, with
    the reals of all nets formatted in one pass (a Nagata export writes ~10^5 patches).

    nets : (E, p + 1, q + 1, 3) control nets, [e, i, j] with i along u; labels : one
    (label, subscript) per patch."""
    nets = np.asarray(nets, dtype=float)
    if nets.ndim != 4 or nets.shape[3] != 3:
        raise ValueError(f"nets must have shape (E, p + 1, q + 1, 3), got {nets.shape}")
    labels = _check_labels(labels, len(nets))
    e, nu, nv = nets.shape[:3]
    p, q = nu - 1, nv - 1
    k = nu * nv * 3
    # every patch shares all parameters but its control points: those of one patch, from the
    # generic `_surface_params` (degrees, knots, weights, then the net, then the domain)
    one = _surface_params(NurbsSurface(p, q, [0.0] * nu + [1.0] * nu, [0.0] * nv + [1.0] * nv,
                                       nets[0] if e else np.zeros((nu, nv, 3))))
    head, tail = one[: len(one) - k - 4], one[len(one) - 4 :]
    cps = _reals(nets.transpose(0, 2, 1, 3))  # IGES order: the u index fastest
    f = _File()
    for i, (lab, sub) in enumerate(labels):
        f.add(_Entity(128, head + cps[i * k : (i + 1) * k] + tail, status=ST_INDEPENDENT, label=lab, subscript=sub))
    max_coord = float(np.max(np.abs(nets))) if e else 0.0
    return _file_text(f, description or "cadbridge IGES 5.3 export", _global(None, units, None, filename, max_coord))


def _file_text(f: _File, description: str, gl: list[str]) -> str:
    """Start, Global, Directory, Parameter and Terminate sections of the entities of ``f``."""
    out: list[str] = []
    start = [description[i : i + 72] for i in range(0, len(description), 72)]
    out += [s.ljust(72)[:72] + f"S{k + 1:7d}" for k, s in enumerate(start)]
    out += [s.ljust(72) + f"G{k + 1:7d}" for k, s in enumerate(gl)]
    plines: list[str] = []
    dlines: list[str] = []
    for e in f.entities:
        body = pack_lines([str(e.etype)] + e.params, 64)
        pptr = len(plines) + 1
        tail = f" {e.de:7d}P"
        plines += [s.ljust(64) + tail + f"{pptr + k:7d}" for k, s in enumerate(body)]
        d1 = f"{e.etype:8d}{pptr:8d}{0:8d}{0:8d}{0:8d}{0:8d}{0:8d}{0:8d}{e.status:>8s}"
        d2 = f"{e.etype:8d}{0:8d}{e.color:8d}{len(body):8d}{e.form:8d}{'':8s}{'':8s}{e.label[:8]:>8s}{e.subscript:8d}"
        dlines.append(d1 + f"D{len(dlines) + 1:7d}")
        dlines.append(d2 + f"D{len(dlines) + 1:7d}")
    out += dlines + plines
    t = f"S{len(start):7d}G{len(gl):7d}D{len(dlines):7d}P{len(plines):7d}"
    out.append(t.ljust(72) + f"T{1:7d}")
    return "\n".join(out) + "\n"


def write_iges(model_or_faces: Model | Iterable[Face], path: str | PathLike, *, units: Units | None = None,
               author: str | None = None, labels: Sequence[tuple[str, int]] | None = None,
               description: str | None = None) -> None:
    """Write faces as IGES 5.3: a 128 per face; trimmed faces as 144 over the 128 with 142
    curves on surface whose parameter-space curves are 126 (a 102 when a loop has several
    pieces; model-space curves written when the loop has them). Colours as 314, names as
    406 form 15. ``labels`` optionally gives each face's DE entity label (at most 8
    characters) and subscript; ``description`` the Start section text. The file is written
    to a temporary file beside ``path`` and renamed."""
    if isinstance(model_or_faces, Model):
        model, faces = model_or_faces, list(model_or_faces.faces)
    else:
        model, faces = None, list(model_or_faces)
    path = Path(path)
    text = iges_text(faces, model, units=units, author=author, filename=path.name, labels=labels,
                     description=description)
    with atomic_write(path, "w", encoding="latin-1") as fh:
        fh.write(text)
