"""Tool file format: exact round trips, the documented layout, reader errors, atomic writes.

References: bit-for-bit equality with the written arrays (round trips); docs/toolfile.md
(the example in the spec is parsed, and an independent token-stream reader that follows the
spec's Fortran sketch reads the written files); hand-built broken files (errors).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from cadbridge.common.atomic import atomic_write
from cadbridge.io.toolfile import (
    ToolData,
    ToolFileError,
    format_toolfile,
    parse_toolfile,
    read_toolfile,
    write_toolfile,
)

DOC = Path(__file__).resolve().parents[2] / "docs" / "toolfile.md"

# awkward doubles: signed zero, subnormals, extremes, non-terminating binary fractions
NASTY = np.array([0.0, -0.0, 5e-324, -2.2250738585072014e-308, 1 / 3, -2 / 3, 0.1, 1e300, -1.7976931348623157e308,
                  123456789.12345679, 1e-7, 2.0**-1074 * 3, 6.02214076e23])


def make_tool(seed: int = 0, n: int = 9, et: int = 4, eq: int = 3, c: int = 3, coef: bool = True,
              b: int = 0) -> ToolData:
    rng = np.random.default_rng(seed)
    nodes = rng.normal(size=(n, 3)) * 10.0 ** rng.integers(-3, 4, size=(n, 1))
    nodes.ravel()[: min(nodes.size, NASTY.size)] = NASTY[: nodes.size]
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    tri = rng.integers(0, n, size=(et, 3))
    quad = rng.integers(0, n, size=(eq, 4))
    celem = rng.choice(et + eq, size=c, replace=False) if et + eq else np.zeros(0, int)
    ccorner = np.array([rng.integers(0, 3 if e < et else 4) for e in celem], dtype=int)
    cn = rng.normal(size=(c, 3))
    edge_nodes = rng.integers(0, n, size=(b, 2))
    edge_nodes[:, 1] = (edge_nodes[:, 0] + 1 + rng.integers(0, n - 1, size=b)) % n  # two different nodes
    return ToolData(
        edge_nodes=edge_nodes, edge_normals=rng.normal(size=(b, 2, 3)),
        name="die  upper (op20) ", units="MM", nodes=nodes, normals=normals, triangles=tri, quads=quad,
        corner_element=celem, corner_local=ccorner, corner_normals=cn,
        tri_coefficients=rng.normal(size=(et, 6, 3)) * 1e3 if coef else None,
        quad_coefficients=rng.normal(size=(eq, 8, 3)) * 1e-3 if coef else None,
        source="/data/cad/die 20.igs", normal_source="cad",
        metadata={"mesher": "gmsh 4.13", "h": "2.5"}, comments=["first", "", "  indented, trailing  "],
    )


def roundtrip(tool: ToolData, tmp_path: Path) -> ToolData:
    path = tmp_path / "tool.nag"
    write_toolfile(tool, path)
    return read_toolfile(path)


# ------------------------------------------------------------------------- exact round trips
@pytest.mark.parametrize(
    "kw",
    [dict(), dict(coef=False), dict(eq=0), dict(et=0), dict(et=0, eq=0, c=0), dict(c=0), dict(n=1, et=2, eq=1)],
    ids=["mixed", "no-coef", "tri-only", "quad-only", "no-elements", "no-corners", "one-node"],
)
def test_roundtrip_is_bit_exact(tmp_path, kw):
    tool = make_tool(**kw)
    back = roundtrip(tool, tmp_path)
    assert back.equals(tool)
    # reference: raw bytes of every array
    for name in ("nodes", "normals", "corner_normals", "tri_coefficients", "quad_coefficients"):
        a, b = getattr(tool, name), getattr(back, name)
        assert (a is None and b is None) or a.tobytes() == b.tobytes()
    assert np.signbit(back.nodes.ravel()[1])  # -0.0 survives
    assert back.triangles.dtype == np.int64 and back.corner_element.dtype == np.int64


@settings(max_examples=40, deadline=None)
@given(
    nodes=hnp.arrays(np.float64, st.tuples(st.integers(1, 6), st.just(3)), elements=st.floats(allow_nan=False, allow_infinity=False)),
    name=st.text(alphabet=st.characters(blacklist_categories=("Cc", "Cs", "Zl", "Zp")), max_size=20),
)
def test_roundtrip_property(tmp_path_factory, nodes, name):
    """Any finite doubles and any one-line name come back unchanged."""
    n = len(nodes)
    tool = ToolData(name=name, units="M", nodes=nodes, normals=nodes[::-1].copy(), triangles=[[0, n - 1, 0]],
                    tri_coefficients=np.tile(nodes[:1], (1, 6, 1)), quad_coefficients=None)
    back = roundtrip(tool, tmp_path_factory.mktemp("prop"))
    assert back.equals(tool)


def test_empty_coefficient_block_normalised():
    """None for an empty block becomes a (0, k, 3) array, so write/read stays exact."""
    tool = make_tool(eq=0)
    tool2 = ToolData(tool.name, tool.units, tool.nodes, tool.normals, tool.triangles,
                     tri_coefficients=tool.tri_coefficients, quad_coefficients=None)
    assert tool2.quad_coefficients.shape == (0, 8, 3)
    assert parse_toolfile(format_toolfile(tool2)).equals(tool2)


# ------------------------------------------------------------------------- documented layout
def test_layout_follows_spec():
    tool = make_tool(seed=3, n=5, et=2, eq=2, c=2, b=2)
    lines = format_toolfile(tool).splitlines()
    assert lines[0] == "CADBRIDGE-NAGATA-TOOL 2"
    assert lines[1] == "NAME die  upper (op20) "
    counts = next(ln for ln in lines if ln.startswith("COUNTS "))
    assert counts == "COUNTS 5 2 2 2 1 2"
    k = lines.index("EDGE_NORMALS 2")  # right after the CORNER_NORMALS records
    assert lines[k - 3] == "CORNER_NORMALS 2"
    rec = lines[k + 2].split()
    assert rec[:3] == ["2"] + [str(i + 1) for i in tool.edge_nodes[1]]
    assert [float(x) for x in rec[3:]] == tool.edge_normals[1].ravel().tolist()
    i = lines.index("ELEMENTS 4")
    # 1-based ids, triangles first (nn = 3), then quads (nn = 4), node ids 1-based
    assert [ln.split()[:2] for ln in lines[i + 1 : i + 5]] == [["1", "3"], ["2", "3"], ["3", "4"], ["4", "4"]]
    assert [int(x) - 1 for x in lines[i + 3].split()[2:]] == tool.quads[0].tolist()
    j = lines.index("COEFFICIENTS 28")
    assert lines[j + 1].split()[:2] == ["1", "1"] and lines[j + 13].split()[:2] == ["3", "1"]
    assert lines[j + 20].split()[:2] == ["3", "8"]
    assert float(lines[j + 20].split()[2]) == tool.quad_coefficients[0, 7, 0]  # k = 8 is c12
    assert lines[-1] == "END"
    # every real has a '.' or an exponent and is repr-exact
    nums = " ".join(lines[lines.index("NODES 5") + 1 : lines.index("NORMALS 5")]).split()
    assert all(("." in t or "e" in t) for k, t in enumerate(nums) if k % 4)


def test_doc_example_parses():
    """The complete example in docs/toolfile.md is a valid file with the stated content."""
    text = DOC.read_text()
    block = re.search(r"## Complete example.*?```\n(.*?)```", text, re.S).group(1)
    tool = parse_toolfile(block, "docs example")
    assert tool.name == "punch upper" and tool.units == "MM" and tool.normal_source == "cad"
    assert tool.metadata == {"mesher": "gmsh 4.13"}
    assert tool.triangles.tolist() == [[0, 1, 2]] and tool.quads.tolist() == [[1, 3, 4, 2]]
    assert tool.corner_element.tolist() == [1] and tool.corner_local.tolist() == [3]
    # the example's coefficients interpolate its corner nodes (flat patches)
    c = tool.tri_coefficients[0]
    assert np.allclose(c[0] + c[1] + c[4], tool.nodes[1]) and np.allclose(c.sum(0), tool.nodes[2])
    q = tool.quad_coefficients[0]
    assert np.allclose(q.sum(0), tool.nodes[4]) and np.allclose(q[0] + q[2] + q[5], tool.nodes[2])


def spec_token_reader(text: str) -> dict:
    """Independent reader following the spec's Fortran sketch: skip to COUNTS, then read tokens."""
    lines = text.splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("COUNTS "))
    n, et, eq, nc, kc, nb = map(int, lines[k].split()[1:])
    tok = iter(" ".join(lines[k + 1 :]).split())
    nxt = lambda: next(tok)  # noqa: E731
    out = {}
    for sec in ("NODES", "NORMALS"):
        assert nxt() == sec and int(nxt()) == n
        out[sec] = np.array([[float(nxt()) for _ in range(4)][1:] for _ in range(n)]).reshape(n, 3)
    assert nxt() == "ELEMENTS" and int(nxt()) == et + eq
    conn = []
    for _ in range(et + eq):
        nxt()
        nn = int(nxt())
        conn.append([int(nxt()) for _ in range(nn)])
    out["ELEMENTS"] = conn
    assert nxt() == "CORNER_NORMALS" and int(nxt()) == nc
    out["CORNER_NORMALS"] = [(int(nxt()), int(nxt()), float(nxt()), float(nxt()), float(nxt())) for _ in range(nc)]
    assert nxt() == "EDGE_NORMALS" and int(nxt()) == nb
    out["EDGE_NORMALS"] = [(int(nxt()), int(nxt()), int(nxt()), *[float(nxt()) for _ in range(6)]) for _ in range(nb)]
    if kc:
        assert nxt() == "COEFFICIENTS"
        coef = np.zeros((et + eq, 8, 3))
        for _ in range(int(nxt())):
            e, kk = int(nxt()), int(nxt())
            coef[e - 1, kk - 1] = [float(nxt()) for _ in range(3)]
        out["COEFFICIENTS"] = coef
    assert nxt() == "END"
    return out


