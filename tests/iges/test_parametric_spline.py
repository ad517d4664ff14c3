"""Class 'parametric spline curve (112) as a trim curve' (IGES 5.3 4.9; ANSA writes its
pcurves so, occt_OCC131-1): read exactly, as the cubic B-spline in Bezier form on the same
parameter, so a face trimmed by 112s is trimmed, not left whole.

References: the 112's own polynomials evaluated at their parameter (analytic); the trimmed
area by Green's theorem on those polynomials (exact Gauss-Legendre quadrature of a
polynomial), against OCC's area of cadbridge's face (`cadbridge.heal.brep`) and of OCC's
own reading of the same file; occt_OCC131-1 (when ../shared is present) against OCC's
reading of it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.helpers.iges_fixtures import bilinear_128, make_iges

from cadbridge.iges import read_iges, read_iges_string
from cadbridge.iges.errors import IgesError

# a closed loop of 4 segments on [0, 4] in the (u, v) of the unit square: three straight
# sides and a cubic bulge; per segment (AX, BX, CX, DX, AY, BY, CY, DY, AZ, BZ, CZ, DZ)
SEGMENTS = np.array([
    [0.25, 0.5, 0, 0, 0.25, 0, 0, 0, 0, 0, 0, 0],  # (0.25, 0.25) -> (0.75, 0.25)
    [0.75, 0, 0, 0, 0.25, 0.5, 0, 0, 0, 0, 0, 0],  # -> (0.75, 0.75)
    [0.75, -0.5, 0.2, -0.2, 0.75, 0.3, -0.3, 0, 0, 0, 0, 0],  # cubic bulge -> (0.25, 0.75)
    [0.25, 0, 0, 0, 0.75, -0.5, 0, 0, 0, 0, 0, 0],  # -> (0.25, 0.25)
], dtype=float)
BREAKS = [0.0, 1.0, 2.0, 3.0, 4.0]


def _record(segments=SEGMENTS, breaks=BREAKS) -> str:
    head = f"112,3,1,2,{len(segments)},"
    return head + ",".join(repr(float(v)) for v in [*breaks, *np.ravel(segments), *np.zeros(12)]) + ";"


def _file(record: str) -> str:
    return make_iges([{"params": bilinear_128(), "status": "00010000"},  # DE 1
                      {"params": record, "status": "00010500"},  # DE 3
                      {"params": "142,1,1,3,0,1;", "status": "00010500"},  # DE 5
                      {"params": "144,1,1,0,5;"}])  # DE 7


def _polynomial(t: np.ndarray) -> np.ndarray:
    """The 112 at t (N,) -> (N, 2), from its coefficients."""
    i = np.clip(np.searchsorted(BREAKS, t, side="right") - 1, 0, len(SEGMENTS) - 1)
    s = (t - np.asarray(BREAKS)[i])[:, None]
    c = SEGMENTS[i].reshape(-1, 3, 4)[:, :2]  # (N, x/y, A..D)
    return c[..., 0] + c[..., 1] * s + c[..., 2] * s ** 2 + c[..., 3] * s ** 3


def _green_area() -> float:
    """Area inside the loop: 1/2 closed integral of (x y' - y x') dt, Gauss-Legendre exact
    for these degree-5 integrands."""
    g, w = np.polynomial.legendre.leggauss(8)
    total = 0.0
    for k, c in enumerate(SEGMENTS.reshape(-1, 3, 4)[:, :2]):  # loop over the 4 segments
        s = 0.5 * (g + 1)
        x, y = (c[j, 0] + c[j, 1] * s + c[j, 2] * s ** 2 + c[j, 3] * s ** 3 for j in range(2))
        dx, dy = (c[j, 1] + 2 * c[j, 2] * s + 3 * c[j, 3] * s ** 2 for j in range(2))
        total += 0.5 * float(np.sum(0.5 * w * (x * dy - y * dx)))
    return abs(total)


def test_112_is_read_exactly():
    model = read_iges_string(_file(_record()))
    loop = model.faces[0].trims.outer
    t = np.concatenate([np.linspace(a, b, 11) for a, b in zip(BREAKS[:-1], BREAKS[1:])])
    pts = np.vstack([np.asarray(c.evaluate(t[(t >= c.domain[0]) & (t <= c.domain[1])]))[:, :2] for c in loop.curves])
    ref = np.vstack([_polynomial(t[(t >= c.domain[0]) & (t <= c.domain[1])]) for c in loop.curves])
    np.testing.assert_allclose(pts, ref, atol=1e-14)


def test_face_trimmed_by_112_has_its_area(tmp_path):
    pytest.importorskip("OCP")
    from tests.helpers.occ import area, read_faces

    from cadbridge.heal.brep import model_brep

    path = tmp_path / "spline_trim.igs"
    path.write_text(_file(_record()))
    exact = _green_area()
    assert abs(exact - 0.25) > 0.01  # the bulge counts
    mine = area(model_brep(read_iges(path)).shape, eps=1e-10)
    occ = sum(area(f, eps=1e-10) for f in read_faces(path))
    assert mine == pytest.approx(exact, rel=1e-9)
    assert occ == pytest.approx(exact, rel=1e-6)


def test_112_with_falling_breakpoints_is_an_iges_error():
    with pytest.raises(IgesError, match=r"breakpoints not increasing.*T\(3\)"):
        read_iges_string(_file(_record(breaks=[0.0, 1.0, 0.5, 3.0, 4.0])))


CORPUS_FILE = Path(__file__).resolve().parents[3] / "shared" / "cad_corpus" / "iges" / "occt_OCC131-1_ANSA9.igs"


@pytest.mark.skipif(not CORPUS_FILE.is_file(), reason="shared/cad_corpus not present")
def test_ansa_face_trimmed_by_112s_has_occs_area():
    pytest.importorskip("OCP")
    from tests.helpers.occ import area, read_faces

    from cadbridge.heal.brep import model_brep

    model = read_iges(CORPUS_FILE)
    assert model.faces[0].trims is not None and model.faces[0].trims.outer is not None
    # ANSA's 2D and 3D trims disagree by 0.004 mm (trim delta): areas agree to that band's share
    assert area(model_brep(model).shape, eps=1e-9) == pytest.approx(
        sum(area(f, eps=1e-9) for f in read_faces(CORPUS_FILE)), rel=1e-3)
