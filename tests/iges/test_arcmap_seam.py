"""`cad.analytic.ArcMap` at the ends of its angle range.

Reference: the closed form itself at the range's ends (f(start_in) = start_out, f(start_in +
sweep) = start_out + sweep, the arc parameter of a rational quadratic arc) and modularity
of angles. An angle beyond an end by rounding only (the seam of a full turn read as 1e-16
past 2 pi) is that end; one a whole turn off is shifted back into the range (the analytic
die's BED01060 &c.: pcurves at 5.05..6.28 rad on an arc of -1.23..0). Before the fix the
first kind was shifted a whole turn too, to the other end of a full-turn arc, and the
analytic die's boss BOS00346 read with its seam edge on the wrong side: its trim loop ran
back over itself and its centre was outside the face.
"""

from __future__ import annotations

import numpy as np
import pytest

from cadbridge.cad.analytic import ArcMap

TWO_PI = 2.0 * np.pi


@pytest.mark.parametrize("start", [-TWO_PI, 0.0, 1.3])
def test_full_turn_ends_within_rounding_stay_ends(start):
    m = ArcMap(start_in=start, sweep=TWO_PI, start_out=5.0)
    lo, hi = m(np.array([start, start + TWO_PI]), 0)[0]
    assert lo == pytest.approx(5.0, abs=1e-14) and hi == pytest.approx(5.0 + TWO_PI, abs=1e-12)
    for eps in (4e-16, 1e-13, 1e-11):
        f = m(np.array([start - eps, start + TWO_PI + eps]), 0)[0]
        np.testing.assert_allclose(f, [lo, hi], rtol=0, atol=1e-9)


def test_angles_a_turn_off_are_shifted_into_the_range():
    m = ArcMap(start_in=-1.23, sweep=1.23)
    x = np.array([5.1, 5.6, TWO_PI])  # the BED faces' pcurve angles
    np.testing.assert_allclose(m(x, 0)[0], m(x - TWO_PI, 0)[0], rtol=0, atol=1e-12)
    assert np.ptp(m(x, 0)[0]) > 0.5  # not clipped to one point
