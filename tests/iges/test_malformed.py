"""Malformed input: each case must raise IgesError naming the line and the DE (reference:
the line/DE where the defect was planted), and random mutants of a valid file must either
raise IgesError or read into a valid Model — never another exception, hang or huge allocation."""

from __future__ import annotations

import re
import time
from math import pi

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tests.helpers.iges_fixtures import THESIS_APPENDIX_A, bilinear_128, make_iges

from cadbridge.iges import IgesError, read_iges_string
from cadbridge.cad.model import Model


def _line_of(text: str, needle: str) -> int:
    for k, line in enumerate(text.splitlines(), start=1):
        if needle in line:
            return k
    raise AssertionError(needle)


def _fails(text: str, *, line: int | None, de: int | None, field: str | None = None, match: str = "") -> IgesError:
    with pytest.raises(IgesError) as info:
        read_iges_string(text, "bad.igs")
    err = info.value
    msg = str(err)
    assert msg.startswith("bad.igs")
    if line is not None:
        assert err.line == line and f"line {line}" in msg, msg
    if de is not None:
        assert err.de == de and f"DE {de}" in msg, msg
    if field is not None:
        assert err.field == field and f"field {field}" in msg, msg
    assert re.search(match, msg), msg
    return err


GOOD = make_iges([{"params": bilinear_128()}])


def test_truncated_file():
    """File cut inside the P section: the record delimiter is missing."""
    lines = THESIS_APPENDIX_A.splitlines()
    text = "\n".join(lines[:10]) + "\n"  # up to P line 5 of 9
    _fails(text, line=10, de=1, match="record delimiter")


def test_truncated_directory():
    """Directory cut after the first of an entry's two lines."""
    lines = GOOD.splitlines()
    text = "\n".join(lines[:5]) + "\n"  # S, 3 G lines, first D line
    _fails(text, line=5, de=None, match="odd number")


def test_wrong_section_letter():
    lines = GOOD.splitlines()
    lines[3] = lines[3][:72] + "X" + lines[3][73:]
    _fails("\n".join(lines), line=4, de=None, match="section letter")


def test_broken_sequence_number():
    lines = GOOD.splitlines()
    lines[4] = lines[4][:73] + "      7"
    _fails("\n".join(lines), line=5, de=None, match="sequence number 7, expected 1")


def test_sections_out_of_order():
    lines = GOOD.splitlines()
    d = [l for l in lines if l[72] == "D"]
    p = [l for l in lines if l[72] == "P"]
    text = "\n".join(lines[:4] + p + d + lines[-1:])  # P before D
    _fails(text, line=5 + len(p), de=None, match="section D after section P")


def test_parameter_count_mismatch():
    """128 with K1=1, K2=1, M1=1, M2=1 but one control point too few."""
    bad = "128,1,1,1,1,0,0,1,0,0,0.,0.,1.,1.,0.,0.,1.,1.,1.,1.,1.,1.,0.,0.,0.,1.,0.,0.,0.,1.,0.,0.,1.,1.;"
    text = make_iges([{"params": bad}])
    _fails(text, line=_line_of(text, "128,1,1"), de=1, field="K1", match="need 37 parameters, the entity has 33")


def test_absurd_count_rejected_before_allocation():
    """K1 = 10**12: IgesError from the count check, not MemoryError, and fast."""
    bad = bilinear_128().replace("128,1,1,1,1", "128,1000000000000,1000000000000,1,1", 1)
    t = time.perf_counter()
    _fails(make_iges([{"params": bad}]), line=None, de=1, field="K1", match="need")
    assert time.perf_counter() - t < 1.0


def test_decreasing_knots():
    bad = bilinear_128().replace("0.0,0.0,1.0,1.0,0.0,0.0,1.0,1.0", "0.0,0.5,0.2,1.0,0.0,0.0,1.0,1.0", 1)
    text = make_iges([{"params": bad}])
    _fails(text, line=_line_of(text, "128,1,1"), de=1, field="S(1)", match="knots decrease")