def test_spec_reader_reads_written_file():
    tool = make_tool(seed=5, b=3)
    got = spec_token_reader(format_toolfile(tool))
    assert [list(r[1:3]) for r in got["EDGE_NORMALS"]] == (tool.edge_nodes + 1).tolist()
    assert np.array([r[3:] for r in got["EDGE_NORMALS"]]).tobytes() == tool.edge_normals.reshape(-1, 6).tobytes()
    assert got["NODES"].tobytes() == tool.nodes.tobytes()
    assert got["ELEMENTS"] == (tool.triangles + 1).tolist() + (tool.quads + 1).tolist()
    assert [c[:2] for c in got["CORNER_NORMALS"]] == list(zip((tool.corner_element + 1).tolist(),
                                                              (tool.corner_local + 1).tolist()))
    et = len(tool.triangles)
    assert np.array_equal(got["COEFFICIENTS"][:et, :6], tool.tri_coefficients)
    assert np.array_equal(got["COEFFICIENTS"][et:], tool.quad_coefficients)


def test_corner_normal_dict():
    tool = make_tool(seed=2)
    d = tool.corner_normal_dict()
    e, k = int(tool.corner_element[0]), int(tool.corner_local[0])
    assert np.array_equal(d[(e, k)], tool.corner_normals[0])


