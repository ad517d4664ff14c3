"""Trim loops of B-spline (128) faces built from model-space edges (508 loops without
parameter-space curves): `analytic.invert_edges` and `Builder._model_loop`.

References: analytic geometry (a NURBS cylinder and sphere built by `construct`, whose
parameters of a point follow in closed form from its height, longitude and latitude through
`construct.revolved_angle_to_v` / `construct.arc_parameter`, not through any projection),
and OpenCASCADE (`BRepClass_FaceClassifier` on the faces OCC builds from the same files).
"""

from __future__ import annotations

from math import pi
from pathlib import Path

import numpy as np
import pytest

from cadbridge.cad.analytic import SurfaceInvertedCurve, invert_edges
from cadbridge.iges.entities import reverse_curve
from cadbridge.cad.model import Trim, TrimLoop
from cadbridge.nurbs import construct
from cadbridge.nurbs.project import closed_directions
from cadbridge.cad.trims import trim_contains
from tests.helpers import occ as OCC

REAL = Path(__file__).parents[2].parent / "shared" / "iges_real"


def _on_surface(surface, curves, size):
    """Largest |S(uv(t)) - C(t)| over samples of the inverted pieces (C = the 3D edge)."""
    worst = 0.0
    for c in curves:
        if not isinstance(c, SurfaceInvertedCurve):
            continue
        t = np.linspace(*c.domain, 41)
        uv = c.evaluate(t)
        worst = max(worst, float(np.max(np.linalg.norm(surface.evaluate(uv[:, 0], uv[:, 1]) - c.base.evaluate(t),
                                                       axis=1))))
    return worst / size


def _closes(curves, rel=1e-9):
    """Every piece ends where the next (cyclically) starts, in (u, v)."""
    gaps = [np.linalg.norm(a.evaluate([a.domain[1]])[0] - b.evaluate([b.domain[0]])[0])
            for a, b in zip(curves, curves[1:] + curves[:1])]
    return max(gaps) <= rel


def test_loop_on_the_seam_of_a_closed_cylinder():
    """Half of a full-turn NURBS cylinder (angles pi..2 pi): the edge on the seam (angle 0 =
    2 pi) projects to either end of the closed v range; unwrapped along the loop it is v = 2 pi.
    Inside / outside against the analytic parameters of points at known angle and height."""
    r, h = 3.0, 5.0
    s = construct.revolved_surface(construct.line([r, 0, 0], [r, 0, h]), [0, 0, 0], [0, 0, 1], 0.0, 2 * pi)
    assert closed_directions(s) == (False, True)
    bottom = construct.circular_arc([0, 0, 0], [-r, 0, 0], [r, 0, 0])  # pi -> 2 pi
    seam = construct.line([r, 0, 0], [r, 0, h])
    top = reverse_curve(construct.circular_arc([0, 0, h], [-r, 0, h], [r, 0, h]))  # 2 pi -> pi
    side = construct.line([-r, 0, h], [-r, 0, 0])
    curves = invert_edges(s, [bottom, seam, top, side])
    assert len(curves) == 4 and _closes(curves)
    assert _on_surface(s, curves, r) <= 1e-9
    v_seam = curves[1].evaluate(np.linspace(0, 1, 11))[:, 1]
    assert np.allclose(v_seam, 2 * pi, atol=1e-9), v_seam
    # analytic (u, v) of points at angle theta, height z: u = z / h, v = revolved_angle_to_v(theta)
    rng = np.random.default_rng(1)
    theta = rng.uniform(0.02, 2 * pi - 0.02, 400)
    z = rng.uniform(0.02, h - 0.02, 400)
    u, v = z / h, construct.revolved_angle_to_v(theta, 0.0, 2 * pi)
    got = trim_contains(Trim(TrimLoop(curves), []), u, v)
    want = theta > pi
    keep = np.abs(theta - pi) > 1e-3
    assert np.array_equal(got[keep], want[keep])


