"""`cadbridge.io.error_map`: the error pictures of the convert report.

References: a quarter cylinder with two flat flanges built here (exact normals by hand; the
view that sees the whole radius best is at 45 degrees between its end normals, the
analytic answer), per-element maxima taken by a plain Python loop over the samples, and the
PNG file's own header.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest

from cadbridge.io.error_map import element_max, plot_error_map, view_direction
from cadbridge.nagata.mesh import NagataMesh

R = 5.0  # radius [mm]


def radius_strip(n_arc: int = 6, n_flat: int = 3, flat: float = 20.0, width: float = 10.0, n_y: int = 3):
    """A flange (z = 0, x from -flat to 0), a quarter cylinder of radius R about the y axis
    centred at (0, 0, -R) (normal (sin t, 0, cos t), t from 0 to 90 deg) and a wall (x = R,
    z from -R down to -R - flat), extruded over y in [0, width]; quads with the exact normals.
    Returns the NagataMesh and the (E,) bool of the elements on the cylinder."""
    s_flange = np.linspace(-flat, 0.0, n_flat + 1)
    t = np.linspace(0.0, np.pi / 2, n_arc + 1)
    s_wall = np.linspace(0.0, flat, n_flat + 1)
    px = np.concatenate([s_flange, R * np.sin(t[1:]), np.full(n_flat, R)])
    pz = np.concatenate([np.zeros(n_flat + 1), -R + R * np.cos(t[1:]), -R - s_wall[1:]])
    nx = np.concatenate([np.zeros(n_flat + 1), np.sin(t[1:]), np.ones(n_flat)])
    nz = np.concatenate([np.ones(n_flat + 1), np.cos(t[1:]), np.zeros(n_flat)])
    y = np.linspace(0.0, width, n_y + 1)
    k = len(px)
    nodes = np.array([[px[i], yy, pz[i]] for i in range(k) for yy in y])
    normals = np.array([[nx[i], 0.0, nz[i]] for i in range(k) for _ in y])
    idx = np.arange(k * len(y)).reshape(k, len(y))
    quads = np.array([[idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]]
                      for i in range(k - 1) for j in range(len(y) - 1)])
    on_arc = np.repeat((np.arange(k - 1) >= n_flat) & (np.arange(k - 1) < n_flat + n_arc), len(y) - 1)
    return NagataMesh(nodes, quads, normals), on_arc


def png_size(path) -> tuple[int, int]:
    with open(path, "rb") as fh:
        head = fh.read(24)
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", head[16:24])


def max_angle_to_arc(d: np.ndarray) -> float:
    """Largest angle [deg] between ``d`` and the cylinder's exact normals (t in 0..90 deg)."""
    t = np.linspace(0.0, np.pi / 2, 1001)
    n = np.column_stack([np.sin(t), np.zeros_like(t), np.cos(t)])
    return float(np.degrees(np.arccos(np.clip(n @ d, -1, 1))).max())


def test_view_sees_the_radius_at_45_degrees_at_most(tmp_path):
    """Analytic answer: the normals of a quarter cylinder span 90 degrees in the x-z plane;
    the direction that sees all of them at the smallest largest angle is their bisector
    (sin 45, 0, cos 45), which sees every point of the radius at 45 degrees or less. Both
    views (the whole tool by curvature, the close-up by error) must find it, not look
    along the flanges (0 or 90 degrees: the far end of the radius edge-on)."""
    nm, on_arc = radius_strip()
    values = np.where(on_arc, 1e-3, 0.0)  # error on the radius only, as with exact normals
    drawn = plot_error_map(tmp_path / "m.png", nm, values, title="t", label="e")
    for d in (drawn.whole_view, drawn.close_view):
        assert abs(d[1]) < 1e-9  # perpendicular to the axis
        assert max_angle_to_arc(d) == pytest.approx(45.0, abs=0.5)
    assert png_size(tmp_path / "m.png") == (1760, 880)