@pytest.mark.parametrize("w", ["0.", "-1."])
def test_non_positive_weight(w):
    bad = bilinear_128().replace("1.,1.,1.,1.", f"1.,1.,{w},1.", 1)
    text = make_iges([{"params": bad}])
    _fails(text, line=None, de=1, field="W(0,1)", match="not positive")


def test_pointer_to_missing_de():
    text = make_iges([{"params": "144,99,0,0,0;"}])
    _fails(text, line=_line_of(text, "144,99"), de=1, field="PTS", match="DE 99, which does not exist")


def test_cycle_of_transformation_matrices():
    m = "124,1.,0.,0.,0.,0.,1.,0.,0.,0.,0.,1.,0.;"
    text = make_iges([{"params": bilinear_128(), "transform": 3},
                      {"params": m, "transform": 5}, {"params": m, "transform": 3}])
    _fails(text, line=9, de=5, field="transformation matrix", match="cycle")  # DE 5 is on line 9


def test_cycle_of_composite_curves():
    """A 102 that contains itself (through another 102) must not recurse forever."""
    ents = [{"params": bilinear_128(), "status": "00010000"},
            {"params": "102,1,5;", "status": "00010500"},  # 3
            {"params": "102,1,3;", "status": "00010500"},  # 5
            {"params": "142,0,1,3,0,1;", "status": "00010000"},  # 7
            {"params": "144,1,1,0,7;"}]
    _fails(make_iges(ents), line=None, de=3, match="cycle")


def test_cycle_of_subfigures():
    ents = [{"params": "308,0,1Ha,1,3;", "status": "00000200"},  # 1 contains the instance at 3
            {"params": "408,1,0.,0.,0.,1.;", "status": "00010000"},  # 3 instance of 1
            {"params": "408,1,0.,0.,0.,1.;"}]  # 5: top-level instance of 1
    _fails(make_iges(ents), line=None, de=None, match="cycle|nested")


def test_non_numeric_field():
    bad = bilinear_128().replace("128,1,1,1,1", "128,1,x1,1,1", 1)
    text = make_iges([{"params": bad}])
    _fails(text, line=_line_of(text, "128,1,x1"), de=1, field="K2", match="expected an integer")


def test_wrong_de_back_pointer():
    lines = GOOD.splitlines()
    k = next(i for i, l in enumerate(lines) if l[72] == "P")
    lines[k] = lines[k][:65] + "      9" + lines[k][72:]
    _fails("\n".join(lines), line=k + 1, de=1, field="DE back pointer", match="belongs to DE 9")


def test_first_parameter_not_entity_type():
    text = make_iges([{"params": bilinear_128()}]).replace("128,1,1,1,1", "126,1,1,1,1", 1)
    _fails(text, line=None, de=1, field="entity type", match="not the entity type")


def test_domain_outside_knots():
    bad = bilinear_128(domain=(0.0, 1.0, 0.0, 1.0))
    bad = bad[: bad.rindex(",1.0,0.0,1.0;")] + ",2.0,0.0,1.0;"
    _fails(make_iges([{"params": bad}]), line=None, de=1, field="U1", match="outside the knot range")


def test_domain_slightly_outside_is_clamped():
    """U1 = 1 + 1e-9 (within the relative tolerance): clamped to 1 with a diagnostic."""
    ok = bilinear_128()
    ok = ok[: ok.rindex(",1.0,0.0,1.0;")] + ",1.000000001,0.0,1.0;"
    m = read_iges_string(make_iges([{"params": ok}]))
    assert m.faces[0].surface.domain == (0.0, 1.0, 0.0, 1.0)
    assert any("clamped" in d.message for d in m.diagnostics)


def test_huge_hollerith_count():
    """A Hollerith count far beyond the record, in the Global section and in a used 308."""
    from tests.helpers.iges_fixtures import DEFAULT_GLOBAL
    g = DEFAULT_GLOBAL.replace("4Htest", "99999999999999Htest", 1)
    _fails(make_iges([{"params": bilinear_128()}], global_text=g), line=2, de=None, match="Hollerith")
    ents = [{"params": bilinear_128(), "status": "00010000"},
            {"params": "308,0,99999HX,1,1;", "status": "00000200"}, {"params": "408,3;"}]
    _fails(make_iges(ents), line=None, de=3, match="Hollerith")


