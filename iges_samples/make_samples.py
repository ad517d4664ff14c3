"""Regenerate every sample IGES file in this folder (deterministic: same bytes on every run).

    /work/venv/bin/python iges_samples/make_samples.py [OUT_DIR]

Files made by OpenCASCADE go through `cadbridge.ushape.export_iges` (OCC's IGES writer in
"faces" mode, reals at round-trip precision, fixed dates). Two files are written by hand
here, entity by entity, because OCC cannot produce them: the thesis' appendix A surface and
the surfaces placed by 124 transformation matrices (OCC bakes locations into the geometry).
The entity-count table of README.md is rewritten between its markers on every run.
"""

from __future__ import annotations

import collections
import math
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakeWire
from OCP.Geom import (
    Geom_BSplineSurface,
    Geom_CylindricalSurface,
    Geom_Plane,
    Geom_RectangularTrimmedSurface,
    Geom_SphericalSurface,
    Geom_Surface,
    Geom_ToroidalSurface,
)
from OCP.GeomConvert import GeomConvert
from OCP.gp import gp_Ax2, gp_Ax3, gp_Circ, gp_Dir, gp_Pnt
from OCP.TColgp import TColgp_Array2OfPnt
from OCP.TColStd import TColStd_Array1OfInteger, TColStd_Array1OfReal, TColStd_Array2OfReal

from cadbridge.ushape import UShapeParams, export_iges, tool_faces
from cadbridge.ushape.geometry import TOOL_COLORS

HERE = Path(__file__).resolve().parent
README = HERE / "README.md"
_DATE = "20100101.000000"


# ---------------------------------------------------------------------- reading back
def entity_counts(path: str | os.PathLike) -> dict[int, int]:
    """{entity type: number of directory entries} of an IGES file (from its D section)."""
    d_lines = [ln for ln in Path(path).read_text(encoding="latin-1").splitlines() if len(ln) >= 73 and ln[72] == "D"]
    return dict(sorted(collections.Counter(int(d_lines[i][:8]) for i in range(0, len(d_lines), 2)).items()))


# ---------------------------------------------------------------------- a tiny IGES writer
class _Entity:
    """One entity for the hand-written files: type, form, parameters (after the type), DE fields."""

    def __init__(self, etype: int, params: Sequence, form: int = 0, transform: int = 0, label: str = "", subscript: int = 0, status: str = "00000000") -> None:
        self.etype, self.params, self.form = etype, list(params), form
        self.transform, self.label, self.subscript, self.status = transform, label, subscript, status


def _fmt(x) -> str:
    if isinstance(x, str):  # already formatted (keeps the thesis' own spelling of numbers)
        return x
    if isinstance(x, int):
        return str(x)
    r = repr(float(x)).upper()  # IGES exponents: E (or D)
    return r if ("." in r or "E" in r) else r + "."


def _pack(tokens: list[str], width: int) -> list[str]:
    """Lay out delimited tokens on lines of at most ``width`` characters, breaking after delimiters."""
    lines, cur = [], ""
    for tok in tokens:
        if len(cur) + len(tok) > width:
            lines.append(cur)
            cur = ""
        cur += tok
    if cur:
        lines.append(cur)
    return lines


def _hollerith(s: str) -> str:
    return f"{len(s)}H{s}" if s else ""


