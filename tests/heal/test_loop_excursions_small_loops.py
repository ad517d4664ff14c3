"""Trim loops small against the excursion width (`cadbridge.heal.loop_excursions`).

Class of defect: the hairpin pre-check slid a window of 2 x width of arc along the loop
taken twice; a loop shorter than that window (a small hole in a model whose size, and so
whose default width 1e-3 x size, is large: one control point moved far away by a damaged
number does it) ran the window past the end of its arrays (IndexError).

Reference: analytic polygons. A square loop never runs back beside itself, so it has no
excursion whatever the width; what a width larger than the whole loop finds still meets the
definition of an excursion.
"""

from __future__ import annotations

import numpy as np
import pytest

from cadbridge.cad.model import Face, Model, Trim, TrimLoop
from cadbridge.heal.loop_excursions import RATIO, find_excursions, heal_excursions
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.surface import NurbsSurface


def _plane(side: float) -> NurbsSurface:
    """S(u, v) = (u, v, 0) over [0, side]^2."""
    cp = np.array([[[0.0, 0.0, 0.0], [0.0, side, 0.0]], [[side, 0.0, 0.0], [side, side, 0.0]]])
    return NurbsSurface(1, 1, [0, 0, side, side], [0, 0, side, side], cp)


def _loop(poly) -> TrimLoop:
    return TrimLoop([NurbsCurve(1, [0, 0, 1, 1], np.array([poly[k], poly[(k + 1) % len(poly)]], dtype=float))
                     for k in range(len(poly))])


def _square(x0, y0, a, clockwise=False):
    p = [(x0, y0), (x0 + a, y0), (x0 + a, y0 + a), (x0, y0 + a)]
    return p[::-1] if clockwise else p


@pytest.mark.parametrize("hole", [0.1, 1e-3])
def test_small_hole_in_a_large_face_has_no_excursion(hole):
    """A 1000 x 1000 face with a square hole of side ``hole``: the default width (1e-3 x the
    model size, 1.41) exceeds the hole's whole perimeter."""
    face = Face(surface=_plane(1000.0), de=1, name="big",
                trims=Trim(_loop(_square(0, 0, 1000.0)), [_loop(_square(500.0, 500.0, hole, clockwise=True))]))
    model = Model(faces=[face])
    assert 1e-3 * model.size() > 4 * hole
    assert find_excursions(model) == []
    assert heal_excursions(model) == []


@pytest.mark.parametrize("width", [10.0, 1e6])
def test_width_beyond_the_loop_keeps_the_definition(width):
    """The unit square whose left edge runs down with a Z (strands 2e-4 apart), searched with
    widths far larger than the whole loop (4.4): whatever is found is an excursion by the
    definition (chord within the width, loop length over RATIO x the chord)."""
    left = [(0.0, 1.0), (2e-4, 0.40), (4e-4, 0.60), (6e-4, 0.45), (6e-4, 0.0)]
    poly = [(left[-1][0], 0.0), (1.0, 0.0), (1.0, 1.0)] + left
    model = Model(faces=[Face(surface=_plane(1.0), de=1, name="Z", trims=Trim(_loop(poly)))])
    for e in find_excursions(model, width=width):
        assert e.chord <= width and e.length > RATIO * e.chord
