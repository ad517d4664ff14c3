"""Limit normals of NURBS surfaces at collapsed edges (`NurbsSurface.limit_normal`, `normal`,
`collapsed_sides`): cone apexes, sphere poles, a profile leaving the axis with zero speed.

References: analytic geometry (a sphere's pole normal is its axis; a cone's normal along a
generatrix is constant, (cos az cos a, sin az cos a, sin a) for half angle 90 - a; a surface
of revolution's normal at the apex is its profile's normal there, turned with the azimuth) and
OpenCASCADE's normal (GeomLProp-style D1 cross product, tests/helpers/occ.py) a small step off
the singular point along the generatrix, where OCC has one (at the point itself it has none).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cadbridge.iges.reader import read_iges
from tests.helpers.surfaces import revolved

SAMPLES = Path(__file__).parents[2] / "iges_samples"


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))


def _sample(name: str):
    return read_iges(SAMPLES / name).faces[0].surface


def test_collapsed_sides_of_the_samples() -> None:
    assert _sample("cone_apex.igs").collapsed_sides() == (False, False, True, False)
    assert _sample("hemisphere_pole.igs").collapsed_sides() == (False, False, False, True)
    assert _sample("revolved_apex.igs").collapsed_sides() == (False, False, True, False)
    assert not any(_sample("sphere_patch.igs").collapsed_sides())  # latitude 0..60: no pole
    assert not any(_sample("torus_patch.igs").collapsed_sides())


def test_sphere_pole_is_the_axis() -> None:
    s = _sample("hemisphere_pole.igs")
    u0, u1, v0, v1 = s.domain
    u = np.linspace(u0, u1, 37)
    n, degenerate = s.normal(u, np.full(len(u), v1), return_flags=True)
    assert degenerate.all()
    assert np.abs(n - [0.0, 0.0, 1.0]).max() < 1e-15  # outwards, from every direction


def _azimuth(s, u: np.ndarray, v: float) -> np.ndarray:
    p = s.evaluate(u, np.full(len(u), v))
    return np.arctan2(p[:, 1], p[:, 0])


def test_cone_apex_limit_is_the_generatrix_normal() -> None:
    s = _sample("cone_apex.igs")  # apex (0, 0, 20), half angle 30 deg, opening downwards
    u0, u1, v0, v1 = s.domain
    u = np.linspace(u0, u1, 37)
    n, degenerate = s.normal(u, np.full(len(u), v0), return_flags=True)
    assert degenerate.all()
    az = _azimuth(s, u, v1)
    ref = np.column_stack([np.cos(az) * math.cos(math.radians(30)), np.sin(az) * math.cos(math.radians(30)),
                           np.full(len(u), math.sin(math.radians(30)))])
    assert np.abs(n - ref).max() < 1e-14


def test_revolved_apex_limit_is_the_profile_normal() -> None:
    s = _sample("revolved_apex.igs")  # the profile leaves the axis at 50 deg downwards
    u0, u1, v0, v1 = s.domain
    u = np.linspace(u0, u1, 37)
    n = s.normal(u, np.full(len(u), v0))
    az = _azimuth(s, u, 0.5 * (v0 + v1))
    b = math.radians(50.0)  # tangent (sin b, -cos b) in (r, z): normal +-(cos b, sin b)
    ref = np.column_stack([np.cos(az) * math.cos(b), np.sin(az) * math.cos(b), np.full(len(u), math.sin(b))])
    assert np.abs(np.abs(np.einsum("ij,ij->i", n, ref)) - 1.0).max() < 1e-14
    assert len(np.unique(np.sign(np.einsum("ij,ij->i", n, ref)))) == 1  # one side all around


def test_stationary_profile_needs_the_third_order_term() -> None:
    """The profile's first two control points coincide on the axis: Su, Sv and Suv all vanish at
    the apex, Su x Sv grows like t^3 and its direction is Suvv x Svv: the profile's normal at
    its start, perpendicular to P2 - P0 = (4, -3) in (r, z)."""
    s = revolved([(0.0, 15.0), (0.0, 15.0), (4.0, 12.0), (9.0, 6.0), (14.0, 1.0)], [1.0] * 5,
                 [0, 0, 0, 0, 0.5, 1, 1, 1, 1], 3)
    assert s.collapsed_sides()[2]
    u = np.linspace(0.0, 1.0, 25)
    n, degenerate = s.normal(u, np.zeros(len(u)), return_flags=True)
    assert degenerate.all() and np.all(np.isfinite(n))
    az = _azimuth(s, u, 0.5)
    ref = np.column_stack([0.6 * np.cos(az), 0.6 * np.sin(az), np.full(len(u), 0.8)])
    assert np.abs(np.abs(np.einsum("ij,ij->i", n, ref)) - 1.0).max() < 1e-14
    # the normals just off the apex converge to it linearly
    for h in (1e-3, 1e-5):
        assert _angle(n, s.normal(u, np.full(len(u), h))).max() < 20.0 * h


def test_limit_direction_matters() -> None:
    """The same parameter point approached along v (into the cone) or along u (along the
    collapsed edge, where Su x Sv stays 0 to every order along the ray): the first is the
    generatrix normal, the second falls back to the normal one step along its ray, not NaN."""
    s = _sample("cone_apex.igs")
    u0, u1, v0, v1 = s.domain
    a = s.limit_normal([1.0], [v0], [0.0], [1.0])
    assert np.all(np.isfinite(a))
    az = _azimuth(s, np.array([1.0]), v1)[0]
    assert abs(a[0, 0] - math.cos(az) * math.cos(math.radians(30))) < 1e-14
    b = s.limit_normal([1.0], [v0], [1.0], [0.0])
    assert np.all(np.isfinite(b))


@pytest.mark.parametrize("name, side", [("cone_apex.igs", 2), ("hemisphere_pole.igs", 3), ("revolved_apex.igs", 2)])
def test_limit_against_occ_off_the_point(name: str, side: int) -> None:
    """OCC's normal a step h (1e-7 of the parameter range) inside the domain, on the same
    generatrix, against the limit at the point: they differ by O(h) (nothing on the cone,
    whose normal is constant along a generatrix). At the point itself OCC's S_u x S_v is 0 or
    round-off (a random direction)."""
    pytest.importorskip("OCP")
    from tests.helpers.occ import read_surfaces, surface_normals

    s = _sample(name)
    (occ,) = read_surfaces(SAMPLES / name)
    u0, u1, v0, v1 = s.domain
    u = np.linspace(u0, u1, 13)[:-1]
    at = v0 if side == 2 else v1
    h = 1e-7 * (v1 - v0) * (1.0 if side == 2 else -1.0)
    ours = s.normal(u, np.full(len(u), at))
    theirs = surface_normals(occ, u, np.full(len(u), at + h))
    assert np.all(np.isfinite(theirs))
    assert _angle(ours, theirs).max() < 1e-5


def test_limit_tangent_leaves_the_apex_along_the_generatrix() -> None:
    """The direction a generatrix leaves the apex in: on the cone the unit generatrix (analytic),
    on the stationary profile (P0 = P1 on the axis) the direction of P2 - P0, from Svv."""
    s = _sample("cone_apex.igs")
    u0, u1, v0, v1 = s.domain
    u = np.linspace(u0, u1, 13)
    t = s.limit_tangent(u, np.full(len(u), v0), 0.0, 1.0)
    az = _azimuth(s, u, v1)
    a = math.radians(30.0)
    ref = np.column_stack([np.cos(az) * math.sin(a), np.sin(az) * math.sin(a), np.full(len(u), -math.cos(a))])
    assert np.abs(t - ref).max() < 1e-14
    p = revolved([(0.0, 15.0), (0.0, 15.0), (4.0, 12.0), (9.0, 6.0), (14.0, 1.0)], [1.0] * 5,
                 [0, 0, 0, 0, 0.5, 1, 1, 1, 1], 3)
    u = np.linspace(0.0, 1.0, 13)
    t = p.limit_tangent(u, np.zeros(len(u)), 0.0, 1.0)
    az = _azimuth(p, u, 0.5)
    ref = np.column_stack([0.8 * np.cos(az), 0.8 * np.sin(az), np.full(len(u), -0.6)])
    assert np.abs(t - ref).max() < 1e-14
