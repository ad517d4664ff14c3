"""Projection onto the sample IGES files, face by face and over whole models, against OpenCASCADE.

Reference: OpenCASCADE 7.9 (OCP) reading the same file (`cadbridge.verify.reference.occ_read`),
faces paired with ours geometrically (`cadbridge.verify.faces.pair_faces`: our sample points lie
on the paired OCC surface).

- one face (`project_to_surface` on the untrimmed surface): points on, above, below and beyond
  the edges of the face. Where our parametrisation is OCC's (every 128 face), the reference is
  `GeomAPI_ProjectPointOnSurf` for interior extrema plus `GeomAPI_ProjectPointOnCurve` on the
  four boundary iso-curves (as in tests/nurbs/test_project.py): foot within 1e-9 x model size,
  normal within 1e-9 rad of `GeomLProp_SLProps` at our (u, v) (at a pole or cone apex, where
  OCC has no normal, within 1e-6 rad of OCC's 1e-7 inside), never farther than OCC's best.
  Where it is not (analytic-mode faces converted to NURBS by our reader), interior feet are
  compared with OCC's projection on its own surface, normals up to the sign of the
  parametrisation.
- whole model (`project_points`, trims respected): `BRepExtrema_DistShapeShape` between a
  vertex and OCC's shape of all faces gives the nearest point on the trimmed faces; distance
  and (where the nearest point is unique) foot within 1e-9 x model size; our normal against
  OCC's normal of the paired surface at our foot.

"""

from __future__ import annotations

import math
import zlib
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("OCP")

from tests.helpers import occ as OCC  # noqa: E402  (OCC.surface_nearest: interior + boundary reference)

from cadbridge.iges import read_iges  # noqa: E402
from cadbridge.nurbs.project import CONVERGED, FAILED, ON_BOUNDARY, project_to_surface  # noqa: E402
from cadbridge.cad.search import project_points  # noqa: E402
from cadbridge.verify.reference import occ_normal, occ_project, occ_read, occ_read_shape  # noqa: E402
from cadbridge.verify.faces import pair_faces  # noqa: E402

