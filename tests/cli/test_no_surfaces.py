"""A file without surfaces (a 2D drawing, a lone curve, points) is refused with exit 2 and one
line that says so, and nothing is written.

References: the files' own contents (the corpus README lists them as wireframe only, one 126
curve, three 116 points; OCC reads 0 faces from each) and hand-made files holding only a
line (110) or a point (116).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers.iges_fixtures import make_iges

from cadbridge.cli import EXIT_BAD_INPUT, main

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT.parent / "shared" / "cad_corpus" / "iges"
NO_SURFACE_FILES = ["occt_Disc_HPME.igs", "occt_bug24012_line_OpenCASCADE.igs",
                    "occt_bug27069_points-with-comments_OpenCASCADE.igs"]


def _refused(capsys, argv: list[str], out: Path, name: str) -> None:
    assert main(["--quiet", *argv]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert f"{name}: no surfaces in this file, nothing to convert" in err[0]
    assert "Error" not in err[0]  # no internal exception's name
    assert not out.exists()


@pytest.mark.parametrize("entity", ["110,0.,0.,0.,1.,0.,0.;", "116,1.,2.,3.,0;"])
@pytest.mark.parametrize("command", ["convert", "mesh"])
def test_hand_made_file_without_surfaces(tmp_path, capsys, entity, command):
    cad = tmp_path / "wire.igs"
    cad.write_text(make_iges([{"params": entity}]))
    out = tmp_path / ("out.msh" if command == "mesh" else "out")
    _refused(capsys, [command, str(cad), "-o", str(out)], out, "wire.igs")


@pytest.mark.skipif(not CORPUS.is_dir(), reason="shared/cad_corpus not present")
@pytest.mark.parametrize("name", NO_SURFACE_FILES)
def test_corpus_files_without_surfaces(tmp_path, capsys, name):
    out = tmp_path / "out"
    _refused(capsys, ["convert", str(CORPUS / name), "-o", str(out)], out, name)
