"""The compiled pieces that make large fits fast (`cadbridge.nurbs.fit`): the exact grid kNN,
the one-pass parameter correction / projection (`reproject`), the symmetric normal-equation
assembly. Each is checked against an independent reference (scipy's cKDTree, the existing
`project_to_surface`, analytic feet on a sphere, the dense product A^T W A)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from cadbridge.nurbs.construct import cylinder_patch, sphere_patch
from cadbridge.nurbs.fit import _normal_equations, nearest_neighbours, reproject, uniform_knots
from cadbridge.nurbs.project import FAILED, project_to_surface
from cadbridge.nurbs.surface import NurbsSurface


@pytest.mark.parametrize("case", ["strip", "thin", "hole_and_duplicates", "clusters"])
def test_nearest_neighbours_match_kdtree(case):
    # reference: scipy cKDTree.query (k + 1 nearest, the point itself dropped): the same distances
    rng = np.random.default_rng(3)
    if case == "strip":
        xy = rng.uniform(0, 1, (20000, 2)) * [230.0, 40.0]
    elif case == "thin":
        xy = rng.uniform(0, 1, (5000, 2)) * [1.0, 1e-4]
    elif case == "hole_and_duplicates":
        xy = rng.uniform(0, 5, (8000, 2))
        xy = xy[np.hypot(xy[:, 0] - 2.5, xy[:, 1] - 2.5) > 1.5]
        xy = np.vstack([xy, xy[:25]])  # 25 points twice
    else:  # dense clusters far apart: most grid cells empty
        xy = np.vstack([rng.normal(c, 0.01, (2000, 2)) for c in ([0, 0], [50, 3], [7, 40])])
    k = 8
    nb = nearest_neighbours(xy, k)
    assert nb.shape == (len(xy), k)
    assert not (nb == np.arange(len(xy))[:, None]).any()  # never the point itself
    d = np.linalg.norm(xy[nb] - xy[:, None, :], axis=2)
    d_ref = cKDTree(xy).query(xy, k=k + 1)[0][:, 1:]
    if case == "hole_and_duplicates":
        # a duplicated point's twin is at distance 0: cKDTree may list the twin before the point
        # itself, so compare the k nearest of the k + 1 including the point
        d_ref = np.sort(cKDTree(xy).query(xy, k=k + 2)[0], axis=1)[:, 1 : k + 1]
        twins = np.zeros(len(xy), bool)
        twins[:25] = twins[-25:] = True
        d_ref[~twins] = cKDTree(xy).query(xy[~twins], k=k + 1)[0][:, 1:]
    assert np.array_equal(d, d_ref)
    assert np.all(np.diff(d, axis=1) >= 0)  # nearest first


def test_nearest_neighbours_few_points():
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    nb = nearest_neighbours(xy, 8)  # k capped at N - 1
    assert nb.tolist() == [[1, 2], [0, 2], [0, 1]]


def _sphere_points(n, seed=0):
    s = sphere_patch(10.0, lat_range=(-1.0, 1.0), lon_range=(0.0, 2.0))
    rng = np.random.default_rng(seed)
    u0, u1, v0, v1 = s.domain
    u = rng.uniform(u0 + 0.05 * (u1 - u0), u1 - 0.05 * (u1 - u0), n)
    v = rng.uniform(v0 + 0.05 * (v1 - v0), v1 - 0.05 * (v1 - v0), n)
    off = rng.uniform(-0.5, 0.5, n)
    foot = s.evaluate(u, v)
    x = foot + off[:, None] * s.normal(u, v)
    return s, u, v, off, x


def test_reproject_newton_matches_project_to_surface():
    # reference: the existing projection from the same start parameters (rational sphere patch)
    s, u, v, off, x = _sphere_points(5000)
    rng = np.random.default_rng(1)
    us = np.clip(u + rng.normal(0, 0.01, len(u)), *s.domain[:2])
    vs = np.clip(v + rng.normal(0, 0.01, len(v)), *s.domain[2:])
    ru, rv, dist, signed, moved = reproject(s, x, us, vs, tol=1e-12, max_iter=30)
    ref = project_to_surface(s, x, uv0=np.column_stack([us, vs]), tol=1e-12, max_iter=30)
    ok = ref.status != FAILED
    assert ok.mean() > 0.99 and moved[ok].all()
    assert np.abs(ru - ref.u)[ok].max() <= 1e-12 and np.abs(rv - ref.v)[ok].max() <= 1e-12
    assert np.abs(dist - ref.distance)[ok].max() <= 1e-12
    # and the analytic feet: distance |offset|, signed distance along the sphere's normal
    assert np.abs(dist - np.abs(off)).max() <= 1e-9
    assert np.abs(signed - off).max() <= 1e-9


def test_reproject_gauss_newton_steps_reach_the_feet():
    # reference: the analytic feet (u, v) the points were built from (x = S(u, v) + d n)
    s, u, v, off, x = _sphere_points(5000, seed=2)
    du = 2e-3 * (s.domain[1] - s.domain[0])
    ru, rv, dist, signed, moved = reproject(s, x, u + du, v - du, steps=3)
    assert moved.all()
    err = np.linalg.norm(s.evaluate(ru, rv) - s.evaluate(u, v), axis=1)
    err0 = np.linalg.norm(s.evaluate(u + du, v - du) - s.evaluate(u, v), axis=1)
    # Gauss-Newton converges linearly at the rate |d| x curvature (<= 0.05 here) plus the
    # parametrisation's non-linearity: after 3 steps the foot error is below 1e-3 of the start's
    assert np.all(err <= 1e-3 * err0 + 1e-12), (err / err0).max()
    near_surface = np.abs(off) < 0.05  # scan-like offsets: the foot to round-off
    assert err[near_surface].max() <= 1e-8 * 10.0
    # the distance at the corrected parameters: second order in the foot error
    assert np.abs(dist - np.abs(off)).max() <= 1e-9
    # residuals only (near < 0): nothing moves, distances at the given parameters
    ru0, rv0, d0, _, m0 = reproject(s, x, u + du, v - du, near=-1.0)
    assert not m0.any() and np.array_equal(ru0, u + du)
    assert np.allclose(d0, np.linalg.norm(x - s.evaluate(u + du, v - du), axis=1), rtol=0, atol=1e-12)


def test_reproject_keeps_edge_points_on_their_edge_and_respects_near():
    # reference: the cylinder's analytic feet; a point flagged on the edge u = u0 moves only in v
    s = cylinder_patch(5.0, 20.0, angle=np.pi)
    u0, u1, v0, v1 = s.domain
    rng = np.random.default_rng(4)
    n = 400
    u = rng.uniform(u0, u1, n)
    v = rng.uniform(v0, v1, n)
    x = s.evaluate(u, v) + 0.1 * s.normal(u, v)
    start_u = u.copy()
    start_u[:50] = u0  # these sit on the edge u = u0
    edge = np.zeros(n, np.uint8)
    edge[:50] = 1
    start_v = np.clip(v + 0.01 * (v1 - v0), v0, v1)
    ru, rv, dist, _, moved = reproject(s, x, start_u, start_v, edge=edge, tol=1e-12, max_iter=30)
    assert np.all(ru[:50] == u0)
    assert np.abs(rv[50:] - v[50:]).max() <= 1e-9 and np.abs(ru[50:] - u[50:]).max() <= 1e-9
    # near: only points within it of S(start) move
    d_start = np.linalg.norm(x - s.evaluate(start_u, start_v), axis=1)
    near = float(np.median(d_start))
    _, _, _, _, moved = reproject(s, x, start_u, start_v, near=near)
    assert not moved[d_start > near].any()
    assert moved[d_start <= near].mean() > 0.9


@pytest.mark.parametrize("p,q,spans_u,spans_v,rational", [(3, 3, 7, 1, False), (2, 3, 5, 4, True), (1, 1, 3, 2, True)])
def test_normal_equations_against_the_dense_product(p, q, spans_u, spans_v, rational):
    # reference: A^T W A and A^T W X with A built column by column from NurbsSurface evaluations
    # of unit control nets (the rational basis R_ab with the fixed weights)
    rng = np.random.default_rng(5)
    ku, kv = uniform_knots(p, spans_u, 0.0, 1.0), uniform_knots(q, spans_v, 0.0, 2.0)
    nu, nv = len(ku) - p - 1, len(kv) - q - 1
    n = 3000
    u, v = rng.uniform(0, 1, n), rng.uniform(0, 2, n)
    x = rng.normal(size=(n, 3))
    w = rng.uniform(0.0, 1.0, n)
    w[::7] = 0.0  # down-weighted points take no part
    cw = rng.uniform(0.5, 2.0, (nu, nv)) if rational else np.ones((nu, nv))
    mat, rhs = _normal_equations(ku, kv, p, q, cw, u, v, x, w)
    a = np.zeros((n, nu * nv))
    for k in range(nu * nv):
        c = np.zeros((nu, nv, 3))
        c.reshape(-1, 3)[k, 0] = 1.0
        a[:, k] = NurbsSurface(p, q, ku, kv, c, cw if rational else None).evaluate(u, v)[:, 0]
    ref = a.T @ (w[:, None] * a)
    assert np.abs(mat.toarray() - ref).max() <= 1e-11 * np.abs(ref).max()
    assert np.abs(rhs - a.T @ (w[:, None] * x)).max() <= 1e-11 * max(1.0, np.abs(rhs).max())


@pytest.mark.parametrize("angle", [np.pi, 2 * np.pi])
def test_face_base_feet_on_open_and_closed_cylinders(angle):
    # reference: analytic feet of points 0.01 off a cylinder (a half, compiled Newton from the
    # nearest sample; the full one is closed: Newton must wrap across the seam, project_to_surface)
    from cadbridge.fitting.surface_fit import face_base
    from cadbridge.cad.model import Face, Model

    s = cylinder_patch(5.0, 20.0, angle=angle)
    rng = np.random.default_rng(0)
    u0, u1, v0, v1 = s.domain
    u, v = rng.uniform(u0, u1, 3000), rng.uniform(v0, v1, 3000)
    x = s.evaluate(u, v) + 0.01 * s.normal(u, v)
    par = face_base(x, Model(faces=[Face(s, de=1)]))
    assert np.abs(par.distance - 0.01).max() <= 1e-9
    feet = s.evaluate(par.u, par.v)
    assert np.abs(np.linalg.norm(feet - s.evaluate(u, v), axis=1)).max() <= 1e-7


@pytest.mark.parametrize("text", ["1 2 3\n4 5 6\n7 8 9.5\n", "x,y,z\n1,2,3\n4, 5, 6\n7,8,9.5\n",
                                  "# scan\n\n1;2;3\n4;5;6\n7;8;9.5\n", "1\t2\t3\t0 0 1\n4 5 6 0 0 1\n7 8 9.5 0 0 1\n"])
def test_text_reader_fast_path_equals_the_line_reader(tmp_path, text):
    # reference: the line-by-line reader (`_read_text` without its numpy fast path)
    from cadbridge.fitting import surface_fit as fitting

    path = tmp_path / "p.xyz"
    path.write_text(text)
    fast = fitting._read_text_fast(path)
    assert fast is not None
    rows = [[float(t) for t in ln.replace(",", " ").replace(";", " ").split()[:3]] for ln in text.splitlines()
            if ln.strip() and ln.strip()[0] not in "#x"]
    assert np.array_equal(fast, np.array(rows))


def test_beyond_csv_lists_exactly_the_flagged_points(tmp_path):
    # reference: the fit's own arrays (the CSV round-trips them exactly, %.17g)
    from cadbridge.fitting.surface_fit import fit_points, write_fit_outputs

    rng = np.random.default_rng(2)
    xy = rng.uniform(0, 50, (4000, 2))
    z = 0.01 * xy[:, 0] ** 2 / 50 + rng.normal(0, 0.004, len(xy))
    z[:40] += 0.5  # outliers
    rep = fit_points(np.column_stack([xy, z]), tolerance=0.005)
    paths = write_fit_outputs(rep, tmp_path / "f.igs")
    csv = [p for p in paths if p.name.endswith("_beyond.csv")][0]
    a = np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2)
    f = rep.fit
    sel = np.nonzero((f.distance > f.tolerance) | f.outliers)[0]
    assert f.outliers[:40].all() and len(sel) > 40
    assert np.array_equal(a[:, 0], sel) and np.array_equal(a[:, 1:4], rep.points[sel])
    assert np.array_equal(a[:, 4], f.u[sel]) and np.array_equal(a[:, 6], f.signed[sel])
    assert np.array_equal(a[:, 8], f.outliers[sel])