SAMPLES = Path(__file__).resolve().parents[2] / "iges_samples"
FILES = sorted(p.name for p in SAMPLES.glob("*.igs") if not p.name.startswith("production_die"))  # die: on request, git-ignored
N_FACE = 40  # points per face
REL = 1e-9  # foot tolerance relative to the model size
ANG = 1e-9  # normal tolerance, radians


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def points_around(rng, s, n: int, spread: float) -> np.ndarray:
    """S(u, v) + t N over a domain enlarged by 15 % (clamped, then pushed outwards along the
    tangents): points on (10 %), above, below and beyond the edges of the surface."""
    u0, u1, v0, v1 = s.domain
    du, dv = u1 - u0, v1 - v0
    u = rng.uniform(u0 - 0.15 * du, u1 + 0.15 * du, n)
    v = rng.uniform(v0 - 0.15 * dv, v1 + 0.15 * dv, n)
    uc, vc = np.clip(u, u0, u1), np.clip(v, v0, v1)
    der = s.derivatives(uc, vc, order=1)
    t = rng.uniform(-spread, spread, n)
    t[: n // 10] = 0.0
    return (der[:, 0, 0] + t[:, None] * s.normal(uc, vc)
            + (u - uc)[:, None] * der[:, 1, 0] + (v - vc)[:, None] * der[:, 0, 1])


def _occ_reference_normal(occ_surface, s, u: float, v: float) -> tuple[np.ndarray, float]:
    """OCC's normal to compare ours at (u, v) with, and the tolerance (radians). At a collapsed
    edge (a pole, a cone apex: S_u x S_v = 0) OCC's normal at the point is round-off (a sphere's
    pole came back 41 deg off its axis): there ours, the limit from inside the domain, is
    compared with OCC's a step of 1e-7 of the parameter range inside, within 1e-6 rad."""
    _, degenerate = s.normal([u], [v], return_flags=True)
    if not degenerate[0]:
        return occ_normal(occ_surface, u, v)[0], ANG
    u0, u1, v0, v1 = s.domain
    cu0, cu1, cv0, cv1 = s.collapsed_sides()
    du = 1.0 if (cu0 and u == u0) else -1.0 if (cu1 and u == u1) else 0.0
    dv = 1.0 if (cv0 and v == v0) else -1.0 if (cv1 and v == v1) else 0.0
    return occ_normal(occ_surface, u + 1e-7 * (u1 - u0) * du, v + 1e-7 * (v1 - v0) * dv)[0], 1e-6


def same_parametrisation(face, occ, size: float) -> bool:
    from cadbridge.verify.reference import occ_eval

    u0, u1, v0, v1 = face.surface.domain
    uu = np.linspace(u0, u1, 5).repeat(5)
    vv = np.tile(np.linspace(v0, v1, 5), 5)
    ours = face.surface.evaluate(uu, vv)
    theirs = occ_eval(occ.surface, uu, vv, order=0)[0]
    return float(np.max(np.linalg.norm(ours - theirs, axis=1))) <= 1e-10 * size


@pytest.fixture(scope="module", params=FILES)
def sample(request):
    path = SAMPLES / request.param
    model = read_iges(path)
    occ = occ_read(path)
    pairs = pair_faces(model, occ)
    assert all(len(p) == 1 for p in pairs), f"{request.param}: pairing {pairs}"
    return request.param, path, model, occ, [p[0] for p in pairs]


def test_single_face_against_occ(sample):
    """Reference: OCC GeomAPI_ProjectPointOnSurf / ProjectPointOnCurve (boundary) on the
    paired OCC surface, GeomLProp_SLProps normals. See the module docstring."""
    name, _, model, occ, pair = sample
    size = model.size()
    tol = REL * size
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    compared = total = 0
    for k, face in enumerate(model.faces):
        o = occ[pair[k]]
        s = face.surface
        b = s.bbox()
        pts = points_around(rng, s, N_FACE, 0.1 * float(np.linalg.norm(b[1] - b[0])))
        res = project_to_surface(s, pts)
        assert np.all(res.status != FAILED), f"{name} face {k}: FAILED at {np.nonzero(res.status == FAILED)[0]}"
        total += len(pts)
        if same_parametrisation(face, o, size):
            # OCC's surface may extend beyond our face (an unbounded Geom_Plane): restrict it
            # to our domain so its iso-curves are our edges
            from OCP.Geom import Geom_RectangularTrimmedSurface

            gs = Geom_RectangularTrimmedSurface(o.surface, *map(float, s.domain))
            for i, p in enumerate(pts):
                cands, _ = OCC.surface_nearest(gs, s, p)
                d_ref, f_ref, _ = cands[0]
                assert res.distance[i] <= d_ref + tol, f"{name} face {k} point {i}: {res.distance[i]} > OCC {d_ref}"
                if len(cands) > 1 and cands[1][0] - d_ref < 1e-6 * size and np.linalg.norm(cands[1][1] - f_ref) > 1e-6 * size:
                    continue  # two nearest points: no unique foot to compare
                if res.distance[i] < d_ref - tol:
                    continue  # OCC missed the global minimum
                err = float(np.linalg.norm(res.foot[i] - f_ref))
                assert err <= tol, f"{name} face {k} point {i} ({p.tolist()}): foot differs from OCC by {err:.3g}"
                n_ref, ang = _occ_reference_normal(o.surface, s, res.u[i], res.v[i])
                if np.all(np.isfinite(n_ref)):
                    a = float(_angle(res.normal[i], n_ref))
                    assert a <= ang, f"{name} face {k} point {i}: normal off OCC's by {a:.3g} rad"
                compared += 1
        else:
            # other parametrisation: interior feet against OCC's projection on its surface
            inner = np.nonzero(res.status == CONVERGED)[0]
            ou, ov, ofoot, od = occ_project(o.surface, pts[inner])
            ok = np.isfinite(od)
            for j in np.nonzero(ok)[0]:
                i = inner[j]
                if od[j] < res.distance[i] - tol:
                    continue  # OCC's surface extends beyond our face (e.g. an unbounded plane)
                err = float(np.linalg.norm(res.foot[i] - ofoot[j]))
                assert err <= tol, f"{name} face {k} point {i}: foot differs from OCC by {err:.3g}"
                n_ref = occ_normal(o.surface, ou[j], ov[j])[0]
                a = float(_angle(res.normal[i], n_ref))
                a = min(a, math.pi - a)  # the orientation of another parametrisation may differ
                assert a <= ANG, f"{name} face {k} point {i}: normal off OCC's by {a:.3g} rad"
                compared += 1
    assert compared >= 0.5 * total, f"{name}: only {compared} of {total} points compared"


def _occ_nearest(shape, pts: np.ndarray, size: float):
    """Nearest points on OCC's shape: (distance (N,), foot (N, 3), unique (N,) bool)."""
    from OCP.BRepExtrema import BRepExtrema_DistShapeShape

    n = len(pts)
    dist = np.full(n, np.nan)
    foot = np.full((n, 3), np.nan)
    unique = np.zeros(n, dtype=bool)
    for i, p in enumerate(pts):
        ext = BRepExtrema_DistShapeShape(OCC.vertex(p), shape)
        if not ext.IsDone() or ext.NbSolution() == 0:
            continue
        dist[i] = ext.Value()
        sols = np.array([ext.PointOnShape2(j).Coord() for j in range(1, ext.NbSolution() + 1)])
        foot[i] = sols[0]
        unique[i] = bool(np.all(np.linalg.norm(sols - sols[0], axis=1) <= 1e-6 * size))
    return dist, foot, unique


def test_whole_model_against_occ(sample):
    """Reference: OCC BRepExtrema_DistShapeShape (vertex to the trimmed faces of OCC's shape)
    for distance and foot; GeomLProp_SLProps on the paired OCC surface for the normal."""
    name, path, model, occ, pair = sample
    size = model.size()
    tol = REL * size
    rng = np.random.default_rng(zlib.crc32(name.encode()) + 1)
    pts = np.concatenate([
        points_around(rng, f.surface, N_FACE, 0.05 * size) for f in model.faces
    ])
    res = project_points(pts, model)
    assert np.all(res.status != FAILED), f"{name}: FAILED at {np.nonzero(res.status == FAILED)[0]}"
    shape = occ_read_shape(path)
    d_ref, f_ref, unique = _occ_nearest(shape, pts, size)
    ok = np.isfinite(d_ref)
    assert ok.mean() > 0.9
    derr = np.abs(res.distance[ok] - d_ref[ok])
    assert derr.max() <= tol, f"{name}: distance differs from OCC by {derr.max():.3g} (point {np.nonzero(ok)[0][np.argmax(derr)]})"
    # where ours is strictly nearer, OCC's extremum did not converge (seen next to edges,
    # where the distance is flat along the edge): check only that our foot lies on OCC's shape
    d_pt = np.linalg.norm(f_ref - pts, axis=1)  # BRepExtrema's Value() can be finer than its point
    nearer = ok & (res.distance < d_pt - 1e-12 * size)
    if np.any(nearer):
        on = _occ_nearest(shape, res.foot[nearer], size)[0]
        assert np.nanmax(on) <= tol, f"{name}: our foot is {np.nanmax(on):.3g} off OCC's shape"
    cmp_ = ok & unique & ~nearer
    ferr = np.linalg.norm(res.foot[cmp_] - f_ref[cmp_], axis=1)
    assert ferr.max() <= tol, f"{name}: foot differs from OCC by {ferr.max():.3g} (point {np.nonzero(cmp_)[0][np.argmax(ferr)]})"
    assert cmp_.sum() >= 0.8 * len(pts)
    # normals: OCC's normal of the paired surface at our foot (interior feet)
    for k in np.unique(res.face):
        sel = np.nonzero((res.face == k) & (res.status == CONVERGED))[0]
        if not len(sel):
            continue
        o = occ[pair[k]]
        ou, ov, ofoot, od = occ_project(o.surface, res.foot[sel])
        n_ref = occ_normal(o.surface, ou, ov)
        good = np.isfinite(od) & np.all(np.isfinite(n_ref), axis=1)
        a = _angle(res.normal[sel][good], n_ref[good])
        if not same_parametrisation(model.faces[k], o, size):
            a = np.minimum(a, math.pi - a)
        assert a.max(initial=0.0) <= ANG, f"{name} face {k}: normal off OCC's by {a.max():.3g} rad"
    # points beyond an open edge really are reported as edge feet somewhere
    assert np.any(res.status == ON_BOUNDARY) or name == "ushape_tools_analytic.igs"