# ------------------------------------------------------------------ mutation fuzzing
def _base() -> str:
    """A valid file exercising most paths: 144 with loops, 124 chain, 308/408, 314, 406."""
    sq = [(0.1, 0.1), (0.9, 0.1), (0.9, 0.9), (0.1, 0.9)]
    ents = [{"params": "314,100.,50.,0.;"},  # 1
            {"params": "406,1,4Hname;", "form": 15},  # 3
            {"params": bilinear_128(((0, 0, 0), (10, 0, 0), (0, 10, 0), (10, 10, 1))), "status": "00010000",
             "transform": 19}]  # 5
    for a, b in zip(sq, sq[1:] + sq[:1]):  # 7..13
        ents.append({"params": f"110,{a[0]!r},{a[1]!r},0.,{b[0]!r},{b[1]!r},0.;", "status": "00010500"})
    ents += [{"params": "102,4,7,9,11,13;", "status": "00010500"},  # 15
             {"params": "142,0,5,15,0,1;", "status": "00010000"},  # 17
             {"params": f"124,0.,-1.,0.,1.,1.,0.,0.,2.,0.,0.,1.,{pi!r};", "transform": 21},  # 19
             {"params": "124,1.,0.,0.,0.,0.,1.,0.,0.,0.,0.,1.,5.;"},  # 21
             {"params": "144,5,1,0,17,0,1,3;", "color": -1},  # 23
             {"params": bilinear_128(), "status": "00010000"},  # 25
             {"params": "308,0,3Hsub,1,25;", "status": "00000200"},  # 27
             {"params": "408,27,1.,2.,3.,0.5;"},  # 29
             {"params": "126,1,1,0,0,1,0,0.,0.,1.,1.,1.,1.,0.,0.,0.,1.,1.,1.,0.,1.,0.,0.,1.;"}]  # 31
    return make_iges(ents)


BASE = _base()


def test_base_is_valid():
    m = read_iges_string(BASE)
    assert len(m.faces) == 2 and m.faces[0].trims is not None and m.faces[0].name == "name"


_NUM = re.compile(r"-?\d+\.?\d*(?:[EeDd][+-]?\d+)?")


@st.composite
def mutants(draw):
    lines = BASE.splitlines()
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["flip", "delete_char", "dup_char", "dup_line", "del_line", "number",
                                     "swap_lines"]))
        i = draw(st.integers(0, len(lines) - 1))
        line = lines[i]
        if kind == "dup_line":
            lines.insert(i, line)
        elif kind == "del_line":
            del lines[i]
        elif kind == "swap_lines":
            j = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
        elif kind == "number":
            nums = list(_NUM.finditer(line))
            if nums:
                m = nums[draw(st.integers(0, len(nums) - 1))]
                new = draw(st.sampled_from(["999999999999", "-1", "-7", "0", "x", "1.5", "", "1E400", "3",
                                            "2147483648", "1" * 200, "0.", "-0.5"]))
                line = line[: m.start()] + new + line[m.end():]
        else:
            if not line:
                continue
            k = draw(st.integers(0, len(line) - 1))
            if kind == "flip":
                c = draw(st.sampled_from(list("0123456789,;H.-E Dx")))
                line = line[:k] + c + line[k + 1:]
            elif kind == "delete_char":
                line = line[:k] + line[k + 1:]
            else:
                line = line[:k] + line[k] + line[k:]
        if kind in ("flip", "delete_char", "dup_char", "number"):
            lines[i] = line
        if not lines:
            lines = [""]
    return "\n".join(lines) + "\n"


@settings(max_examples=300, deadline=2000)
@given(text=mutants())
def test_mutants_raise_iges_error_or_read(text):
    """Every mutant raises IgesError or gives a Model whose faces are valid NURBS."""
    try:
        m = read_iges_string(text, "mutant.igs")
    except IgesError as e:
        assert str(e).startswith("mutant.igs")
        return
    assert isinstance(m, Model)
    for f in m.faces:
        u0, u1, v0, v1 = f.surface.domain
        assert u0 < u1 and v0 < v1
        f.surface.evaluate([u0, u1], [v0, v1])
