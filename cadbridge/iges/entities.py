"""Entity construction: from directory entries and parameter lists to exact NURBS geometry.

`Builder` resolves pointers lazily (each entity parsed once, cached), applies the
transformation matrices (124) of each entity, and turns surfaces, trimmed/bounded surfaces,
B-rep faces and subfigure instances into `Face` objects. Field numbers in comments are the
1-based numbers of the IGES 5.3 specification; ``p.int(k, ...)`` reads field k.
"""

from __future__ import annotations

import math
from contextlib import contextmanager

import numpy as np

from cadbridge.iges.directory import DirectoryEntry
from cadbridge.cad.analytic import (ArcMap, Frame, MappedLoops, ParamMap, cylinder_map, fixed_map,
                                     invert_edges, map_loops, plane_map, revolution_map, sphere_map,
                                     torus_map)
from cadbridge.iges.trimcheck import DeltaBatch, loop_deltas
from cadbridge.iges.errors import IgesError
from cadbridge.iges.lexer import Record
from cadbridge.iges.parameters import FastTokens, Params, prepare_params, read_params
from cadbridge.cad.model import Diagnostic, Face, Trim, TrimLoop
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.knots import from_homogeneous, remove_surplus_knots, to_homogeneous
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["Builder", "Unsupported", "SURFACE_TYPES", "ANALYTIC_TYPES", "FACE_TYPES", "INTERPRETED_TYPES"]

SURFACE_TYPES = (128, 108, 118, 120, 122)
FULL_TURN_MAX_GAP = 1e-3
"""A 120 sweep further from 2 pi (rad) is never read as a full turn (`Builder._full_turn`)."""
ROUNDED_TURN = 5e-5
"""A 120 sweep this close to 2 pi (rad) is a full turn with 2 pi printed to 5 digits or more
(`Builder._full_turn`)."""
SURFACE_NAMES = {108: "plane", 114: "parametric spline surface", 118: "ruled surface", 120: "surface of revolution",
                 122: "tabulated cylinder", 128: "B-spline surface", 140: "offset surface", 190: "plane surface",
                 192: "right circular cylindrical surface", 194: "right circular conical surface",
                 196: "spherical surface", 198: "toroidal surface"}
AGREE_REL = 1e-6  # PREF = model space: the 2D curves are used if delta <= AGREE_REL x size
DISAGREE_REL = 1e-3  # beyond DISAGREE_REL x size the 2D and 3D trims are called inconsistent
ANALYTIC_TYPES = (190, 192, 194, 196, 198)  # IGES 5.3 unbounded analytic surfaces (faces only under 510/144/143)
FACE_TYPES = SURFACE_TYPES + (143, 144)
CURVE_TYPES = (100, 102, 104, 106, 110, 126)
INTERPRETED_TYPES = frozenset(
    FACE_TYPES + ANALYTIC_TYPES + CURVE_TYPES + (116, 123, 124, 141, 142, 186, 308, 314, 406, 408, 502, 504, 508, 510, 514, 0)
)
MAX_DEPTH = 64  # pointer nesting guard (no unbounded recursion on cyclic or deep files)
DOMAIN_REL_TOL = 1e-6  # U0..V1 this close outside the knot range are clamped (with a note)
VERTEX_REL = 1e-6  # an edge curve read over its whole knot range must end at its vertices (x its extent)

# IGES standard colours (DE field 13 values 1..8) as RGB in 0..1
STANDARD_COLORS = {1: (0.0, 0.0, 0.0), 2: (1.0, 0.0, 0.0), 3: (0.0, 1.0, 0.0), 4: (0.0, 0.0, 1.0),
                   5: (1.0, 1.0, 0.0), 6: (1.0, 0.0, 1.0), 7: (0.0, 1.0, 1.0), 8: (1.0, 1.0, 1.0)}

Affine = tuple[np.ndarray, np.ndarray]  # (R (3, 3), t (3,)) for x -> R x + t
_MISSING = object()
_LINE_KNOTS = np.array([0.0, 0.0, 1.0, 1.0])
_LINE_KNOTS.setflags(write=False)
_ONES2 = np.ones(2)
_ONES2.setflags(write=False)
_EYE3 = np.eye(3)
_EYE3.setflags(write=False)


def _arc100(p: Params, v: np.ndarray) -> NurbsCurve:
    """IGES 100 (ZT, X1, Y1 centre, X2, Y2 start, X3, Y3 end) as the rational quadratic of
    `construct.circular_arc(centre, start, end, normal=+Z)` (same angles, knots, control
    points and weights; counter-clockwise, start == end within 1e-12 R the full circle), built
    from scalars: the reader makes one per 100 entity and the general function's vector
    checks dominate there. Raises the IgesError of a zero radius."""
    zt, cx, cy, sx, sy, ex, ey = (float(a) for a in v)
    dx, dy = sx - cx, sy - cy
    r = math.hypot(dx, dy)
    if not r > 0:
        raise p.error("start coincides with center: zero radius", 4, "X2")
    ux, uy = dx / r, dy / r  # X of the arc's frame; Y = Z x X = (-uy, ux)
    qx, qy = ex - cx, ey - cy
    if math.hypot(ex - sx, ey - sy) <= 1e-12 * r:
        theta = 2 * math.pi
    else:
        theta = math.atan2(qx * -uy + qy * ux, qx * ux + qy * uy) % (2 * math.pi)
        if theta <= 1e-12:
            theta = 2 * math.pi
    n = max(1, math.ceil(theta / (math.pi / 2) * (1.0 - 1e-12)))  # `construct.arc_segments`
    d = theta / n
    h = math.cos(d / 2)
    pts, w, knots = [], [], [0.0, 0.0, 0.0]
    for k in range(2 * n + 1):  # at most 9 points: scalar arithmetic beats array calls
        t = 0.5 * d * k
        a, b = (math.cos(t), math.sin(t)) if k % 2 == 0 else (math.cos(t) / h, math.sin(t) / h)
        pts.append((cx + r * (a * ux - b * uy), cy + r * (a * uy + b * ux), zt))
        w.append(1.0 if k % 2 == 0 else h)
    for k in range(1, n):
        knots += [d * k, d * k]
    knots += [theta] * 3
    pts[0] = (sx, sy, zt)  # exact start
    if theta == 2 * math.pi:
        pts[-1] = pts[0]
    pts, w, knots = np.array(pts), np.array(w), np.array(knots)
    return NurbsCurve._trusted(2, knots, pts, w, (0.0, theta), True)


def _closed(loop, surface: NurbsSurface, rel: float = 1e-6) -> bool:
    """Whether a loop of (u, v) pieces closes (last end = first start within rel x domain)."""
    u0, u1, v0, v1 = surface.domain
    a = loop[0][1].evaluate([loop[0][1].domain[0]])[0]
    b = loop[-1][1].evaluate([loop[-1][1].domain[1]])[0]
    return bool(np.linalg.norm(a - b) <= rel * np.hypot(u1 - u0, v1 - v0))


class Unsupported(Exception):
    """Internal: geometry the reader cannot represent (becomes a diagnostic, never escapes)."""

    def __init__(self, message: str, de: int | None = None, etype: int | None = None, line: int | None = None):
        super().__init__(message)
        self.de, self.etype, self.line = de, etype, line


def _construct():
    try:
        from cadbridge.nurbs import construct  # lazy: written in parallel, optional for 128-only files
    except ImportError as e:
        raise Unsupported(f"exact construction needs cadbridge.nurbs.construct ({e})") from None
    return construct


def reverse_curve(c: NurbsCurve) -> NurbsCurve:
    """The same curve traversed backwards: t -> a + b - t with [a, b] = the knot range."""
    a, b = c.knots[0], c.knots[-1]
    return NurbsCurve(c.degree, (a + b) - c.knots[::-1], c.control_points[::-1], c.weights[::-1],
                      ((a + b) - c.domain[1], (a + b) - c.domain[0]))


def to_2d(c: NurbsCurve) -> NurbsCurve:
    """Drop z of a parameter-space curve: (u, v, 0) -> (u, v)."""
    if c.dim == 2:
        return c
    # the (u, v) columns of a valid curve: the same checks would pass again
    return NurbsCurve._trusted(c.degree, c.knots, c.control_points[:, :2], c.weights,
                               (float(c.domain[0]), float(c.domain[1])), c.rational)


def _is_identity(a: Affine | None) -> bool:
    return a is None or (np.array_equal(a[0], _EYE3) and not np.any(a[1]))


def compose(outer: Affine | None, inner: Affine | None) -> Affine | None:
    """x -> outer(inner(x))."""
    if _is_identity(outer):
        return inner
    if _is_identity(inner):
        return outer
    return outer[0] @ inner[0], outer[0] @ inner[1] + outer[1]


def apply_surface(s: NurbsSurface, a: Affine | None) -> NurbsSurface:
    return s if _is_identity(a) else s.transformed(a[0], a[1])


def apply_curve(c: NurbsCurve, a: Affine | None) -> NurbsCurve:
    """The curve under x -> R x + t (a 2D curve taken at z = 0): `NurbsCurve.transformed`'s
    arithmetic, without re-validating knots and weights (those of a valid curve)."""
    if _is_identity(a):
        return c
    cp = c.control_points
    if cp.shape[1] == 2:
        cp = np.column_stack([cp, np.zeros(len(cp))])
    out = cp @ np.asarray(a[0], dtype=float).reshape(3, 3).T + np.asarray(a[1], dtype=float).reshape(3)
    if not np.isfinite(out).all():  # overflow: the constructor's error
        return NurbsCurve(c.degree, c.knots, out, c.weights, c.domain)
    return NurbsCurve._trusted(c.degree, c.knots, out, c.weights, c.domain, c.rational)


