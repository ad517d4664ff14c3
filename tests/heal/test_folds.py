"""Fold lines inside faces (issues 13 and 8): faces whose surface runs back over itself.

References: an analytic Z-fold, S(u, v) = (L u, y(v), e L v) with y'(v) = 3 L (v - a)(v - b),
a Bezier surface whose fold lines are exactly v = a and v = b (the speed minimum of the
v-lines, S_v . S_vv = y' y'' = 0), with across radius (e L)^2 / |y''(a)| and cusp normal
(0, 0, +-1); OpenCASCADE's own derivatives and normals of the ANSA face FACE(274) (OCP
``Geom_BSplineSurface`` from the IGES reader) for the corpus file.
"""

from __future__ import annotations

import re
from pathlib import Path

import meshio
import numpy as np
import pytest

from cadbridge.cli import EXIT_CHECK_FAILED, PROGRESS_LINE, main
from cadbridge.heal.folds import cusp_normal, fold_lines, fold_nodes, fold_straddling, folds_for
from cadbridge.iges import read_iges
from cadbridge.iges.writer import write_iges
from cadbridge.cad.model import Face, Model
from cadbridge.nurbs.surface import NurbsSurface
from tests.helpers import occ as OCC

SAMPLES = Path(__file__).parents[2] / "iges_samples"
REAL = Path(__file__).parents[3] / "shared" / "iges_real"
ANSA = REAL / "occt_OCC131-2_ANSA9.igs"
L, E, A, B = 100.0, 1e-3, 1.0 / 3.0, 2.0 / 3.0


def z_fold(L=L, e=E, a=A, b=B) -> NurbsSurface:
    """(L u, y(v), e L v), y(v) = L (v^3 - 1.5 (a + b) v^2 + 3 a b v), as a degree (1, 3)
    Bezier surface (Bernstein control values from y and y' at the ends)."""
    d0, y1, d1 = 3 * L * a * b, L * (1 - 1.5 * (a + b) + 3 * a * b), 3 * L * (1 - a) * (1 - b)
    yc = [0.0, d0 / 3, y1 - d1 / 3, y1]
    zc = [e * L * k / 3 for k in range(4)]
    cp = np.array([[[x, yc[j], zc[j]] for j in range(4)] for x in (0.0, L)])
    return NurbsSurface(1, 3, [0, 0, 1, 1], [0, 0, 0, 0, 1, 1, 1, 1], cp)


@pytest.fixture(scope="module")
def folded(tmp_path_factory):
    path = tmp_path_factory.mktemp("fold") / "zfold.igs"
    write_iges(Model(faces=[Face(z_fold(), de=1, name="ZFOLD")]), path)
    return path, read_iges(path)


def test_fold_lines_of_the_analytic_z_fold(folded):
    _, model = folded
    size = model.size()
    f = fold_lines(model)
    assert f.partial == [] and [(l.face, l.across) for l in f.lines] == [(0, "v"), (0, "v")]
    s = model.faces[0].surface
    for line, exact in zip(f.lines, (A, B)):
        np.testing.assert_allclose(line.s, exact, atol=1e-12)  # fold points: y'(v) = 0
        assert line.t[0] == 0.0 and line.t[-1] == 1.0
        # the 3D curve is the line S(t, exact) within 1e-9 x size, also between its nodes
        t = np.linspace(0, 1, 257)
        x = s.evaluate(t, np.full_like(t, exact))
        assert np.linalg.norm(line.curve.evaluate(t) - x, axis=1).max() <= 1e-9 * size
        # across radius |S_v|^3 / |S_v x S_vv| = (e L)^2 / |y''|, y'' = 3 L (2 v - a - b)
        np.testing.assert_allclose(line.radius, (E * L) ** 2 / abs(3 * L * (2 * exact - A - B)), rtol=1e-9)


