"""Short C0 pieces of trim curves made C1, for the mesher's copy of the file.

OCC's reader cuts every B-spline at its C0 knots (``read.iges.bspline.continuity`` 1, the
default, which gmsh cannot change), and each cut is a CAD vertex. The analytic production
die's face 0 has parameter-space trim curves (126) whose C0 knots halve their spacing
towards a point: OCC makes 520 edges of its 320 pieces, 16 of them along FRD00011 from
3.1 mm down to 1e-5 mm. gmsh puts a node on every vertex (sewing cuts the neighbour's edge
there too), so the mesh is as fine there as the shortest piece; the node merge then joins
those nodes and the elements beside them fold over (quads straddling the crease of FRD00011
that ends on that edge).

`smooth_short_knots` rewrites, for the mesher only, every parameter-space trim curve (126
under a 142's BPTR) at its C0 knots where the curve is tangent within `CORNER_DEG` and a C0
segment beside the knot is shorter than the threshold: the curve is made C1 there on its own
parameters (`_c1_composite`) and one copy of the knot removed, unless that moves the curve by
more than `MAX_MOVE`. Its parameters stay: OCC pairs them with the model-space curve's
(reparametrizing the pieces to equal speeds made OCC drop a hole of the NURBS die's face 0).
The 126 is rewritten in its own lines, or, where its new numbers take more room, appended to
the D and P sections with its parent's pointer moved to it. OCC builds the die's edges from these curves; the model-space curves stay as
they are (rewriting them as well made OCC's wire fixing fail on the die's face 0 in gmsh's
import: "Could not fix wire in surface 1"). cadbridge keeps its own reading of the file
(projection, trims, normals): only the mesher reads the copy.
"""

from __future__ import annotations

import re

import numpy as np

from cadbridge.nurbs.curve import NurbsCurve

__all__ = ["CORNER_DEG", "JOIN_SHORTER", "MAX_MOVE", "has_c0_knots", "smooth_short_knots", "smoothed_curve"]

CORNER_DEG = 5.0
"""Two pieces whose tangents at their joint differ by more than this (degrees) meet at a
corner, which stays a vertex."""

MAX_MOVE = 2.5e-5
"""A knot is smoothed only if making the curve C1 there moves it by at most this, in model
units scaled to parameter space by the ratio of the 142's composites' sizes: a quarter of
the sewing tolerance of `cadbridge.mesh.generate.mesh_cad` (1e-4), so the faces on either
side still sew, and 2e-4 of cadbridge's node tolerance on the production die."""

JOIN_SHORTER = 1e-4
"""A C0 knot is smoothed if a segment beside it is shorter than this x the model size (box
diagonal)."""


def _length(c: NurbsCurve, n: int = 9) -> float:
    x = c.evaluate(np.linspace(c.domain[0], c.domain[1], n))
    return float(np.linalg.norm(np.diff(x, axis=0), axis=1).sum())


UNIT_WEIGHTS = 1e-9
"""A rational curve whose weights differ by less than this (relative) is taken as the
polynomial one (OCC writes its B-spline conversions with weights 1 +- 2e-11)."""


def _polynomial(c: NurbsCurve) -> NurbsCurve | None:
    """``c`` if polynomial, its polynomial twin if its weights are equal within
    `UNIT_WEIGHTS` (the curves differ by that times the control legs), else None."""
    if not c.rational:
        return c
    w = c.weights
    if np.ptp(w) > UNIT_WEIGHTS * float(np.max(w)):
        return None
    return NurbsCurve(c.degree, c.knots, c.control_points, None, c.domain)


def has_c0_knots(model) -> bool:
    """Whether some parameter-space trim curve of ``model`` has an interior C0 knot
    (multiplicity >= degree, degree >= 3, polynomial or nearly: `_polynomial`): the cheap
    test before `smooth_short_knots`."""
    for f in model.faces:
        t = f.trims
        if t is None:
            continue
        for loop in ([t.outer] if t.outer is not None else []) + list(t.inner):
            for c in loop.curves:
                if c.degree < 3 or len(c.knots) <= 2 * (c.degree + 1) or _polynomial(c) is None:
                    continue
                _, mult = np.unique(c.knots, return_counts=True)
                if np.any(mult[1:-1] >= c.degree):
                    return True
    return False


