"""The CAD model that flows out of the IGES reader: faces (exact NURBS + trims), units, notes.

Everything here is plain data: numpy arrays inside `NurbsSurface` / `NurbsCurve`, small
dataclasses around them. No OCC objects, no global state.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["Diagnostic", "EmptyModelError", "Face", "Model", "TrimLoop", "Trim", "Units", "distance_to_polygon", "points_in_polygon"]


@dataclass(frozen=True)
class Diagnostic:
    """A reader warning: where it was found and what it says."""

    message: str
    line: int | None = None  # 1-based line number in the file
    de: int | None = None  # directory entry sequence number (odd, 1-based)
    entity_type: int | None = None
    kind: str | None = None  # "reread": the face was read otherwise than the file says (see `mesh_source`)

    def __str__(self) -> str:
        where = []
        if self.line is not None:
            where.append(f"line {self.line}")
        if self.de is not None:
            where.append(f"DE {self.de}")
        if self.entity_type is not None:
            where.append(f"entity {self.entity_type}")
        return (", ".join(where) + ": " if where else "") + self.message


@dataclass(frozen=True)
class Units:
    """Model units from the IGES Global section (fields 14-15).

    ``flag`` is the IGES units flag (1 inch, 2 mm, ... 6 m, ...), ``name`` its name and
    ``to_mm`` the factor that converts one model unit to millimetres.
    """

    flag: int = 2
    name: str = "MM"
    to_mm: float = 1.0


@dataclass
class TrimLoop:
    """One closed boundary loop in the (u, v) parameter space of a face.

    ``curves`` are 2D `NurbsCurve` pieces (control points (n, 2) in (u, v)), joined end to
    start in order. ``model_curves`` optionally keeps the 3D model-space counterparts.
    """

    curves: list[NurbsCurve]
    model_curves: list[NurbsCurve] | None = None

    def polygon(self, samples_per_span: int = 16) -> np.ndarray:
        """Polyline through the loop, (M, 2) in (u, v); first point not repeated at the end."""
        pieces = []
        for c in self.curves:
            if isinstance(c, NurbsCurve) and c.degree == 1 and tuple(c.domain) == (c.knots[1], c.knots[-2]):
                pts = c.control_points[:, :2]  # a polyline is its own polygon
            else:
                pts = c.evaluate(c.sample_parameters(samples_per_span))[:, :2]
            pieces.append(pts[:-1])  # the last point is the next curve's first
        if not pieces:
            return np.zeros((0, 2))
        return np.concatenate(pieces, axis=0)

    @cached_property
    def boundary(self):
        """The loop's `cadbridge.cad.trims.LoopBoundary`: polygon with chord bounds and the grid
        index of its edges, built once (the curves are not to change afterwards)."""
        from cadbridge.cad.trims import LoopBoundary  # lazy: data flows model -> trims

        return LoopBoundary(self.curves)


@dataclass
class Trim:
    """Trimming of a face (IGES 144 / 143): an outer loop and holes.

    ``outer`` None means the outer boundary is the boundary of the surface domain.
    """

    outer: TrimLoop | None
    inner: list[TrimLoop] = field(default_factory=list)

    def contains(self, u: np.ndarray, v: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """Whether each (u, v) (N,) lies in the closed trimmed region, decided on the exact
        trim curves (`cadbridge.cad.trims`): inside or on the outer loop and not strictly inside
        a hole; a point within ``tol`` (parameter units) of a loop's exact curve is on it,
        i.e. inside, so a mesh node on a trim edge belongs to the faces on both sides. (N,) bool.
        """
        from cadbridge.cad.trims import trim_contains  # lazy: data flows model -> trims

        return trim_contains(self, u, v, tol)


def points_in_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd test of (N, 2) points against a closed (M, 2) polygon through a grid index of
    its edges (`cadbridge.cad.trims.polygon_contains`). Returns (N,) bool."""
    from cadbridge.cad.trims import polygon_contains

    return polygon_contains(points, polygon)