def write_iges_by_hand(path: Path, entities: list[_Entity], start: list[str], *, product: str, system: str, author: str, organization: str, resolution: float = 1e-7, max_coord: float = 100.0) -> None:
    """Write entities as an IGES 5.3 fixed-format file (S, G, D, P, T sections)."""
    glob = [",", ";", _hollerith(product), _hollerith(path.name), _hollerith(system), _hollerith(system),
            "32", "38", "6", "308", "15", _hollerith(product), "1.0", "2", "2HMM", "1", "0.01",
            _hollerith(_DATE), _fmt(resolution), _fmt(max_coord), _hollerith(author), _hollerith(organization),
            "11", "0", _hollerith(_DATE)]
    glob = [f"1H{g}" if g in (",", ";") else g for g in glob]
    g_tokens = [g + "," for g in glob[:-1]] + [glob[-1] + ";"]
    g_lines = _pack(g_tokens, 72)

    d_lines: list[str] = []
    p_lines: list[str] = []
    for k, ent in enumerate(entities):
        de = 2 * k + 1  # DE numbers are odd and 1-based (the first line of the pair)
        toks = [str(ent.etype)] + [_fmt(x) for x in ent.params]
        toks = [t + "," for t in toks[:-1]] + [toks[-1] + ";"]
        body = _pack(toks, 64)
        first_p = len(p_lines) + 1
        for line in body:
            p_lines.append(f"{line:<64} {de:>7d}P{len(p_lines) + 1:07d}")
        f = lambda v: f"{v:>8}"  # noqa: E731
        d_lines.append(f(ent.etype) + f(first_p) + f(0) + f(0) + f(0) + f(0) + f(ent.transform) + f(0) + ent.status + f"D{len(d_lines) + 1:07d}")
        d_lines.append(f(ent.etype) + f(0) + f(0) + f(len(body)) + f(ent.form) + f("") + f("") + f(ent.label[:8]) + f(ent.subscript) + f"D{len(d_lines) + 1:07d}")
    out = [f"{s:<72}S{i + 1:07d}" for i, s in enumerate(start)]
    out += [f"{g:<72}G{i + 1:07d}" for i, g in enumerate(g_lines)]
    out += d_lines + p_lines
    out.append(f"S{len(start):7d}G{len(g_lines):7d}D{len(d_lines):7d}P{len(p_lines):7d}".ljust(72) + "T0000001")
    path.write_text("\n".join(out) + "\n", encoding="ascii")


def bspline_128_params(bs: Geom_BSplineSurface) -> list:
    """IGES 128 parameters (after the type number) of an OCC B-spline surface."""
    nu, nv = bs.NbUPoles(), bs.NbVPoles()

    def flat(n: int, knot, mult) -> list[float]:
        return [knot(i) for i in range(1, n + 1) for _ in range(mult(i))]

    su = flat(bs.NbUKnots(), bs.UKnot, bs.UMultiplicity)
    sv = flat(bs.NbVKnots(), bs.VKnot, bs.VMultiplicity)
    rational = bs.IsURational() or bs.IsVRational()
    # IGES order: first index (u) varies fastest; OCC poles are 1-based (i, j)
    w = [bs.Weight(i, j) for j in range(1, nv + 1) for i in range(1, nu + 1)]
    pts = [c for j in range(1, nv + 1) for i in range(1, nu + 1) for c in bs.Pole(i, j).Coord()]
    u0, u1, v0, v1 = bs.Bounds()
    return [nu - 1, nv - 1, bs.UDegree(), bs.VDegree(), 0, 0, 0 if rational else 1, 0, 0, *su, *sv, *w, *pts, u0, u1, v0, v1]


# ---------------------------------------------------------------------- geometry helpers
def _ax3(origin=(0.0, 0.0, 0.0), z=(0.0, 0.0, 1.0), x=(1.0, 0.0, 0.0)) -> gp_Ax3:
    return gp_Ax3(gp_Pnt(*origin), gp_Dir(*z), gp_Dir(*x))


def _exact_bspline(surf: Geom_Surface, u0: float, u1: float, v0: float, v1: float) -> Geom_BSplineSurface:
    """Exact rational B-spline of an analytic surface restricted to [u0, u1] x [v0, v1]."""
    return GeomConvert.SurfaceToBSplineSurface_s(Geom_RectangularTrimmedSurface(surf, u0, u1, v0, v1))


def _face(surf: Geom_Surface):
    return BRepBuilderAPI_MakeFace(surf, 1e-7).Face()


def quarter_cylinder() -> Geom_BSplineSurface:
    """R 5 quarter cylinder (the U-shape die shoulder, axis +y), v over the 20.5 mm tool half width."""
    return _exact_bspline(Geom_CylindricalSurface(_ax3((41.0, 0.0, -5.0), (0, 1, 0), (-1, 0, 0)), 5.0), 0.0, math.pi / 2, 0.0, 20.5)