def _c1_composite(pieces: list[NurbsCurve], max_move: float) -> NurbsCurve:
    """``pieces`` (meeting end to end, nearly tangent) as one curve, C1 at their joints.

    `construct.composite_curve` of the pieces, at least cubic, on their own parameters (the
    trim curve keeps its parametrization, which OCC pairs with the model-space curve's); each
    joint is a knot t of multiplicity p with the curve through P_k. The point beside P_k on
    the shorter piece is set so that both one-sided derivatives are the longer piece's,
    Q = (P_k - P_k-1) / (t - t_l) = (P_k+1 - P_k) / (t_r - t) (t_l, t_r the knots either side of t's group;
    Piegl & Tiller eq. 3.9; polynomial curves), so P_k lies on P_k-1 P_k+1 at
    (t - t_l) / (t_r - t_l): it is the point that inserting t into the curve without P_k
    would make, and goes with one copy of t (knot removal, exact). OCC's reader splits a
    B-spline at knots of multiplicity p, so the joints must not be such knots. Moves the
    shorter piece by about the derivatives' mismatch (angle and speed) times its control
    leg. Raises ValueError where the curve would move by more than ``max_move`` (in its own
    units; measured at 8 points per knot span)."""
    from cadbridge.nurbs import edits
    from cadbridge.nurbs.construct import composite_curve

    deg = max(3, max(c.degree for c in pieces))
    cs = [edits.restrict_curve(edits.elevate_curve(c, deg - c.degree) if c.degree < deg else c) for c in pieces]
    c = composite_curve(cs, tol=1e-7)
    p, kn = c.degree, np.array(c.knots, dtype=float)
    pw = c._pw.copy()
    lengths = [_length(d) for d in cs]
    joints = np.cumsum([d.domain[1] - d.domain[0] for d in cs])[:-1] + cs[0].domain[0]
    first = np.searchsorted(kn, joints - 1e-12 * (kn[-1] - kn[0]))
    drop_pt, drop_kn = [], []
    for t, s in zip(kn[first], first):  # loop over the joints: three points each
        k = s - 1  # the curve passes through P_k at t
        tl, tr = kn[s - 1], kn[s + p]
        if not (t > tl and tr > t and np.count_nonzero(kn == t) == p):
            raise ValueError("joined curve: a joint is not a knot of multiplicity p")
        i = len(drop_pt)  # the joint between cs[i] and cs[i + 1]: the longer one keeps its tangent
        q = (pw[k] - pw[k - 1]) / (t - tl) if lengths[i] >= lengths[i + 1] else (pw[k + 1] - pw[k]) / (tr - t)
        pw[k - 1] = pw[k] - q * (t - tl)
        pw[k + 1] = pw[k] + q * (tr - t)
        drop_pt.append(k)
        drop_kn.append(s)
    if not np.all(pw[:, -1] > 0):
        raise ValueError("joined curve: a weight turned non-positive")
    out = edits.curve_from_homogeneous(p, np.delete(kn, drop_kn), np.delete(pw, drop_pt, axis=0))
    t = out.sample_parameters(8)
    move = float(np.linalg.norm(out.evaluate(t) - c.evaluate(t), axis=1).max())
    if move > max_move:
        raise ValueError(f"joined curve: the joints would move it by {move:.3g}")
    return out


def _c0_segments(c: NurbsCurve) -> list[NurbsCurve]:
    """``c`` cut at its interior knots of multiplicity >= p (C0 or worse), in order."""
    from cadbridge.nurbs import edits

    c = edits.restrict_curve(c)
    vals, mult = np.unique(c.knots, return_counts=True)
    cuts = vals[1:-1][mult[1:-1] >= c.degree]
    ends = np.concatenate([[c.domain[0]], cuts, [c.domain[1]]])
    return [edits.restrict_curve(c, float(t0), float(t1)) for t0, t1 in zip(ends[:-1], ends[1:])]