def distance_to_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Distance of (N, 2) points to the closed polyline (M, 2), (N,), through a KD-tree of
    edge midpoints (`cadbridge.cad.trims.polygon_distance`)."""
    from cadbridge.cad.trims import polygon_distance

    return polygon_distance(points, polygon)


class _DeferredDelta:
    """Descriptor behind `Face.trim_delta`: a plain attribute (set, read, constructor argument)
    that the reader may instead point at a shared batch (`Face.defer_trim_delta`); the first
    read of any face of that batch computes all of them in one pass (`iges.trimcheck`)."""

    def __get__(self, obj, owner=None):
        if obj is None:
            return None  # the dataclass default
        d = obj.__dict__
        src = d.pop("_delta_source", None)
        if src is not None:
            d["_trim_delta"] = src[0].value(src[1])
        return d.get("_trim_delta")

    def __set__(self, obj, value) -> None:
        obj.__dict__.pop("_delta_source", None)
        obj.__dict__["_trim_delta"] = None if value is None else float(value)


@dataclass
class Face:
    """One face of the model: an exact NURBS surface in model coordinates (after transforms).

    ``de`` is the directory entry number of the entity the face came from (the 144/143/128/...
    at the top level), ``surface_de`` that of the underlying surface entity.

    ``trim_delta`` is the file's trim tolerance of the face, max |S(c2d(t)) - C3d| in model
    units (`iges.trimcheck`), None without both trim representations. The IGES reader computes
    it at read time only for faces whose trim route depends on it (PREF = model / unspecified
    over analytic surfaces); for all other faces it is computed on the first access of any
    face's ``trim_delta`` -- for all faces of that read in one pass, from their surfaces and
    trim curves as they are at that moment.
    """

    surface: NurbsSurface
    de: int
    name: str | None = None
    color: tuple[float, float, float] | None = None  # RGB in 0..1
    level: int = 0
    trims: Trim | None = None
    entity_type: int = 128  # IGES type of the top-level entity (128, 144, 143, 108, 118, 120, 122)
    surface_de: int | None = None
    surface_type: int = 128  # IGES type of the underlying surface entity
    trim_delta: float | None = _DeferredDelta()  # see the class docstring

    def defer_trim_delta(self, batch, index: int) -> None:
        """Let ``batch.value(index)`` supply ``trim_delta`` on its first access (one pass for all)."""
        self.__dict__["_delta_source"] = (batch, index)

    def contains(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Whether (u, v) (arrays (N,)) lie inside the face: in the domain and inside the trims."""
        u = np.asarray(u, dtype=float)
        v = np.asarray(v, dtype=float)
        u0, u1, v0, v1 = self.surface.domain
        tol_u = 1e-12 * max(1.0, abs(u1 - u0))
        tol_v = 1e-12 * max(1.0, abs(v1 - v0))
        ok = (u >= u0 - tol_u) & (u <= u1 + tol_u) & (v >= v0 - tol_v) & (v <= v1 + tol_v)
        if self.trims is not None and np.any(ok):
            ok[ok] = self.trims.contains(u[ok], v[ok], tol=1e-9 * max(u1 - u0, v1 - v0))
        return ok


class EmptyModelError(ValueError):
    """A model without faces where surfaces are needed (a wireframe drawing, curves or points
    only): the input holds nothing to mesh or project onto (exit code 2 in the CLI)."""


_BBOX_KEY = "_cadbridge_bbox"  # Model.bbox's cache in the model's __dict__ (as `cadbridge.cad.search.index_for`)


@dataclass
class Model:
    """What `read_iges` returns.

    faces          list[Face], in directory order of the top-level faces
    units          `Units`
    resolution     minimum user-intended resolution (Global field 19), model units
    entity_counts  {entity type: count} over all directory entries
    raw            {DE number: (entity type, form, parameter list)} for entities not interpreted
    diagnostics    reader warnings with line numbers
    source         name of the file read
    """

    faces: list[Face] = field(default_factory=list)
    units: Units = field(default_factory=Units)
    resolution: float | None = None
    filename: str | None = None
    author: str | None = None
    organization: str | None = None
    system: str | None = None
    preprocessor: str | None = None
    product_id: str | None = None
    global_params: list = field(default_factory=list)
    entity_counts: dict[int, int] = field(default_factory=dict)
    raw: dict[int, tuple] = field(default_factory=dict)
    diagnostics: list[Diagnostic] = field(default_factory=list)
    source: str | None = None  # name of the file read (``filename`` is the one its header states)

    def empty_reason(self) -> str:
        """One line saying that the file holds no surface and what it holds instead, or, when
        its faces were all skipped (unsupported), why."""
        src = self.source or self.filename or "model"
        skipped = [d for d in self.diagnostics if d.message.startswith("face skipped: ")]
        if skipped:
            why = list(dict.fromkeys(f"DE {d.de}: {d.message[len('face skipped: '):]}" for d in skipped))
            return (f"{src}: none of its {len(skipped)} faces can be read ({'; '.join(why[:2])}"
                    f"{' ...' if len(why) > 2 else ''})")
        held = ", ".join(f"{n} x {t}" for t, n in sorted(self.entity_counts.items())[:8]) or "no entities"
        more = " ..." if len(self.entity_counts) > 8 else ""
        return f"{src}: no surfaces in this file, nothing to convert (entity types: {held}{more})"

    def bbox(self) -> np.ndarray:
        """Axis-aligned box of all faces, (2, 3): [min, max] (from the control nets)."""
        if not self.faces:
            raise EmptyModelError(self.empty_reason())
        # cached on the model for the same surfaces and control nets (held, compared by
        # identity): `size` is asked ~200 times per convert of the production die, 13 ms each
        # over its 1 102 faces (2.6 s of CPU) without it
        key = tuple((f.surface, f.surface.control_points) for f in self.faces)
        hit = self.__dict__.get(_BBOX_KEY)
        if hit is not None and len(hit[0]) == len(key) and all(
                a[0] is b[0] and a[1] is b[1] for a, b in zip(hit[0], key)):
            return hit[1].copy()
        boxes = np.array([f.surface.bbox() for f in self.faces])
        box = np.array([boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)])
        self.__dict__[_BBOX_KEY] = (key, box)
        return box.copy()

    def size(self) -> float:
        """Diagonal of the bounding box (model units); the length scale for tolerances."""
        b = self.bbox()
        return float(np.linalg.norm(b[1] - b[0]))