class Builder:
    """Builds geometry for the entities of one file.

    entries : {DE: DirectoryEntry}; precs : P-section records; ``diagnostics`` collects notes.
    """

    def __init__(self, entries: dict[int, DirectoryEntry], precs: list[Record], pdelim: str, rdelim: str,
                 filename: str, diagnostics: list[Diagnostic]) -> None:
        self.entries = entries
        self.precs = precs
        self.pdelim, self.rdelim = pdelim, rdelim
        self.filename = filename
        self.diagnostics = diagnostics
        self.resolution: float | None = None  # the file's G19 where the reader knows it (`_full_turn`)
        self._params: dict[int, Params] = {}
        self._cache: dict[tuple, object] = {}
        self._own_end: dict[int, int] = {}  # DE -> index of the first trailing (NV/NP) field
        self._active: list[int] = []  # entities under construction (cycle guard, error location)
        self._keys: list[tuple[str, int]] = []
        self._failed_at: tuple | None = None  # (DE, line, type) where an exception first passed
        self.pref: dict[int, str | None] = {}  # 142 / 141 DE -> preferred representation (`mapped_trims`)
        self._delta: dict[int, float] = {}  # face DE -> trim delta before placement (route decided on it)
        self._delta_lazy: dict[int, tuple] = {}  # face DE -> (surface, pairs) for a deferred delta (mapped faces)
        self.deltas = DeltaBatch()  # every other face's delta: computed on first access of any (`Face.trim_delta`)
        prepare_params(entries, precs, pdelim, rdelim)  # compiled scan of the plain records (fast path)
        bulk = getattr(precs, "derived", None)
        fast = getattr(bulk, "fast", None)
        ok = fast is not None and bulk.n == len(precs) and fast.delims == (pdelim, rdelim)
        self._fast = fast if ok else None
        self._scanned: dict = fast.entity if ok else {}  # DE -> (entry, first token, count, last record, numeric)

    # ------------------------------------------------------------------ infrastructure
    def note(self, message: str, de: int | None = None, line: int | None = None) -> None:
        e = self.entries.get(de) if de is not None else None
        self.diagnostics.append(Diagnostic(message, line if line is not None else (e.line if e else None), de,
                                           e.entity_type if e else None))

    def params(self, de: int) -> Params:
        p = self._params.get(de)
        if p is None:
            e = self.entries[de]
            hit = self._scanned.get(de)
            if hit is not None and hit[0] is e:  # `read_params`'s first fast path, inlined (once per entity)
                _, a, c, r, ok = hit
                p = Params._scanned(e, FastTokens(self._fast, a, c, ok), self.filename, self._fast.lines[r])
            else:
                p = read_params(e, self.precs, self.pdelim, self.rdelim, self.filename)
            self._params[de] = p
        return p

    def entry(self, de: int, src: Params | None = None, k: int | None = None, name: str | None = None,
              types: tuple[int, ...] | None = None) -> DirectoryEntry:
        """The entry a pointer refers to; IgesError located at the pointer field if missing
        or of the wrong type."""
        e = self.entries.get(de)
        if e is None:
            msg = f"pointer to DE {de}, which does not exist"
            if src is not None:
                raise src.error(msg, k, name)
            raise IgesError(msg, filename=self.filename)
        if types is not None and e.entity_type not in types:
            msg = f"DE {de} is entity {e.entity_type}, expected one of {types}"
            if src is not None:
                raise src.error(msg, k, name)
            raise IgesError(msg, filename=self.filename, de=de, entity_type=e.entity_type)
        return e

    @contextmanager
    def visiting(self, de: int, kind: str = ""):
        """Guard one level of pointer following: raises on a cycle (the same DE entered again
        for the same purpose) or on nesting deeper than MAX_DEPTH."""
        self._enter(de, kind)
        try:
            yield
        except Exception:
            if self._failed_at is None:
                self._failed_at = self.current_location()
            raise
        finally:
            self._active.pop()
            self._keys.pop()

    def _enter(self, de: int, kind: str = "") -> None:
        """`visiting`'s checks and push (the caller pops ``_active`` and ``_keys`` in a
        ``finally``, noting ``_failed_at`` on an exception, as `visiting` does)."""
        key = (kind, de)
        if key in self._keys:
            e = self.entries[de]
            chain = " -> ".join(str(d) for _, d in self._keys[self._keys.index(key):] + [key])
            raise IgesError(f"cycle of pointers: DE {chain}", filename=self.filename, line=e.line, de=de,
                            entity_type=e.entity_type)
        if len(self._active) >= MAX_DEPTH:
            e = self.entries[de]
            raise IgesError(f"pointers nested deeper than {MAX_DEPTH} levels", filename=self.filename,
                            line=e.line, de=de, entity_type=e.entity_type)
        self._active.append(de)
        self._keys.append(key)

    def current_location(self) -> tuple[int | None, int | None, int | None]:
        """(DE, line, entity type) of the innermost entity under construction (or where the
        last exception was raised)."""
        if not self._active and self._failed_at is not None:
            return self._failed_at
        if not self._active:
            return None, None, None
        e = self.entries[self._active[-1]]
        return e.de, e.line, e.entity_type

    def _wrap(self, p: Params, exc: ValueError, field: str | None = None) -> IgesError:
        return p.error(str(exc), 1, field)

    def _cached(self, key: tuple, make):
        v = self._cache.get(key, _MISSING)
        if v is not _MISSING:
            return v
        self._enter(key[1], key[0])  # `visiting`, inlined (hot path)
        try:
            v = self._cache[key] = make()
        except Exception:
            if self._failed_at is None:
                self._failed_at = self.current_location()
            raise
        finally:
            self._active.pop()
            self._keys.pop()
        return v

    # ------------------------------------------------------------------ 124 transformations
    def matrix(self, de: int) -> Affine:
        """The 124 at ``de`` alone: R (3, 3) and T (3,) from fields 1-12 (rows R1j, T1, ...)."""
        p = self.params(de)
        if p.entry.form not in (0, 1, 10, 11, 12):
            self.note(f"transformation matrix form {p.entry.form} is not 0, 1, 10, 11 or 12; used as given", de)
        v = p.reals(1, 12, "R11..T3")
        m = v.reshape(3, 4)
        self._own_end[de] = 13
        r = m[:, :3].copy()
        if p.entry.form in (0, 1):
            # forms 0 and 1 promise an orthonormal R (det +1 / -1); applying any other R is
            # still exact for NURBS, but other readers (OpenCASCADE) treat it differently
            dev = float(np.abs(r.T @ r - _EYE3).max())
            (a, b, c), (d, e, f), (g, h, i) = r.tolist()
            det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)  # scalar: one per 124
            want = 1.0 if p.entry.form == 0 else -1.0
            if dev > 1e-6 or abs(det - want) > 1e-6:
                self.note(f"transformation matrix form {p.entry.form} is not orthonormal with determinant "
                          f"{want:+.0f} (|R^T R - I| = {dev:.3g}, det {det:.6g}); applied as written", de)
        return r, m[:, 3].copy()

    def transform(self, de: int) -> Affine | None:
        """The full transformation of entity ``de`` (its DE field 7 and the 124 chain behind
        it: a 124 that points to another 124 is applied first, the pointed-to one after)."""
        if self.entries[de].transform == 0:  # most entities: no matrix
            return None
        key = ("xf", de)
        if key in self._cache:
            return self._cache[key]
        total: Affine | None = None
        seen: list[int] = []
        cur = self.entries[de]
        while cur.transform != 0:
            t = cur.transform
            if t < 0 or t not in self.entries or self.entries[t].entity_type != 124:
                what = "does not exist" if t not in self.entries else f"is entity {self.entries[t].entity_type}"
                raise IgesError(f"transformation matrix pointer {t} {what}, expected a 124",
                                filename=self.filename, line=cur.line, de=cur.de, entity_type=cur.entity_type,
                                field="transformation matrix")
            if t in seen or t == de:
                raise IgesError("cycle of transformation matrices: DE " + " -> ".join(map(str, seen + [t])),
                                filename=self.filename, line=cur.line, de=cur.de, entity_type=cur.entity_type,
                                field="transformation matrix")
            seen.append(t)
            if len(seen) > MAX_DEPTH:
                raise IgesError("transformation matrix chain too long", filename=self.filename, line=cur.line,
                                de=cur.de, entity_type=cur.entity_type, field="transformation matrix")
            m = self._cache.get(("m", t))
            if m is None:  # once per 124 (its check notes once)
                m = self._cache[("m", t)] = self.matrix(t)
            total = compose(m, total)
            cur = self.entries[t]
        self._cache[key] = total
        return total

    # ------------------------------------------------------------------ curves
    def curve_pieces(self, de: int) -> list[NurbsCurve]:
        """Curve entity ``de`` as a list of NURBS pieces joined end to start (a 102 gives its
        components), in the entity's parent space (its own transformation applied)."""
        return self._cached(("curve", de), lambda: self._curve_pieces(de))

    def _curve_pieces(self, de: int) -> list[NurbsCurve]:
        e = self.entries[de]
        t = e.entity_type
        p = self.params(de)
        if t == 126:
            pieces = self.bspline_curve(p)
        elif t == 102:
            n = p.int(1, "N")
            if n < 0:
                raise p.error(f"negative number of curves {n}", 1, "N")
            p.require(1 + n, "N")
            pieces = []
            for j in range(n):
                sub = p.pointer(2 + j, f"DE({j + 1})", allow_zero=False)
                self.entry(sub, p, 2 + j, f"DE({j + 1})")
                pieces.extend(self.curve_pieces(sub))
            self._own_end[de] = 2 + n
            if not pieces:
                raise Unsupported("composite curve with no components", de, t, e.line)
        elif t == 110:
            v = p.reals(1, 6, "X1..Z2")
            self._own_end[de] = 7
            if (v[:3] == v[3:]).all():
                raise p.error("line with coincident end points", 1, "X1")
            # `construct.line(v[:3], v[3:])`, built directly: `Params.reals` values are finite,
            # so its NurbsCurve checks pass (same knots, points, unit weights and domain)
            pieces = [NurbsCurve._trusted(1, _LINE_KNOTS, v.reshape(2, 3), _ONES2,
                                          (_LINE_KNOTS[1], _LINE_KNOTS[2]), False)]
        elif t == 100:
            v = p.reals(1, 7, "ZT..Y3")
            self._own_end[de] = 8
            pieces = [_arc100(p, v)]
        elif t == 104:
            c = _construct()
            if not hasattr(c, "conic_arc"):
                raise Unsupported("conic arc (104) not supported by construct", de, t, e.line)
            v = p.reals(1, 11, "A..Y2")
            self._own_end[de] = 12
            try:
                pieces = [c.conic_arc(*v[:7], (v[7], v[8], v[6]), (v[9], v[10], v[6]))]
            except ValueError as exc:
                raise self._wrap(p, exc) from None
        elif t == 106:
            pieces = [self.copious(p)]
        elif t == 112:
            pieces = [self.parametric_spline(p)]
        else:
            raise Unsupported(f"curve entity {t} is not supported", de, t, e.line)
        xf = self.transform(de)
        return pieces if xf is None else [apply_curve(c, xf) for c in pieces]

    def curve(self, de: int) -> NurbsCurve:
        """Curve entity ``de`` as one NURBS curve (composites joined by construct)."""
        pieces = self.curve_pieces(de)
        if len(pieces) == 1:
            return pieces[0]
        try:
            return _construct().composite_curve(pieces)
        except ValueError as exc:
            raise self._wrap(self.params(de), exc) from None

    def parametric_spline(self, p: Params) -> NurbsCurve:
        """112 parametric spline curve (IGES 5.3 4.9): CTYPE, H, NDIM, N, breakpoints T(1..N+1),
        then per segment i the cubic coefficients A, B, C, D of x, y and z in s = t - T(i)
        (12 values; NDIM = 2 has them too), then the terminal derivatives (not needed).
        Exactly the cubic B-spline in Bezier form on the same parameter: segment i's control
        points A, A + B h/3, A + 2 B h/3 + C h^2/3, A + B h + C h^2 + D h^3 (h = T(i+1) - T(i)),
        knots T(i) of multiplicity 3. Where a segment's end misses the next one's start (the
        file's continuity H says it should not), the next start is kept and the gap noted."""
        ctype, n = p.int(1, "CTYPE"), p.int(4, "N")
        if not 1 <= ctype <= 6:
            raise p.error(f"spline type CTYPE = {ctype} is not 1..6", 1, "CTYPE")
        if n < 1:
            raise p.error(f"number of segments N = {n} must be at least 1", 4, "N")
        p.require(5 + n + 12 * n, "N")
        t = p.reals(5, n + 1, "T")
        if not (np.diff(t) > 0).all():
            j = int(np.flatnonzero(~(np.diff(t) > 0))[0])
            raise p.error(f"breakpoints not increasing: T({j + 2}) = {t[j + 1]!r} after {t[j]!r}", 6 + j, f"T({j + 2})")
        k0 = 6 + n
        coef = p.reals(k0, 12 * n, "AX..DZ").reshape(n, 3, 4)  # (segment, x/y/z, A..D)
        self._own_end[p.de] = k0 + 12 * n + (12 if p.has(k0 + 12 * n + 11) else 0)
        h = np.diff(t)[:, None]
        a, b, c, d = (coef[:, :, j] for j in range(4))  # (N, 3) each
        ends = a + b * h + c * h * h + d * h ** 3
        gap = np.linalg.norm(ends[:-1] - a[1:], axis=1) if n > 1 else np.zeros(0)
        scale = float(np.ptp(np.vstack([a, ends]), axis=0).max()) or 1.0
        if gap.size and gap.max() > 1e-9 * scale:
            j = int(np.argmax(gap))
            self.note(f"parametric spline segments {j + 1} and {j + 2} miss each other by {gap[j]:.3g}: "
                      f"the curve runs on from the start of segment {j + 2}", p.de, p.line(k0))
        cp = np.empty((3 * n + 1, 3))
        cp[0:-1:3], cp[1::3], cp[2::3] = a, a + b * h / 3, a + (2 * b * h + c * h * h) / 3
        cp[-1] = ends[-1]
        knots = np.concatenate([[t[0]] * 4, np.repeat(t[1:-1], 3), [t[-1]] * 4])
        try:
            return NurbsCurve(3, knots, cp)
        except ValueError as exc:
            raise self._wrap(p, exc, "T") from None

    def copious(self, p: Params) -> NurbsCurve:
        """106 copious data forms 1, 2, 11, 12, 63 as a degree-1 curve through the points."""
        form = p.entry.form
        if form not in (1, 2, 11, 12, 63):
            raise Unsupported(f"copious data form {form} is not supported", p.de, 106, p.line(0))
        ip = p.int(1, "IP")
        n = p.int(2, "N")
        if ip not in (1, 2, 3) or n < 2:
            raise p.error(f"IP={ip}, N={n}: need IP in 1..3 and N >= 2", 1, "IP")
        if ip == 1:
            p.require(3 + 2 * n, "N")
            zt = p.real(3, "ZT")
            xy = p.reals(4, 2 * n, "X,Y").reshape(n, 2)
            pts = np.column_stack([xy, np.full(n, zt)])
            self._own_end[p.de] = 4 + 2 * n
        else:
            step = 3 if ip == 2 else 6
            p.require(2 + step * n, "N")
            pts = p.reals(3, step * n, "X,Y,Z").reshape(n, step)[:, :3]
            self._own_end[p.de] = 3 + step * n
        knots = np.concatenate([[0.0], np.arange(n, dtype=float), [n - 1.0]])
        try:
            return NurbsCurve(1, knots, pts)
        except ValueError as exc:
            raise self._wrap(p, exc, "N") from None

    def bspline_curve(self, p: Params, whole_if_empty: bool = False) -> list[NurbsCurve]:
        """126: K, M, PROP1-4, knots T(-M..N+M), weights W(0..K), points (K+1)x3, V0, V1.
        ``whole_if_empty``: an empty range V0 = V1 means the whole knot range (noted).

        One curve, or several pieces joined end to start where an interior knot of
        multiplicity above M marks a jump (`_surplus_knots`)."""
        k = p.int(1, "K")
        m = p.int(2, "M")
        if m < 1:
            raise p.error(f"degree M = {m} must be at least 1", 2, "M")
        if k < m:
            raise p.error(f"K = {k} must be at least M = {m} (N = 1 + K - M >= 1)", 1, "K")
        nk = k + m + 2
        t0 = 7
        w0 = t0 + nk
        c0 = w0 + k + 1
        v0 = c0 + 3 * (k + 1)
        if v0 + 1 >= len(p.tokens):
            raise p.error(f"K={k}, M={m} need {v0 + 1} parameters, the entity has {len(p) }", 1, "K")
        knots = p.reals(t0, nk, "T")
        self._check_knots(p, knots, t0, m, "T")
        w = p.reals(w0, k + 1, "W")
        if not (w > 0).all():
            j = int(np.flatnonzero(~(w > 0))[0])
            raise p.error(f"weight {w[j]!r} is not positive", w0 + j, f"W({j})")
        cp = p.reals(c0, 3 * (k + 1), "X,Y,Z").reshape(k + 1, 3)
        a, b = p.real(v0, "V0"), p.real(v0 + 1, "V1")
        self._own_end[p.de] = v0 + 2 + (3 if p.has(v0 + 4) else 0)
        lo, hi = knots[m], knots[k + 1]
        if whole_if_empty and a == b and lo < hi:
            self.note(f"V0 = V1 = {a!r}: the whole knot range [{float(lo)!r}, {float(hi)!r}] used", p.de,
                      p.line(v0))
            a, b = float(lo), float(hi)
        a, b = self._clamp_range(p, a, b, lo, hi, v0, "V0", "V1")
        inner = knots[m + 1 : k + 1]
        if lo <= a < b <= hi:
            # knots non-decreasing (checked above), values finite (`Params.reals` rejects
            # overflow), weights positive, lo <= a < b <= hi: NurbsCurve's checks reduce to
            # the interior knot multiplicity; when it passes, the same curve without
            # re-validation (anything else: the constructor, and its error, below)
            if inner.size <= m or not (inner[m:] == inner[:-m]).any():
                knots.setflags(write=False)
                wr = w.min() < w.max()
                return [NurbsCurve._trusted(m, knots, cp, w, (float(a), float(b)), bool(wr))]
        nets = [(knots, cp, w)]
        if self._has_surplus(knots, m):
            nets = [(kn, *from_homogeneous(q))
                    for kn, q in self._surplus_knots(p, m, knots, to_homogeneous(cp, w), t0, "T", "curve")]
        pieces = []
        try:
            for kn, pts, ws in nets:
                lo_i, hi_i = max(a, kn[m]), min(b, kn[-m - 1])
                if lo_i < hi_i:
                    pieces.append(NurbsCurve(m, kn, pts, ws, (lo_i, hi_i)))
        except ValueError as exc:
            raise p.error(str(exc), t0, "T") from None
        return pieces

    def _surplus_knots(self, p: Params, deg: int, knots: np.ndarray, qw: np.ndarray, k: int, name: str,
                       what: str, axis: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
        """Interior knots of multiplicity above the degree ``deg`` (IGES 5.3 4.23 and 4.24
        allow at most the degree): lowered exactly where the curve or surface is continuous
        (`remove_surplus_knots`); a curve is split where it jumps, a surface refused there.
        knots (m+1,); qw homogeneous (n, 4) or (nu, nv, 4), ``axis`` along the knots; ``k``,
        ``name``: the knot field. Returns (knots, qw) of the pieces; every change is noted."""
        counts = dict(zip(*np.unique(knots[deg + 1 : len(knots) - deg - 1], return_counts=True)))
        kn, qw, removed, breaks = remove_surplus_knots(knots, deg, qw, axis)
        for u, gap in breaks:
            how = "its weights disagree" if gap == float("inf") else f"it jumps by {gap:.3g}"
            if what == "surface":
                raise p.error(f"knot {u!r} has multiplicity {counts[u]} > degree {deg} and the surface is not "
                              f"continuous there ({how}): no exact reading as one surface", k, name)
            self.note(f"knot {name} = {u!r} of multiplicity {counts[u]} > degree {deg}: the {what} is not "
                      f"continuous there ({how}): split into two pieces", p.de, p.line(k))
        for u, r in removed:
            where = "" if any(u == v for v, _ in breaks) else f", where the {what} is continuous"
            self.note(f"knot {name} = {u!r} of multiplicity {counts[u]} > degree {deg}{where}: {r} occurrence(s) "
                      f"removed (exact)", p.de, p.line(k))
        nets = []
        for u, _ in breaks:  # curves only
            a = int(np.searchsorted(kn, u))  # first occurrence: the run kn[a .. a+deg] of deg + 1
            nets.append((kn[: a + deg + 1], qw[:a]))
            kn, qw = kn[a:], qw[a:]
        nets.append((kn, qw))
        return nets

    @staticmethod
    def _has_surplus(knots: np.ndarray, deg: int) -> bool:
        """True if an interior knot (knots[deg+1 .. n-1]) has multiplicity above ``deg``."""
        inner = knots[deg + 1 : len(knots) - deg - 1]
        return inner.size > deg and bool((inner[deg:] == inner[:-deg]).any())

    def _check_knots(self, p: Params, knots: np.ndarray, start: int, m: int, name: str) -> None:
        if (knots[1:] >= knots[:-1]).all():
            return
        d = np.diff(knots)
        bad = np.flatnonzero(~(d >= 0))
        if bad.size:
            j = int(bad[0]) + 1
            raise p.error(f"knots decrease: {float(knots[j - 1])!r} then {float(knots[j])!r}", start + j, f"{name}({j - m})")

    def _ordered(self, p: Params, k: int, na: str, nb: str) -> tuple[float, float]:
        """Fields k, k+1 of a 128 (U0, U1 or V0, V1; IGES 5.3 4.24 has U0 < U1, V0 < V1) in
        increasing order: a reversed range names the same rectangle of the surface, so it is
        read in order (noted)."""
        a, b = p.real(k, na), p.real(k + 1, nb)
        if a > b:
            self.note(f"{na} = {a!r} > {nb} = {b!r}: parameter range reversed, read as [{b!r}, {a!r}]", p.de,
                      p.line(k))
            a, b = b, a
        return a, b

    def _clamp_range(self, p: Params, a: float, b: float, lo: float, hi: float, k: int, na: str, nb: str):
        tol = DOMAIN_REL_TOL * max(1.0, hi - lo)
        if not a < b:
            raise p.error(f"parameter range [{a!r}, {b!r}] is empty or reversed", k, na)
        if a < lo - tol or b > hi + tol:
            raise p.error(f"parameter range [{a!r}, {b!r}] outside the knot range [{float(lo)!r}, {float(hi)!r}]",
                          k if a < lo - tol else k + 1, na if a < lo - tol else nb)
        if a < lo or b > hi:
            self.note(f"{na}/{nb} range [{a!r}, {b!r}] slightly outside the knot range [{float(lo)!r}, {float(hi)!r}]: clamped",
                      p.de, p.line(k))
            a, b = max(a, lo), min(b, hi)
        return a, b

    # ------------------------------------------------------------------ surfaces
    def bspline_surface(self, p: Params) -> NurbsSurface:
        """128: K1, K2, M1, M2, PROP1-5, S, T, W, control points (first index fastest), U0..V1."""
        k1, k2 = p.int(1, "K1"), p.int(2, "K2")
        m1, m2 = p.int(3, "M1"), p.int(4, "M2")
        for val, k, name in ((m1, 3, "M1"), (m2, 4, "M2")):
            if val < 1:
                raise p.error(f"degree {name} = {val} must be at least 1", k, name)
        if k1 < m1:
            raise p.error(f"K1 = {k1} must be at least M1 = {m1} (N1 = 1 + K1 - M1 >= 1)", 1, "K1")
        if k2 < m2:
            raise p.error(f"K2 = {k2} must be at least M2 = {m2} (N2 = 1 + K2 - M2 >= 1)", 2, "K2")
        na, nb = k1 + m1 + 2, k2 + m2 + 2  # A + 1 and B + 1 knots
        c = (k1 + 1) * (k2 + 1)
        s0 = 10
        t0 = s0 + na
        w0 = t0 + nb
        x0 = w0 + c
        r0 = x0 + 3 * c
        if r0 + 3 >= len(p.tokens):  # checked before any allocation
            raise p.error(f"K1={k1}, K2={k2}, M1={m1}, M2={m2} need {r0 + 3} parameters, the entity has "
                          f"{len(p)}", 1, "K1")
        su = p.reals(s0, na, "S")
        self._check_knots(p, su, s0, m1, "S")
        tv = p.reals(t0, nb, "T")
        self._check_knots(p, tv, t0, m2, "T")
        w = p.reals(w0, c, "W")
        if not (w > 0).all():
            j = int(np.flatnonzero(~(w > 0))[0])
            raise p.error(f"weight {w[j]!r} is not positive", w0 + j, f"W({j % (k1 + 1)},{j // (k1 + 1)})")
        xyz = p.reals(x0, 3 * c, "X,Y,Z")
        # IGES order: first index (u) fastest -> reshape (v, u), then transpose to [i along u, j along v]
        cp = xyz.reshape(k2 + 1, k1 + 1, 3).transpose(1, 0, 2)
        w = w.reshape(k2 + 1, k1 + 1).T
        u_a, u_b = self._clamp_range(p, *self._ordered(p, r0, "U0", "U1"), su[m1], su[k1 + 1], r0, "U0", "U1")
        v_a, v_b = self._clamp_range(p, *self._ordered(p, r0 + 2, "V0", "V1"), tv[m2], tv[k2 + 1], r0 + 2,
                                     "V0", "V1")
        self._own_end[p.de] = r0 + 4
        if self._has_surplus(su, m1) or self._has_surplus(tv, m2):
            qw = to_homogeneous(cp, w)
            if self._has_surplus(su, m1):
                [(su, qw)] = self._surplus_knots(p, m1, su, qw, s0, "S", "surface", axis=0)
            if self._has_surplus(tv, m2):
                [(tv, qw)] = self._surplus_knots(p, m2, tv, qw, t0, "T", "surface", axis=1)
            cp, w = from_homogeneous(qw)
        try:
            return NurbsSurface(m1, m2, su, tv, cp, w, (u_a, u_b, v_a, v_b))
        except ValueError as exc:
            msg = str(exc)
            k, name = (t0, "T") if "knots_v" in msg else (s0, "S")
            raise p.error(msg, k, name) from None

    def surface(self, de: int) -> tuple[NurbsSurface, Trim | None]:
        """Surface entity ``de`` (128, 108 bounded, 118, 120, 122) with its own
        transformation applied; the Trim is the boundary of a bounded plane, else None."""
        return self._cached(("surface", de), lambda: self._surface(de))

    def _surface(self, de: int) -> tuple[NurbsSurface, Trim | None]:
        e = self.entries[de]
        t = e.entity_type
        p = self.params(de)
        trim = None
        if t == 128:
            s = self.bspline_surface(p)
        elif t == 108:
            s, trim = self.plane(p)
        elif t == 118:
            d1 = p.pointer(1, "DE1", allow_zero=False)
            d2 = p.pointer(2, "DE2", allow_zero=False)
            self.entry(d1, p, 1, "DE1")
            self.entry(d2, p, 2, "DE2")
            dirflg = p.int(3, "DIRFLG", 0)
            self._own_end[de] = 5
            if e.form == 0:
                self.note("ruled surface form 0 (equal arc length) built with equal parametric values", de)
            c1, c2 = self.curve(d1), self.curve(d2)
            try:
                s = _construct().ruled_surface(c1, c2, reverse_second=(dirflg == 1))
            except ValueError as exc:
                raise self._wrap(p, exc, "DE1") from None
        elif t == 120:
            a, b, sa, ta = self._revolution_axis(de)
            gen = self.curve(p.pointer(2, "C", allow_zero=False))
            ta = self._full_turn(de, sa, ta, gen, a, b)
            try:
                s = _construct().revolved_surface(gen, a, b - a, sa, ta)
            except ValueError as exc:
                raise self._wrap(p, exc, "SA") from None
        elif t == 140:  # offset surface (IGES 5.3 4.25): NX, NY, NZ, D, DE of the base surface
            bde = p.pointer(5, "DE", allow_zero=False)
            base = self.entry(bde, p, 5, "DE").entity_type
            self._own_end[de] = 6
            gen = self._offset_generatrix(bde, p.real(4, "D")) if base == 120 else None
            if gen is None:
                what = SURFACE_NAMES.get(base, "surface")
                if base == 120:
                    what += " whose generatrix is not a line in a plane through the axis"
                raise Unsupported(f"offset surface (140) over a {what} ({base}, DE {bde}) is not supported", de, t,
                                  e.line)
            a, b, sa, ta = self._revolution_axis(bde)
            ta = self._full_turn(bde, sa, ta, self.curve(self.params(bde).pointer(2, "C", allow_zero=False)), a, b)
            try:
                s = _construct().revolved_surface(gen, a, b - a, sa, ta)
            except ValueError as exc:
                raise self._wrap(p, exc, "D") from None
            s = apply_surface(s, self.transform(bde))
        elif t == 122:
            dd = p.pointer(1, "DE", allow_zero=False)
            self.entry(dd, p, 1, "DE")
            end = p.reals(2, 3, "LX,LY,LZ")
            self._own_end[de] = 5
            dirx = self.curve(dd)
            start = dirx.evaluate([dirx.domain[0]])[0]
            try:
                s = _construct().tabulated_cylinder(dirx, end - start)
            except ValueError as exc:
                raise self._wrap(p, exc, "LX") from None
        else:
            raise Unsupported(f"surface entity {t} is not supported", de, t, e.line)
        return apply_surface(s, self.transform(de)), trim

    def _revolution_axis(self, de: int) -> tuple[np.ndarray, np.ndarray, float, float]:
        """120 at ``de``: axis line ends a, b (3,) (the 110's own transformation applied) and
        the angles SA, TA (fields 1-4)."""
        p = self.params(de)
        lde = p.pointer(1, "L", allow_zero=False)
        cde = p.pointer(2, "C", allow_zero=False)
        self.entry(lde, p, 1, "L", types=(110,))
        self.entry(cde, p, 2, "C")
        sa, ta = p.real(3, "SA"), p.real(4, "TA")
        self._own_end[de] = 5
        lp = self.params(lde)
        with self.visiting(lde):
            ends = lp.reals(1, 6, "X1..Z2")
            xf = self.transform(lde)
        a, b = ends[:3], ends[3:]
        if not _is_identity(xf):
            a, b = xf[0] @ a + xf[1], xf[0] @ b + xf[1]
        if not np.any(b - a):
            raise lp.error("axis line of a surface of revolution has zero length", 1, "X1")
        return a, b, sa, ta

    def _full_turn(self, de: int, sa: float, ta: float, gen: NurbsCurve, a: np.ndarray, b: np.ndarray) -> float:
        """TA of the 120 at ``de``: a sweep TA - SA within `ROUNDED_TURN` rad of 2 pi (2 pi
        printed to 5 or 6 digits: CATIA V4 writes 6.28318, 5e-6 rad short; 6.2832 is 1.5e-5 over),
        or short of it by a sliver no wider than the file's resolution (G19) at the
        generatrix's largest radius (a bound: its control points'), is a full turn: TA is
        then SA + 2 pi, noted. Left as written, a loop's points in the sliver wrap to the
        start angle (its (u, v) jumps by a period), and a sweep over 2 pi is refused."""
        gap = 2 * np.pi - (ta - sa)
        if gap == 0 or abs(gap) > FULL_TURN_MAX_GAP or gen.dim != 3:
            return ta
        axis = (b - a) / np.linalg.norm(b - a)
        rel = gen.control_points - a
        radius = float(np.max(np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1)))
        res = self.resolution if self.resolution and np.isfinite(self.resolution) and self.resolution > 0 else 0.0
        if abs(gap) > max(ROUNDED_TURN, res / max(radius, 1e-300)):
            return ta
        if ("full turn", de) not in self._cache:  # noted once (the surface and its trim map both ask)
            self._cache["full turn", de] = True
            self.note(f"surface of revolution: sweep TA - SA = {ta - sa:.9g} read as a full turn (2 pi "
                      f"{'-' if gap > 0 else '+'} {abs(gap):.3g} rad, {abs(gap) * radius:.3g} at radius {radius:.6g})",
                      de)
        return sa + 2 * np.pi

    def _offset_generatrix(self, de: int, d: float) -> NurbsCurve | None:
        """Generatrix of the 120 at ``de`` offset by ``d`` along the surface's unit normal
        S_u x S_v (IGES 5.3 4.25), when that is exact: a line (110) in a plane through the
        axis (a cone or cylinder: the normal is one vector along the line, and the offset is
        the surface of revolution of the shifted line). None otherwise. In the 120's space."""
        p = self.params(de)
        cde = p.pointer(2, "C", allow_zero=False)
        if self.entry(cde, p, 2, "C").entity_type != 110:
            return None
        a, b, _, _ = self._revolution_axis(de)
        gen = self.curve(cde)
        p0, p1 = gen.evaluate(np.array(gen.domain))
        ax = (b - a) / np.linalg.norm(b - a)
        line = p1 - p0
        size = max(float(np.linalg.norm(line)), float(np.linalg.norm(p0 - a)), float(np.linalg.norm(p1 - a)))
        if abs(float(ax @ np.cross(line, p0 - a))) > 1e-12 * size * size:  # skew line: a hyperboloid
            return None
        far = p0 if np.linalg.norm(np.cross(ax, p0 - a)) >= np.linalg.norm(np.cross(ax, p1 - a)) else p1
        n = np.cross(line, np.cross(ax, far - a))  # S_u x S_v at angle 0 (S_v: right-hand turn about the axis)
        if not np.linalg.norm(n) > 1e-12 * size * size:
            return None
        n /= np.linalg.norm(n)
        return NurbsCurve(gen.degree, gen.knots, gen.control_points + d * n, gen.weights, gen.domain)

    def plane(self, p: Params) -> tuple[NurbsSurface, Trim]:
        """108 form 1: the plane A x + B y + C z = D over the extent of its boundary curve,
        the curve (mapped to (u, v)) as the outer trim loop."""
        de = p.de
        if p.entry.form != 1:
            raise Unsupported(f"plane form {p.entry.form} (unbounded or hole) is not a face", de, 108, p.line(0))
        abcd = p.reals(1, 4, "A,B,C,D")
        ptr = p.pointer(5, "PTR", allow_zero=False)
        self.entry(ptr, p, 5, "PTR")
        self._own_end[de] = 10 if p.has(9) else len(p.tokens)
        n = abcd[:3]
        nn = float(np.dot(n, n))
        if not nn > 0:
            raise p.error("plane normal (A, B, C) is zero", 1, "A")
        pieces = self.curve_pieces(ptr)
        pts = np.concatenate([c.control_points if c.dim == 3 else
                              np.column_stack([c.control_points, np.zeros(len(c.control_points))])
                              for c in pieces])
        origin = n * (abcd[3] / nn)
        nu = n / np.sqrt(nn)
        rel = pts - origin
        rel -= np.outer(rel @ nu, nu)
        # u along the first edge of the boundary (a rectangle gives a tight, aligned box)
        step = np.linalg.norm(rel - rel[0], axis=1)
        moved = np.flatnonzero(step > 1e-9 * step.max()) if step.max() > 0 else []
        far = rel[moved[0]] - rel[0] if len(moved) else np.zeros(3)
        if np.linalg.norm(far) == 0:
            raise p.error("bounding curve of the plane is a single point", 5, "PTR")
        udir = far / np.linalg.norm(far)
        vdir = np.cross(nu, udir)
        uu, vv = rel @ udir, rel @ vdir
        if np.ptp(vv) == 0:
            raise p.error("bounding curve of the plane is degenerate (a line)", 5, "PTR")
        try:
            s = _construct().plane_surface(origin, nu, udir, (uu.min(), uu.max()), (vv.min(), vv.max()))
        except ValueError as exc:
            raise self._wrap(p, exc, "A") from None
        # affine map model -> (u, v) read off the surface itself (independent of how it is parametrised)
        u0, u1, v0, v1 = s.domain
        c = s.evaluate([u0, u1, u0], [v0, v0, v1])
        basis = np.column_stack([c[1] - c[0], c[2] - c[0]])  # (3, 2)
        loop = []
        for piece in pieces:
            cp3 = piece.control_points if piece.dim == 3 else np.column_stack(
                [piece.control_points, np.zeros(len(piece.control_points))])
            ab = np.linalg.lstsq(basis, (cp3 - c[0]).T, rcond=None)[0].T  # (n, 2)
            uv = np.column_stack([u0 + ab[:, 0] * (u1 - u0), v0 + ab[:, 1] * (v1 - v0)])
            loop.append(NurbsCurve(piece.degree, piece.knots, uv, piece.weights, piece.domain))
        return s, Trim(TrimLoop(loop, pieces), [])

    # ------------------------------------------------------------------ trimming
    def curve_on_surface(self, de: int) -> TrimLoop | None:
        """142: CRTN, SPTR, BPTR, CPTR, PREF -> a loop from the parameter-space curve BPTR
        (None, with a diagnostic, when there is none)."""
        return self._cached(("cos", de), lambda: self._curve_on_surface(de))

    def _curve_on_surface(self, de: int) -> TrimLoop | None:
        pc, mc = self.cos_raw(de)
        if pc is None:
            self.note("curve on surface without a parameter-space curve (model space only or unusable): "
                      "face left untrimmed", de)
            return None
        return TrimLoop(pc, mc)

    def cos_raw(self, de: int) -> tuple[list[NurbsCurve] | None, list[NurbsCurve] | None]:
        """142: CRTN, SPTR, BPTR, CPTR, PREF -> (parameter-space pieces of BPTR, model-space
        pieces of CPTR), each None when absent or unusable.

        Transformations (IGES 5.3, 4.32): BPTR lives in the parameter space of the surface,
        so only its own 124 (a 2D map of (u, v)) applies to it -- never the 124 of the 142,
        of the 144 above it or of the surface; ``curve_pieces`` applies exactly the curve's
        own chain. CPTR is a model-space curve like the surface: the 144's placement is
        applied to it by the caller, as to the surface."""
        return self._cached(("cosraw", de), lambda: self._cos_raw(de))

    def _cos_raw(self, de: int):
        p = self.params(de)
        sptr = p.pointer(2, "SPTR")
        bptr = p.pointer(3, "BPTR")
        cptr = p.pointer(4, "CPTR")
        pref = p.int(5, "PREF", 0)
        # 142 PREF (IGES 5.3, 4.32): 1 = S o B (parameter space) preferred, 2 = C (model space), 3 = equal
        self.pref[de] = {1: "pcurve", 2: "model", 3: "equal"}.get(pref)
        self._own_end[de] = 6
        if sptr:
            self.entry(sptr, p, 2, "SPTR")
        pc = mc = None
        if bptr:
            self.entry(bptr, p, 3, "BPTR")
            try:
                pc = [to_2d(c) for c in self.curve_pieces(bptr)]
            except Unsupported as u:
                self.note(f"parameter-space curve not usable ({u})", de)
        if cptr:
            self.entry(cptr, p, 4, "CPTR")
            try:
                mc = self.curve_pieces(cptr)
            except Unsupported:
                mc = None
        return pc, mc

    def boundary(self, de: int) -> TrimLoop | None:
        """141 as a loop of parameter-space curves (None, with a note, if any is missing)."""
        edges = self.boundary_raw(de, want_model=False)
        if edges is None:
            return None
        if any(pc is None for pc, _ in edges):
            self.note("boundary curve without parameter-space curves: face left untrimmed", de)
            return None
        pieces = [c for pc, _ in edges for c in pc]
        return TrimLoop(pieces) if pieces else None

    def boundary_raw(self, de: int, want_model: bool = True):
        """141: TYPE, PREF, SPTR, N, then N x (CRVPT, SENSE, K, PSCPT(1..K)) -> list of
        (parameter-space pieces or None, model-space pieces or None) in loop order (SENSE 2
        reversed). Parameter-space curves get only their own 124 (see `cos_raw`)."""
        p = self.params(de)
        typ = p.int(1, "TYPE")
        # 141 PREF (IGES 5.3, 4.31) codes differently from 142: 1 = model space, 2 = parameter space
        self.pref[de] = {1: "model", 2: "pcurve", 3: "equal"}.get(p.int(2, "PREF", 0))
        n = p.int(4, "N")
        if n < 0:
            raise p.error(f"negative number of curves {n}", 4, "N")
        k = 5
        edges = []
        for j in range(n):
            p.require(k + 2, "N")
            crv = p.pointer(k, f"CRVPT({j + 1})")
            sense = p.int(k + 1, f"SENSE({j + 1})")
            kk = p.int(k + 2, f"K({j + 1})")
            if kk < 0:
                raise p.error(f"negative count {kk}", k + 2, f"K({j + 1})")
            p.require(k + 2 + kk, f"K({j + 1})")
            part: list[NurbsCurve] | None = []
            for i in range(kk):
                ptr = p.pointer(k + 3 + i, f"PSCPT({j + 1},{i + 1})", allow_zero=False)
                self.entry(ptr, p, k + 3 + i, f"PSCPT({j + 1},{i + 1})")
                try:
                    if part is not None:
                        part.extend(to_2d(c) for c in self.curve_pieces(ptr))
                except Unsupported as u:
                    self.note(f"parameter-space curve not usable ({u})", de)
                    part = None
            if kk == 0 or typ == 0:
                part = None
            model = None
            if crv:
                self.entry(crv, p, k, f"CRVPT({j + 1})")
                if want_model:
                    model = self._model_curve(crv, de)
            if sense == 2:
                part = None if part is None else [reverse_curve(c) for c in reversed(part)]
                model = None if model is None else [reverse_curve(c) for c in reversed(model)]
            edges.append((part, model))
            k += 3 + kk
        self._own_end[de] = k
        return edges

    # ------------------------------------------------------------------ faces
    def face(self, de: int, placement: Affine | None = None) -> Face | None:
        """Face for a top-level surface entity (128, 108, 118, 120, 122, 143, 144, 510), or
        None with a diagnostic when it cannot be represented. ``placement`` (from 408
        instances) is applied after the entity's own transformation."""
        e = self.entries[de]
        try:
            self._enter(de)  # `visiting`, inlined
            try:
                face = self._face(de)
            except Exception:
                if self._failed_at is None:
                    self._failed_at = self.current_location()
                raise
            finally:
                self._active.pop()
                self._keys.pop()
        except Unsupported as u:
            self.diagnostics.append(Diagnostic(f"face skipped: {u}", u.line if u.line else e.line,
                                               u.de if u.de else de, u.etype if u.etype else e.entity_type))
            return None
        if face is None:
            return None
        # 124 matrices are rotations; a 408 scales by S
        scale = 1.0 if _is_identity(placement) else abs(float(np.linalg.det(placement[0]))) ** (1.0 / 3.0)
        if de in self._delta:
            face.trim_delta = self._delta[de] * scale
        elif de in self._delta_lazy:
            surf, pairs, note = self._delta_lazy[de]
            face.defer_trim_delta(self.deltas, self.deltas.add_pairs(surf, pairs, scale, note))
        elif face.trims is not None and any(lp is not None and lp.model_curves for lp in [face.trims.outer]
                                            + list(face.trims.inner)):
            face.defer_trim_delta(self.deltas, self.deltas.add_face(face))  # read after the placement below
        if not _is_identity(placement):
            face.surface = face.surface.transformed(*placement)
            if face.trims is not None:
                for loop in [face.trims.outer] + list(face.trims.inner):
                    if loop is not None and loop.model_curves is not None:
                        loop.model_curves = [apply_curve(c, placement) for c in loop.model_curves]
        return face

    def _face(self, de: int) -> Face | None:
        e = self.entries[de]
        t = e.entity_type
        p = self.params(de)
        trims = None
        if t in SURFACE_TYPES:
            surface, trims = self.surface(de)
            sde = de
        elif t == 144:
            sde = p.pointer(1, "PTS", allow_zero=False)
            se = self.entry(sde, p, 1, "PTS")
            n1, n2 = p.int(2, "N1"), p.int(3, "N2")
            if n1 not in (0, 1):
                raise p.error(f"N1 = {n1} must be 0 or 1", 2, "N1")
            if n2 < 0:
                raise p.error(f"N2 = {n2} is negative", 3, "N2")
            p.require(4 + n2, "N2")
            pto = p.pointer(4, "PTO")
            if n1 == 1 and pto == 0:
                raise p.error("N1 = 1 but no outer boundary pointer", 4, "PTO")
            ptis = [p.pointer(5 + j, f"PTI({j + 1})", allow_zero=False) for j in range(n2)]
            self._own_end[de] = 5 + n2
            for k, ptr in [(4, pto)] * (n1 == 1) + [(5 + j, q) for j, q in enumerate(ptis)]:
                self.entry(ptr, p, k, "PTO" if k == 4 else f"PTI({k - 4})", types=(142,))
            if se.entity_type == 128:
                surface, _ = self.surface(sde)
                ok = True
                outer = None
                if n1 == 1:
                    outer = self.curve_on_surface(pto)
                    ok = outer is not None
                inner = []
                for q in ptis:
                    loop = self.curve_on_surface(q)
                    ok = ok and loop is not None
                    inner.append(loop)
                if ok and (outer is not None or inner):
                    trims = Trim(outer, inner)
                prefs = [self.pref.get(q) for q in ([pto] if n1 == 1 else []) + ptis]
                if trims is not None and "model" in prefs:
                    surface, trims = self._trimmed_128(surface, trims, sde, de, n1, pto, ptis, prefs)
            else:
                raw_outer = [self.cos_raw(pto)] if n1 == 1 else None
                raw_inner = [[self.cos_raw(q)] for q in ptis]
                prefs = [self.pref.get(q) for q in ([pto] if n1 == 1 else []) + ptis]
                surface, trims = self.mapped_trims(sde, raw_outer, raw_inner, de, prefs)
            xf = self.transform(de)
            surface = apply_surface(surface, xf)
            if trims is not None and not _is_identity(xf):
                for loop in [trims.outer] + trims.inner:
                    if loop is not None and loop.model_curves is not None:
                        loop.model_curves = [apply_curve(c, xf) for c in loop.model_curves]
            t_s = se.entity_type
        elif t == 143:
            p.int(1, "TYPE")
            sde = p.pointer(2, "SPTR", allow_zero=False)
            se = self.entry(sde, p, 2, "SPTR")
            n = p.int(3, "N")
            if n < 0:
                raise p.error(f"N = {n} is negative", 3, "N")
            p.require(3 + n, "N")
            bdpts = [p.pointer(4 + j, f"BDPT({j + 1})", allow_zero=False) for j in range(n)]
            self._own_end[de] = 4 + n
            for j, b in enumerate(bdpts):
                self.entry(b, p, 4 + j, f"BDPT({j + 1})", types=(141,))
            # the first boundary is the outer one
            surface, trims = self._bounded(sde, se, bdpts, self.boundary, self.boundary_raw, True, de)
            surface = apply_surface(surface, self.transform(de))
            t_s = se.entity_type
        elif t == 510:
            sde = p.pointer(1, "SURF", allow_zero=False)
            se = self.entry(sde, p, 1, "SURF")
            n = p.int(2, "N")
            if n < 0:
                raise p.error(f"N = {n} is negative", 2, "N")
            of = p.int(3, "OF")
            p.require(3 + n, "N")
            lps = [p.pointer(4 + j, f"LOOP({j + 1})", allow_zero=False) for j in range(n)]
            self._own_end[de] = 4 + n
            for j, lp in enumerate(lps):
                self.entry(lp, p, 4 + j, f"LOOP({j + 1})", types=(508,))
            # OF = 1: the first loop is the outer boundary; else all loops are holes
            surface, trims = self._bounded(sde, se, lps, self.brep_loop, self.loop_raw, of == 1, de)
            surface = apply_surface(surface, self.transform(de))
            t_s = se.entity_type
        else:
            raise Unsupported(f"entity {t} is not a face", de, t, e.line)
        if t not in (144, 143, 510):
            t_s = t
        return Face(surface=surface, de=de, name=self.name(de, sde), color=self.color(de, sde),
                    level=max(e.level, 0), trims=trims, entity_type=t, surface_de=sde, surface_type=t_s)

    def _bounded(self, sde: int, se, loop_des: list[int], load, load_raw, first_is_outer: bool, de: int):
        """(surface, trims) of a face bounded by the loops ``loop_des`` (143 boundaries, 510
        loops): over a 128 the loops' parameter curves as they are (``load``), over other
        surfaces mapped into the NURBS parameters (``load_raw`` + `mapped_trims`)."""
        if se.entity_type == 128:
            surface, _ = self.surface(sde)
            loops = []
            for x in loop_des:
                with self.visiting(x):
                    # 508 loops without parameter-space curves: from their model-space edges
                    loops.append(load(x, surface) if load == self.brep_loop else load(x))
            trims = None
            if loops and all(lp is not None for lp in loops):
                trims = Trim(loops[0], loops[1:]) if first_is_outer else Trim(None, loops)
            return surface, trims
        raws = []
        for x in loop_des:
            with self.visiting(x):
                raws.append(load_raw(x))
        prefs = [self.pref.get(x) for x in loop_des]
        if first_is_outer:
            return self.mapped_trims(sde, raws[0] if raws else None, raws[1:], de, prefs)
        return self.mapped_trims(sde, None, raws, de, prefs)

    # ------------------------------------------------------------------ trims over non-128 surfaces
    def point116(self, de: int, src: Params, k: int, name: str) -> np.ndarray:
        """116 point (X, Y, Z) with its own transformation applied."""
        self.entry(de, src, k, name, types=(116,))
        with self.visiting(de):
            p = self.params(de)
            xyz = p.reals(1, 3, "X,Y,Z")
            self._own_end[de] = 5 if p.has(4) else 4
            xf = self.transform(de)
        return xyz if _is_identity(xf) else xf[0] @ xyz + xf[1]

    def direction123(self, de: int, src: Params, k: int, name: str) -> np.ndarray:
        """123 direction (X, Y, Z), rotated by its own transformation; must be non-zero."""
        self.entry(de, src, k, name, types=(123,))
        with self.visiting(de):
            p = self.params(de)
            d = p.reals(1, 3, "X,Y,Z")
            self._own_end[de] = 4
            xf = self.transform(de)
            if not _is_identity(xf):
                d = xf[0] @ d
            if not np.linalg.norm(d) > 0:
                raise p.error("direction is the zero vector", 1, "X")
        return d

    def param_map(self, de: int) -> ParamMap:
        """How trim data over base surface ``de`` (not a 128) maps to our NURBS (u, v)."""
        return self._cached(("pmap", de), lambda: self._param_map(de))

    def _param_map(self, de: int) -> ParamMap:
        e = self.entries[de]
        t = e.entity_type
        p = self.params(de)
        xf = self.transform(de)

        def place(o, a, x=None):
            if _is_identity(xf):
                return o, a, x
            return xf[0] @ o + xf[1], xf[0] @ a, None if x is None else xf[0] @ x

        def frame(o, a, ref):
            o, a, ref = place(o, a, ref)
            try:
                return Frame.make(o, a, ref)
            except ValueError as exc:
                raise self._wrap(p, exc) from None

        def positive(k, name):
            r = p.real(k, name)
            if not r > 0:
                raise p.error(f"{name} = {r!r} must be positive", k, name)
            return r

        if t == 108:
            abcd = p.reals(1, 4, "A,B,C,D")
            self._own_end[de] = 10 if p.has(9) else len(p.tokens)
            n = abcd[:3]
            nn = float(n @ n)
            if not nn > 0:
                raise p.error("plane normal (A, B, C) is zero", 1, "A")
            # OCC: gp_Pln(A, B, C, -D): origin the foot of the world origin, X by gp_Ax2's rule
            return plane_map(frame(n * (abcd[3] / nn), n, None))
        if t in ANALYTIC_TYPES:
            ref = None  # form 0 (no REFDIR): OCC's gp_Ax2 X direction; form 1: the REFDIR
            if t == 190:
                o = self.point116(p.pointer(1, "LOCATION", allow_zero=False), p, 1, "LOCATION")
                a = self.direction123(p.pointer(2, "NORMAL", allow_zero=False), p, 2, "NORMAL")
                r = p.pointer(3, "REFDIR") if p.has(3) else 0
                if r:
                    ref = self.direction123(r, p, 3, "REFDIR")
                self._own_end[de] = 4 if p.has(3) else 3
                return plane_map(frame(o, a, ref))
            if t in (192, 194):
                o = self.point116(p.pointer(1, "LOCATION", allow_zero=False), p, 1, "LOCATION")
                a = self.direction123(p.pointer(2, "AXIS", allow_zero=False), p, 2, "AXIS")
                rad = positive(3, "RADIUS")
                k = 4
                tan = 0.0
                if t == 194:
                    ang = p.real(4, "SANGLE")
                    if not 0 < ang < 90:
                        raise p.error(f"semi-angle {ang!r} must be in (0, 90) degrees", 4, "SANGLE")
                    tan = float(np.tan(np.radians(ang)))
                    k = 5
                r = p.pointer(k, "REFDIR") if p.has(k) else 0
                if r:
                    ref = self.direction123(r, p, k, "REFDIR")
                self._own_end[de] = k + 1 if p.has(k) else k
                return cylinder_map(frame(o, a, ref), rad, tan, "cylinder" if t == 192 else "cone")
            if t == 196:
                o = self.point116(p.pointer(1, "CENTER", allow_zero=False), p, 1, "CENTER")
                rad = positive(2, "RADIUS")
                ax = p.pointer(3, "AXIS") if p.has(3) else 0
                a = self.direction123(ax, p, 3, "AXIS") if ax else np.array([0.0, 0.0, 1.0])
                r = p.pointer(4, "REFDIR") if p.has(4) else 0
                if r:
                    ref = self.direction123(r, p, 4, "REFDIR")
                self._own_end[de] = 5 if p.has(4) else 4
                return sphere_map(frame(o, a, ref), rad)
            if t == 198:
                o = self.point116(p.pointer(1, "CENTER", allow_zero=False), p, 1, "CENTER")
                a = self.direction123(p.pointer(2, "AXIS", allow_zero=False), p, 2, "AXIS")
                big, small = positive(3, "MAJRAD"), positive(4, "MINRAD")
                r = p.pointer(5, "REFDIR") if p.has(5) else 0
                if r:
                    ref = self.direction123(r, p, 5, "REFDIR")
                self._own_end[de] = 6 if p.has(5) else 5
                return torus_map(frame(o, a, ref), big, small)
        surface, _ = self.surface(de)
        if t == 140:  # read only over a 120 (`_surface`): that 120's map, with the offset generatrix
            bde = p.pointer(5, "DE", allow_zero=False)
            xf = compose(xf, self.transform(bde))
            p = self.params(bde)
            gde = p.pointer(2, "C", allow_zero=False)
            gen = self._offset_generatrix(bde, self.params(de).real(4, "D"))
            t = 120
        elif t == 120:
            gde = p.pointer(2, "C", allow_zero=False)
            gen = self.curve(gde)
        if t == 120:
            sa, ta = p.real(3, "SA"), p.real(4, "TA")
            ge = self.entries[gde]
            gen_arc, gen_aff = None, (1.0, 0.0)
            if ge.entity_type == 100:
                # IGES 100 is parametrised by the angle (T from the start angle to the end angle);
                # ours equals the angle from the start only at knots: the exact ArcMap
                v = self.params(gde).reals(1, 7, "ZT..Y3")
                a0 = float(np.arctan2(v[4] - v[2], v[3] - v[1]))
                gen_arc = ArcMap(a0, gen.domain[1] - gen.domain[0], 0.0)
                gen_aff = None
            lp = self.params(p.pointer(1, "L", allow_zero=False))
            ends = lp.reals(1, 6, "X1..Z2")
            a, b = ends[:3], ends[3:]
            lxf = self.transform(lp.de)
            if not _is_identity(lxf):
                a, b = lxf[0] @ a + lxf[1], lxf[0] @ b + lxf[1]
            if gen.dim == 3:
                ta = self._full_turn(de, sa, ta, gen, a, b)  # as the surface was built (`_surface`)
            gen_m = gen
            if not _is_identity(xf):  # the 120's own 124 places axis and generatrix like the surface
                a, b = xf[0] @ a + xf[1], xf[0] @ (b - a) + xf[0] @ a + xf[1]
                gen_m = apply_curve(gen, xf)
            return revolution_map(surface, sa, ta, gen_aff, gen_arc, (a, b - a), gen_m if gen_m.dim == 3 else None)
        if t == 122:
            a, b = surface.domain[0], surface.domain[1]
            return fixed_map(surface, (np.array([[b - a, 0.0], [0.0, 1.0]]), np.array([a, 0.0])), "tabulated")
        if t == 118:
            return fixed_map(surface, (np.eye(2), np.zeros(2)), "ruled")
        if t == 128:  # only for loops built from model-space curves (PREF = model, see `trimmed_128`)
            return fixed_map(surface, (np.eye(2), np.zeros(2)), "bspline")
        raise Unsupported(f"trim curves over surface entity {t} are not supported", de, t, e.line)

    def mapped_trims(self, sde: int, outer, inner: list, de: int,
                     prefs: list | None = None) -> tuple[NurbsSurface, Trim | None]:
        """Surface and trims of a face over base surface ``sde`` (not a 128) from raw loops
        (lists of (parameter-space pieces, model-space pieces) per edge; ``outer`` None: no
        outer loop); ``prefs`` per loop the 142/141 preferred representation ("pcurve",
        "model", "equal" or None).

        The file's trim tolerance delta (`trimcheck.loop_deltas`: max distance of S(c2d) to
        the model-space curves) is measured on the parameter-space route and kept for the
        face: at read time when the route depends on it (PREF "model", or "equal" / unspecified
        over 190-198 or with loops that do not close), else deferred to the first access of
        `Face.trim_delta` (`trimcheck.DeltaBatch`; the "disagree" note of such a face is then
        added to the diagnostics at that access). Which representation trims the face (IGES 5.3, 4.31-4.32):
          - only one representation on an edge: that one;
          - "pcurve" preferred: the parameter-space curves, unless their loops do not close
            on the surface (then the model-space curves);
          - "model" preferred: the parameter-space curves when they agree with the model-space
            curves within ``AGREE_REL`` x surface size, else the model-space curves (exactly
            inverted, `InvertedCurve`);
          - "equal" / unspecified: the parameter-space curves unless delta exceeds
            ``DISAGREE_REL`` x size; then over 190-198 (exact analytic inversion) the
            model-space curves, over 118/120/122 the parameter-space curves if their loops
            close (the spec fixes that parametrisation; OCC's faces agree).
        Each choice against the file's preference or beyond DISAGREE_REL is noted ("pcurve"
        loops are decided by closure alone, unmeasured: their delta is the face's
        ``trim_delta``, which `cadbridge inspect` and `verify` report)."""
        pm = self.param_map(sde)
        loops = ([outer] if outer is not None else []) + list(inner)
        if not loops:
            if pm.surface is not None:
                return pm.surface, None
            raise Unsupported(f"unbounded {pm.kind} surface without trim loops is not a face", sde,
                              self.entries[sde].entity_type, self.entries[sde].line)
        try:
            res = map_loops(pm, loops, outer is not None, True)
        except ValueError as exc:
            # the parameter-space loops are unusable: the model-space curves, where the file has them
            if not any(m is not None for raw in loops for _, m in raw):
                return self._untrimmed(pm, sde, de, str(exc))
            try:
                res = map_loops(pm, loops, outer is not None, False)
            except ValueError:
                return self._untrimmed(pm, sde, de, str(exc))
            self.note(f"parameter-space curves over the {pm.kind} surface unusable ({exc}): trim derived from the "
                      f"model-space curves", de)
            return res.surface, self._trim_of(loops, res, outer is not None)
        prefs = list(prefs) if prefs is not None else [None] * len(loops)
        pref = "model" if "model" in prefs else ("pcurve" if "pcurve" in prefs else "equal")
        closed = all(res.closed())
        has_both = any(pc is not None and mc is not None for raw in loops for pc, mc in raw)
        pairs = self._mapped_pairs(res, loops)
        box = res.surface.bbox()
        size = max(float(np.linalg.norm(box[1] - box[0])), 1e-300)
        # over 118/120/122 with closed loops and no model preference the parameter-space curves
        # trim the face whatever delta is (see the rule above): delta only decides the note
        fixed_route = pref == "equal" and closed and pm.kind in ("revolution", "ruled", "tabulated")
        delta = None
        arc = None
        if pairs is not None and pm.kind == "revolution":  # the generatrix arc measured from its start?
            from cadbridge.iges.arc_convention import repair_arc_start

            arc = repair_arc_start(pm, loops, outer is not None, res, size, DISAGREE_REL, AGREE_REL)
        if arc is not None:  # re-read (decided on the loop vertices); its delta deferred as below
            res, closed = arc.mapped, True
            pairs = self._mapped_pairs(res, loops)
            e, diags = self.entries[de], self.diagnostics
            diags.append(Diagnostic(arc.note(size), e.line, de, e.entity_type, kind="reread"))
            if pairs is not None:
                self._delta_lazy[de] = (res.surface, pairs, arc.delta_note(
                    size, AGREE_REL, lambda msg, e=e, diags=diags: diags.append(
                        Diagnostic(msg, e.line, e.de, e.entity_type, kind="reread"))))
        elif pairs is not None and pref != "pcurve" and not fixed_route:  # the route depends on delta: measured now
            d = float(loop_deltas([(res.surface, pairs)])[0])
            delta = None if np.isnan(d) else d
        elif pairs is not None:
            note = None
            if fixed_route:  # the disagreement note, on the first `Face.trim_delta` access (no Builder kept)
                kind, e, diags = pm.kind, self.entries[de], self.diagnostics

                def note(d, kind=kind, size=size, e=e, diags=diags):
                    if d > DISAGREE_REL * size:
                        diags.append(Diagnostic(
                            f"parameter-space curves over the {kind} surface disagree with the model-space curves "
                            f"(delta {d:.3g}, {d / size:.3g} x size): the parameter-space loops are used "
                            f"(preferred: equal; noted when delta was computed)", e.line, e.de, e.entity_type))
            self._delta_lazy[de] = (res.surface, pairs, note)
        use_model = False
        if has_both and pref == "pcurve":
            use_model = not closed
            why = "preferred: pcurve, but the parameter-space loops do not close on the surface"
        elif has_both and delta is not None:
            if pref == "model":
                use_model = delta > AGREE_REL * size
                why = "the model-space curves are preferred"
            else:
                use_model = delta > DISAGREE_REL * size and not (
                    pm.kind in ("revolution", "ruled", "tabulated") and closed)
                why = "the model-space inversion is exact"
            if delta > DISAGREE_REL * size and not use_model:
                self.note(f"parameter-space curves over the {pm.kind} surface disagree with the model-space curves "
                          f"(delta {delta:.3g}, {delta / size:.3g} x size): the parameter-space loops are used "
                          f"(preferred: {pref})", de)
        if use_model:
            try:
                res2 = map_loops(pm, loops, outer is not None, False)
            except ValueError as exc:
                return self._untrimmed(pm, sde, de, str(exc))
            if delta is None:
                self.note(f"trim derived from the model-space curves over the {pm.kind} surface ({why})", de)
            else:
                self.note(f"parameter-space curves over the {pm.kind} surface disagree with the model-space curves "
                          f"(delta {delta:.3g}, {delta / size:.3g} x size): trim derived from the model-space curves "
                          f"({why})", de)
            res = res2
        if delta is not None:
            self._delta[de] = delta
        return res.surface, self._trim_of(loops, res, outer is not None)

    @staticmethod
    def _trim_of(loops: list, res: MappedLoops, has_outer: bool) -> Trim:
        """The `Trim` of mapped loops ``res`` (model-space curves kept where every edge has them)."""
        tl = []
        for raw, lp in zip(loops, res.loops):
            mc = [c for _, m in raw for c in m] if all(m is not None for _, m in raw) else None
            tl.append(TrimLoop([c for _, c, _ in lp], mc))
        return Trim(tl[0], tl[1:]) if has_outer else Trim(None, tl)

    def _trimmed_128(self, surface, trims, sde, de, n1, pto, ptis, prefs):
        """144 over a 128 whose 142s prefer the model-space curve: the parameter-space loops
        stay when they agree within AGREE_REL x size, else `mapped_trims` inverts the model
        curves onto the 128 (`InvertedCurve`)."""
        lps = [lp for lp in [trims.outer] + list(trims.inner) if lp is not None and lp.model_curves]
        if not lps:
            return surface, trims
        d = float(loop_deltas([(surface, [(lp.curves, lp.model_curves) for lp in lps])])[0])
        box = surface.bbox()
        if np.isnan(d) or d <= AGREE_REL * float(np.linalg.norm(box[1] - box[0])):
            return surface, trims
        raw_outer = [self.cos_raw(pto)] if n1 == 1 else None
        return self.mapped_trims(sde, raw_outer, [[self.cos_raw(q)] for q in ptis], de, prefs)

    def _untrimmed(self, pm: ParamMap, sde: int, de: int, why: str):
        if pm.surface is not None:
            self.note(f"trim loops unusable ({why}): face left untrimmed", de)
            return pm.surface, None
        raise Unsupported(f"{pm.kind} surface needs its trim loops for its extent: {why}", de, None, None)

    @staticmethod
    def _mapped_pairs(res: MappedLoops, loops: list) -> list[tuple] | None:
        """What the trim delta of the parameter-space route ``res`` compares: per loop, the
        pieces of edges with both representations against those edges' model-space curves
        (None if no edge has both)."""
        pairs = []
        for raw, lp, src in zip(loops, res.loops, res.sources):
            ok = [j for j, (pc, mc) in enumerate(raw) if src[j] == "pcurve" and mc is not None]
            if ok:
                pairs.append(([c for i, c, _ in lp if i in ok], [c for j in ok for c in raw[j][1]]))
        return pairs or None

    def brep_loop(self, de: int, surface: NurbsSurface | None = None) -> TrimLoop | None:
        """508 loop as parameter-space curves; where an edge has none and the face's NURBS
        ``surface`` (a 128) is given, the loop built from the model-space curves of its edges
        (`_model_loop`); else None, with a note."""
        edges = self.loop_raw(de, want_model=False)
        if edges and all(pc is not None for pc, _ in edges):
            return TrimLoop([c for pc, _ in edges for c in pc])
        if edges and surface is not None:
            loop = self._model_loop(de, surface)
            if loop is not None:
                return loop
        self.note("B-rep loop without parameter-space curves: face left untrimmed", de)
        return None

    def _model_loop(self, de: int, surface: NurbsSurface) -> TrimLoop | None:
        """508 loop ``de`` over the NURBS ``surface`` from the model-space curves of its 504
        edges (in loop order, each reversed where OF = 0: `loop_raw`), inverted onto the
        surface by Newton (`analytic.invert_edges`: seams unwrapped along the loop, poles
        bridged). Its trim delta (largest distance of S(uv(t)) from the edges) is the face's
        deferred ``trim_delta`` (`trimcheck.DeltaBatch`, computed on first access; the loop
        keeps its edges as ``model_curves``). None (with a note) when an edge has no usable
        model-space curve or the result does not close in (u, v)."""
        edges = self.loop_raw(de, want_model=True)
        pieces = [c for _, m in edges if m for c in m]
        skipped = sum(1 for _, m in edges if not m)
        if not pieces:
            self.note("B-rep loop without parameter-space curves and without usable model-space curves", de)
            return None
        # an edge without a usable model-space curve (a 126 with V0 = V1: a point edge) is
        # dropped; its neighbours must then join in model space (`invert_edges` checks)
        try:
            curves = invert_edges(surface, pieces)
        except ValueError as exc:
            self.note(f"B-rep loop without parameter-space curves: model-space edges not invertible ({exc})", de)
            return None
        u0, u1, v0, v1 = surface.domain
        # ends of the loop: an inverted piece's reference table holds the feet of its end
        # points (what its evaluation converges to from there); a bridge line is evaluated
        a = curves[0].nat_ref[0] if hasattr(curves[0], "nat_ref") else curves[0].evaluate([curves[0].domain[0]])[0]
        b = curves[-1].nat_ref[-1] if hasattr(curves[-1], "nat_ref") else curves[-1].evaluate([curves[-1].domain[1]])[0]
        gap = float(np.linalg.norm(a - b))
        if not gap <= 1e-6 * np.hypot(u1 - u0, v1 - v0):
            self.note(f"B-rep loop without parameter-space curves: its model-space edges do not close on the "
                      f"surface ((u, v) gap {gap:.3g})", de)
            return None
        pts = f" ({skipped} point edges dropped)" if skipped else ""
        # delta (S(uv(t)) against the edges) decides nothing here: deferred with the face's
        # other loops to the first `Face.trim_delta` access (`face`, `trimcheck.DeltaBatch`)
        self.note(f"B-rep loop without parameter-space curves: trim loop built from its {len(edges) - skipped} "
                  f"model-space edges{pts} inverted onto the B-spline surface (its delta: the face's trim_delta)",
                  de)
        return TrimLoop(curves, pieces)

    def loop_raw(self, de: int, want_model: bool = True):
        """508 loop: N, then per edge TYPE, EDGE, NDX, OF, K, K x (ISOP, CURV) -> list of
        (parameter-space pieces of the first CURV or None, model-space pieces of the 504
        edge or None, reversed where OF = 0)."""
        p = self.params(de)
        n = p.int(1, "N")
        if n < 0:
            raise p.error(f"N = {n} is negative", 1, "N")
        k = 2
        edges = []
        for j in range(n):
            p.require(k + 4, "N")
            typ = p.int(k, f"TYPE({j + 1})")
            edge = p.pointer(k + 1, f"EDGE({j + 1})", allow_zero=False)
            ndx = p.int(k + 2, f"NDX({j + 1})")
            of = p.int(k + 3, f"OF({j + 1})")
            kk = p.int(k + 4, f"K({j + 1})")
            if kk < 0:
                raise p.error(f"K = {kk} is negative", k + 4, f"K({j + 1})")
            p.require(k + 4 + 2 * kk, f"K({j + 1})")
            part = None
            if kk > 0:
                ptr = p.pointer(k + 6, f"CURV({j + 1},1)", allow_zero=False)
                self.entry(ptr, p, k + 6, f"CURV({j + 1},1)")
                try:
                    part = [to_2d(c) for c in self.curve_pieces(ptr)]
                except Unsupported as u:
                    self.note(f"parameter-space curve not usable ({u})", de)
            model = None
            ee = self.entry(edge, p, k + 1, f"EDGE({j + 1})")
            if typ == 0 and ee.entity_type == 504 and want_model:
                try:
                    with self.visiting(edge, "edge"):
                        model = self.edge_curve(edge, ndx, p, k + 2)
                except (Unsupported, IgesError) as exc:
                    # model-space edges only stand in for missing / inconsistent pcurves: a
                    # degenerate one (e.g. a 126 with V0 = V1 at a pole) is noted, not fatal
                    self.note(f"model-space curve of edge {j + 1} not usable: {exc}", de)
                    self._failed_at = None
                    model = None
            if of == 0:
                # OF relates the edge to its model-space curve only: the parameter-space curves
                # are written in loop order already (OCC's B-rep files: they join end to start
                # as given, and reversing them per OF breaks the chain)
                model = None if model is None else [reverse_curve(c) for c in reversed(model)]
            edges.append((part, model))
            k += 5 + 2 * kk
        self._own_end[de] = k
        return edges

    def _model_curve(self, crv: int, de: int) -> list[NurbsCurve] | None:
        try:
            return list(self.curve_pieces(crv))
        except (Unsupported, IgesError) as exc:
            self.note(f"model-space curve DE {crv} not usable: {exc}", de)
            self._failed_at = None
            return None

    def edge_curve(self, de: int, ndx: int, src: Params, k: int) -> list[NurbsCurve]:
        """Model-space curve of edge NDX (1-based) of the 504 edge list ``de``: N, then
        N x (CURV, SVP, SV, TVP, TV)."""
        p = self.params(de)
        n = p.int(1, "N")
        if not 1 <= ndx <= n:
            raise src.error(f"edge index {ndx} outside 1..{n} of edge list DE {de}", k, "NDX")
        p.require(1 + 5 * n, "N")
        self._own_end[de] = 2 + 5 * n
        k0 = 2 + 5 * (ndx - 1)
        c = p.pointer(k0, f"CURV({ndx})", allow_zero=False)
        ce = self.entry(c, p, k0, f"CURV({ndx})")
        try:
            return list(self.curve_pieces(c))
        except IgesError:
            done = self._cache.get(("edge-whole", de, ndx))
            if done is not None:
                self._failed_at = None
                return list(done)
            ends = self._edge_vertices(p, k0) if ce.entity_type == 126 else None
            if ends is None:
                raise
            # a 126 edge curve with V0 = V1 (SolidEdge writes 0, 0 on knots [-1, 0]): its whole
            # knot range, if that runs between the edge's start and terminate vertices (either
            # way: then oriented from start to terminate); else (e.g. a point edge at a pole)
            # the curve stays unusable
            self._failed_at = None
            pieces = self._cached(("curve-whole", c), lambda: [apply_curve(
                q, self.transform(c)) for q in self.bspline_curve(self.params(c), whole_if_empty=True)])
            a = pieces[0].evaluate([pieces[0].domain[0]])[0]
            b = pieces[-1].evaluate([pieces[-1].domain[1]])[0]
            fwd = max(np.linalg.norm(a - ends[0]), np.linalg.norm(b - ends[1]))
            rev = max(np.linalg.norm(a - ends[1]), np.linalg.norm(b - ends[0]))
            span = max(float(np.ptp(np.vstack([q.control_points for q in pieces]), axis=0).max()), 1e-300)
            if not min(fwd, rev) <= VERTEX_REL * span or not np.linalg.norm(ends[1] - ends[0]) > VERTEX_REL * span:
                raise
            if rev < fwd:
                self.note(f"edge curve DE {c} runs from the terminate to the start vertex of edge {ndx}: reversed", de)
                pieces = [reverse_curve(q) for q in reversed(pieces)]
            self._cache[("edge-whole", de, ndx)] = pieces
            return list(pieces)

    def _edge_vertices(self, p: Params, k0: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(start, terminate) vertex of the 504 edge whose CURV is field k0 of ``p`` (SVP, SV,
        TVP, TV follow it; a 502 vertex list: N, then N x (X, Y, Z)), None if unreadable."""
        out = []
        try:
            for j in (1, 3):
                vl, ix = p.pointer(k0 + j, "SVP" if j == 1 else "TVP"), p.int(k0 + j + 1, "SV" if j == 1 else "TV")
                e = self.entries.get(vl)
                if e is None or e.entity_type != 502:
                    return None
                q = self.params(vl)
                if not 1 <= ix <= q.int(1, "N"):
                    return None
                x = q.reals(2 + 3 * (ix - 1), 3, "X,Y,Z")
                xf = self.transform(vl)
                out.append(x if _is_identity(xf) else xf[0] @ x + xf[1])
        except IgesError:
            return None
        return out[0], out[1]

    def shell_faces(self, de: int) -> list[int]:
        """DEs of the 510 faces of a 514 shell (N, then N x (FACE, OF))."""
        p = self.params(de)
        n = p.int(1, "N")
        if n < 0:
            raise p.error(f"N = {n} is negative", 1, "N")
        p.require(1 + 2 * n, "N")
        out = []
        for j in range(n):
            f = p.pointer(2 + 2 * j, f"FACE({j + 1})", allow_zero=False)
            self.entry(f, p, 2 + 2 * j, f"FACE({j + 1})", types=(510,))
            out.append(f)
        self._own_end[de] = 2 + 2 * n
        return out

    def msbo_shells(self, de: int) -> list[int]:
        """DEs of the 514 shells of a 186 solid (SHELL, SOF, N, N x (VOID, VOF))."""
        p = self.params(de)
        shell = p.pointer(1, "SHELL", allow_zero=False)
        self.entry(shell, p, 1, "SHELL", types=(514,))
        n = p.int(3, "N", 0)
        if n < 0:
            raise p.error(f"N = {n} is negative", 3, "N")
        p.require(3 + 2 * n, "N")
        out = [shell]
        for j in range(n):
            v = p.pointer(4 + 2 * j, f"VOID({j + 1})", allow_zero=False)
            self.entry(v, p, 4 + 2 * j, f"VOID({j + 1})", types=(514,))
            out.append(v)
        self._own_end[de] = 4 + 2 * n
        return out

    # ------------------------------------------------------------------ attributes
    def properties(self, de: int) -> list[int]:
        """Property pointers from the trailing NV/NP fields after the entity's own fields."""
        k = self._own_end.get(de)
        p = self._params.get(de)
        if k is None or p is None or k >= len(p.tokens):
            return []
        try:
            nv = p.int(k, "NV", 0)
            if nv < 0 or k + 1 + nv >= len(p.tokens):
                return []
            npr = p.int(k + 1 + nv, "NP", 0)
            if npr <= 0 or k + 1 + nv + npr >= len(p.tokens):
                return []
            return [abs(p.int(k + 2 + nv + j, "property", 0)) for j in range(npr)]
        except IgesError:
            return []

    def name(self, *des: int) -> str | None:
        """Name from a 406 form 15 property of the first of ``des`` that has one, else the
        first entity's DE label (with its subscript)."""
        for de in des:
            for ptr in self.properties(de):
                e = self.entries.get(ptr)
                if e is not None and e.entity_type == 406 and e.form == 15:
                    try:
                        q = self.params(ptr)
                        s = q.string(2, "NAME", "")
                    except IgesError:
                        continue
                    if s:
                        return s
        e = self.entries[des[0]]
        if e.label:
            return e.label if e.subscript == 0 else f"{e.label}({e.subscript})"
        return None

    def color(self, *des: int) -> tuple[float, float, float] | None:
        """RGB in 0..1 from the DE colour field of the first of ``des`` that has one."""
        for de in des:
            c = self.entries[de].color
            if c > 0:
                return STANDARD_COLORS.get(c)
            if c < 0:
                e = self.entries.get(-c)
                if e is None or e.entity_type != 314:
                    self.note(f"colour pointer {-c} is not a 314 colour definition: ignored", de)
                    return None
                try:
                    rgb = self.params(-c).reals(1, 3, "CC1..CC3")
                except IgesError as err:
                    self.note(f"colour definition unreadable: {err.message}", -c)
                    return None
                return tuple(float(x) for x in np.clip(rgb / 100.0, 0.0, 1.0))
        return None
