"""`cadbridge fit --base-curves`: four boundary curves read from IGES (written by OpenCASCADE,
an independent writer), ordered into a loop, their Coons patch as the base. References: the
analytic surfaces whose boundaries the curves are (a hyperbolic paraboloid z = x y / 200 spanned
by four lines, an extruded cubic), which a bilinearly blended Coons patch reproduces exactly."""

from __future__ import annotations

import re

import numpy as np
import pytest

import cadbridge
from cadbridge.fitting.boundary_curves import boundary_loop, coons_base, read_boundary_curves
from cadbridge.cli import PROGRESS_LINE, main
from cadbridge.fitting.surface_fit import FitInputError

OCP = pytest.importorskip("OCP")


def _occ_bspline(pts, deg):
    from OCP.Geom import Geom_BSplineCurve
    from OCP.gp import gp_Pnt
    from OCP.TColgp import TColgp_Array1OfPnt
    from OCP.TColStd import TColStd_Array1OfInteger, TColStd_Array1OfReal

    n = len(pts)
    arr = TColgp_Array1OfPnt(1, n)
    for i, p in enumerate(pts):
        arr.SetValue(i + 1, gp_Pnt(*map(float, p)))
    nk = n - deg + 1
    kn, mu = TColStd_Array1OfReal(1, nk), TColStd_Array1OfInteger(1, nk)
    for i in range(nk):
        kn.SetValue(i + 1, i / (nk - 1))
        mu.SetValue(i + 1, deg + 1 if i in (0, nk - 1) else 1)
    return Geom_BSplineCurve(arr, kn, mu, deg)