# ------------------------------------------------------------------------- reader errors
def _mutate(text: str, old: str, new: str, count: int = 1) -> str:
    assert old in text
    return text.replace(old, new, count)


@pytest.fixture
def good_text() -> str:
    return format_toolfile(make_tool(seed=1, n=4, et=2, eq=1, c=1))


@pytest.mark.parametrize(
    "edit, line, section, phrase",
    [
        (lambda t: _mutate(t, "CADBRIDGE-NAGATA-TOOL 2", "HELLO 2"), 1, "header", "not a cadbridge"),
        (lambda t: _mutate(t, "CADBRIDGE-NAGATA-TOOL 2", "CADBRIDGE-NAGATA-TOOL 3"), 1, "header", "version"),
        (lambda t: re.sub(r"(COUNTS \d+ \d+ \d+ \d+ \d+) \d+", r"\1", t), 12, "header", "version 2"),
        (lambda t: _mutate(t, "EDGE_NORMALS 0", "EDGE_NORMALS 1"), 29, "EDGE_NORMALS", "does not match"),
        (lambda t: _mutate(t, "UNITS MM\n", ""), 11, "header", "no UNITS"),
        (lambda t: _mutate(t, "UNITS MM\n", "UNITS MM\nCOLOR red\n"), 4, "header", "unknown header keyword"),
        (lambda t: _mutate(t, "NODES 4", "NODES 5"), 13, "NODES", "does not match"),
        (lambda t: re.sub(r"(NODES 4\n[^\n]*\n2 )\S+", r"\1abc", t), 15, "NODES", "'abc'"),
        (lambda t: re.sub(r"(NORMALS 4\n1 \S+ \S+) \S+", r"\1", t), 19, "NORMALS", "expected 4 fields"),
        (lambda t: re.sub(r"(NODES 4\n)1 ", r"\g<1>7 ", t), 14, "NODES", "id 7 where 1"),
        (lambda t: re.sub(r"(NODES 4\n1 )\S+", r"\1nan", t), 14, "NODES", "non-finite"),
        (lambda t: re.sub(r"(NODES 4\n1 )\S+", r"\g<1>1_0", t), 14, "NODES", "'1_0'"),
        (lambda t: re.sub(r"\n1 3 \d+", "\n1 3 1.0", t), 24, "ELEMENTS", "integer"),
        (lambda t: _mutate(t, "\n3 4 ", "\n3 4x "), 26, "ELEMENTS", "integer"),
        (lambda t: re.sub(r"\n1 3 \d+", "\n1 3 99", t), 24, "ELEMENTS", "out of range"),
        (lambda t: re.sub(r"\n2 3 (\d+ \d+ \d+)\n3 4 (\d+ \d+ \d+ \d+)", r"\n2 4 \2\n3 3 \1", t), 25, "ELEMENTS",
         "triangles must come first"),
        (lambda t: re.sub(r"(CORNER_NORMALS 1\n\d+ )\d+", r"\g<1>5", t), 28, "CORNER_NORMALS", "out of range"),
        (lambda t: re.sub(r"(COEFFICIENTS 20\n1 )1", r"\g<1>2", t), 31, "COEFFICIENTS", "coefficient 1"),
        (lambda t: t[: t.index("COEFFICIENTS")], 29, "COEFFICIENTS", "unexpected end of file"),
        (lambda t: t.replace("END\n", ""), 50, "END", "unexpected end"),
        (lambda t: t + "more\n", 52, "END", "text after END"),
    ],
)
def test_reader_errors_name_line_and_section(good_text, edit, line, section, phrase):
    bad = edit(good_text)
    with pytest.raises(ToolFileError) as exc:
        parse_toolfile(bad, "bad.nag")
    msg = str(exc.value)
    assert f"bad.nag, line {line}, section {section}:" in msg, msg
    assert phrase in msg, msg


