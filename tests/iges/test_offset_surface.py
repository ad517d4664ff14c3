"""Class 'offset surface (140)' (IGES 5.3 4.25: S + D N, N the unit normal S_u x S_v).

Read exactly where the base allows: over a surface of revolution (120) whose generatrix is a
line in a plane through the axis (cone, cylinder) the offset is the surface of revolution of
the line shifted by D along the normal. Any other base: the face is skipped with a
diagnostic naming it, and a file whose faces are all skipped is refused (exit 2) with one
line saying why -- not 'no surfaces in this file'. References: occt_bug23171_tube_surf
(2 x 140 over 120; `cadbridge verify` agrees with OCC's OffsetSurface to 3e-16 x size, which
also fixes the sign convention), a hand-made offset cylinder (radius by hand), and
hand-made 140s over a 128 and over a 120 with a skew generatrix (refused by name).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.helpers.iges_fixtures import bilinear_128, make_iges

from cadbridge.cli import EXIT_BAD_INPUT, main
from cadbridge.iges import read_iges_string

ROOT = Path(__file__).resolve().parents[2]
TUBE = ROOT.parent / "shared" / "cad_corpus" / "iges" / "occt_bug23171_tube_surf_OpenCASCADE.igs"

OFFSET = make_iges([{"params": bilinear_128(), "status": "00010000"},  # DE 1
                    {"params": "140,0.,0.,1.,2.,1;", "status": "00010000"},  # DE 3: 2 along +z over DE 1
                    {"params": "144,3,0,0,0;"}])  # DE 5


def _refused(capsys, argv: list[str], expected: str) -> None:
    assert main(["--quiet", *argv]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert expected in err[0] and "no surfaces in this file" not in err[0]


def test_hand_made_offset_face_skipped_by_name(tmp_path, capsys):
    m = read_iges_string(OFFSET, "off.igs")
    assert m.faces == []
    [d] = m.diagnostics
    assert d.de == 3 and d.entity_type == 140
    assert d.message == "face skipped: offset surface (140) over a B-spline surface (128, DE 1) is not supported"
    cad = tmp_path / "off.igs"
    cad.write_text(OFFSET)
    _refused(capsys, ["convert", str(cad), "-o", str(tmp_path / "out")],
             "off.igs: none of its 1 faces can be read (DE 3: offset surface (140) over a B-spline surface (128, "
             "DE 1) is not supported)")


def _cylinder_offset(generatrix: str, d: float) -> str:
    """140 (DE 7) at distance ``d`` over the 120 (DE 5) turning ``generatrix`` (110, DE 3) half
    a turn about the z axis (DE 1), as an untrimmed 144 (DE 9)."""
    return make_iges([{"params": "110,0.,0.,0.,0.,0.,1.;", "status": "00010000"},
                      {"params": generatrix, "status": "00010000"},
                      {"params": "120,1,3,0.,3.141592653589793;", "status": "00010000"},
                      {"params": f"140,1.,0.,0.,{d!r},5;", "status": "00010000"},
                      {"params": "144,7,0,0,0;"}])


def test_offset_of_a_cylinder_is_the_cylinder_of_the_shifted_line():
    """Generatrix x = 1 from z = 0 to 2: S_u = +z, S_v = +y at angle 0, so N = S_u x S_v = -x
    (inward) and D = 0.25 gives radius 0.75; D = -0.25 radius 1.25."""
    for d, r in ((0.25, 0.75), (-0.25, 1.25)):
        m = read_iges_string(_cylinder_offset("110,1.,0.,0.,1.,0.,2.;", d))
        [f] = m.faces
        assert f.surface_type == 140
        u, v = np.meshgrid(np.linspace(*f.surface.domain[:2], 7), np.linspace(*f.surface.domain[2:], 9))
        x = f.surface.evaluate(u.ravel(), v.ravel())
        assert np.abs(np.hypot(x[:, 0], x[:, 1]) - r).max() <= 1e-15
        assert x[:, 2].min() == 0.0 and x[:, 2].max() == 2.0 and x[:, 1].min() >= -1e-15  # half a turn


def test_offset_over_a_skew_generatrix_refused_by_name():
    m = read_iges_string(_cylinder_offset("110,1.,0.,0.,1.,1.,2.;", 0.25))
    assert m.faces == []
    assert m.diagnostics[0].message == ("face skipped: offset surface (140) over a surface of revolution whose "
                                        "generatrix is not a line in a plane through the axis (120, DE 5) is not "
                                        "supported")


@pytest.mark.skipif(not TUBE.is_file(), reason="shared/cad_corpus not present")
def test_tube_offset_faces_read():
    from cadbridge.iges import read_iges

    m = read_iges(TUBE)
    assert [(f.de, f.surface_type) for f in m.faces] == [(3, 140), (35, 140)]
    assert m.diagnostics == []