def sphere_patch() -> Geom_BSplineSurface:
    """Sphere R 10: longitude 0..90 deg, latitude 0..60 deg (no pole)."""
    return _exact_bspline(Geom_SphericalSurface(_ax3(), 10.0), 0.0, math.pi / 2, 0.0, math.pi / 3)


def torus_patch() -> Geom_BSplineSurface:
    """Torus R 20, r 5: a quarter turn around the axis, the outer half of the tube."""
    return _exact_bspline(Geom_ToroidalSurface(_ax3(), 20.0, 5.0), 0.0, math.pi / 2, -math.pi / 2, math.pi / 2)


def multiple_knots_surface() -> Geom_BSplineSurface:
    """Bicubic, rational, u knots 0 0 0 0 | 1 1 (C1) | 2 2 2 (C0) | 3 3 3 3, v knots 0^4 0.5 1^4."""
    uk, um = [0.0, 1.0, 2.0, 3.0], [4, 2, 3, 4]
    vk, vm = [0.0, 0.5, 1.0], [4, 1, 4]
    nu = sum(um) - 4  # 9 poles along u
    nv = sum(vm) - 4  # 5 poles along v
    poles = TColgp_Array2OfPnt(1, nu, 1, nv)
    weights = TColStd_Array2OfReal(1, nu, 1, nv)
    for i in range(1, nu + 1):
        for j in range(1, nv + 1):
            x, y = 10.0 * (i - 1), 8.0 * (j - 1)
            z = 6.0 * math.sin(0.7 * i) * math.cos(0.9 * j) + (5.0 if i >= 7 else 0.0)  # a step after the C0 knot
            poles.SetValue(i, j, gp_Pnt(x, y, z))
            weights.SetValue(i, j, 1.0 + 0.25 * ((i + 2 * j) % 3))
    arr = lambda vals, cls: _fill(cls(1, len(vals)), vals)  # noqa: E731
    return Geom_BSplineSurface(poles, weights, arr(uk, TColStd_Array1OfReal), arr(vk, TColStd_Array1OfReal),
                               arr(um, TColStd_Array1OfInteger), arr(vm, TColStd_Array1OfInteger), 3, 3, False, False)


def _fill(array, values):
    for k, v in enumerate(values, start=1):
        array.SetValue(k, v)
    return array


def plate_with_hole():
    """Plane plate 100 x 60 mm with a circular hole of radius 10 mm centred at (30, 25)."""
    plane = Geom_Plane(_ax3())
    pts = [gp_Pnt(0, 0, 0), gp_Pnt(100, 0, 0), gp_Pnt(100, 60, 0), gp_Pnt(0, 60, 0)]
    outer = BRepBuilderAPI_MakeWire()
    for a, b in zip(pts, pts[1:] + pts[:1]):
        outer.Add(BRepBuilderAPI_MakeEdge(a, b).Edge())
    circ = gp_Circ(gp_Ax2(gp_Pnt(30, 25, 0), gp_Dir(0, 0, -1)), 10.0)  # clockwise seen from +z: a hole
    hole = BRepBuilderAPI_MakeWire(BRepBuilderAPI_MakeEdge(circ).Edge()).Wire()
    maker = BRepBuilderAPI_MakeFace(plane, outer.Wire(), True)
    maker.Add(hole)
    return maker.Face()


# ---------------------------------------------------------------------- the samples
def _ushape_tool(tool: str) -> Callable[[Path], None]:
    def make(path: Path) -> None:
        faces = tool_faces(UShapeParams())[tool]
        export_iges(faces, path, "nurbs", colors={k: TOOL_COLORS[tool] for k in faces},
                    description=f"cadbridge: NUMISHEET'93 U-shape {tool} contact surfaces (quarter model), NURBS mode")
    return make


def make_tools_nurbs(path: Path) -> None:
    faces = tool_faces(UShapeParams())
    flat = {k: f for tool in faces.values() for k, f in tool.items()}
    colors = {k: TOOL_COLORS[t] for t, d in faces.items() for k in d}
    export_iges(flat, path, "nurbs", colors=colors, description="cadbridge: NUMISHEET'93 U-shape die, punch and blank holder (quarter model), NURBS mode")