def test_cusp_normal_is_the_limit_of_both_sheets(folded):
    """Analytic: the cusp normal is +-z; the sheet normal at v = a +- h is
    (0, -e L, y'(v)) / |.|, whose angle to z is atan(e L / |y'(v)|) -> 0 away from the fold."""
    _, model = folded
    s = model.faces[0].surface
    t = np.linspace(0, 1, 5)
    for exact in (A, B):
        n = cusp_normal(s, "v", t, np.full_like(t, exact))
        np.testing.assert_allclose(np.abs(n[:, 2]), 1.0, atol=1e-12)
        for h in (1e-3, 1e-2, 1e-1):
            for v in (exact - h, exact + h):
                ns = s.normal(t, np.full_like(t, v))
                ang = np.arccos(np.clip(np.abs(ns @ np.array([0.0, 0.0, 1.0])), 0, 1))
                yp = 3 * L * (v - A) * (v - B)
                np.testing.assert_allclose(ang, np.arctan(E * L / abs(yp)), atol=1e-9)


def _no_folds(files):
    for p in files:
        f = fold_lines(read_iges(p))
        assert f.lines == [] and f.partial == [], p.name


def test_no_fold_lines_on_smooth_samples():
    """Tight radii, poles and C0 creases are no folds: every small sample file (and the
    corpus files other than ANSA, when present) has none."""
    files = [p for p in sorted(SAMPLES.glob("*.igs")) if "production" not in p.name]
    if REAL.is_dir():
        files += [p for p in sorted(REAL.glob("*.ig*")) if p.name != ANSA.name]
    _no_folds(files)


@pytest.mark.slow
def test_no_fold_lines_on_the_production_dies():
    """The 1 102-face dies: fillets, bead radii and poles, no folds."""
    _no_folds(sorted(SAMPLES.glob("production_die_*.igs")))


def _grid_mesh(tmp_path, s, v_cols, name):
    u = np.linspace(0.0, 1.0, 5)
    v = np.asarray(v_cols, dtype=float)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    x = s.evaluate(uu.ravel(), vv.ravel())
    idx = np.arange(len(x)).reshape(len(u), len(v))
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1).reshape(-1, 4)
    path = tmp_path / f"{name}.msh"
    meshio.write(path, meshio.Mesh(x, [("quad", quads)]), file_format="gmsh")
    return path, x, quads, uu.ravel(), vv.ravel()


def test_fold_straddling_hand_made(tmp_path, folded):
    """Reference: the construction. Columns v = 0, .25, .5, .75, 1: the column [.25, .5]
    holds the fold v = 1/3, [.5, .75] the fold v = 2/3; columns at 0, 1/3, 2/3, 1 put nodes
    on both folds and no element straddles."""
    _, model = folded
    s = model.faces[0].surface
    folds = folds_for(model)
    _, x, quads, u, v = _grid_mesh(tmp_path, s, [0, 0.25, 0.5, 0.75, 1], "across")
    ids = fold_straddling([quads], model, folds, x, np.zeros(len(x), dtype=np.int64), u, v)
    vq = v[quads]
    expect = np.flatnonzero(((vq.min(1) < A) & (vq.max(1) > A)) | ((vq.min(1) < B) & (vq.max(1) > B)))
    assert ids.tolist() == expect.tolist() and len(ids) == 8
    _, x, quads, u, v = _grid_mesh(tmp_path, s, [0, A, B, 1], "on")
    assert len(fold_straddling([quads], model, folds, x, np.zeros(len(x), dtype=np.int64), u, v)) == 0
    ids, which, _ = fold_nodes(x, folds, model)
    assert sorted(ids.tolist()) == np.flatnonzero(np.isin(v, [A, B])).tolist()


def test_guard_stops_a_mesh_that_straddles_a_fold(tmp_path, folded, capsys):
    path, _ = folded
    msh, *_ = _grid_mesh(tmp_path, z_fold(), [0, 0.25, 0.5, 0.75, 1], "across")
    out = tmp_path / "tool"
    code = main(["nagata", str(msh), "--cad", str(path), "-o", str(out)])
    err = [x for x in capsys.readouterr().err.splitlines()
           if "compiling numerical kernels" not in x and not re.match(PROGRESS_LINE, x)]
    assert code == EXIT_CHECK_FAILED, err
    assert len(err) == 1 and "straddles a crease" in err[0], err  # one line, the guard's
    assert not out.exists()