def test_view_direction_is_the_mean_normal_when_nothing_is_grazing():
    t = np.linspace(0.1, 0.7, 7)
    n = np.column_stack([np.sin(t), np.zeros_like(t), np.cos(t)])
    d = view_direction(n, np.ones(len(t)))
    np.testing.assert_allclose(d, [np.sin(0.4), 0.0, np.cos(0.4)], atol=1e-12)


def test_labelled_elements_are_the_largest_in_the_grid(tmp_path):
    """Reference: the maximum of |error| per element by a loop over the samples (NaN samples
    skipped), sorted by value; the picture labels the five largest, 1-based."""
    nm, _ = radius_strip()
    g = nm.sample_grid(4)
    rng = np.random.default_rng(7)
    err = rng.normal(0.0, 1e-3, len(g.elem))
    err[rng.choice(len(err), 40, replace=False)] = np.nan
    err[g.elem == 5] = np.nan  # an element without a single measured sample
    ref = np.full(nm.n_elements, np.nan)
    for e, v in zip(g.elem, err):
        if np.isfinite(v) and not abs(v) <= ref[e]:
            ref[e] = abs(v)
    values = element_max(g.elem, err, nm.n_elements)
    np.testing.assert_array_equal(np.isnan(values), np.isnan(ref))
    np.testing.assert_array_equal(values[~np.isnan(ref)], ref[~np.isnan(ref)])
    drawn = plot_error_map(tmp_path / "m.png", nm, values, title="t", label="e", unit="mm")
    measured = [e for e in range(nm.n_elements) if np.isfinite(ref[e])]
    expected = sorted(measured, key=lambda e: -ref[e])[:5]
    assert drawn.worst.tolist() == expected
    assert drawn.labels == [str(e + 1) for e in expected]
    np.testing.assert_array_equal(drawn.values, ref[expected])
    assert drawn.unmeasured == 1
    assert 5 not in drawn.worst


def test_error_free_tool_still_draws(tmp_path):
    nm, _ = radius_strip()
    drawn = plot_error_map(tmp_path / "zero.png", nm, np.zeros(nm.n_elements), title="t", label="e")
    assert png_size(tmp_path / "zero.png") == (1760, 880)
    assert len(drawn.worst) == 0 and drawn.unmeasured == 0
    # round-off of a flat tool (1e-16 x its size) at or below ``negligible``: drawn, not labelled
    roundoff = np.full(nm.n_elements, 2.2e-16)
    drawn = plot_error_map(tmp_path / "roundoff.png", nm, roundoff, title="t", label="e", negligible=1e-12)
    assert len(drawn.worst) == 0 and (tmp_path / "roundoff.png").is_file()


def test_nothing_measured_draws_grey_and_labels_nothing(tmp_path):
    nm, _ = radius_strip()
    drawn = plot_error_map(tmp_path / "nan.png", nm, np.full(nm.n_elements, np.nan), title="t", label="e")
    assert (tmp_path / "nan.png").is_file()
    assert len(drawn.worst) == 0 and drawn.unmeasured == nm.n_elements


def test_values_must_be_one_per_element(tmp_path):
    nm, _ = radius_strip()
    with pytest.raises(ValueError, match="values must be"):
        plot_error_map(tmp_path / "bad.png", nm, np.zeros(3), title="t", label="e")
    assert not (tmp_path / "bad.png").exists()


def test_view_keeps_the_worst_element_in_sight():
    """Elements facing +x (weight 1) and the worst element facing +z: unconstrained the view is
    +x, which sees the worst element edge-on (90 degrees). With ``must_see`` the view stays
    within 60 degrees of +z; the best such direction (analytic) is on that cone's rim nearest
    +x, 30 degrees from +x, and the candidates are about 10 degrees apart."""
    n = np.array([[1.0, 0.0, 0.0]] * 20 + [[0.0, 0.0, 1.0]])
    w = np.r_[np.ones(20), 1e-6]
    np.testing.assert_allclose(view_direction(n, w), [1.0, 0.0, 0.0], atol=1e-6)
    d = view_direction(n, w, must_see=np.array([0.0, 0.0, 1.0]))
    assert np.degrees(np.arccos(d[2])) <= 60.0 + 1e-9
    assert np.degrees(np.arccos(d[0])) <= 40.0
