"""`project_points` against OpenCASCADE on the real IGES files of seven CAD systems
(../shared/iges_real; skipped when absent).

Points: nodes of OCC's own triangulation of every face (BRepMesh), pushed off along the face
normal by up to 1 % of the model size; boundary nodes of each face's triangulation are also
pushed outward in the tangent plane by up to 1 % (beyond trim edges, over holes, next to the
creases between faces).

Reference: OCC `BRepExtrema_DistShapeShape` between a vertex at the point and the set of
all faces (a compound; not the solid, to which an inside point is at distance 0): distance, nearest point, the face it lies on and its (u, v) there; the face normal
from `BRepAdaptor_Surface.D1` (the face location applied). The analytic production die is
measured against OCC's reading of the NURBS die, the same B-rep (`REFERENCE`: OCC's distance
is wrong on its reflected surfaces of revolution).

delta is the file's own trim tolerance, how far its 2D and 3D trim curves disagree, per
face: `Face.trim_delta` where the reader computed it, else the largest OCC tolerance of the
face's edges (`BRep_Tool.Tolerance`, which OCC's IGES transfer sets from that disagreement);
at least 1e-9 x size. A point uses the larger delta of our face and OCC's (paired by order,
as in tests/iges/test_real_files.py). Not a single file-wide maximum: OCC's edge tolerances reach
1.3 % of the bearing's size on a few edges (median 1e-7), and `Face.trim_delta` reported
14.1 (10 sqrt 2) on four of nine faces of the 108-mm SolidWorks part before those were read
from their generatrix arc's start (now 1e-7).

Faces the reader leaves untrimmed (entity 510 whose loops have no parameter-space curves,
reported by a reader diagnostic; SolidEdge, Inventor) are a known reader limit: points whose
foot lands on one are counted, the rest are checked, and the test is then an xfail naming
them.

Checked for every point: our projection did not FAIL, our foot lies on OCC's shape within
delta (never on trimmed-away surface), our distance equals OCC's within delta; where OCC's
nearest point lies inside a face and farther than delta from every edge of the shape, and
ours is not on a trim edge either (a file whose neighbouring faces leave a gap of about
delta between their edges puts the nearest point on that strip: Inventor faces 0 and 5),
our distance equals OCC's within 1e-9 x size and our normal is OCC's face normal within
1e-9 rad (sign-insensitive: OCC faces may be reversed).
"""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import occ as OCC

REAL = Path(__file__).parents[2].parent / "shared" / "iges_real"
FILES = sorted(REAL.glob("*.ig*")) if REAL.is_dir() else []
# the production dies (git-ignored, `iges_samples/make_samples.py --production`; slow: ~45 s
# each). The analytic die is measured against OCC's reading of the NURBS die: the same B-rep
# (make_samples.py writes one shape in both modes, faces in the same order with the same
# names), because OCC's exact distance is wrong on the analytic die's own shape. 245 of its
# faces lie on a 120 surface of revolution placed by a reflecting 124 (determinant -1).
# `IGESData_ToolLocation::ConvertLocation` keeps the reflection in the face's gp_Trsf, and
# the revolution-surface extrema (`Extrema_ExtPRevS`, through the adaptor's transformed axis
# and generatrix) then turn the angle the other way, so `BRepExtrema_DistShapeShape`
# classifies (-u, v) in the face's pcurves: it called our points 1 to 16 mm off the face,
# while OCC's own BRepMesh nodes of the same faces lie on the NURBS die's face within 1.1e-6
# mm, and so do ours within 1.2e-13 mm (`tests/iges/test_die_faces_vs_occ.py`, which checks both).
REFERENCE = {"production_die_analytic.igs": "production_die_nurbs.igs"}
DIES = [p for p in sorted((Path(__file__).parents[2] / "iges_samples").glob("production_die_*.igs"))]
CASES = [pytest.param(p, id=p.name) for p in FILES] + [
    pytest.param(p, id=p.name, marks=[pytest.mark.slow]) for p in DIES]

pytestmark = pytest.mark.skipif(not CASES, reason=f"{REAL} not present and no production die generated")

N_POINTS = 200  # per file (half pushed off interior nodes, half off boundary nodes)
REL = 1e-9  # distance tolerance away from trim edges, x model size
ANGLE = 1e-9  # normal tolerance away from trim edges, rad