def make_tools_analytic(path: Path) -> None:
    faces = tool_faces(UShapeParams())
    flat = {k: f for tool in faces.values() for k, f in tool.items()}
    colors = {k: TOOL_COLORS[t] for t, d in faces.items() for k in d}
    export_iges(flat, path, "analytic", colors=colors, description="cadbridge: NUMISHEET'93 U-shape tools (quarter model), OCC analytic faces mode")


# Appendix A of Neto (2010), entity data exactly as printed (numbers kept as strings).
THESIS_128 = (
    "7,1,3,1,0,0,1,0,0,"
    "0,0,0,0,0.2696129,0.50025292,0.69102833,0.81038681,1,1,1,1,"
    "0,0,1,1,"
    + ",".join(["1"] * 16) + ","
    "-2.804053,-5.16892,0,-3.0315653,-4.0968669,0,-3.0830998,-2.6158131,0,"
    "-2.450814,-0.24658376,0,-1.5993302,1.3546726,0,-1.2423752,3.0707054,0,"
    "-1.1892867,3.9613801,0,-1.250001,4.729729,0,"
    "-2.804053,-5.16892,10,-3.0315653,-4.0968669,10,-3.0830998,-2.6158131,10,"
    "-2.450814,-0.24658376,10,-1.5993302,1.3546726,10,-1.2423752,3.0707054,10,"
    "-1.1892867,3.9613801,10,-1.250001,4.729729,10,"
    "0,1,0,1"
).split(",")


def make_thesis(path: Path) -> None:
    ent = _Entity(128, THESIS_128, label="NURBSURF", subscript=1)
    write_iges_by_hand(path, [ent], ["Translator GID - IGES (entity data of Neto 2010, appendix A;",
                                      "S and G sections reconstructed by cadbridge)"],
                       product="GID", system="GID", author="", organization="CIMNE", max_coord=10.0)


def _exact_face_sample(build: Callable[[], Geom_BSplineSurface], label: str, text: str) -> Callable[[Path], None]:
    def make(path: Path) -> None:
        export_iges({label: _face(build())}, path, "nurbs", description=f"cadbridge: {text}")
    return make