def test_loop_through_the_pole_of_a_sphere():
    """A spherical triangle with a corner at the north pole of a NURBS sphere: at the pole
    the longitude parameter is undefined; each meridian keeps its own, and the degenerate
    edge between them is bridged by a (u, v) line (one 3D point). Inside / outside against
    the analytic parameters of points at known latitude and longitude."""
    r, a, b, lat0 = 2.0, 0.5, 1.5, 0.3
    gen = construct.circular_arc([0, 0, 0], [0, 0, -r], [0, 0, r], normal=[0, -1, 0])  # south -> north via +x
    s = construct.revolved_surface(gen, [0, 0, 0], [0, 0, 1], 0.0, 2 * pi)

    def at(lat, lon):
        return r * np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])

    north = np.array([0.0, 0.0, r])
    down = construct.circular_arc([0, 0, 0], north, at(lat0, a), normal=[-np.sin(a), np.cos(a), 0])
    across = construct.circular_arc([0, 0, r * np.sin(lat0)], at(lat0, a), at(lat0, b))
    up = construct.circular_arc([0, 0, 0], at(lat0, b), north, normal=[np.sin(b), -np.cos(b), 0])
    curves = invert_edges(s, [down, across, up])
    assert len(curves) == 4 and _closes(curves)  # the bridge at the pole inserted
    bridge = curves[3]
    ends = bridge.evaluate([0.0, 1.0])
    assert np.allclose(s.evaluate(ends[:, 0], ends[:, 1]), north, atol=1e-12)
    assert _on_surface(s, curves, r) <= 1e-9
    rng = np.random.default_rng(2)
    lon = rng.uniform(0.02, 2 * pi - 0.02, 400)
    lat = rng.uniform(-pi / 2 + 0.02, pi / 2 - 0.02, 400)
    u = construct.arc_parameter(lat + pi / 2, pi)  # generatrix from the south pole
    v = construct.revolved_angle_to_v(lon, 0.0, 2 * pi)
    got = trim_contains(Trim(TrimLoop(curves), []), u, v)
    want = (lon > a) & (lon < b) & (lat > lat0)
    keep = (np.abs(lon - a) > 1e-3) & (np.abs(lon - b) > 1e-3) & (np.abs(lat - lat0) > 1e-3)
    assert np.array_equal(got[keep], want[keep])


def test_edges_that_do_not_join_are_refused():
    s = construct.revolved_surface(construct.line([1, 0, 0], [1, 0, 1]), [0, 0, 0], [0, 0, 1], 0.0, pi)
    with pytest.raises(ValueError, match="do not join"):
        invert_edges(s, [construct.circular_arc([0, 0, 0], [1, 0, 0], [0, 1, 0]), construct.line([0, 1, 1], [1, 0, 1])])


FILES = ["occt_occ22470_SolidEdge_SpatialXPlus.igs", "occt_bug22869_Inventor2011_Spring.igs"]


