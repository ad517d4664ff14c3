"""Class 'reversed parameter range in a 128' (U0 > U1 or V0 > V1; IGES 5.3 4.24 asks for
U0 < U1, V0 < V1): the two values name the same rectangle of the surface, so the range is
read in increasing order, with a Diagnostic naming the fields. Reference: the same surface
written with the range in order (hand-made files)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers.iges_fixtures import bilinear_128, make_iges

from cadbridge.iges import IgesError, read_iges_string

CORNERS = ((0, 0, 0), (2, 0, 1), (0, 1, 0), (2, 1, 3))


def _with_range(u0: float, u1: float, v0: float, v1: float) -> str:
    rec = bilinear_128(CORNERS, domain=(0.0, 1.0, 0.0, 1.0))
    return rec[: rec.rindex(",0.0,1.0,0.0,1.0;")] + f",{u0!r},{u1!r},{v0!r},{v1!r};"


@pytest.mark.parametrize("rng, fields", [
    ((0.75, 0.25, 0.0, 1.0), ["U0 = 0.75 > U1 = 0.25"]),
    ((0.0, 1.0, 0.9, 0.1), ["V0 = 0.9 > V1 = 0.1"]),
    ((0.75, 0.25, 0.9, 0.1), ["U0 = 0.75 > U1 = 0.25", "V0 = 0.9 > V1 = 0.1"]),
])
def test_reversed_range_read_in_order(rng, fields):
    m = read_iges_string(make_iges([{"params": _with_range(*rng)}]))
    u0, u1, v0, v1 = rng
    ordered = (min(u0, u1), max(u0, u1), min(v0, v1), max(v0, v1))
    ref = read_iges_string(make_iges([{"params": _with_range(*ordered)}]))
    s, r = m.faces[0].surface, ref.faces[0].surface
    assert s.domain == r.domain == ordered
    uv = np.random.default_rng(3).uniform(0, 1, (20, 2))
    assert np.array_equal(s.evaluate(uv[:, 0], uv[:, 1]), r.evaluate(uv[:, 0], uv[:, 1]))
    msgs = [d.message for d in m.diagnostics if d.de == 1 and d.entity_type == 128]
    assert len(msgs) == len(fields)
    for f, msg in zip(fields, msgs):
        assert msg.startswith(f) and "parameter range reversed" in msg


def test_empty_range_still_refused():
    with pytest.raises(IgesError, match=r"field U0\): parameter range \[0.5, 0.5\] is empty"):
        read_iges_string(make_iges([{"params": _with_range(0.5, 0.5, 0.0, 1.0)}]), "e.igs")