def _write_curves(path, curves):
    """IGES by OpenCASCADE: each item a ("line", p0, p1), ("bspline", points, degree) or
    ("arc", p0, p_mid, p1): one standalone 110 / 126 entity each."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge
    from OCP.GC import GC_MakeArcOfCircle
    from OCP.gp import gp_Pnt
    from OCP.IGESControl import IGESControl_Writer

    w = IGESControl_Writer("MM", 0)
    for c in curves:
        if c[0] == "line":
            e = BRepBuilderAPI_MakeEdge(gp_Pnt(*c[1]), gp_Pnt(*c[2])).Edge()
        elif c[0] == "bspline":
            e = BRepBuilderAPI_MakeEdge(_occ_bspline(c[1], c[2])).Edge()
        else:
            e = BRepBuilderAPI_MakeEdge(GC_MakeArcOfCircle(gp_Pnt(*c[1]), gp_Pnt(*c[2]), gp_Pnt(*c[3])).Value()).Edge()
        assert w.AddShape(e)
    w.ComputeModel()
    assert w.Write(str(path))
    return path


SADDLE = [("line", (0, 0, 0), (100, 0, 0)), ("line", (100, 0, 0), (100, 60, 30)),
          ("line", (100, 60, 30), (0, 60, 0)), ("line", (0, 60, 0), (0, 0, 0))]


def test_saddle_from_four_lines_in_any_order(tmp_path):
    # reference: the bilinear patch P(u, v) = (100 u, 60 v, 30 u v), i.e. z = x y / 200; the lines
    # are written shuffled and partly reversed, the loop must still close
    shuffled = [SADDLE[2], ("line", SADDLE[0][2], SADDLE[0][1]), SADDLE[3], ("line", SADDLE[1][2], SADDLE[1][1])]
    path = _write_curves(tmp_path / "edges.igs", shuffled)
    curves = read_boundary_curves(path)
    assert len(curves) == 4 and all(c.degree == 1 for c in curves)
    s = coons_base(curves)
    u, v = s.grid(30, 30)
    p = s.evaluate(u, v)
    assert np.abs(p[:, 2] - p[:, 0] * p[:, 1] / 200.0).max() <= 1e-9
    assert s.bbox()[0] == pytest.approx([0, 0, 0], abs=1e-9) and s.bbox()[1] == pytest.approx([100, 60, 30], abs=1e-9)


def test_extruded_cubic_is_reproduced(tmp_path):
    # reference: the extrusion S(t, w) = c(t) + (0, 50 w, 0) of a cubic B-spline c in the xz plane,
    # evaluated through OCC's own copy of c (its curve, our reading of the IGES 126)
    cpts = np.array([(0, 0, 0), (30, 0, 12), (60, 0, -8), (90, 0, 5), (120, 0, 0)], dtype=float)
    top = cpts + [0, 50, 0]
    path = _write_curves(tmp_path / "edges.igs", [("bspline", cpts, 3), ("line", cpts[-1], top[-1]),
                                                  ("bspline", top[::-1], 3), ("line", top[0], cpts[0])])
    s = coons_base(read_boundary_curves(path))
    occ = _occ_bspline(cpts, 3)
    t = np.linspace(0.0, 1.0, 41)
    for w in (0.0, 0.3, 1.0):
        got = s.evaluate(t, np.full_like(t, w))
        ref = np.array([[occ.Value(float(tt)).X(), occ.Value(float(tt)).Y(), occ.Value(float(tt)).Z()] for tt in t])
        assert np.abs(got - (ref + [0, 50 * w, 0])).max() <= 1e-9


def test_cli_fit_on_the_coons_base(tmp_path, capsys):
    # reference: the analytic saddle z = x y / 200; noisy scan-like points over the patch (sigma
    # 0.005, a hole), fitted on the Coons base of its four edges, read back by our reader
    path = _write_curves(tmp_path / "edges.igs", SADDLE)
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 1, (20000, 2)) * [100, 60]
    xy = xy[np.hypot(xy[:, 0] - 50, xy[:, 1] - 30) > 8]
    pts = np.column_stack([xy, xy[:, 0] * xy[:, 1] / 200.0 + rng.normal(0, 0.005, len(xy))])
    pf = tmp_path / "scan.xyz"
    np.savetxt(pf, pts)
    out = tmp_path / "fit.igs"
    rc = main(["fit", str(pf), "-o", str(out), "--base-curves", str(path), "--tolerance", "0.01", "--no-report"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    face = cadbridge.read_iges(out).faces[0]
    u, v = face.surface.grid(80, 80)
    q = face.surface.evaluate(u, v)
    inside = (q[:, 0] > 1) & (q[:, 0] < 99) & (q[:, 1] > 1) & (q[:, 1] < 59)
    assert inside.mean() > 0.8
    assert np.abs(q[inside, 2] - q[inside, 0] * q[inside, 1] / 200.0).max() <= 0.01 + 3 * 0.005


def test_bad_boundary_curves(tmp_path, capsys):
    three = _write_curves(tmp_path / "three.igs", SADDLE[:3])
    with pytest.raises(FitInputError, match="exactly 4 curves, got 3"):
        coons_base(read_boundary_curves(three))
    gap = _write_curves(tmp_path / "gap.igs", SADDLE[:3] + [("line", (0, 60, 0), (0, 1, 0))])
    with pytest.raises(FitInputError, match="do not close|closed loop"):
        coons_base(read_boundary_curves(gap))
    arc = _write_curves(tmp_path / "arc.igs", [("arc", (0, 0, 0), (50, -10, 0), (100, 0, 0))] + SADDLE[1:3]
                        + [("arc", (0, 60, 0), (-10, 30, 0), (0, 0, 0))])
    with pytest.raises(FitInputError, match="rational"):
        coons_base(read_boundary_curves(arc))
    # the CLI: one line, exit 2
    pf = tmp_path / "p.xyz"
    np.savetxt(pf, np.random.default_rng(1).uniform(0, 1, (200, 3)))
    for bad in (three, tmp_path / "missing.igs"):
        rc = main(["fit", str(pf), "-o", str(tmp_path / "o.igs"), "--base-curves", str(bad)])
        err = capsys.readouterr().err.strip()
        lines = [ln for ln in err.splitlines()  # without a fresh checkout's notice and the progress lines
                 if 'compiling numerical kernels' not in ln and not re.match(PROGRESS_LINE, ln)]
        assert rc == 2 and len(lines) == 1, err


def test_loop_orientation_and_corners():
    # reference: the corners of the saddle; the first curve keeps its direction
    from cadbridge.nurbs.construct import line

    segs = [line(np.array(a[1], float), np.array(a[2], float)) for a in SADDLE]
    loop = boundary_loop([segs[0], segs[2], segs[1], segs[3]])
    ends = [c.evaluate(np.array(c.domain)) for c in loop]
    for a, b in zip(ends, ends[1:] + ends[:1]):
        assert np.allclose(a[1], b[0])
    assert np.allclose(ends[0][0], [0, 0, 0]) and np.allclose(ends[0][1], [100, 0, 0])