def test_writer_rejects_invalid_data(tmp_path):
    with pytest.raises(ToolFileError, match="single line"):
        ToolData("a\nb", "MM", np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(ToolFileError, match="finite"):
        ToolData("a", "MM", np.full((1, 3), np.inf), np.zeros((1, 3)))
    with pytest.raises(ToolFileError, match="node index"):
        ToolData("a", "MM", np.zeros((2, 3)), np.zeros((2, 3)), triangles=[[0, 1, 2]])
    with pytest.raises(ToolFileError, match="all elements"):
        ToolData("a", "MM", np.zeros((4, 3)), np.zeros((4, 3)), [[0, 1, 2]], [[0, 1, 2, 3]],
                 tri_coefficients=np.zeros((1, 6, 3)))
    with pytest.raises(ToolFileError, match="corner_local"):
        ToolData("a", "MM", np.zeros((3, 3)), np.zeros((3, 3)), [[0, 1, 2]], corner_element=[0],
                 corner_local=[3], corner_normals=[[0, 0, 1.0]])
    with pytest.raises(ToolFileError, match="integer"):
        ToolData("a", "MM", np.zeros((3, 3)), np.zeros((3, 3)), [[0.0, 1.0, 2.0]])


# ------------------------------------------------------------------------- atomic writes
def test_failed_write_leaves_old_file(tmp_path):
    path = tmp_path / "tool.nag"
    tool = make_tool()
    write_toolfile(tool, path)
    before = path.read_bytes()
    tool.nodes[0, 0] = np.nan  # invalid: the writer refuses before touching the file
    with pytest.raises(ToolFileError):
        write_toolfile(tool, path)
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["tool.nag"]


def test_atomic_write_exception_cleans_up(tmp_path):
    """Reference: the file system — no temp files left, target unchanged or replaced whole."""
    path = tmp_path / "x.txt"
    path.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_write(path) as fh:
            fh.write("half")
            raise RuntimeError("crash")
    assert path.read_text() == "old" and os.listdir(tmp_path) == ["x.txt"]
    with atomic_write(path, "wb") as fh:
        fh.write(b"new")
    assert path.read_bytes() == b"new" and os.listdir(tmp_path) == ["x.txt"]


def test_version_1_file_still_reads():
    """A version 1 file (five COUNTS, no EDGE_NORMALS section; docs/toolfile.md "Versioning")
    reads with no edge normals, and the same tool written as version 2 reads back equal."""
    tool = make_tool(seed=7)
    v2 = format_toolfile(tool)
    v1 = re.sub(r"(COUNTS \d+ \d+ \d+ \d+ \d+) 0\n", r"\1\n", v2.replace("CADBRIDGE-NAGATA-TOOL 2", "CADBRIDGE-NAGATA-TOOL 1"))
    v1 = v1.replace("EDGE_NORMALS 0\n", "")
    back = parse_toolfile(v1, "v1.nag")
    assert back.equals(tool) and back.edge_nodes.shape == (0, 2)
    with pytest.raises(ToolFileError, match="section COEFFICIENTS"):  # a v2 section in a v1 file is not read
        parse_toolfile(v2.replace("CADBRIDGE-NAGATA-TOOL 2", "CADBRIDGE-NAGATA-TOOL 1").replace(" 1 0\nNODES", " 1\nNODES"))


def test_edge_normals_roundtrip_exact(tmp_path):
    tool = make_tool(seed=11, b=4)
    back = roundtrip(tool, tmp_path)
    assert back.equals(tool)
    assert back.edge_nodes.tolist() == tool.edge_nodes.tolist()
