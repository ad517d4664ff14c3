"""Class 'undefined length unit' (Global G14 units flag, G15 units name; IGES 5.3
2.2.4.3.14-15: flag 1..11, 3 = the unit named by G15, an omitted flag is 1 = inches).

A flag outside 1..11, or 3, needs a G15 name of the standard's list; without one the unit
is undefined and the file is refused (IgesError naming file, line and field; exit 2 with
one line in `inspect` and `convert`). With one, the named unit is used and noted.
References: occt_bad_header_Rhino.igs (G14 = 0, G15 empty; the corpus README marks it
'expected: clear refusal'; OCC assumes inches) and hand-made Global sections.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers.iges_fixtures import DEFAULT_GLOBAL, bilinear_128, make_iges

from cadbridge.cli import EXIT_BAD_INPUT, main
from cadbridge.iges import IgesError, read_iges_string

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT.parent / "shared" / "cad_corpus" / "iges"
RHINO = CORPUS / "occt_bad_header_Rhino.igs"


def _text(flag_and_name: str) -> str:
    """A one-surface file whose G14, G15 fields are ``flag_and_name`` (e.g. ``"0,"``)."""
    assert ",1.,2,2HMM," in DEFAULT_GLOBAL
    return make_iges([{"params": bilinear_128()}], global_text=DEFAULT_GLOBAL.replace(",1.,2,2HMM,",
                                                                                      f",1.,{flag_and_name},", 1))


@pytest.mark.parametrize("fields, field, match", [
    ("0,", "units flag (G14)", r"units flag \(G14\) = 0 is not an IGES 5.3 value \(1..11\) and units name \(G15\) "
                               r"is empty: the length unit is undefined"),
    ("12,", "units flag (G14)", r"= 12 is not an IGES 5.3 value"),
    ("-1,4HFOOT", "units flag (G14)", r"= -1 is not an IGES 5.3 value \(1..11\) and units name \(G15\) 'FOOT' is no "
                                      r"IGES 5.3 unit name"),
    ("3,", "units name (G15)", r"units flag \(G14\) = 3 names the unit by G15, but units name \(G15\) is empty"),
    ("3,3HFOO", "units name (G15)", r"but units name \(G15\) 'FOO' is no IGES 5.3 unit name"),
])
def test_undefined_unit_refused(fields, field, match):
    text = _text(fields)
    with pytest.raises(IgesError, match=match) as info:
        read_iges_string(text, "u.igs")
    e = info.value
    flag, name = fields.split(",")
    token = name if field.startswith("units name") and name else f",1.,{flag},"  # where the field starts
    line = next(k for k, ln in enumerate(text.splitlines(), 1) if ln[72] == "G" and token in ln[:72])
    assert e.filename == "u.igs" and e.field == field and e.line == line
    assert str(e).startswith(f"u.igs line {line} (field {field}): ")


@pytest.mark.parametrize("fields, flag, to_mm, note", [
    ("0,2HMM", 2, 1.0, "units flag (G14) = 0 is not an IGES 5.3 value (1..11): the unit named by G15, 'MM', used"),
    ("12,2HCM", 10, 10.0, "= 12 is not an IGES 5.3 value (1..11): the unit named by G15, 'CM', used"),
    (",2HFT", 4, 304.8, "units flag (G14) omitted: the unit named by G15, 'FT', used"),
    (",", 1, 25.4, "units flag (G14) and name (G15) omitted: IGES 5.3 default 1 (inches) used"),
    ("3,4HINCH", 3, 25.4, None),
    ("6,1HM", 6, 1000.0, None),
])
def test_unit_named_or_default(fields, flag, to_mm, note):
    m = read_iges_string(_text(fields))
    assert m.units.flag == flag and m.units.to_mm == to_mm
    notes = [d.message for d in m.diagnostics if "G14" in d.message]
    assert len(notes) == (note is not None) and all(note in n for n in notes)


@pytest.mark.skipif(not RHINO.is_file(), reason="shared/cad_corpus not present")
@pytest.mark.parametrize("command", ["inspect", "convert"])
def test_rhino_file_without_unit_refused(tmp_path, capsys, command):
    out = tmp_path / "out"
    argv = ["--quiet", command, str(RHINO)] + (["-o", str(out)] if command == "convert" else [])
    assert main(argv) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert ("occt_bad_header_Rhino.igs line 7 (field units flag (G14)): units flag (G14) = 0 is not an IGES 5.3 "
            "value (1..11) and units name (G15) is empty: the length unit is undefined") in err[0]
    assert not out.exists()
