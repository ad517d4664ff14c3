"""Class 'knot line where the normal is undefined on both sides' (CTS17806-38038, CATIA V4:
a bicubic 128 whose knot line u = 1 has no normal on either side): `crease_knots` takes it
for no crease, without numpy's "All-NaN slice" RuntimeWarning (which `cadbridge convert`
showed the user as a warning line). Reference: the knots whose one-sided normals are finite
and differ (u = 2 and u = 4, `knot_jump`), and no warning at all."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from cadbridge.iges import read_iges

CTS = Path(__file__).resolve().parents[3] / "shared" / "cad_corpus" / "iges" / "occt_CTS17806-38038_CATIAV4.igs"


@pytest.mark.skipif(not CTS.is_file(), reason="shared/cad_corpus not present")
def test_undefined_knot_line_is_no_crease_and_warns_nothing():
    s = read_iges(CTS).faces[0].surface
    v0, v1 = s.domain[2:]
    along = v0 + (v1 - v0) * np.linspace(0.0, 1.0, 17)
    assert np.all(np.isnan(s.knot_jump("u", 1.0, along)))  # the case: no normal on either side
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ku, kv = s.crease_knots()
    expect = [k for k in np.unique(s.knots_u)[1:-1] if np.nanmax(np.append(s.knot_jump("u", float(k), along), 0)) > 1e-6]
    np.testing.assert_array_equal(ku, expect)
    assert list(ku) == [2.0, 4.0] and len(kv) == 0