def _rotation(axis: tuple[float, float, float], angle: float) -> list[list[float]]:
    """Rotation matrix (Rodrigues) about a unit axis."""
    x, y, z = axis
    n = math.sqrt(x * x + y * y + z * z)
    x, y, z = x / n, y / n, z / n
    c, s, C = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    return [[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
            [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
            [z * x * C - y * s, z * y * C + x * s, c + z * z * C]]


def _matrix_124(rot: list[list[float]], t: tuple[float, float, float]) -> list[float]:
    return [rot[0][0], rot[0][1], rot[0][2], t[0], rot[1][0], rot[1][1], rot[1][2], t[1], rot[2][0], rot[2][1], rot[2][2], t[2]]


#: the two matrices of placed_by_124.igs: (rotation axis, angle, translation)
PLACEMENTS = {
    "T1": ((0.0, 0.0, 1.0), math.radians(30.0), (10.0, 0.0, 5.0)),
    "T2": ((1.0, 1.0, 0.0), math.radians(20.0), (0.0, -4.0, 2.0)),
}


def _placements() -> tuple[_Entity, _Entity]:
    t1 = _Entity(124, _matrix_124(_rotation(*PLACEMENTS["T1"][:2]), PLACEMENTS["T1"][2]))
    t2 = _Entity(124, _matrix_124(_rotation(*PLACEMENTS["T2"][:2]), PLACEMENTS["T2"][2]))
    return t1, t2


def make_placed(path: Path) -> None:
    t1, t2 = _placements()
    s1 = _Entity(128, bspline_128_params(sphere_patch()), transform=1, label="SPHERE")
    s2 = _Entity(128, bspline_128_params(quarter_cylinder()), transform=3, label="CYLINDER")
    write_iges_by_hand(path, [t1, t2, s1, s2], ["cadbridge: two 128 surfaces placed by 124 matrices:",
                                               "DE 5 (sphere patch) by 124 DE 1 (T1), DE 7 (quarter cylinder) by",
                                               "124 DE 3 (T2)."],
                       product="cadbridge placed_by_124", system="cadbridge make_samples.py", author="cadbridge", organization="cadbridge")


def make_chained(path: Path) -> None:
    t1, t2 = _placements()
    t2.transform = 1  # T2 is itself placed by T1: the surface under T2 maps to T1(T2(x)) (IGES 5.3, 4.21)
    s2 = _Entity(128, bspline_128_params(quarter_cylinder()), transform=3, label="CYLINDER")
    write_iges_by_hand(path, [t1, t2, s2], ["cadbridge: a 128 surface (DE 5, quarter cylinder) placed by 124 DE 3",
                                           "(T2), which is itself placed by 124 DE 1 (T1): x -> T1(T2(x)).",
                                           "OpenCASCADE 7.9 applies T2 only."],
                       product="cadbridge placed_by_chained_124", system="cadbridge make_samples.py", author="cadbridge", organization="cadbridge")


def make_hole(path: Path) -> None:
    export_iges({"PLATE": plate_with_hole()}, path, "nurbs", description="cadbridge: plate 100 x 60 with a hole R10 at (30, 25), NURBS mode (144 with an inner boundary)")


SAMPLES: dict[str, Callable[[Path], None]] = {
    "ushape_die_nurbs.igs": _ushape_tool("die"),
    "ushape_punch_nurbs.igs": _ushape_tool("punch"),
    "ushape_blankholder_nurbs.igs": _ushape_tool("blankholder"),
    "ushape_tools_nurbs.igs": make_tools_nurbs,
    "ushape_tools_analytic.igs": make_tools_analytic,
    "thesis_appendix_a.igs": make_thesis,
    "rational_quarter_cylinder.igs": _exact_face_sample(quarter_cylinder, "QCYL", "exact rational quarter cylinder R5 (die shoulder), 20.5 long"),
    "sphere_patch.igs": _exact_face_sample(sphere_patch, "SPHERE", "exact rational sphere patch R10, lon 0-90, lat 0-60 deg"),
    "torus_patch.igs": _exact_face_sample(torus_patch, "TORUS", "exact rational torus patch R20 r5, quarter turn, outer half"),
    "multiple_knots.igs": _exact_face_sample(multiple_knots_surface, "MULTKNOT", "rational bicubic with u knots of multiplicity 2 (C1) and 3 (C0)"),
    "placed_by_124.igs": make_placed,
    "trimmed_hole.igs": make_hole,
}


#: Reader test cases that are not samples (OpenCASCADE, the reference of `cadbridge verify`,
#: reads them differently from the IGES standard), written to tests/data/iges/.
TEST_DATA: dict[str, Callable[[Path], None]] = {
    "placed_by_chained_124.igs": make_chained,
}
TEST_DATA_DIR = HERE.parent / "tests" / "data" / "iges"


def counts_table(folder: Path) -> str:
    """Markdown table: file, size, entity counts."""
    rows = ["| file | bytes | entities (type: count) |", "|---|---:|---|"]
    for name in SAMPLES:
        p = folder / name
        counts = ", ".join(f"{t}: {n}" for t, n in entity_counts(p).items())
        rows.append(f"| `{name}` | {p.stat().st_size} | {counts} |")
    return "\n".join(rows)


def update_readme(folder: Path) -> None:
    """Rewrite the table between the README markers."""
    if not README.exists():
        return
    text = README.read_text()
    a, b = "<!-- counts:start -->", "<!-- counts:end -->"
    if a in text and b in text:
        head, rest = text.split(a, 1)
        _, tail = rest.split(b, 1)
        README.write_text(f"{head}{a}\n{counts_table(folder)}\n{b}{tail}")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    out = Path(argv[0]) if argv else HERE
    out.mkdir(parents=True, exist_ok=True)
    for name, make in SAMPLES.items():
        make(out / name)
    if out == HERE:
        update_readme(out)
        TEST_DATA_DIR.mkdir(parents=True, exist_ok=True)
    for name, make in TEST_DATA.items():
        make((TEST_DATA_DIR if out == HERE else out) / name)
    for name in SAMPLES:
        print(f"{name:32s} {entity_counts(out / name)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