def _links(segs: list[NurbsCurve], shorter: float, gap: float, cos_max: float) -> np.ndarray:
    """(S-1,) bool: the joints to make C1, where the segments meet within ``gap``, tangent
    within ``cos_max``, and one of the two is shorter than ``shorter``."""
    lengths = [_length(c) for c in segs]
    link = np.zeros(max(len(segs) - 1, 0), dtype=bool)
    for i in range(len(segs) - 1):  # loop over joints: one derivative each side
        if min(lengths[i], lengths[i + 1]) >= shorter:
            continue
        a, b = segs[i], segs[i + 1]
        da = a.derivatives(a.domain[1], 1)[0]
        db = b.derivatives(b.domain[0], 1)[0]
        if np.linalg.norm(da[0] - db[0]) > gap:
            continue
        ta, tb = np.linalg.norm(da[1]), np.linalg.norm(db[1])
        link[i] = ta > 0 and tb > 0 and float(da[1] @ db[1]) >= cos_max * ta * tb
    return link


def smoothed_curve(c: NurbsCurve, shorter: float, max_move: float, corner_deg: float = CORNER_DEG) -> NurbsCurve | None:
    """``c`` made C1 at its short tangent C0 knots (module docs), or None where there is none
    to smooth, or smoothing would move the curve by more than ``max_move``, or ``c`` is below
    cubic or rational (`_polynomial`: the fix holds for the homogeneous curve, whose
    weights' derivatives would still jump)."""
    from cadbridge.nurbs.construct import composite_curve

    c = _polynomial(c)
    if c is None or c.degree < 3:
        return None
    segs = _c0_segments(c)
    if len(segs) < 2:
        return None
    size = float(np.linalg.norm(np.ptp(c.control_points, axis=0)))
    link = _links(segs, shorter, 1e-9 * max(size, 1e-300), float(np.cos(np.radians(corner_deg))))
    if not link.any():
        return None
    runs, i = [], 0
    while i < len(segs):
        j = i
        while j < len(segs) - 1 and link[j]:
            j += 1
        runs.append(segs[i : j + 1])
        i = j + 1
    try:
        parts = [_c1_composite(r, max_move) if len(r) > 1 else r[0] for r in runs]
        return composite_curve(parts, tol=1e-9) if len(parts) > 1 else parts[0]
    except ValueError:
        return None


