"""Nagata tool files: a versioned plain-text format a Fortran/C forming code can read.

The format is specified in ``docs/toolfile.md``. In short::

    CADBRIDGE-NAGATA-TOOL 2
    NAME <text>            UNITS <word>       SOURCE <text>     NORMAL_SOURCE <word>
    EDGE_RULE bounded|published   (the edge coefficients' rule; no line: bounded)
    META <key> <text>      COMMENT <text>     (any number, optional)
    COUNTS <nodes> <triangles> <quads> <corner_normals> <has_coefficients 0|1> <edge_normals>
    NODES <N>              then N lines: id x y z
    NORMALS <N>            then N lines: id nx ny nz
    ELEMENTS <Et+Eq>       then lines: id nnodes n1 .. nn   (all triangles first, then quads)
    CORNER_NORMALS <C>     then C lines: element corner nx ny nz
    EDGE_NORMALS <B>       then B lines: id node1 node2 px py pz qx qy qz
    COEFFICIENTS <6Et+8Eq> (optional) then lines: element k cx cy cz  (k = 1..6 or 1..8)
    END

All ids in the file are 1-based; in `ToolData` every index is 0-based. Global element
numbering is "blocks in the order given": triangles 1..Et, then quads Et+1..Et+Eq.
Floats are written with ``repr`` (shortest round-trip form), so ``read(write(t))`` is exact.
Version 1 files (no EDGE_NORMALS, five COUNTS) are still read.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cadbridge.common.atomic import atomic_write
from cadbridge.nagata.edge import EDGE_RULES

__all__ = [
    "FORMAT_VERSION",
    "MAGIC",
    "COEFFICIENT_NAMES",
    "ToolData",
    "ToolFileError",
    "format_toolfile",
    "parse_toolfile",
    "read_toolfile",
    "write_toolfile",
]

MAGIC = "CADBRIDGE-NAGATA-TOOL"
FORMAT_VERSION = 2
READ_VERSIONS = (1, 2)
COEFFICIENT_NAMES = ("c00", "c10", "c01", "c11", "c20", "c02", "c21", "c12")

_WORD = re.compile(r"^\S+$")


class ToolFileError(ValueError):
    """A malformed tool file (message names file, line and section) or invalid ToolData."""


@dataclass
class ToolData:
    """Everything a forming code needs to rebuild the Nagata tool surface.

    Attributes
    ----------
    name, units : str
        Tool name (free text, one line) and length unit (one word, e.g. "MM").
    nodes, normals : (N, 3) float
        Node positions and one unit normal per node.
    triangles : (Et, 3) int, quads : (Eq, 4) int
        0-based node indices; corner order (x00, x10, x11[, x01]) of the Nagata patch.
    corner_element, corner_local : (C,) int
        0-based global element index (triangles first, then quads) and 0-based local corner
        of each corner-normal override (used where a node lies on a sharp edge).
    corner_normals : (C, 3) float
        The normal that element corner uses instead of ``normals[node]``.
    edge_nodes : (B, 2) int, edge_normals : (B, 2, 3) float
        Mesh edges (0-based node pairs) with one extra normal at each end (``edge_normals[:, 0]``
        at ``edge_nodes[:, 0]``): the conormals of the trim curve a boundary edge follows.
    tri_coefficients : (Et, 6, 3) | None, quad_coefficients : (Eq, 8, 3) | None
        Patch coefficients in the order c00 c10 c01 c11 c20 c02 [c21 c12]; both or neither.
    source, normal_source : str
        CAD file the tool came from and how normals were obtained (cad, mwe, ...).
    edge_rule : str
        The rule the edge coefficients follow, one of `cadbridge.nagata.edge.EDGE_RULES`
        ("bounded", "published"; docs/toolfile.md "Rebuilding the coefficients").
    metadata : dict[str, str]
        Further key/value notes (keys: one word; values: one line).
    comments : list[str]
        Free comment lines.
    """

    name: str
    units: str
    nodes: np.ndarray
    normals: np.ndarray
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), dtype=np.int64))
    quads: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), dtype=np.int64))
    corner_element: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    corner_local: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    corner_normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    edge_nodes: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    edge_normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    tri_coefficients: np.ndarray | None = None
    quad_coefficients: np.ndarray | None = None
    source: str = ""
    normal_source: str = ""
    edge_rule: str = "bounded"
    metadata: dict[str, str] = field(default_factory=dict)
    comments: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.nodes = _float_array(self.nodes, (None, 3), "nodes")
        self.normals = _float_array(self.normals, (len(self.nodes), 3), "normals")
        self.triangles = _int_array(self.triangles, (None, 3), "triangles")
        self.quads = _int_array(self.quads, (None, 4), "quads")
        self.corner_element = _int_array(self.corner_element, (None,), "corner_element")
        c = len(self.corner_element)
        self.corner_local = _int_array(self.corner_local, (c,), "corner_local")
        self.corner_normals = _float_array(self.corner_normals, (c, 3), "corner_normals")
        self.edge_nodes = _int_array(self.edge_nodes, (None, 2), "edge_nodes")
        self.edge_normals = _float_array(self.edge_normals, (len(self.edge_nodes), 2, 3), "edge_normals")
        et, eq = len(self.triangles), len(self.quads)
        if self.tri_coefficients is not None or self.quad_coefficients is not None:
            # an empty block may be given as None: normalise so that write/read is exact
            if self.tri_coefficients is None and et == 0:
                self.tri_coefficients = np.zeros((0, 6, 3))
            if self.quad_coefficients is None and eq == 0:
                self.quad_coefficients = np.zeros((0, 8, 3))
            if self.tri_coefficients is None or self.quad_coefficients is None:
                raise ToolFileError("coefficients must be given for all elements (triangles and quads) or none")
            self.tri_coefficients = _float_array(self.tri_coefficients, (et, 6, 3), "tri_coefficients")
            self.quad_coefficients = _float_array(self.quad_coefficients, (eq, 8, 3), "quad_coefficients")
        n = len(self.nodes)
        for arr, what in ((self.triangles, "triangles"), (self.quads, "quads"), (self.edge_nodes, "edge_nodes")):
            if arr.size and (arr.min() < 0 or arr.max() >= n):
                raise ToolFileError(f"{what}: node index out of range [0, {n})")
        if c:
            if self.corner_element.min() < 0 or self.corner_element.max() >= et + eq:
                raise ToolFileError(f"corner_element: element index out of range [0, {et + eq})")
            ncorner = np.where(self.corner_element < et, 3, 4)
            if np.any((self.corner_local < 0) | (self.corner_local >= ncorner)):
                raise ToolFileError("corner_local: corner index out of range for its element type")
        if not _WORD.match(self.units):
            raise ToolFileError(f"units must be one word, got {self.units!r}")
        if self.edge_rule not in EDGE_RULES:
            raise ToolFileError(f"edge_rule must be one of {', '.join(EDGE_RULES)}, got {self.edge_rule!r}")
        if self.normal_source and not _WORD.match(self.normal_source):
            raise ToolFileError(f"normal_source must be one word, got {self.normal_source!r}")
        for what, text in [("name", self.name), ("source", self.source)] + [
            (f"metadata[{k!r}]", v) for k, v in self.metadata.items()
        ] + [("comment", t) for t in self.comments]:
            _check_line(text, what)
        for k in self.metadata:
            if not _WORD.match(k):
                raise ToolFileError(f"metadata key must be one word, got {k!r}")

    # ------------------------------------------------------------------ conveniences
    @property
    def n_elements(self) -> int:
        """Et + Eq (global element numbering: triangles first, then quads)."""
        return len(self.triangles) + len(self.quads)

    @property
    def has_coefficients(self) -> bool:
        return self.tri_coefficients is not None

    def corner_normal_dict(self) -> dict[tuple[int, int], np.ndarray]:
        """{(global element index, local corner): normal (3,)}, all 0-based."""
        return {
            (int(e), int(k)): n for e, k, n in zip(self.corner_element, self.corner_local, self.corner_normals)
        }

    def corner_normal_blocks(self) -> list[np.ndarray]:
        """Per element block (triangles, then quads; empty blocks left out) the normal of every
        corner, (E_b, 3|4, 3): rule 1 of docs/toolfile.md."""
        blocks, out, off = [], [], 0
        for conn in (self.triangles, self.quads):
            if len(conn):
                cn = self.normals[conn].copy()
                m = (self.corner_element >= off) & (self.corner_element < off + len(conn))
                cn[self.corner_element[m] - off, self.corner_local[m]] = self.corner_normals[m]
                out.append(cn)
            off += len(conn)
        return out

    def nagata_mesh(self):
        """The `cadbridge.nagata.NagataMesh` this file describes (rebuild rule of docs/toolfile.md)."""
        from cadbridge.nagata.mesh import NagataMesh  # lazy: io does not need the Nagata maths

        blocks = [b for b in (self.triangles, self.quads) if len(b)]
        return NagataMesh(self.nodes, blocks, self.corner_normal_blocks(),
                          edge_normals=(self.edge_nodes, self.edge_normals[:, 0], self.edge_normals[:, 1]),
                          edge_rule=self.edge_rule)

    def equals(self, other: "ToolData") -> bool:
        """Bit-for-bit equality of all arrays and text fields."""

        def same(a, b) -> bool:
            if a is None or b is None:
                return a is None and b is None
            return a.shape == b.shape and a.dtype.kind == b.dtype.kind and a.tobytes() == b.tobytes()

        arrays = ("nodes", "normals", "triangles", "quads", "corner_element", "corner_local", "corner_normals",
                  "edge_nodes", "edge_normals", "tri_coefficients", "quad_coefficients")
        texts = ("name", "units", "source", "normal_source", "edge_rule", "metadata", "comments")
        return all(same(getattr(self, a), getattr(other, a)) for a in arrays) and all(
            getattr(self, t) == getattr(other, t) for t in texts
        )


def _float_array(a, shape: tuple, what: str) -> np.ndarray:
    arr = np.ascontiguousarray(a, dtype=np.float64)
    if arr.size == 0 and arr.ndim != len(shape):
        arr = arr.reshape([0 if s is None else s for s in shape])
    _check_shape(arr, shape, what)
    if not np.all(np.isfinite(arr)):
        raise ToolFileError(f"{what}: values must be finite")
    return arr


def _int_array(a, shape: tuple, what: str) -> np.ndarray:
    raw = np.asarray(a)
    if raw.size and raw.dtype.kind not in "iu":
        raise ToolFileError(f"{what}: integer array expected, got dtype {raw.dtype}")
    arr = np.ascontiguousarray(raw, dtype=np.int64)
    if arr.size == 0 and arr.ndim != len(shape):
        arr = arr.reshape([0 if s is None else s for s in shape])
    _check_shape(arr, shape, what)
    return arr


def _check_shape(arr: np.ndarray, shape: tuple, what: str) -> None:
    if arr.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, arr.shape)):
        want = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ")"
        raise ToolFileError(f"{what}: expected shape {want}, got {arr.shape}")


def _check_line(text: str, what: str) -> None:
    if not isinstance(text, str):
        raise ToolFileError(f"{what} must be a str, got {type(text).__name__}")
    if any(ch in text for ch in "\r\n\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029"):
        raise ToolFileError(f"{what} must be a single line of text: {text!r}")


# ---------------------------------------------------------------------------------- writing
def _rows(ids: np.ndarray, ints: list[np.ndarray], floats: np.ndarray | None) -> list[str]:
    """One text line per row: ids, extra integer columns, then floats in repr form (shortest
    round trip). One ``%``-format per row over the zipped columns: the same text as joining
    ``str`` / ``repr`` of each value, 1.6x faster (the die's tool file has ~1.4 M rows)."""
    cols = [np.asarray(ids).tolist()] + [np.asarray(c).tolist() for c in ints]
    nf = 0 if floats is None else int(np.shape(floats)[1])
    fmt = " ".join(["%d"] * len(cols) + ["%r"] * nf)
    if nf:
        cols += np.asarray(floats, dtype=float).T.tolist()
    return [fmt % row for row in zip(*cols)]


def _element_lines(tri: np.ndarray, quad: np.ndarray) -> list[str]:
    et = len(tri)
    lines = [f"{i} 3 {a} {b} {c}" for i, (a, b, c) in enumerate((tri + 1).tolist(), start=1)]
    lines += [f"{i} 4 {a} {b} {c} {d}" for i, (a, b, c, d) in enumerate((quad + 1).tolist(), start=et + 1)]
    return lines


def _coefficient_lines(tri: np.ndarray, quad: np.ndarray) -> list[str]:
    et, eq = len(tri), len(quad)
    elem = np.concatenate([np.repeat(np.arange(1, et + 1), 6), np.repeat(np.arange(et + 1, et + eq + 1), 8)])
    k = np.concatenate([np.tile(np.arange(1, 7), et), np.tile(np.arange(1, 9), eq)])
    vec = np.concatenate([tri.reshape(-1, 3), quad.reshape(-1, 3)])
    return _rows(elem, [k], vec)


def format_toolfile(tool: ToolData) -> str:
    """The complete text of the tool file for ``tool``."""
    tool.__post_init__()  # re-validate (the dataclass is mutable)
    n, et, eq, c = len(tool.nodes), len(tool.triangles), len(tool.quads), len(tool.corner_element)
    lines = [
        f"{MAGIC} {FORMAT_VERSION}",
        f"NAME {tool.name}",
        f"UNITS {tool.units}",
        f"SOURCE {tool.source}",
        f"NORMAL_SOURCE {tool.normal_source}",
        f"EDGE_RULE {tool.edge_rule}",
    ]
    lines += [f"META {k} {v}" for k, v in tool.metadata.items()]
    lines += [f"COMMENT {t}" for t in tool.comments]
    nb = len(tool.edge_nodes)
    lines.append(f"COUNTS {n} {et} {eq} {c} {int(tool.has_coefficients)} {nb}")
    ids = np.arange(1, n + 1)
    lines.append(f"NODES {n}")
    lines += _rows(ids, [], tool.nodes)
    lines.append(f"NORMALS {n}")
    lines += _rows(ids, [], tool.normals)
    lines.append(f"ELEMENTS {et + eq}")
    lines += _element_lines(tool.triangles, tool.quads)
    lines.append(f"CORNER_NORMALS {c}")
    lines += _rows(tool.corner_element + 1, [tool.corner_local + 1], tool.corner_normals)
    lines.append(f"EDGE_NORMALS {nb}")
    lines += _rows(np.arange(1, nb + 1), [tool.edge_nodes[:, 0] + 1, tool.edge_nodes[:, 1] + 1],
                   tool.edge_normals.reshape(nb, 6))
    if tool.has_coefficients:
        lines.append(f"COEFFICIENTS {6 * et + 8 * eq}")
        lines += _coefficient_lines(tool.tri_coefficients, tool.quad_coefficients)
    lines.append("END")
    return "\n".join(lines) + "\n"


def write_toolfile(tool: ToolData, path: str | os.PathLike) -> None:
    """Write ``tool`` to ``path`` atomically (temporary file + fsync + rename).

    Example::

        >>> tool = cadbridge.read_toolfile("die_out/die/die.nagata")     # doctest: +SKIP
        >>> cadbridge.write_toolfile(tool, "copy.nagata")                 # the same bytes again
    """
    text = format_toolfile(tool)
    with atomic_write(path, "w") as fh:
        fh.write(text)


# ---------------------------------------------------------------------------------- reading
class _Lines:
    """Cursor over the file's lines with error messages that name file, line and section."""

    def __init__(self, lines: list[str], filename: str) -> None:
        self.lines = lines
        self.filename = filename
        self.pos = 0  # 0-based index of the next line
        self.section = "header"

    def error(self, msg: str, lineno: int | None = None) -> ToolFileError:
        ln = self.pos if lineno is None else lineno
        return ToolFileError(f"{self.filename}, line {ln}, section {self.section}: {msg}")

    def next(self) -> str:
        if self.pos >= len(self.lines):
            raise self.error("unexpected end of file", len(self.lines))
        line = self.lines[self.pos]
        self.pos += 1
        return line

    def peek_keyword(self) -> str | None:
        if self.pos >= len(self.lines):
            return None
        parts = self.lines[self.pos].split(None, 1)
        return parts[0] if parts else ""

    def section_header(self, keyword: str, expected: int) -> None:
        self.section = keyword
        line = self.next()
        parts = line.split()
        if not parts or parts[0] != keyword:
            raise self.error(f"expected section keyword {keyword!r}, got {line!r}")
        if len(parts) != 2 or not _is_int(parts[1]):
            raise self.error(f"expected '{keyword} <count>', got {line!r}")
        if int(parts[1]) != expected:
            raise self.error(f"{keyword} count {parts[1]} does not match the expected {expected} (COUNTS line)")

    def table(self, count: int, n_int: int, n_float: int, what: str) -> tuple[np.ndarray, np.ndarray]:
        """Read ``count`` records of n_int integers then n_float floats: (count, n_int), (count, n_float)."""
        start = self.pos
        block = self.lines[start : start + count]
        if len(block) < count:
            raise self.error(f"{what}: file ends after {len(block)} of {count} records", len(self.lines))
        self.pos += count
        width = n_int + n_float
        try:
            joined = " ".join(block)
            toks = joined.split()
            if len(toks) != count * width or not joined.isascii() or "_" in joined:
                raise ValueError  # (numpy would accept '1_0' and non-ASCII digits)
            arr = np.array(toks, dtype=str).reshape(count, width)
            if n_int and not all(map(_is_int, arr[:, :n_int].ravel().tolist())):
                raise ValueError
            ints = arr[:, :n_int].astype(np.int64)
            floats = arr[:, n_int:].astype(np.float64)  # PyOS_string_to_double: correctly rounded
        except (ValueError, OverflowError):
            self._locate_bad_record(block, start, n_int, n_float, what)
            raise  # pragma: no cover - _locate_bad_record always raises
        if not np.all(np.isfinite(floats)):
            bad = int(np.nonzero(~np.all(np.isfinite(floats), axis=1))[0][0])
            raise self.error(f"{what}: non-finite value", start + bad + 1)
        return ints, floats

    def _locate_bad_record(self, block: list[str], start: int, n_int: int, n_float: int, what: str) -> None:
        for i, line in enumerate(block):
            toks = line.split()
            lineno = start + i + 1
            if len(toks) != n_int + n_float:
                raise self.error(f"{what}: expected {n_int + n_float} fields, got {len(toks)}: {line!r}", lineno)
            for t in toks[:n_int]:
                if not _is_int(t):
                    raise self.error(f"{what}: expected an integer, got {t!r}", lineno)
            for t in toks[n_int:]:
                try:
                    if not t.isascii() or "_" in t:
                        raise ValueError
                    float(t)
                except ValueError:
                    raise self.error(f"{what}: expected a number, got {t!r}", lineno) from None
        raise self.error(f"{what}: malformed records", start + 1)

    def check_ids(self, ids: np.ndarray, start_line: int, what: str) -> None:
        expected = np.arange(1, len(ids) + 1)
        bad = np.nonzero(ids != expected)[0]
        if bad.size:
            i = int(bad[0])
            raise self.error(f"{what}: id {ids[i]} where {i + 1} was expected (ids must be 1, 2, 3, ...)",
                             start_line + i + 1)


_INT = re.compile(r"[+-]?[0-9]+")


def _is_int(tok: str) -> bool:
    return _INT.fullmatch(tok) is not None


def read_toolfile(path: str | os.PathLike) -> ToolData:
    """Read a tool file written by `write_toolfile` (or by hand, following docs/toolfile.md).

    Example::

        >>> tool = cadbridge.read_toolfile("die_out/die/die.nagata")     # doctest: +SKIP
        >>> tool.nodes.shape, tool.normals.shape                          # (N, 3) each
    """
    path = Path(path)
    with open(path, encoding="utf-8", newline="") as fh:
        text = fh.read()
    return parse_toolfile(text, filename=str(path))


def parse_toolfile(text: str, filename: str = "<string>") -> ToolData:
    """Parse the text of a tool file; errors are `ToolFileError` naming line and section."""
    raw = text.split("\n")
    if raw and raw[-1] == "":
        raw.pop()
    cur = _Lines([ln[:-1] if ln.endswith("\r") else ln for ln in raw], filename)

    # ---- header
    first = cur.next().split()
    if len(first) != 2 or first[0] != MAGIC:
        raise cur.error(f"not a cadbridge Nagata tool file (first line must be '{MAGIC} <version>')")
    if not _is_int(first[1]) or int(first[1]) not in READ_VERSIONS:
        raise cur.error(f"unsupported format version {first[1]!r} (this reader knows "
                        f"{', '.join(map(str, READ_VERSIONS))})")
    version = int(first[1])
    head: dict[str, str] = {}
    metadata: dict[str, str] = {}
    comments: list[str] = []
    counts = None
    while counts is None:
        line = cur.next()
        kw, _, value = line.partition(" ")
        if kw in ("NAME", "UNITS", "SOURCE", "NORMAL_SOURCE", "EDGE_RULE"):
            if kw in head:
                raise cur.error(f"duplicate {kw} line")
            head[kw] = value
            if kw == "EDGE_RULE" and value not in EDGE_RULES:
                raise cur.error(f"EDGE_RULE must be one of {', '.join(EDGE_RULES)}, got {value!r}")
        elif kw == "META":
            key, _, val = value.partition(" ")
            if not key:
                raise cur.error("META line needs a key")
            metadata[key] = val
        elif kw == "COMMENT":
            comments.append(value)
        elif kw == "COUNTS":
            parts = value.split()
            want = "<nodes> <triangles> <quads> <corner_normals> <0|1>" + (" <edge_normals>" if version >= 2 else "")
            if len(parts) != (5 if version == 1 else 6) or not all(_is_int(p) for p in parts):
                raise cur.error(f"expected 'COUNTS {want}' (version {version}), got {line!r}")
            counts = [int(p) for p in parts] + ([0] if version == 1 else [])
            if min(counts) < 0 or counts[4] not in (0, 1):
                raise cur.error(f"invalid counts {line!r}")
        elif kw.strip() == "":
            raise cur.error("blank line in header")
        else:
            raise cur.error(f"unknown header keyword {kw!r}")
    for kw in ("NAME", "UNITS"):
        if kw not in head:
            raise cur.error(f"header has no {kw} line")
    edge_rule = head.get("EDGE_RULE", "bounded")  # files before the line: the bounded rule
    n, et, eq, c, has_coef, nb = counts

    # ---- NODES, NORMALS
    cur.section_header("NODES", n)
    start = cur.pos
    ids, nodes = cur.table(n, 1, 3, "node record 'id x y z'")
    cur.check_ids(ids[:, 0], start, "node")
    cur.section_header("NORMALS", n)
    start = cur.pos
    ids, normals = cur.table(n, 1, 3, "normal record 'id nx ny nz'")
    cur.check_ids(ids[:, 0], start, "normal")

    # ---- ELEMENTS: triangles (3 nodes) first, then quads (4 nodes)
    cur.section_header("ELEMENTS", et + eq)
    start = cur.pos
    for i, line in enumerate(cur.lines[start : start + et + eq]):  # node counts before field counts
        toks = line.split()
        want = "3" if i < et else "4"
        if len(toks) >= 2 and toks[1] != want and toks[1] in ("3", "4"):
            raise cur.error(
                f"element {i + 1}: node count {toks[1]} where {want} was expected "
                f"(COUNTS says {et} triangles then {eq} quads; triangles must come first)", start + i + 1)
    tri_ints, _ = cur.table(et, 5, 0, "triangle record 'id 3 n1 n2 n3'") if et else (np.zeros((0, 5), np.int64), None)
    quad_ints, _ = cur.table(eq, 6, 0, "quad record 'id 4 n1 n2 n3 n4'") if eq else (np.zeros((0, 6), np.int64), None)
    cur.check_ids(np.concatenate([tri_ints[:, 0], quad_ints[:, 0]]), start, "element")
    for ints, nn, off in ((tri_ints, 3, 0), (quad_ints, 4, et)):
        bad = np.nonzero(ints[:, 1] != nn)[0]
        if bad.size:
            i = int(bad[0])
            raise cur.error(
                f"element {off + i + 1}: node count {ints[i, 1]} where {nn} was expected "
                f"(COUNTS says {et} triangles then {eq} quads; triangles must come first)", start + off + i + 1)
        conn = ints[:, 2:]
        bad = np.nonzero(np.any((conn < 1) | (conn > n), axis=1))[0]
        if bad.size:
            i = int(bad[0])
            raise cur.error(f"element {off + i + 1}: node id out of range 1..{n}", start + off + i + 1)
    triangles = tri_ints[:, 2:] - 1
    quads = quad_ints[:, 2:] - 1

    # ---- CORNER_NORMALS
    cur.section_header("CORNER_NORMALS", c)
    start = cur.pos
    cints, cnormals = cur.table(c, 2, 3, "corner normal record 'element corner nx ny nz'")
    celem, ccorner = cints[:, 0] - 1, cints[:, 1] - 1
    ncorner = np.where(celem < et, 3, 4)
    bad = np.nonzero((celem < 0) | (celem >= et + eq) | (ccorner < 0) | (ccorner >= ncorner))[0]
    if bad.size:
        i = int(bad[0])
        raise cur.error(f"element {cints[i, 0]} / corner {cints[i, 1]} out of range", start + i + 1)

    # ---- EDGE_NORMALS (version 2)
    enodes, enormals = np.zeros((0, 2), np.int64), np.zeros((0, 2, 3))
    if version >= 2:
        cur.section_header("EDGE_NORMALS", nb)
        start = cur.pos
        eints, evec = cur.table(nb, 3, 6, "edge normal record 'id node1 node2 px py pz qx qy qz'")
        cur.check_ids(eints[:, 0], start, "edge normal")
        bad = np.nonzero(np.any((eints[:, 1:] < 1) | (eints[:, 1:] > n), axis=1) | (eints[:, 1] == eints[:, 2]))[0]
        if bad.size:
            i = int(bad[0])
            raise cur.error(f"edge normal {i + 1}: nodes {eints[i, 1]} {eints[i, 2]} are not two nodes in 1..{n}",
                            start + i + 1)
        enodes, enormals = eints[:, 1:] - 1, evec.reshape(nb, 2, 3)

    # ---- COEFFICIENTS (optional)
    tri_coef = quad_coef = None
    if has_coef:
        cur.section_header("COEFFICIENTS", 6 * et + 8 * eq)
        start = cur.pos
        kints, vec = cur.table(6 * et + 8 * eq, 2, 3, "coefficient record 'element k cx cy cz'")
        want_e = np.concatenate([np.repeat(np.arange(1, et + 1), 6), np.repeat(np.arange(et + 1, et + eq + 1), 8)])
        want_k = np.concatenate([np.tile(np.arange(1, 7), et), np.tile(np.arange(1, 9), eq)])
        bad = np.nonzero((kints[:, 0] != want_e) | (kints[:, 1] != want_k))[0]
        if bad.size:
            i = int(bad[0])
            raise cur.error(
                f"expected element {want_e[i]} coefficient {want_k[i]}, got {kints[i, 0]} {kints[i, 1]} "
                "(6 per triangle, 8 per quad, in element order)", start + i + 1)
        tri_coef = vec[: 6 * et].reshape(et, 6, 3)
        quad_coef = vec[6 * et :].reshape(eq, 8, 3)

    cur.section = "END"
    line = cur.next()
    if line.strip() != "END":
        raise cur.error(f"expected 'END', got {line!r}")
    if any(ln.strip() for ln in cur.lines[cur.pos :]):
        raise cur.error("text after END", cur.pos + 1)

    try:
        return ToolData(
            name=head["NAME"], units=head["UNITS"], nodes=nodes, normals=normals, triangles=triangles,
            quads=quads, corner_element=celem, corner_local=ccorner, corner_normals=cnormals,
            edge_nodes=enodes, edge_normals=enormals,
            tri_coefficients=tri_coef, quad_coefficients=quad_coef, source=head.get("SOURCE", ""),
            normal_source=head.get("NORMAL_SOURCE", ""), edge_rule=edge_rule, metadata=metadata, comments=comments,
        )
    except ToolFileError as exc:
        raise ToolFileError(f"{filename}: {exc}") from None