@pytest.mark.parametrize("name", FILES)
def test_brep_faces_without_pcurves_trimmed_as_occ(name):
    """Every 510 face of the file (508 loops without parameter-space curves) is trimmed from
    its model-space edges, with a diagnostic that points to the face's delta (deferred: not
    computed by the read, but on the first access of `Face.trim_delta`, then finite for every
    face); on a grid of (u, v) over each
    face's surface our inside / outside equals OCC's (`BRepClass_FaceClassifier`) wherever the
    3D point is farther than 2 x (our delta + OCC's largest edge tolerance of the face) from
    OCC's edges."""
    pytest.importorskip("OCP")
    path = REAL / name
    if not path.is_file():
        pytest.skip(f"{path} not present")
    from OCP.BRep import BRep_Tool

    from cadbridge.iges import read_iges
    from cadbridge.verify.reference import occ_inside, occ_read

    model = read_iges(path)
    occ = occ_read(path)
    assert len(occ) == len(model.faces)
    built = [d for d in model.diagnostics if "trim loop built from" in d.message]
    assert built and all("trim_delta" in d.message for d in built)
    assert all("_delta_source" in f.__dict__ for f in model.faces)  # nothing computed at read time
    assert not [d for d in model.diagnostics if "untrimmed" in d.message]
    checked = 0
    for k, (f, o) in enumerate(zip(model.faces, occ)):
        assert f.trims is not None, k
        assert f.trim_delta is not None and np.isfinite(f.trim_delta)
        edges = OCC.edges(o.face)
        tol = max([0.0] + [BRep_Tool.Tolerance_s(e) for e in edges])
        margin = 2 * (f.trim_delta + tol)
        u0, u1, v0, v1 = f.surface.domain
        uu, vv = np.meshgrid(np.linspace(u0, u1, 9)[1:-1], np.linspace(v0, v1, 9)[1:-1])
        uu, vv = uu.ravel(), vv.ravel()
        ours = trim_contains(f.trims, uu, vv)
        theirs = occ_inside(o, uu, vv)
        pts = f.surface.evaluate(uu, vv)
        for i in np.flatnonzero(ours != theirs):
            d = min(OCC.distance(pts[i], e) for e in edges)
            assert d <= margin, (name, k, f.de, (uu[i], vv[i]), bool(ours[i]), d, margin)
        checked += len(uu)
    assert checked > 0


def test_edge_off_the_surface_foot_and_derivatives():
    """An edge 0.01 off a NURBS cylinder (a circle of radius r + 0.01 at height z0; the
    files' edges are up to 1e-4 x size off their surfaces): the foot of C(t) is at the same
    angle and height, so uv(t) = (z0 / h, revolved_angle_to_v(a0 + arc_angle(t))) in closed
    form; values and first and second derivatives of the inverted curve against it (the
    derivatives against central differences of the closed form)."""
    r, h, z0, off = 3.0, 5.0, 2.0, 0.01
    s = construct.revolved_surface(construct.line([r, 0, 0], [r, 0, h]), [0, 0, 0], [0, 0, 1], 0.0, 2 * pi)
    a0, a1 = 0.4, 2.6
    rr = r + off
    arc = construct.circular_arc([0, 0, z0], [rr * np.cos(a0), rr * np.sin(a0), z0],
                                 [rr * np.cos(a1), rr * np.sin(a1), z0])
    back = reverse_curve(construct.circular_arc([0, 0, z0 + 1], [rr * np.cos(a0), rr * np.sin(a0), z0 + 1],
                                                [rr * np.cos(a1), rr * np.sin(a1), z0 + 1]))
    lines = [construct.line(arc.evaluate([arc.domain[1]])[0], back.evaluate([back.domain[0]])[0]),
             construct.line(back.evaluate([back.domain[1]])[0], arc.evaluate([arc.domain[0]])[0])]
    c = invert_edges(s, [arc, lines[0], back, lines[1]])[0]
    sweep = a1 - a0

    def exact(t):
        return np.column_stack([np.full(len(t), z0 / h),
                                construct.revolved_angle_to_v(a0 + construct.arc_angle(t, sweep), 0.0, 2 * pi)])

    t = np.linspace(*c.domain, 37)[1:-1]
    t = t[np.min(np.abs(t[:, None] - np.asarray(arc.knots)[None]), axis=1) > 1e-3]  # away from C1 knots of v(angle)
    d = c.derivatives(t, 2)
    assert np.allclose(d[:, 0], exact(t), atol=1e-12)
    e = 1e-5
    d1 = (exact(t + e) - exact(t - e)) / (2 * e)
    d2 = (exact(t + e) - 2 * exact(t) + exact(t - e)) / e**2
    assert np.allclose(d[:, 1], d1, atol=1e-8), np.abs(d[:, 1] - d1).max()
    assert np.allclose(d[:, 2], d2, atol=1e-4), np.abs(d[:, 2] - d2).max()
