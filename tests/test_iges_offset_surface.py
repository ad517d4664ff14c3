"""Class 'offset surface (140)', not read yet: a face over one is skipped with a diagnostic
naming the base surface, and a file whose faces are all skipped is refused (exit 2) with one
line saying why -- not 'no surfaces in this file'. References: occt_bug23171_tube_surf
(2 x 140 over 120 surfaces of revolution; OCC: OffsetSurface) and a hand-made 140 over a 128.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from test_iges_fixtures import bilinear_128, make_iges

from cadbridge.cli import EXIT_BAD_INPUT, main
from cadbridge.iges import read_iges_string

ROOT = Path(__file__).resolve().parents[1]
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


@pytest.mark.skipif(not TUBE.is_file(), reason="shared/cad_corpus not present")
def test_tube_offset_faces_refused_by_name(tmp_path, capsys):
    _refused(capsys, ["convert", str(TUBE), "-o", str(tmp_path / "out")],
             "none of its 2 faces can be read (DE 5: offset surface (140) over a surface of revolution (120, DE 7) "
             "is not supported; DE 37: offset surface (140) over a surface of revolution (120, DE 39) is not "
             "supported)")