def smooth_short_knots(text: str, shorter: float, filename: str = "<mesh source>",
                       corner_deg: float = CORNER_DEG, max_move: float = MAX_MOVE) -> tuple[str, int]:
    """``text`` (an IGES file) with the parameter-space trim curves smoothed at their short C0
    knots (module docs; ``shorter`` and ``max_move`` in model units, scaled to parameter space
    by the ratio of the 142's two composites' sizes); returns the new text and the number of
    curves rewritten (0: ``text`` unchanged). Files with other delimiters than ',' and ';',
    and curves under a transformation, are left as they are."""
    from cadbridge.iges.directory import parse_directory
    from cadbridge.iges.entities import Builder, to_2d
    from cadbridge.iges.globals import parse_global
    from cadbridge.iges.lexer import split_sections
    from cadbridge.iges.writer import curve_params, pack_lines

    secs = split_sections(text, filename)
    g = parse_global(secs.global_, filename)
    if (g.pdelim, g.rdelim) != (",", ";"):
        return text, 0
    entries = parse_directory(secs.directory, filename)
    b = Builder(entries, secs.parameter, g.pdelim, g.rdelim, filename, [])
    lines = text.split("\n")
    sec = [ln[72] if len(ln) > 72 else "" for ln in lines]
    d_lines = [i for i, c in enumerate(sec) if c == "D"]
    p_lines = [i for i, c in enumerate(sec) if c == "P"]
    t_line = next((i for i, c in enumerate(sec) if c == "T"), None)
    if not d_lines or not p_lines or t_line is None:
        return text, 0
    p_first = p_lines[0]
    new_d: list[str] = []
    new_p: list[str] = []

    def pieces(de: int, parent: int, k: int) -> list[tuple[int, int, int]]:
        """(126 DE, parent DE, the parent's token holding it) of curve ``de``."""
        e = entries.get(de)
        if e is None:
            return []
        if e.entity_type == 126:
            return [(de, parent, k)]
        if e.entity_type != 102:
            return []
        p = b.params(de)
        return [x for j in range(p.int(1, "N")) for x in pieces(p.pointer(2 + j, "DE"), de, 2 + j)]

    def p_index(de: int) -> list[int]:
        e = entries[de]
        return [p_first + e.param_pointer - 1 + k for k in range(e.param_count)]

    def fits(de: int, tokens: list[str]) -> list[str] | None:
        body = pack_lines(tokens, 64)
        return body if len(body) <= entries[de].param_count else None

    def put(de: int, body: list[str]) -> None:
        idx = p_index(de)
        body = body + [""] * (len(idx) - len(body))
        for i, s in zip(idx, body):
            lines[i] = s.ljust(64) + lines[i][64:]

    def append(curve: NurbsCurve, like: int) -> int:
        de = len(d_lines) + len(new_d) + 1
        body = pack_lines(["126"] + curve_params(curve), 64)
        pptr = len(p_lines) + len(new_p) + 1
        new_p.extend(s.ljust(64) + f" {de:7d}P{pptr + k:7d}" for k, s in enumerate(body))
        e = entries[like]
        d1 = lines[d_lines[e.de - 1]][:72].ljust(72)
        d2 = lines[d_lines[e.de]][:72].ljust(72)
        new_d.append(d1[:8] + f"{pptr:8d}" + d1[16:] + f"D{de:7d}")
        new_d.append(d2[:24] + f"{len(body):8d}" + d2[32:] + f"D{de + 1:7d}")
        return de

    def replace(de: int, parent: int, k: int, curve: NurbsCurve) -> bool:
        """The 126 ``de`` rewritten as ``curve``: in its own lines, or else appended with
        the pointer of ``parent`` (token ``k``) moved to it, where that still fits."""
        body = fits(de, ["126"] + curve_params(curve))
        if body is not None:
            put(de, body)
            return True
        flat = "".join(lines[i][:64] for i in p_index(parent))
        tokens = [x.strip() for x in flat.split(";")[0].split(",")]
        if k >= len(tokens) or tokens[k] != str(de):
            return False
        tokens[k] = str(len(d_lines) + len(new_d) + 1)
        pbody = fits(parent, tokens)
        if pbody is None:
            return False
        append(curve, de)
        put(parent, pbody)
        return True

    done: set[int] = set()
    n = 0
    for de, e in entries.items():  # loop over the 142s: their two composites
        if e.entity_type != 142:
            continue
        try:
            p = b.params(de)
            m3 = pieces(p.pointer(4, "CPTR"), de, 4)
            m2 = pieces(p.pointer(3, "BPTR"), de, 3)
            c3 = {x: b.curve_pieces(x[0])[0] for x in m3 if entries[x[0]].transform == 0}
            c2 = {x: to_2d(b.curve_pieces(x[0])[0]) for x in m2 if entries[x[0]].transform == 0}
        except Exception:  # noqa: BLE001 - a malformed 142 is the reader's business, not the mesher copy's
            continue
        s3 = float(np.linalg.norm(np.ptp(np.concatenate([c.control_points for c in c3.values()]), axis=0))) if c3 else 0.0
        s2 = float(np.linalg.norm(np.ptp(np.concatenate([c.control_points for c in c2.values()]), axis=0))) if c2 else 0.0
        scale2 = s2 / s3 if s3 > 0 else 0.0
        if not scale2 > 0:
            continue
        for (m, parent, tok), c in c2.items():
            if m in done:
                continue
            done.add(m)
            new = smoothed_curve(c, shorter * scale2, max_move * scale2, corner_deg)
            if new is not None and replace(m, parent, tok, new):
                n += 1
    if not n:
        return text, 0
    last_d, last_p = d_lines[-1], p_lines[-1]
    lines = lines[: last_d + 1] + new_d + lines[last_d + 1 : last_p + 1] + new_p + lines[last_p + 1 :]
    t = t_line + len(new_d) + len(new_p)
    lines[t] = re.sub(r"D\s*\d+P\s*\d+", f"D{len(d_lines) + len(new_d):7d}P{len(p_lines) + len(new_p):7d}", lines[t], count=1)
    return "\n".join(lines), n
