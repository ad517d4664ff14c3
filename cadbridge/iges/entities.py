"""Entity construction: from directory entries and parameter lists to exact NURBS geometry.

`Builder` resolves pointers lazily (each entity parsed once, cached), applies the
transformation matrices (124) of each entity, and turns surfaces, trimmed/bounded surfaces,
B-rep faces and subfigure instances into `Face` objects. Field numbers in comments are the
1-based numbers of the IGES 5.3 specification; ``p.int(k, ...)`` reads field k.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from cadbridge.iges.directory import DirectoryEntry
from cadbridge.iges.errors import IgesError
from cadbridge.iges.lexer import Record
from cadbridge.iges.parameters import Params, read_params
from cadbridge.model import Diagnostic, Face, Trim, TrimLoop
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["Builder", "Unsupported", "SURFACE_TYPES", "FACE_TYPES", "INTERPRETED_TYPES"]

SURFACE_TYPES = (128, 108, 118, 120, 122)
FACE_TYPES = SURFACE_TYPES + (143, 144)
CURVE_TYPES = (100, 102, 104, 106, 110, 126)
INTERPRETED_TYPES = frozenset(
    FACE_TYPES + CURVE_TYPES + (124, 141, 142, 186, 308, 314, 406, 408, 502, 504, 508, 510, 514, 0)
)
MAX_DEPTH = 64  # pointer nesting guard (no unbounded recursion on cyclic or deep files)
DOMAIN_REL_TOL = 1e-6  # U0..V1 this close outside the knot range are clamped (with a note)

# IGES standard colours (DE field 13 values 1..8) as RGB in 0..1
STANDARD_COLORS = {1: (0.0, 0.0, 0.0), 2: (1.0, 0.0, 0.0), 3: (0.0, 1.0, 0.0), 4: (0.0, 0.0, 1.0),
                   5: (1.0, 1.0, 0.0), 6: (1.0, 0.0, 1.0), 7: (0.0, 1.0, 1.0), 8: (1.0, 1.0, 1.0)}

Affine = tuple[np.ndarray, np.ndarray]  # (R (3, 3), t (3,)) for x -> R x + t


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
    return NurbsCurve(c.degree, c.knots, c.control_points[:, :2], c.weights, c.domain)


def _is_identity(a: Affine | None) -> bool:
    return a is None or (np.array_equal(a[0], np.eye(3)) and not np.any(a[1]))


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
    if _is_identity(a):
        return c
    if c.dim == 2:
        cp = np.column_stack([c.control_points, np.zeros(len(c.control_points))])
        c = NurbsCurve(c.degree, c.knots, cp, c.weights, c.domain)
    return c.transformed(a[0], a[1])


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
        self._params: dict[int, Params] = {}
        self._cache: dict[tuple, object] = {}
        self._own_end: dict[int, int] = {}  # DE -> index of the first trailing (NV/NP) field
        self._active: list[int] = []  # entities under construction (cycle guard, error location)
        self._keys: list[tuple[str, int]] = []
        self._failed_at: tuple | None = None  # (DE, line, type) where an exception first passed

    # ------------------------------------------------------------------ infrastructure
    def note(self, message: str, de: int | None = None, line: int | None = None) -> None:
        e = self.entries.get(de) if de is not None else None
        self.diagnostics.append(Diagnostic(message, line if line is not None else (e.line if e else None), de,
                                           e.entity_type if e else None))

    def params(self, de: int) -> Params:
        p = self._params.get(de)
        if p is None:
            p = read_params(self.entries[de], self.precs, self.pdelim, self.rdelim, self.filename)
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
        try:
            yield
        except Exception:
            if self._failed_at is None:
                self._failed_at = self.current_location()
            raise
        finally:
            self._active.pop()
            self._keys.pop()

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
        if key not in self._cache:
            with self.visiting(key[1], key[0]):
                self._cache[key] = make()
        return self._cache[key]

    # ------------------------------------------------------------------ 124 transformations
    def matrix(self, de: int) -> Affine:
        """The 124 at ``de`` alone: R (3, 3) and T (3,) from fields 1-12 (rows R1j, T1, ...)."""
        p = self.params(de)
        if p.entry.form not in (0, 1, 10, 11, 12):
            self.note(f"transformation matrix form {p.entry.form} is not 0, 1, 10, 11 or 12; used as given", de)
        v = p.reals(1, 12, "R11..T3")
        m = v.reshape(3, 4)
        self._own_end[de] = 13
        return m[:, :3].copy(), m[:, 3].copy()

    def transform(self, de: int) -> Affine | None:
        """The full transformation of entity ``de`` (its DE field 7 and the 124 chain behind
        it: a 124 that points to another 124 is applied first, the pointed-to one after)."""
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
            total = compose(self.matrix(t), total)
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
            pieces = [self.bspline_curve(p)]
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
            if np.array_equal(v[:3], v[3:]):
                raise p.error("line with coincident end points", 1, "X1")
            try:
                pieces = [_construct().line(v[:3], v[3:])]
            except ValueError as exc:
                raise self._wrap(p, exc) from None
        elif t == 100:
            v = p.reals(1, 7, "ZT..Y3")
            self._own_end[de] = 8
            zt = v[0]
            try:
                pieces = [_construct().circular_arc((v[1], v[2], zt), (v[3], v[4], zt), (v[5], v[6], zt),
                                                     normal=(0.0, 0.0, 1.0))]
            except ValueError as exc:
                raise self._wrap(p, exc) from None
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
        else:
            raise Unsupported(f"curve entity {t} is not supported", de, t, e.line)
        xf = self.transform(de)
        return [apply_curve(c, xf) for c in pieces]

    def curve(self, de: int) -> NurbsCurve:
        """Curve entity ``de`` as one NURBS curve (composites joined by construct)."""
        pieces = self.curve_pieces(de)
        if len(pieces) == 1:
            return pieces[0]
        try:
            return _construct().composite_curve(pieces)
        except ValueError as exc:
            raise self._wrap(self.params(de), exc) from None

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

    def bspline_curve(self, p: Params) -> NurbsCurve:
        """126: K, M, PROP1-4, knots T(-M..N+M), weights W(0..K), points (K+1)x3, V0, V1."""
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
        bad = np.flatnonzero(~(w > 0))
        if bad.size:
            j = int(bad[0])
            raise p.error(f"weight {w[j]!r} is not positive", w0 + j, f"W({j})")
        cp = p.reals(c0, 3 * (k + 1), "X,Y,Z").reshape(k + 1, 3)
        a, b = p.real(v0, "V0"), p.real(v0 + 1, "V1")
        self._own_end[p.de] = v0 + 2 + (3 if p.has(v0 + 4) else 0)
        lo, hi = knots[m], knots[k + 1]
        a, b = self._clamp_range(p, a, b, lo, hi, v0, "V0", "V1")
        try:
            return NurbsCurve(m, knots, cp, w, (a, b))
        except ValueError as exc:
            raise p.error(str(exc), t0, "T") from None

    def _check_knots(self, p: Params, knots: np.ndarray, start: int, m: int, name: str) -> None:
        d = np.diff(knots)
        bad = np.flatnonzero(~(d >= 0))
        if bad.size:
            j = int(bad[0]) + 1
            raise p.error(f"knots decrease: {knots[j - 1]!r} then {knots[j]!r}", start + j, f"{name}({j - m})")

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
        bad = np.flatnonzero(~(w > 0))
        if bad.size:
            j = int(bad[0])
            raise p.error(f"weight {w[j]!r} is not positive", w0 + j, f"W({j % (k1 + 1)},{j // (k1 + 1)})")
        xyz = p.reals(x0, 3 * c, "X,Y,Z")
        # IGES order: first index (u) fastest -> reshape (v, u), then transpose to [i along u, j along v]
        cp = xyz.reshape(k2 + 1, k1 + 1, 3).transpose(1, 0, 2)
        w = w.reshape(k2 + 1, k1 + 1).T
        u_a, u_b = self._clamp_range(p, p.real(r0, "U0"), p.real(r0 + 1, "U1"), su[m1], su[k1 + 1], r0, "U0", "U1")
        v_a, v_b = self._clamp_range(p, p.real(r0 + 2, "V0"), p.real(r0 + 3, "V1"), tv[m2], tv[k2 + 1], r0 + 2,
                                     "V0", "V1")
        self._own_end[p.de] = r0 + 4
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
            gen = self.curve(cde)
            try:
                s = _construct().revolved_surface(gen, a, b - a, sa, ta)
            except ValueError as exc:
                raise self._wrap(p, exc, "SA") from None
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
        p = self.params(de)
        sptr = p.pointer(2, "SPTR")
        bptr = p.pointer(3, "BPTR")
        cptr = p.pointer(4, "CPTR")
        p.int(5, "PREF", 0)
        self._own_end[de] = 6
        if sptr:
            self.entry(sptr, p, 2, "SPTR")
        if bptr == 0:
            self.note("curve on surface without a parameter-space curve (model space only): face left untrimmed", de)
            return None
        self.entry(bptr, p, 3, "BPTR")
        try:
            pieces = [to_2d(c) for c in self.curve_pieces(bptr)]
        except Unsupported as u:
            self.note(f"parameter-space curve not usable ({u}): face left untrimmed", de)
            return None
        model = None
        if cptr:
            self.entry(cptr, p, 4, "CPTR")
            try:
                model = self.curve_pieces(cptr)
            except Unsupported:
                model = None
        return TrimLoop(pieces, model)

    def boundary(self, de: int) -> TrimLoop | None:
        """141: TYPE, PREF, SPTR, N, then N x (CRVPT, SENSE, K, PSCPT(1..K))."""
        p = self.params(de)
        typ = p.int(1, "TYPE")
        n = p.int(4, "N")
        if n < 0:
            raise p.error(f"negative number of curves {n}", 4, "N")
        if typ == 0:
            self.note("boundary in model space only (TYPE 0): face left untrimmed", de)
            return None
        k = 5
        pieces: list[NurbsCurve] = []
        for j in range(n):
            p.require(k + 2, "N")
            sense = p.int(k + 1, f"SENSE({j + 1})")
            kk = p.int(k + 2, f"K({j + 1})")
            if kk < 0:
                raise p.error(f"negative count {kk}", k + 2, f"K({j + 1})")
            p.require(k + 2 + kk, f"K({j + 1})")
            part: list[NurbsCurve] = []
            for i in range(kk):
                ptr = p.pointer(k + 3 + i, f"PSCPT({j + 1},{i + 1})", allow_zero=False)
                self.entry(ptr, p, k + 3 + i, f"PSCPT({j + 1},{i + 1})")
                try:
                    part.extend(to_2d(c) for c in self.curve_pieces(ptr))
                except Unsupported as u:
                    self.note(f"parameter-space curve not usable ({u}): face left untrimmed", de)
                    return None
            if kk == 0:
                self.note("boundary curve without parameter-space curves: face left untrimmed", de)
                return None
            if sense == 2:
                part = [reverse_curve(c) for c in reversed(part)]
            pieces.extend(part)
            k += 3 + kk
        self._own_end[de] = k
        return TrimLoop(pieces) if pieces else None

    # ------------------------------------------------------------------ faces
    def face(self, de: int, placement: Affine | None = None) -> Face | None:
        """Face for a top-level surface entity (128, 108, 118, 120, 122, 143, 144, 510), or
        None with a diagnostic when it cannot be represented. ``placement`` (from 408
        instances) is applied after the entity's own transformation."""
        e = self.entries[de]
        try:
            with self.visiting(de):
                face = self._face(de)
        except Unsupported as u:
            self.diagnostics.append(Diagnostic(f"face skipped: {u}", u.line if u.line else e.line,
                                               u.de if u.de else de, u.etype if u.etype else e.entity_type))
            return None
        if face is None:
            return None
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
            trims = self._trims_for(trims, se, de)
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
            surface, _ = self.surface(sde)
            loops = []
            for j, b in enumerate(bdpts):
                self.entry(b, p, 4 + j, f"BDPT({j + 1})", types=(141,))
                with self.visiting(b):
                    loops.append(self.boundary(b))
            if loops and all(l is not None for l in loops):
                trims = Trim(loops[0], loops[1:])  # the first boundary is the outer one
            trims = self._trims_for(trims, se, de)
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
            surface, _ = self.surface(sde)
            loops = []
            for j, lp in enumerate(lps):
                self.entry(lp, p, 4 + j, f"LOOP({j + 1})", types=(508,))
                with self.visiting(lp):
                    loops.append(self.brep_loop(lp))
            if loops and all(l is not None for l in loops):
                trims = Trim(loops[0], loops[1:]) if of == 1 else Trim(None, loops)
            trims = self._trims_for(trims, se, de)
            surface = apply_surface(surface, self.transform(de))
            t_s = se.entity_type
        else:
            raise Unsupported(f"entity {t} is not a face", de, t, e.line)
        if t not in (144, 143, 510):
            t_s = t
        return Face(surface=surface, de=de, name=self.name(de, sde), color=self.color(de, sde),
                    level=max(e.level, 0), trims=trims, entity_type=t, surface_de=sde, surface_type=t_s)

    def _trims_for(self, trims: Trim | None, surface_entry: DirectoryEntry, de: int) -> Trim | None:
        """Trims apply as given only over a 128 (same (u, v) as the NURBS). Over analytic
        surfaces (108, 118, 120, 122) IGES trim curves live in that entity's own
        parametrisation, which the exact NURBS does not share: the face is left untrimmed."""
        if trims is None or surface_entry.entity_type == 128:
            return trims
        self.note(f"trim curves over a {surface_entry.entity_type} surface are in its IGES parametrisation, "
                  "not the NURBS one: face left untrimmed", de)
        return None

    def brep_loop(self, de: int) -> TrimLoop | None:
        """508 loop: N, then per edge TYPE, EDGE, NDX, OF, K, K x (ISOP, CURV). The loop's
        parameter-space curves (first of each edge, reversed where OF = 0)."""
        p = self.params(de)
        n = p.int(1, "N")
        if n < 0:
            raise p.error(f"N = {n} is negative", 1, "N")
        k = 2
        pieces: list[NurbsCurve] = []
        ok = True
        for j in range(n):
            p.require(k + 4, "N")
            of = p.int(k + 3, f"OF({j + 1})")
            kk = p.int(k + 4, f"K({j + 1})")
            if kk < 0:
                raise p.error(f"K = {kk} is negative", k + 4, f"K({j + 1})")
            p.require(k + 4 + 2 * kk, f"K({j + 1})")
            if kk == 0:
                ok = False
            elif ok:
                ptr = p.pointer(k + 6, f"CURV({j + 1},1)", allow_zero=False)
                self.entry(ptr, p, k + 6, f"CURV({j + 1},1)")
                try:
                    part = [to_2d(c) for c in self.curve_pieces(ptr)]
                except Unsupported as u:
                    self.note(f"parameter-space curve not usable ({u})", de)
                    ok = False
                    part = []
                if of == 0:
                    part = [reverse_curve(c) for c in reversed(part)]
                pieces.extend(part)
            k += 5 + 2 * kk
        self._own_end[de] = k
        if not ok or not pieces:
            self.note("B-rep loop without parameter-space curves: face left untrimmed", de)
            return None
        return TrimLoop(pieces)

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
