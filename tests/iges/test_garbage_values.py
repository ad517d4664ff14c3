"""Fields that hold no IGES value, in entities no face needs.

Class of defect: a damaged number or garbage ("-", "1..", "X") in a field of an entity the
reader interprets but does not read for the faces (a 504 edge list's vertex pointer, a line
nothing references) was accepted; the mesher then read the same file with its own IGES reader
(OpenCASCADE inside gmsh 4.15), which crashed (SIGSEGV) on a "-" in a 504. Such a file is
malformed and is refused with an IgesError at the field.

Reference: the IGES 5.3 value syntax (section 2.2.2: integers, reals, Hollerith strings,
empty fields for defaults), on hand-made files (`make_iges`) that read without the damage.
"""

from __future__ import annotations

import pytest

from cadbridge.iges import IgesError, read_iges_string
from tests.helpers.iges_fixtures import bilinear_128, make_iges

LINE = "110,0.,0.,0.,1.,2.,3.;"  # referenced by nothing: not a face, not read for one
NOTE = "212,1,4,2.,1.,1,0.,0.,0,0.,0.,0.,4HNOTE;"  # general note: an entity type the reader keeps raw


def _text(line: str = LINE, note: str = NOTE) -> str:
    return make_iges([{"params": bilinear_128()}, {"params": line}, {"params": note}])


def test_undamaged_file_reads():
    m = read_iges_string(_text(), "ok.igs")
    assert len(m.faces) == 1


@pytest.mark.parametrize("garbage, k", [("-", 5), ("1..", 2), ("X", 6), ("1E999", 4), ("--5", 1)])
def test_garbage_in_an_unread_field_is_refused(garbage, k):
    """Field k (1-based) of the 110 (DE 3) replaced by ``garbage``: refused at that field."""
    fields = LINE.rstrip(";").split(",")
    fields[k] = garbage
    text = _text(",".join(fields) + ";")
    with pytest.raises(IgesError) as info:
        read_iges_string(text, "bad.igs")
    err = info.value
    assert err.de == 3 and err.entity_type == 110 and err.field == f"parameter {k}", str(err)
    assert garbage in str(err) and str(err).startswith("bad.igs line ")
    assert err.line == next(i for i, ln in enumerate(text.splitlines(), 1) if ln[72] == "P" and ln[64:72].strip() == "3")


def test_values_of_every_kind_are_accepted():
    """Integers, reals in every exponent form, empty fields and Hollerith strings all read."""
    line = "110,0,+.5,-1.E+00,1.D0,2.5e-3,;"
    note = "212,1,4,2.,1.,1,0.,0.,0,0.,0.,0.,7HX-1..;,;"
    assert len(read_iges_string(_text(line, note), "ok.igs").faces) == 1


def test_garbage_in_an_uninterpreted_entity_is_kept_raw():
    """An entity type the reader does not interpret (212 here) keeps its fields as text, as
    before: the file still reads."""
    m = read_iges_string(_text(note="212,1,4,2.,1.,1,0.,0.,0,0.,X,0.,4HNOTE;"), "ok.igs")
    assert len(m.faces) == 1 and m.raw[5][2][9] == "X"