def _points(shape, faces, size: float, rng) -> np.ndarray:
    """(N_POINTS, 3) points near the faces from OCC's triangulation (module docstring)."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepMesh import BRepMesh_IncrementalMesh
    from OCP.TopLoc import TopLoc_Location

    BRepMesh_IncrementalMesh(shape, 2e-3 * size, False, 0.5, False)
    per = max(1, int(np.ceil(N_POINTS / (2 * len(faces)))))
    inner, outer = [], []
    for face in faces:
        loc = TopLoc_Location()
        tri = BRep_Tool.Triangulation_s(face, loc)
        if tri is None or not tri.HasUVNodes():
            continue
        trsf = loc.Transformation()
        nodes = np.array([tri.Node(i).Transformed(trsf).Coord() for i in range(1, tri.NbNodes() + 1)])
        uv = np.array([tri.UVNode(i).Coord() for i in range(1, tri.NbNodes() + 1)])
        tris = np.array([tri.Triangle(i).Get() for i in range(1, tri.NbTriangles() + 1)]) - 1
        # boundary nodes: ends of triangle edges used once; outward = away from the triangle
        e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
        owner = np.tile(np.arange(len(tris)), 3)
        key, inv, cnt = np.unique(e, axis=0, return_inverse=True, return_counts=True)
        once = cnt[inv.ravel()] == 1
        bnode, btri = e[once].ravel(), np.repeat(owner[once], 2)
        inode = np.setdiff1d(np.arange(len(nodes)), bnode)
        for pool, out, is_b in ((inode, inner, False), (np.arange(len(bnode)), outer, True)):
            if len(pool) == 0:
                continue
            for j in rng.choice(pool, min(per, len(pool)), replace=False):
                k = bnode[j] if is_b else j
                n = OCC.face_normal(face, *uv[k])
                if not np.all(np.isfinite(n)):
                    continue  # a pole or collapsed edge: no normal to push along
                x = nodes[k] + rng.uniform(-0.01, 0.01) * size * n
                if is_b:
                    t = nodes[k] - nodes[tris[btri[j]]].mean(axis=0)
                    t -= (t @ n) * n
                    if np.linalg.norm(t) > 0:
                        x += rng.uniform(0.0, 0.01) * size * t / np.linalg.norm(t)
                out.append(x)
    pts = np.array(inner + outer)
    if len(pts) > N_POINTS:
        pts = pts[np.sort(rng.choice(len(pts), N_POINTS, replace=False))]
    return pts


def _face_delta(face, occ_face, size: float) -> float:
    """Trim tolerance of one face: `Face.trim_delta` where the reader computed it, else the
    largest OCC tolerance of the face's edges; at least 1e-9 x size."""
    from OCP.BRep import BRep_Tool
    from OCP.TopAbs import TopAbs_EDGE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    d = getattr(face, "trim_delta", None)
    if d is None:
        d = 0.0
        exp = TopExp_Explorer(occ_face, TopAbs_EDGE)
        while exp.More():
            d = max(d, BRep_Tool.Tolerance_s(TopoDS.Edge_s(exp.Current())))
            exp.Next()
    return max(float(d), REL * size)


