"""cadbridge.fitting.surface_fit and `cadbridge fit`: scan of the U-shape die, springback compensation, inputs,
bases, bad input. References: the die CAD (iges_samples/ushape_die_nurbs.igs) through
cadbridge.project_points, OpenCASCADE reading the written IGES, analytic surfaces."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import cadbridge
from cadbridge.cli import PROGRESS_LINE, main
from cadbridge.fitting.surface_fit import (FitInputError, coons_surface, data_outline, fit_points, join_strip, plane_base,
                               read_points, write_fit_outputs)
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.cad.search import project_points
from tests.helpers.scans import die_scan

ROOT = Path(__file__).resolve().parents[2]
DIE = ROOT / "iges_samples" / "ushape_die_nurbs.igs"


def test_join_strip_reproduces_the_die_faces():
    # reference: the three CAD faces themselves (the joined surface must contain their points)
    model = cadbridge.read_iges(DIE)
    strip = join_strip([f.surface for f in model.faces])
    u, v = strip.grid(120, 9)
    pr = project_points(strip.evaluate(u, v), model)
    assert np.nanmax(pr.distance) <= 1e-9 * model.size()
    u0, u1, _, _ = strip.domain
    assert u1 - u0 == pytest.approx(75.0 + 2.5 * np.pi + 149.0, rel=1e-3)  # wall + R5 quarter + land


def _check_scan_fit(n: int, sigma: float = 0.01, tol: float = 0.01):
    model, strip, x, bad = die_scan(n, sigma)
    rep = fit_points(x, base=model, tolerance=tol, trim=True, source="synthetic scan")
    face = rep.face
    # dense samples of the fit inside the data outline (decided on the exact trim curves)
    u, v = face.surface.grid(500, 60)
    inside = face.contains(u, v)
    assert inside.mean() > 0.95
    pr = project_points(face.surface.evaluate(u[inside], v[inside]), model)
    assert np.all(np.isfinite(pr.distance))
    # shape: samples whose nearest CAD point is inside the die face (orthogonal foot); the others lie
    # past the die's end edges, where there is no data: the fit's edge ends within a data spacing
    on_cad = pr.status == 0
    assert on_cad.mean() > 0.99
    assert pr.distance[on_cad].max() <= 3 * sigma + tol, pr.distance[on_cad].max()
    assert pr.distance.max() <= 0.25  # edge overshoot along the surface, about one point spacing
    # the outliers were found: most of the big ones at weight 0, few inliers lost
    big = bad & (np.abs(rep.fit.signed) > 0.1)
    assert rep.fit.outliers[big].mean() > 0.95
    assert rep.fit.outliers[~bad].mean() < 0.01
    return rep, pr


def test_scan_of_the_die_small():
    # reference: the die CAD (project_points of dense samples of the fit onto it); 30 000 points
    _check_scan_fit(30000)


@pytest.mark.slow
def test_scan_of_the_die_100k():
    # acceptance: 100 000 points, sigma 0.01 mm, 2 % outliers up to 1 mm, a 20 mm hole: within
    # 3 sigma + tol of the CAD everywhere inside the data outline
    rep, pr = _check_scan_fit(100000)
    assert rep.fit.stop == "tolerance"


def _moved_die(nodes_per_mm: float = 2.0):
    """FE-like nodes (0.5 mm apart by default) on the die moved along its normal by d = 0.5 sin(pi s) (0.6 + 0.4 cos(pi t)),
    s, t in [0, 1] along and across (a smooth compensation field, max 0.5 mm)."""
    model = cadbridge.read_iges(DIE)
    strip = join_strip([f.surface for f in model.faces])
    u0, u1, v0, v1 = strip.domain

    def field(u, v):
        s, t = (u - u0) / (u1 - u0), (v - v0) / (v1 - v0)
        return 0.5 * np.sin(np.pi * s) * (0.6 + 0.4 * np.cos(np.pi * t))

    uu = np.linspace(u0, u1, int((u1 - u0) * nodes_per_mm) + 1)
    vv = np.linspace(v0, v1, int((v1 - v0) * nodes_per_mm) + 1)
    u, v = (a.ravel() for a in np.meshgrid(uu, vv, indexing="ij"))
    nodes = strip.evaluate(u, v) + field(u, v)[:, None] * strip.normal(u, v)
    return model, strip, field, nodes


def _moved_distance_bound(strip, field, pts):
    """Upper bound of the distance of pts to the moved surface M = S + d n: |y - M(u*, v*)| with
    (u*, v*) the foot of y on S (M(u*, v*) is a point of M)."""
    from cadbridge.nurbs.project import project_to_surface

    r = project_to_surface(strip, pts)
    m = strip.evaluate(r.u, r.v) + field(r.u, r.v)[:, None] * strip.normal(r.u, r.v)
    return np.linalg.norm(pts - m, axis=1)


def test_compensation_fit_read_by_occ(tmp_path):
    # reference: OpenCASCADE reads the written IGES; its surface sampled with Geom_Surface.D0 must
    # lie within 0.005 mm of the moved die surface (bound above)
    pytest.importorskip("OCP")
    from cadbridge.verify.reference import occ_eval, occ_read

    model, strip, field, nodes = _moved_die()
    rep = fit_points(nodes, base=model, tolerance=0.002, noise=0.0, source="compensated FE nodes")
    assert rep.fit.stop == "tolerance"
    out = tmp_path / "moved.igs"
    write_fit_outputs(rep, out, units=model.units)
    faces = occ_read(out)
    assert len(faces) == 1
    u0, u1, v0, v1 = faces[0].bounds
    uu, vv = (a.ravel() for a in np.meshgrid(np.linspace(u0, u1, 400), np.linspace(v0, v1, 25), indexing="ij"))
    pts, _, _ = occ_eval(faces[0].surface, uu, vv, order=0)
    d = _moved_distance_bound(strip, field, pts)
    assert d.max() <= 0.005, d.max()


@pytest.mark.slow
def test_compensation_fit_converts(tmp_path):
    # `cadbridge convert` runs on the fitted surface (mesh + normals + Nagata + report)
    model, strip, field, nodes = _moved_die()
    rep = fit_points(nodes, base=model, tolerance=0.002, noise=0.0)
    out = tmp_path / "moved.igs"
    write_fit_outputs(rep, out, units=model.units, extras=False)
    assert main(["convert", str(out), "-o", str(tmp_path / "conv"), "--size", "4"]) == 0
    assert list((tmp_path / "conv").rglob("*.nagata"))


def test_plane_base_and_collinear():
    rng = np.random.default_rng(1)
    a = rng.random((500, 2))
    pts = np.column_stack([a, 0.2 * a[:, 0]])
    par = plane_base(pts)
    # reference: the parameters are lengths in the plane (distances preserved)
    d_uv = np.hypot(par.u[1:] - par.u[0], par.v[1:] - par.v[0])
    assert np.allclose(d_uv, np.linalg.norm(pts[1:] - pts[0], axis=1))
    with pytest.raises(FitInputError, match="collinear"):
        plane_base(np.outer(np.linspace(0, 1, 50), [1.0, 2.0, 3.0]))
    with pytest.raises(FitInputError, match="coincide"):
        plane_base(np.ones((10, 3)))


def test_coons_surface_of_four_boundary_curves():
    # reference: a bilinear-blended Coons patch interpolates its boundary curves exactly, and for
    # four edges of a bicubic-in-one-direction surface that is ruled... check the edges themselves
    c_v0 = NurbsCurve(3, [0, 0, 0, 0, 1, 1, 1, 1], [[0, 0, 0], [1, 0, 0.5], [2, 0, -0.3], [3, 0, 0]])
    c_v1 = NurbsCurve(2, [0, 0, 0, 1, 1, 1], [[0, 2, 0], [1.5, 2, 1.0], [3, 2, 0]])
    c_u0 = NurbsCurve(1, [0, 0, 1, 1], [[0, 0, 0], [0, 2, 0]])
    c_u1 = NurbsCurve(2, [0, 0, 0, 1, 1, 1], [[3, 0, 0], [3.2, 1, 0.4], [3, 2, 0]])
    s = coons_surface(c_v0, c_v1, c_u0, c_u1)
    t = np.linspace(0, 1, 31)
    one, zero = np.ones_like(t), np.zeros_like(t)
    assert np.allclose(s.evaluate(t, zero), c_v0.evaluate(t), atol=1e-12)
    assert np.allclose(s.evaluate(t, one), c_v1.evaluate(t), atol=1e-12)
    assert np.allclose(s.evaluate(zero, t), c_u0.evaluate(t), atol=1e-12)
    assert np.allclose(s.evaluate(one, t), c_u1.evaluate(t), atol=1e-12)
    # interior: P&T eq. (10.21) evaluated directly
    u, v = 0.3, 0.7
    p = lambda c, x: c.evaluate(np.array([x]))[0]  # noqa: E731
    ref = ((1 - v) * p(c_v0, u) + v * p(c_v1, u) + (1 - u) * p(c_u0, v) + u * p(c_u1, v)
           - ((1 - u) * (1 - v) * p(c_v0, 0) + u * (1 - v) * p(c_v0, 1) + (1 - u) * v * p(c_v1, 0) + u * v * p(c_v1, 1)))
    assert np.allclose(s.evaluate(np.array([u]), np.array([v]))[0], ref, atol=1e-12)


def test_data_outline_of_a_disc():
    # reference: points filling a disc of radius 1 -> the outline encloses ~pi and lies near r = 1
    rng = np.random.default_rng(2)
    r, a = np.sqrt(rng.random(40000)), rng.random(40000) * 2 * np.pi
    loop = data_outline(r * np.cos(a), r * np.sin(a), (-1.0, 1.0, -1.0, 1.0))
    poly = loop.curves[0].control_points
    area = 0.5 * np.sum(poly[:-1, 0] * poly[1:, 1] - poly[1:, 0] * poly[:-1, 1])
    assert area == pytest.approx(np.pi, rel=0.05)
    assert np.abs(np.hypot(poly[:, 0], poly[:, 1]) - 1.0).max() < 0.06


def test_read_points_formats(tmp_path):
    # reference: the same points written in each format come back (meshio round trip)
    import meshio

    rng = np.random.default_rng(3)
    pts = rng.random((30, 3))
    (tmp_path / "a.csv").write_text("x,y,z\n" + "\n".join(",".join(repr(float(c)) for c in p) for p in pts) + "\n")
    got, kind = read_points(tmp_path / "a.csv")
    assert kind == "scan" and np.array_equal(got, pts)
    tri = np.array([[0, 1, 2], [2, 3, 4]])
    meshio.write(tmp_path / "a.stl", meshio.Mesh(pts[:5], [("triangle", tri)]))
    got, kind = read_points(tmp_path / "a.stl")
    assert kind == "mesh vertices" and np.allclose(np.sort(got, axis=0), np.sort(pts[:5], axis=0), atol=1e-6)
    meshio.write(tmp_path / "a.ply", meshio.Mesh(pts[:5], [("triangle", tri)]))
    assert len(read_points(tmp_path / "a.ply")[0]) == 5


def _run(args, capsys):
    rc = main(args)
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_cli_bad_input_one_line_exit_2(tmp_path, capsys):
    few = tmp_path / "few.xyz"
    few.write_text("\n".join(f"{i} {i * i % 7} {i % 3}" for i in range(10)) + "\n")
    line = tmp_path / "line.xyz"
    line.write_text("\n".join(f"{i} {2 * i} {3 * i}" for i in range(100)) + "\n")
    nan = tmp_path / "nan.xyz"
    nan.write_text("0 0 0\n1 nan 0\n0 1 0\n")
    junk = tmp_path / "junk.ply"
    junk.write_text("this is not a mesh\n")
    cases = [(few, "fewer than the 4x4 = 16 control points"), (line, "collinear"),
             (nan, "NaN or infinite coordinates"), (junk, "cannot read"), (tmp_path / "none.xyz", "no such file")]
    for path, msg in cases:
        rc, out, err = _run(["fit", str(path), "-o", str(tmp_path / "o.igs")], capsys)
        assert rc == 2, (path, err)
        lines = [ln for ln in err.splitlines()  # without the compile notice and the progress lines
                 if ln.strip() and "compiling" not in ln and not re.match(PROGRESS_LINE, ln)]
        assert len(lines) == 1 and msg in lines[0], err
        assert "Traceback" not in err
    assert not (tmp_path / "o.igs").exists()


def test_cli_fit_height_field_writes_outputs(tmp_path, capsys):
    # reference: an analytic height field z = f(x, y); the written IGES read back by our reader
    # (round trip) is within tolerance of z = f at dense samples inside the trim
    rng = np.random.default_rng(4)
    xy = rng.uniform(0, 50, (6000, 2))
    f = lambda x, y: 0.002 * (x - 25) ** 2 - 0.001 * x * y + 3.0  # noqa: E731
    pts = np.column_stack([xy, f(xy[:, 0], xy[:, 1])])
    path = tmp_path / "hf.xyz"
    np.savetxt(path, pts)
    out = tmp_path / "hf.igs"
    rc, stdout, err = _run(["fit", str(path), "-o", str(out), "--tolerance", "0.001", "--trim", "--noise", "0"], capsys)
    assert rc == 0, err
    assert "tolerance reached" in stdout and "control net" in stdout
    for suffix in ("_report.txt", "_report.json", "_deviation.vtu", "_deviation.png", "_beyond.csv"):
        assert (tmp_path / f"hf{suffix}").exists()
    model = cadbridge.read_iges(out)
    face = model.faces[0]
    assert face.entity_type == 144
    pytest.importorskip("OCP")
    from cadbridge.verify.reference import occ_read

    assert len(occ_read(out)) == 1  # OpenCASCADE reads the trimmed surface (144 over 128)
    assert main(["verify", str(out)]) == 0  # and evaluates it as we do
    capsys.readouterr()
    u, v = face.surface.grid(60, 60)
    ins = face.contains(u, v)
    s = face.surface.evaluate(u[ins], v[ins])
    assert np.abs(s[:, 2] - f(s[:, 0], s[:, 1])).max() <= 2e-3


@pytest.mark.slow
def test_large_input_path_chooses_knots_on_a_subset():
    # the >max_points_per_level path (knots from a random subset, final net on all points) gives
    # the same quality against the die CAD as the direct fit
    from cadbridge.fitting.surface_fit import face_base
    from cadbridge.nurbs.fit import fit_surface

    model, strip, x, bad = die_scan(30000)
    par = face_base(x, model)
    fit = fit_surface(x, par.u, par.v, tolerance=0.01, max_points_per_level=10000)
    assert fit.stop == "tolerance"
    assert len(fit.distance) == len(x)
    u, v = fit.surface.grid(400, 40)
    pr = project_points(fit.surface.evaluate(u, v), model)
    assert pr.distance[pr.status == 0].max() <= 0.04


@pytest.mark.slow
def test_cli_rational_fit_on_the_die_base(tmp_path, capsys):
    # weights fixed from the base (the die strip's rational quarter circle): the fitted surface is
    # rational and within 3 sigma + tol of the CAD (reference: the die CAD)
    model, strip, x, bad = die_scan(20000)
    path = tmp_path / "scan.xyz"
    np.savetxt(path, x)
    out = tmp_path / "rat.igs"
    rc, stdout, err = _run(["fit", str(path), "-o", str(out), "--base", str(DIE), "--rational", "--no-report"], capsys)
    assert rc == 0, err
    face = cadbridge.read_iges(out).faces[0]
    assert face.surface.rational and face.surface.degree_u == 2
    u, v = face.surface.grid(300, 30)
    pr = project_points(face.surface.evaluate(u, v), model)
    assert pr.distance[pr.status == 0].max() <= 0.04


def test_tool_file_nodes_and_nagata_samples(tmp_path):
    # reference: a tool file of the die (structured quads on the exact strip, exact CAD normals);
    # its Nagata samples lie close to the die (Nagata with exact normals, thesis ch. 5), the fit is
    # within its tolerance of the samples and so within Nagata's error + tol of the die CAD
    from cadbridge.io.toolfile import ToolData, write_toolfile

    model = cadbridge.read_iges(DIE)
    strip = join_strip([f.surface for f in model.faces])
    u0, u1, v0, v1 = strip.domain
    nu_, nv_ = 117, 6
    uu, vv = (a.ravel() for a in np.meshgrid(np.linspace(u0, u1, nu_), np.linspace(v0, v1, nv_), indexing="ij"))
    nodes, normals = strip.evaluate(uu, vv), strip.normal(uu, vv)
    idx = np.arange(nu_ * nv_).reshape(nu_, nv_)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1).reshape(-1, 4)
    path = tmp_path / "die.nagata"
    write_toolfile(ToolData(name="die", units="MM", nodes=nodes, normals=normals, quads=quads), path)
    got, kind = read_points(path)
    assert kind == "tool nodes" and np.allclose(np.sort(got, axis=0), np.sort(nodes, axis=0))
    samples, kind = read_points(path, nagata_samples=4)
    assert kind == "Nagata samples" and len(samples) > 4 * len(nodes)
    nagata_err = project_points(samples, model).distance.max()
    assert nagata_err < 0.03  # 2 mm elements across the plane-radius junctions
    rep = fit_points(samples, base=model, tolerance=0.005, noise=0.0)
    assert rep.fit.stop == "tolerance" and rep.fit.max_deviation <= 0.005  # against the samples
    u, v = rep.face.surface.grid(400, 20)
    pr = project_points(rep.face.surface.evaluate(u, v), model)
    assert pr.distance[pr.status == 0].max() <= nagata_err + 0.005


def test_stray_region_is_left_out():
    # a scanned fixture: a 10 mm patch of 3000 points 6 mm above the land (not die surface); the
    # fit must ignore it (beyond 1 % of the base size) and stay within 3 sigma + tol of the CAD
    model, strip, x, bad = die_scan(30000)
    rng = np.random.default_rng(9)
    blob = np.column_stack([rng.uniform(140, 150, 3000), rng.uniform(5, 15, 3000), np.full(3000, 6.0)])
    rep = fit_points(np.vstack([x, blob]), base=model, tolerance=0.01)
    assert rep.ignored == 3000 and len(rep.points) == len(x)
    assert "left out as stray" in rep.format()
    u, v = rep.face.surface.grid(400, 40)
    pr = project_points(rep.face.surface.evaluate(u, v), model)
    assert pr.distance[pr.status == 0].max() <= 0.04