# ---------------------------------------------------------------- the ANSA corpus face

needs_ansa = pytest.mark.skipif(not ANSA.is_file(), reason="corpus file absent")


@needs_ansa
def test_ansa_fold_lines_against_occ():
    """FACE(274) folds twice in v. On OpenCASCADE's surface: at our fold points the v-speed is
    at its minimum (S_v . S_vv = 0 relative to |S_v||S_vv|, OCC's D2), the OCC normals at
    v -+ 0.03 are opposite (the sheets) and within 0.2 degrees of our cusp normal."""
    from OCP.gp import gp_Pnt, gp_Vec

    model = read_iges(ANSA)
    f = folds_for(model)
    assert [(l.face, l.across) for l in f.lines] == [(0, "v"), (0, "v")] and f.partial == []
    s = model.faces[0].surface
    size = model.size()
    p = s.evaluate(np.array([0.5]), np.array([0.8]))[0]
    occ = [g for g in OCC.read_surfaces(ANSA) if g.Value(0.5, 0.8).Distance(gp_Pnt(*p)) < 1e-6 * size]
    assert len(occ) == 1
    g = occ[0]
    for line in f.lines:
        nc = cusp_normal(s, "v", line.t, line.s)
        for t, sv, n in zip(line.t[::8], line.s[::8], nc[::8]):
            P, du, dv, duu, dvv, duv = gp_Pnt(), gp_Vec(), gp_Vec(), gp_Vec(), gp_Vec(), gp_Vec()
            g.D2(float(t), float(sv), P, du, dv, duu, dvv, duv)
            a, b = np.array([dv.X(), dv.Y(), dv.Z()]), np.array([dvv.X(), dvv.Y(), dvv.Z()])
            assert abs(a @ b) <= 1e-6 * np.linalg.norm(a) * np.linalg.norm(b) + 1e-9
            ns = []
            for h in (-0.03, 0.03):
                g.D1(float(t), float(sv + h), P, du, dv)
                c = np.cross([du.X(), du.Y(), du.Z()], [dv.X(), dv.Y(), dv.Z()])
                ns.append(c / np.linalg.norm(c))
            assert ns[0] @ ns[1] < -0.999
            for m in ns:
                assert np.degrees(np.arccos(min(1.0, abs(m @ n)))) < 0.2


def _convert_ansa(tmp_path, element):
    from cadbridge.tool.pipeline import convert

    return convert(str(ANSA), str(tmp_path / element), element=element)


def _check_ansa(result):
    """Nothing refused (no diagnosis), mesh edges on both fold lines, the fold nodes on the
    exact fold (<= 1e-6 x size, the hairpin's width) and normal error below 2 degrees."""
    model = read_iges(ANSA)
    folds = folds_for(model)
    t = next(t for t in result.tools if "274" in t.name)
    assert t.diagnosis == []
    ids, which, _ = fold_nodes(t.mesh.nodes, folds, model)
    assert np.bincount(which, minlength=2).min() >= 5
    assert t.stats["max_normal_error_deg"] < 2.0
    assert t.stats["max_abs_surface_error"] < 0.25 * t.stats["max_abs_flat_surface_error"]


@needs_ansa
def test_ansa_converts_tri(tmp_path):
    _check_ansa(_convert_ansa(tmp_path, "tri"))


@needs_ansa
@pytest.mark.slow
def test_ansa_converts_quad(tmp_path):
    # FACE(401)'s trim-loop excursion along the fold is cut out of its loop and its mesh
    # (cadbridge.heal.loop_excursions; gmsh wound an element inside out in that sliver)
    _check_ansa(_convert_ansa(tmp_path, "quad"))