@pytest.mark.parametrize("path", CASES)
def test_project_points_exact_vs_occ(path: Path):
    pytest.importorskip("OCP")
    from OCP.BRep import BRep_Tool
    from OCP.BRepExtrema import BRepExtrema_IsInFace
    from OCP.TopoDS import TopoDS

    from cadbridge.iges import read_iges
    from cadbridge.nurbs.project import FAILED, ON_BOUNDARY
    from cadbridge.verify.reference import occ_read_shape
    from cadbridge.cad.search import project_points

    model = read_iges(path)
    size = model.size()
    from cadbridge.heal.mesh_source import mesh_source

    # faces the reader re-read (the SolidWorks sphere caps, `cadbridge.iges.arc_convention`):
    # OCC reads them from the file's model-space curves, as the mesher does
    if path.name in REFERENCE:  # the same B-rep in another writer mode (see REFERENCE)
        ref = path.with_name(REFERENCE[path.name])
        if not ref.is_file():
            pytest.skip(f"{ref.name}, the reference of {path.name}, is not generated")
        shape = occ_read_shape(ref)
    else:
        with mesh_source(path, model) as src:
            shape = occ_read_shape(src)
    faces, edges = OCC.faces(shape), OCC.edges(shape)
    face_set = OCC.compound(faces)  # not the solid: a point inside a solid is at distance 0 from it
    edge_set = OCC.compound(edges)
    assert len(faces) == len(model.faces)  # paired by order (tests/iges/test_real_files.py)
    face_delta = np.array([_face_delta(model.faces[k], faces[k], size) for k in range(len(faces))])
    # faces the reader leaves untrimmed (B-rep loops without parameter-space curves, with a
    # diagnostic): feet on them may lie on surface the file trims away, a known reader limit
    untrimmed = {k for k, f in enumerate(model.faces) if f.trims is None and f.entity_type == 510}
    rng = np.random.default_rng(zlib.crc32(path.name.encode()))
    pts = _points(shape, faces, size, rng)
    assert len(pts) >= min(N_POINTS, 20)
    res = project_points(pts, model)

    fails = []
    n_interior = 0
    skipped = 0
    for i, x in enumerate(pts):
        where = f"{path.name} point {i} {x.tolist()}"
        if res.face[i] in untrimmed:
            skipped += 1
            continue
        if res.status[i] == FAILED:
            fails.append(f"{where}: FAILED (face {res.face[i]})")
            continue
        d = OCC.dist_shape_shape(OCC.vertex(x), face_set)
        d_occ = d.Value()
        # delta of the faces involved: ours and the one OCC's nearest point lies on
        support = d.SupportOnShape2(1)
        k_occ = next((k for k, f in enumerate(faces) if f.IsSame(support)), None) if (
            d.SupportTypeShape2(1) == BRepExtrema_IsInFace) else None
        delta = max(face_delta[res.face[i]], face_delta[k_occ] if k_occ is not None else face_delta.max())
        # our foot is on the trimmed shape (within delta): never on trimmed-away surface
        off = OCC.dist_shape_shape(OCC.vertex(res.foot[i]), face_set).Value()
        if off > delta:
            fails.append(f"{where}: our foot (face {res.face[i]}, DE {model.faces[res.face[i]].de}) is {off:.3g} "
                         f"off OCC's shape (delta {delta:.3g})")
        err = res.distance[i] - d_occ
        if abs(err) > delta:
            fails.append(f"{where}: distance {res.distance[i]!r} vs OCC {d_occ!r} (diff {err:.3g}, delta {delta:.3g}); "
                         f"our face {res.face[i]}, OCC's {k_occ}")
            continue
        # interior: OCC's (unique) nearest point inside a face, farther than delta from every edge
        if d.NbSolution() != 1 or d.SupportTypeShape2(1) != BRepExtrema_IsInFace:
            continue
        foot = np.array(d.PointOnShape2(1).Coord())
        if OCC.dist_shape_shape(OCC.vertex(foot), edge_set).Value() <= delta:
            continue
        # ours must be interior too: a foot on (or within delta of) a trim edge of ours is a
        # near-edge case, e.g. where two faces of the file leave a gap of about delta between
        # their edges (Inventor faces 0 and 5) and the nearest point lies on the strip
        if res.status[i] == ON_BOUNDARY or OCC.dist_shape_shape(OCC.vertex(res.foot[i]), edge_set).Value() <= delta:
            continue
        n_interior += 1
        if abs(err) > REL * size:
            fails.append(f"{where}: interior distance {res.distance[i]!r} vs OCC {d_occ!r} (diff {err:.3g} > "
                         f"{REL * size:.3g}); our face {res.face[i]}")
            continue
        occ_face = TopoDS.Face_s(d.SupportOnShape2(1))
        n_occ = OCC.face_normal(occ_face, *d.ParOnFaceS2(1))
        ang = float(np.arcsin(min(1.0, np.linalg.norm(np.cross(n_occ, res.normal[i])))))
        if ang > ANGLE:
            fails.append(f"{where}: normal {ang:.3g} rad from OCC's (face {res.face[i]}, DE "
                         f"{model.faces[res.face[i]].de})")
    assert not fails, (f"{len(fails)} of {len(pts)} points (face deltas {face_delta.min():.3g}..{face_delta.max():.3g}, "
                       f"size {size:.3g}):\n" + "\n".join(fails[:15]))
    assert n_interior >= (len(pts) - skipped) // 10, f"only {n_interior} of {len(pts) - skipped} checked points are interior"
    if skipped:
        pytest.xfail(f"{skipped} of {len(pts)} points have their foot on faces {sorted(untrimmed)} that the reader "
                     "leaves untrimmed (B-rep loops without parameter-space curves); the other points pass")


@pytest.mark.slow
@pytest.mark.skipif(not FILES, reason=f"{REAL} not present")
def test_bearing_100k_points_never_fail_and_never_farther_than_occ():
    """100 000 points within 0.5 % of the model size of the bearing's trimmed faces (the
    benchmark's set, benchmarks/bench_projection.py): none FAILED (two did, a Newton step cut
    at a domain edge and then halved off it), and where OCC's projection onto the generating
    face's surface (`GeomAPI_ProjectPointOnSurf`) lands inside that face
    (`BRepClass_FaceClassifier`), ours is no farther than it (1e-9 x size)."""
    pytest.importorskip("OCP")
    import sys

    sys.path.insert(0, str(Path(__file__).parents[2] / "benchmarks"))
    from bench_projection import points_on_faces

    from cadbridge.iges import read_iges
    from cadbridge.nurbs.project import FAILED
    from cadbridge.verify.reference import occ_inside, occ_project, occ_read
    from cadbridge.cad.search import project_points

    path = REAL / "occt_bearing_EuclidQuantum.iges"
    model = read_iges(path)
    size = model.size()
    pts, fid = points_on_faces(np.random.default_rng(3), model, 100_000, 0.005 * size)
    res = project_points(pts, model)
    assert np.all(res.status != FAILED), np.nonzero(res.status == FAILED)[0]
    occ = occ_read(path)
    assert len(occ) == len(model.faces)
    for k in np.unique(fid):
        sel = np.nonzero(fid == k)[0]
        u, v, _, d = occ_project(occ[k].surface, pts[sel], occ[k].bounds)
        ok = np.isfinite(d)
        ok[ok] = occ_inside(occ[k], u[ok], v[ok])
        worse = res.distance[sel[ok]] > d[ok] + 1e-9 * size
        assert not np.any(worse), (k, sel[ok][worse][:5], res.distance[sel[ok]][worse][:5], d[ok][worse][:5])
