"""Independent reference reader of the cadbridge tool file (docs/toolfile.md, versions 1 and 2).

Written from docs/toolfile.md alone, for tests and benchmarks: it imports neither
cadbridge.io.toolfile nor cadbridge.nagata (nor anything else of cadbridge), only numpy.

* `read(path) -> ToolFile`: parses and validates every section (ids = record numbers,
  triangles first, counts, corner range, one override per (element, corner), coefficient
  order), 0-based arrays.
* `corner_normals(tf)`: rule 1 ("Corner normals") -> (E, 4, 3), NaN for a triangle's 4th.
* `edge_coefficients(tf)`: rules 2-5 (edges, which formula, two-normal formula with its
  bounded cases, generalized inverse with adj / D0 / D1 / D2, the one-end-multiple rule, 4b)
  of the bounded edge rule (``EDGE_RULE bounded``, or no such line), or "The published rule"
  (``EDGE_RULE published``: eq. 15 without the bounded cases, the generalized inverse with the
  distinct normals wherever an end carries several, no EDGE_NORMALS).
* `rebuild(tf) -> (E, 8, 3)`: rule 6 (patch coefficients; c21 = c12 = 0 for triangles).
* `evaluate(coef, kind, elem, eta, zeta)`: the patch polynomial of "Corners and patch
  parameters"; `flat(tf, elem, eta, zeta)`: the flat element (triangle
  x00 + (x10-x00) eta + (x11-x10) zeta, quad bilinear).
* `sample_grid(tf, n)`: (elem, eta, zeta) of an n-division grid on every patch
  (0 <= zeta <= eta <= 1 on triangles, the unit square on quads).
* `model_size(tf)`: diagonal of the node bounding box.

Everything is vectorised over elements / edges (no Python loop over them), so it reads
tool files of a few 100 000 elements in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

EPS = 1e-10  # docs/toolfile.md "Rebuilding the coefficients": eps
EPS_RANK = 1e-12  # eps_rank
ORDER = ("c00", "c10", "c01", "c11", "c20", "c02", "c21", "c12")  # k = 1..8
TRI_EDGES = ((0, 1), (1, 2), (0, 2))  # (1,2) (2,3) (1,3), 0-based corners -> c1 c2 c3
QUAD_EDGES = ((0, 1), (1, 2), (3, 2), (0, 3))  # (1,2) (2,3) (4,3) (1,4) -> c1 c2 c3 c4


class ToolFileError(ValueError):
    """The file does not follow docs/toolfile.md; the message names the line."""


@dataclass
class ToolFile:
    name: str
    units: str
    source: str
    normal_source: str
    meta: list[tuple[str, str]]
    comments: list[str]
    nodes: np.ndarray  # (N, 3)
    normals: np.ndarray  # (N, 3)
    conn: np.ndarray  # (E, 4) 0-based node ids, -1 in a triangle's 4th column
    nn: np.ndarray  # (E,) 3 or 4
    corner_element: np.ndarray  # (C,) 0-based
    corner_index: np.ndarray  # (C,) 0-based local corner
    corner_normal: np.ndarray  # (C, 3)
    coefficients: np.ndarray | None  # (E, 8, 3) as written, zeros for a triangle's c21 c12
    edge_nodes: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))  # (B, 2) 0-based
    edge_p: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (B, 3) extra normal at edge_nodes[:, 0]
    edge_q: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (B, 3) at edge_nodes[:, 1]
    extra: dict = field(default_factory=dict)
    edge_rule: str = "bounded"  # the EDGE_RULE header line; a file without it: bounded

    @property
    def n_tri(self) -> int:
        return int(np.count_nonzero(self.nn == 3))

    @property
    def n_elements(self) -> int:
        return len(self.nn)


def _fail(path, lineno: int, msg: str):
    raise ToolFileError(f"{path}:{lineno}: {msg}")


def _numeric(path, lines: list[str], start: int, count: int, width: int, what: str) -> np.ndarray:
    """`count` records of `width` numbers from lines[start:start+count] -> (count, width)."""
    chunk = lines[start:start + count]
    if len(chunk) != count:
        _fail(path, start + len(chunk) + 1, f"{what}: file ends after {len(chunk)} of {count} records")
    toks = " ".join(chunk).split()
    if len(toks) != count * width:
        for i, ln in enumerate(chunk):
            if len(ln.split()) != width:
                _fail(path, start + i + 1, f"{what}: record needs {width} fields: {ln!r}")
    try:
        a = np.array(toks, dtype=float).reshape(count, width)
    except ValueError as exc:
        _fail(path, start + 1, f"{what}: {exc}")
    if not np.all(np.isfinite(a)):
        _fail(path, start + 1 + int(np.flatnonzero(~np.isfinite(a).all(axis=1))[0]), f"{what}: non-finite number")
    return a


def _section(path, lines: list[str], i: int, keyword: str) -> int:
    if i >= len(lines):
        _fail(path, i + 1, f"expected '{keyword} <count>', found end of file")
    parts = lines[i].split()
    if len(parts) != 2 or parts[0] != keyword or not parts[1].isdigit():
        _fail(path, i + 1, f"expected '{keyword} <count>', found {lines[i]!r}")
    return int(parts[1])


def _ids(path, a: np.ndarray, start: int, what: str) -> None:
    """Column 0 must be 1, 2, 3, ... (id = record number)."""
    bad = np.flatnonzero(a[:, 0] != np.arange(1, len(a) + 1))
    if len(bad):
        _fail(path, start + int(bad[0]) + 1, f"{what}: id {a[bad[0], 0]!r} is not the record number {bad[0] + 1}")


def read(path: str | Path) -> ToolFile:
    path = Path(path)
    text = path.read_bytes().decode("utf-8")
    lines = [ln[:-1] if ln.endswith("\r") else ln for ln in text.split("\n")]
    if lines and lines[-1] == "":
        lines.pop()  # the final "\n"
    magic = lines[0].split() if lines else []
    if len(magic) != 2 or magic[0] != "CADBRIDGE-NAGATA-TOOL":
        _fail(path, 1, f"not a cadbridge tool file: {lines[0] if lines else ''!r}")
    if magic[1] not in ("1", "2"):
        _fail(path, 1, f"version {magic[1]!r}: this reader knows versions 1 and 2 only")
    version = int(magic[1])
    head: dict[str, str] = {}
    meta, comments = [], []
    i = 1
    while True:
        if i >= len(lines):
            _fail(path, i, "no COUNTS line")
        ln = lines[i]
        key, _, value = ln.partition(" ")  # value: everything after the first blank after the keyword
        if key == "COUNTS":
            break
        if key in ("NAME", "UNITS", "SOURCE", "NORMAL_SOURCE", "EDGE_RULE"):
            if key in head:
                _fail(path, i + 1, f"{key} appears twice")
            head[key] = value
        elif key == "META":
            k, _, v = value.partition(" ")
            if not k:
                _fail(path, i + 1, "META without a key")
            meta.append((k, v))
        elif key == "COMMENT":
            comments.append(value)
        else:
            _fail(path, i + 1, f"unknown header line {ln!r}")
        i += 1
    for req in ("NAME", "UNITS"):
        if req not in head:
            _fail(path, i + 1, f"header has no {req}")
    rule = head.get("EDGE_RULE", "bounded")
    if rule not in ("bounded", "published"):
        _fail(path, i + 1, f"EDGE_RULE must be bounded or published, not {rule!r}")
    counts = lines[i].split()[1:]
    want = 5 if version == 1 else 6
    if len(counts) != want or not all(c.isdigit() for c in counts):
        _fail(path, i + 1, f"COUNTS needs {want} integers in version {version}: {lines[i]!r}")
    N, Et, Eq, C, K = map(int, counts[:5])
    B = int(counts[5]) if version == 2 else 0
    if K not in (0, 1):
        _fail(path, i + 1, f"COUNTS K must be 0 or 1, not {K}")
    E = Et + Eq
    i += 1

    if _section(path, lines, i, "NODES") != N:
        _fail(path, i + 1, f"NODES count differs from COUNTS N = {N}")
    a = _numeric(path, lines, i + 1, N, 4, "NODES")
    _ids(path, a, i + 1, "NODES")
    nodes = a[:, 1:].copy()
    i += 1 + N

    if _section(path, lines, i, "NORMALS") != N:
        _fail(path, i + 1, f"NORMALS count differs from COUNTS N = {N}")
    a = _numeric(path, lines, i + 1, N, 4, "NORMALS")
    _ids(path, a, i + 1, "NORMALS")
    normals = a[:, 1:].copy()
    bad = np.flatnonzero(np.abs(np.linalg.norm(normals, axis=1) - 1.0) > 1e-6)
    if len(bad):
        _fail(path, i + 2 + int(bad[0]), "NORMALS: not a unit vector")
    i += 1 + N

    if _section(path, lines, i, "ELEMENTS") != E:
        _fail(path, i + 1, f"ELEMENTS count differs from COUNTS Et+Eq = {E}")
    conn = -np.ones((E, 4), dtype=np.int64)
    nn = np.zeros(E, dtype=np.int64)
    for r in range(E):
        ln = i + 1 + r
        if ln >= len(lines):
            _fail(path, ln + 1, "ELEMENTS: file ends early")
        f = lines[ln].split()
        try:
            v = [int(x) for x in f]
        except ValueError:
            _fail(path, ln + 1, f"ELEMENTS: not integers: {lines[ln]!r}")
        if len(v) < 2 or v[0] != r + 1 or v[1] not in (3, 4) or len(v) != 2 + v[1]:
            _fail(path, ln + 1, f"ELEMENTS: bad record {lines[ln]!r}")
        want = 3 if r < Et else 4
        if v[1] != want:
            _fail(path, ln + 1, f"ELEMENTS: element {r + 1} has {v[1]} nodes; triangles 1..{Et} first, then quads")
        nn[r] = v[1]
        conn[r, :v[1]] = v[2:]
    used = conn[conn >= 0] if E else conn[:0, 0]
    if E and (used.min() < 1 or used.max() > N):
        _fail(path, i + 2, f"ELEMENTS: node id outside 1..{N}")
    conn[conn > 0] -= 1  # 1-based -> 0-based; -1 stays "no 4th corner"
    i += 1 + E

    if _section(path, lines, i, "CORNER_NORMALS") != C:
        _fail(path, i + 1, f"CORNER_NORMALS count differs from COUNTS C = {C}")
    a = _numeric(path, lines, i + 1, C, 5, "CORNER_NORMALS")
    ce, cc = a[:, 0], a[:, 1]
    if C:
        if np.any(ce != np.round(ce)) or np.any(cc != np.round(cc)):
            _fail(path, i + 2, "CORNER_NORMALS: element and corner must be integers")
        ce, cc = ce.astype(np.int64) - 1, cc.astype(np.int64) - 1
        if ce.min() < 0 or ce.max() >= E:
            _fail(path, i + 2, f"CORNER_NORMALS: element outside 1..{E}")
        if np.any(cc < 0) or np.any(cc >= nn[ce]):
            _fail(path, i + 2 + int(np.flatnonzero((cc < 0) | (cc >= nn[ce]))[0]), "CORNER_NORMALS: corner outside 1..nn")
        key = ce * 4 + cc
        if len(np.unique(key)) != C:
            _fail(path, i + 2, "CORNER_NORMALS: two records for one (element, corner)")
        if np.any(np.abs(np.linalg.norm(a[:, 2:], axis=1) - 1.0) > 1e-6):
            _fail(path, i + 2, "CORNER_NORMALS: not a unit vector")
    else:
        ce, cc = ce.astype(np.int64), cc.astype(np.int64)
    cn = a[:, 2:].copy()
    i += 1 + C

    en, ep, eqn = np.zeros((0, 2), np.int64), np.zeros((0, 3)), np.zeros((0, 3))
    if version == 2:
        if _section(path, lines, i, "EDGE_NORMALS") != B:
            _fail(path, i + 1, f"EDGE_NORMALS count differs from COUNTS B = {B}")
        a = _numeric(path, lines, i + 1, B, 9, "EDGE_NORMALS")
        _ids(path, a, i + 1, "EDGE_NORMALS")
        if B:
            if np.any(a[:, 1:3] != np.round(a[:, 1:3])):
                _fail(path, i + 2, "EDGE_NORMALS: node ids must be integers")
            en = a[:, 1:3].astype(np.int64) - 1
            if en.min() < 0 or en.max() >= N or np.any(en[:, 0] == en[:, 1]):
                _fail(path, i + 2, f"EDGE_NORMALS: nodes must be two different ids in 1..{N}")
            ep, eqn = a[:, 3:6].copy(), a[:, 6:9].copy()
            if np.any(np.abs(np.linalg.norm(np.r_[ep, eqn], axis=1) - 1.0) > 1e-6):
                _fail(path, i + 2, "EDGE_NORMALS: not a unit vector")
        i += 1 + B

    coef = None
    if K == 1:
        M = 6 * Et + 8 * Eq
        if _section(path, lines, i, "COEFFICIENTS") != M:
            _fail(path, i + 1, f"COEFFICIENTS count differs from 6Et+8Eq = {M}")
        a = _numeric(path, lines, i + 1, M, 5, "COEFFICIENTS")
        e_want = np.concatenate([np.repeat(np.arange(1, Et + 1), 6), np.repeat(np.arange(Et + 1, E + 1), 8)])
        k_want = np.concatenate([np.tile(np.arange(1, 7), Et), np.tile(np.arange(1, 9), Eq)])
        bad = np.flatnonzero((a[:, 0] != e_want) | (a[:, 1] != k_want))
        if len(bad):
            _fail(path, i + 2 + int(bad[0]), f"COEFFICIENTS: expected element {e_want[bad[0]]} k {k_want[bad[0]]}")
        coef = np.zeros((E, 8, 3))
        coef[e_want - 1, k_want - 1] = a[:, 2:]
        i += 1 + M
    if i >= len(lines) or lines[i] != "END":
        _fail(path, i + 1, f"expected END, found {lines[i] if i < len(lines) else 'end of file'!r}")
    if any(ln.strip() for ln in lines[i + 1:]):
        _fail(path, i + 2, "text after END")
    return ToolFile(head["NAME"], head["UNITS"], head.get("SOURCE", ""), head.get("NORMAL_SOURCE", ""),
                    meta, comments, nodes, normals, conn, nn, ce, cc, cn, coef, en, ep, eqn, edge_rule=rule)


def model_size(tf: ToolFile) -> float:
    """Diagonal of the node bounding box."""
    return float(np.linalg.norm(tf.nodes.max(axis=0) - tf.nodes.min(axis=0)))


def corner_normals(tf: ToolFile) -> np.ndarray:
    """Rule 1: N(e, j) = CORNER_NORMALS record (e, j) if any, else NORMALS(node(e, j)).
    (E, 4, 3); NaN in a triangle's 4th corner."""
    out = np.full((tf.n_elements, 4, 3), np.nan)
    has = tf.conn >= 0
    out[has] = tf.normals[tf.conn[has]]
    out[tf.corner_element, tf.corner_index] = tf.corner_normal
    return out


def two_normal(d: np.ndarray, n0: np.ndarray, n1: np.ndarray) -> np.ndarray:
    """Rule 4 (Nagata 2005 eq. 15 with the two bounded cases), (M, 3) each."""
    dot = lambda a, b: np.einsum("ij,ij->i", a, b)
    v = (n0 + n1) / 2
    dv = (n0 - n1) / 2
    dd = dot(d, v)
    ddelta = dot(d, dv)
    dc = dot(n0, dv)
    one = 1 - dc
    f1 = np.where(one >= EPS, ddelta / np.where(one >= EPS, one, 1.0), 0.0)
    dd2 = dot(d, d)
    inflected = dot(d, n0) * dot(d, n1) > EPS * dd2
    ok2 = (dc >= EPS) & ~inflected
    f2 = np.where(ok2, dd / np.where(ok2, dc, 1.0), 0.0)
    c = f1[:, None] * v + f2[:, None] * dv
    b = np.cross(d, v)
    bl = np.linalg.norm(b, axis=1)
    keep = bl > 1e-12 * np.sqrt(dd2) * np.linalg.norm(v, axis=1)
    bu = np.zeros_like(b)
    bu[keep] = b[keep] / bl[keep, None]
    return c - dot(c, bu)[:, None] * bu


def two_normal_published(d: np.ndarray, n0: np.ndarray, n1: np.ndarray) -> np.ndarray:
    """"The published rule", one normal per end: eq. 15 with its singular cases only, (M, 3) each."""
    dot = lambda a, b: np.einsum("ij,ij->i", a, b)  # noqa: E731
    v, dv = (n0 + n1) / 2, (n0 - n1) / 2
    dc = dot(n0, dv)
    one = 1 - dc
    f1 = np.where(one >= EPS, dot(d, dv) / np.where(one >= EPS, one, 1.0), 0.0)
    f2 = np.where(dc >= EPS, dot(d, v) / np.where(dc >= EPS, dc, 1.0), 0.0)
    return f1[:, None] * v + f2[:, None] * dv


def _distinct_rows(n: np.ndarray) -> np.ndarray:
    """The rows of ``n`` (K, 3) that differ by more than 1e-12 (componentwise) from every earlier kept row."""
    kept: list = []
    for row in n:
        if not any(np.max(np.abs(row - k)) <= 1e-12 for k in kept):
            kept.append(row)
    return np.array(kept)


def generalized_inverse(d: np.ndarray, S: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Rule 5 from the already averaged S (M, 3, 3) and r (M, 3)."""
    D0 = np.linalg.det(S) if len(S) else np.zeros(0)
    # principal 2x2 minors
    D1 = (S[:, 1, 1] * S[:, 2, 2] - S[:, 1, 2] * S[:, 2, 1] + S[:, 0, 0] * S[:, 2, 2] - S[:, 0, 2] * S[:, 2, 0]
          + S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0])
    D2 = np.trace(S, axis1=1, axis2=2)
    adj = np.empty_like(S)  # adjugate = transpose of the cofactor matrix
    for i in range(3):
        for j in range(3):
            rows = [k for k in range(3) if k != j]
            cols = [k for k in range(3) if k != i]
            minor = (S[:, rows[0], cols[0]] * S[:, rows[1], cols[1]] - S[:, rows[0], cols[1]] * S[:, rows[1], cols[0]])
            adj[:, i, j] = (-1) ** (i + j) * minor
    c = np.zeros_like(r)
    a0 = np.abs(D0) > EPS_RANK
    a1 = ~a0 & (np.abs(D1) > EPS_RANK)
    a2 = ~a0 & ~a1 & (np.abs(D2) > EPS_RANK)
    c[a0] = np.einsum("mij,mj->mi", adj[a0], r[a0]) / D0[a0, None]
    M1 = D2[a1, None, None] * np.eye(3) - S[a1]
    c[a1] = np.einsum("mij,mj->mi", M1, r[a1]) / D1[a1, None]
    c[a2] = r[a2] / D2[a2, None]
    return c


@dataclass
class Edges:
    nodes: np.ndarray  # (M, 2) node pair, first < second (x0 = nodes[:, 0])
    coef: np.ndarray  # (M, 3) c for d = x1 - x0
    kind: np.ndarray  # (M,) 0 two-normal, 1 one end multiple, 2 generalized inverse, 3 with conormals (4b)
    local: np.ndarray  # (E, 4) edge id of local edge c1..c4 of each element (-1 for a triangle's c4)


def edge_coefficients(tf: ToolFile) -> Edges:
    """Rules 2, 3, 4, 5 (4b) for every mesh edge, or "The published rule" (``tf.edge_rule``)."""
    N_ = corner_normals(tf)
    E = tf.n_elements
    tri = np.flatnonzero(tf.nn == 3)
    quad = np.flatnonzero(tf.nn == 4)
    el, a, b, na, nb, slot = [], [], [], [], [], []
    for elems, pairs in ((tri, TRI_EDGES), (quad, QUAD_EDGES)):
        for s, (i, j) in enumerate(pairs):
            el.append(elems)
            a.append(tf.conn[elems, i])
            b.append(tf.conn[elems, j])
            na.append(N_[elems, i])
            nb.append(N_[elems, j])
            slot.append(np.full(len(elems), s))
    el, a, b, slot = (np.concatenate(x) for x in (el, a, b, slot))
    na, nb = np.concatenate(na), np.concatenate(nb)
    # orient every local edge from the smaller node id: c does not depend on the direction
    sw = a > b
    a, b = np.where(sw, b, a), np.where(sw, a, b)
    n0 = np.where(sw[:, None], nb, na)  # collected normal at x0 (node a)
    n1 = np.where(sw[:, None], na, nb)  # at x1 (node b)
    # group by node pair; inside a group, element order
    order = np.lexsort((el, b, a))
    el, a, b, slot, n0, n1 = el[order], a[order], b[order], slot[order], n0[order], n1[order]
    new = np.ones(len(a), dtype=bool)
    new[1:] = (a[1:] != a[:-1]) | (b[1:] != b[:-1])
    gid = np.cumsum(new) - 1
    first = np.flatnonzero(new)
    M = len(first)
    # multiple end: some collected normal differs (exactly) from the group's first one
    diff0 = np.any(n0 != n0[first][gid], axis=1)
    diff1 = np.any(n1 != n1[first][gid], axis=1)
    mult0 = np.zeros(M, dtype=bool)
    mult1 = np.zeros(M, dtype=bool)
    np.logical_or.at(mult0, gid, diff0)
    np.logical_or.at(mult1, gid, diff1)
    x0, x1 = tf.nodes[a[first]], tf.nodes[b[first]]
    d = x1 - x0
    coef = np.zeros((M, 3))
    kind = np.zeros(M, dtype=np.int64)
    local = -np.ones((E, 4), dtype=np.int64)
    local[el, slot] = gid

    if tf.edge_rule == "published":  # "The published rule": eq. 15, or eqs. 19-33 with the distinct normals
        coef = two_normal_published(d, n0[first], n1[first])
        ends = np.append(first, len(gid))
        for g in np.flatnonzero(mult0 | mult1):  # loop over the (few) edges with several normals at an end
            p = _distinct_rows(n0[ends[g]:ends[g + 1]])
            q = _distinct_rows(n1[ends[g]:ends[g + 1]])
            if len(p) == 1 and len(q) == 1:
                continue  # differences below 1e-12: one normal per end
            m = len(p) + len(q)
            S = (p.T @ p + q.T @ q) / m
            r = (p.T @ (p @ d[g]) - q.T @ (q @ d[g])) / m
            coef[g] = generalized_inverse(d[g:g + 1], S[None], r[None])[0]
            kind[g] = 2
        return Edges(np.stack([a[first], b[first]], axis=1), coef, kind, local)

    # neither end multiple
    g = ~mult0 & ~mult1
    coef[g] = two_normal(d[g], n0[first][g], n1[first][g])

    # one end multiple: smallest |n . d| at the multiple end (first in element order on ties)
    for mult, other, nm, no in ((mult0, mult1, n0, n1), (mult1, mult0, n1, n0)):
        g = mult & ~other
        if not np.any(g):
            continue
        rows = np.flatnonzero(g[gid])
        key = np.abs(np.einsum("ij,ij->i", nm[rows], d[gid[rows]]))
        o = np.lexsort((el[rows], key, gid[rows]))  # by group, then |n.d|, then element order
        rs = rows[o]
        firsts = np.ones(len(rs), dtype=bool)
        firsts[1:] = gid[rs][1:] != gid[rs][:-1]
        pick = rs[firsts]
        gg = gid[pick]
        nsel = nm[pick]
        noth = no[first][gg]
        if nm is n0:
            coef[gg] = two_normal(d[gg], nsel, noth)
        else:
            coef[gg] = two_normal(d[gg], noth, nsel)
        kind[gg] = 1

    # both ends multiple: generalized inverse with all collected normals (m = group size)
    g = mult0 & mult1
    if np.any(g):
        rows = np.flatnonzero(g[gid])
        S = np.zeros((M, 3, 3))
        r = np.zeros((M, 3))
        dr = d[gid[rows]]
        p, q = n0[rows], n1[rows]
        np.add.at(S, gid[rows], p[:, :, None] * p[:, None, :] + q[:, :, None] * q[:, None, :])
        np.add.at(r, gid[rows], p * np.einsum("ij,ij->i", p, dr)[:, None] - q * np.einsum("ij,ij->i", q, dr)[:, None])
        # docs/toolfile.md writes "/ m" with m = "all collected normals ... each counted once
        # per element" but also says "(3 x 3, trace 1)": with unit normals, trace 1 needs the
        # division by the number of normals at both ends together, 2 per element (dividing by
        # the element count gives trace 2). The page is ambiguous here; trace 1 is taken
        # (c does not depend on the scale, only the eps_rank tests do).
        m = 2.0 * np.bincount(gid, minlength=M).astype(float)
        gi = np.flatnonzero(g)
        coef[gi] = generalized_inverse(d[gi], S[gi] / m[gi, None, None], r[gi] / m[gi, None])
        kind[gi] = 2
        # "Where that c turns the edge curve back (|c . d| >= |d . d|) or bends it sharply
        # ((d - c) . (d + c) < cos(100°) |d - c| |d + c|) take instead at each end the
        # collected normal with the smallest |n . d| (first in element order on ties), then
        # the two-normal formula"
        cg, dg = coef[gi], d[gi]
        lo_t, hi_t = dg - cg, dg + cg
        sharp = np.einsum("ij,ij->i", lo_t, hi_t) < np.cos(np.deg2rad(100.0)) * (
            np.linalg.norm(lo_t, axis=1) * np.linalg.norm(hi_t, axis=1))
        back = gi[(np.abs(np.einsum("ij,ij->i", cg, dg)) >= np.einsum("ij,ij->i", dg, dg)) | sharp]
        for g in back:  # the (few) hairpin edges
            rows = np.flatnonzero(gid == g)
            rows = rows[np.argsort(el[rows], kind="stable")]
            ends = [nn[rows][np.argmin(np.abs(nn[rows] @ d[g]))] for nn in (n0, n1)]
            coef[g] = two_normal(d[g:g + 1], ends[0][None], ends[1][None])[0]
            kind[g] = 1

    # rule 4b: an edge with an EDGE_NORMALS record and no multiple end: two-normal c plus s b
    if len(tf.edge_nodes):
        ea, eb = tf.edge_nodes[:, 0], tf.edge_nodes[:, 1]
        sw = ea > eb
        lo, hi = np.minimum(ea, eb), np.maximum(ea, eb)
        p = np.where(sw[:, None], tf.edge_q, tf.edge_p)  # conormal at x0 = node lo
        q = np.where(sw[:, None], tf.edge_p, tf.edge_q)
        kx = lo * (len(tf.nodes) + 1) + hi
        kg = a[first] * (len(tf.nodes) + 1) + b[first]
        if len(np.unique(kx)) != len(kx):
            raise ToolFileError("EDGE_NORMALS: two records for one edge")
        pos = np.searchsorted(kg, kx)  # groups are sorted by (a, b)
        pos_c = np.minimum(pos, M - 1)
        if np.any(kg[pos_c] != kx):
            raise ToolFileError("EDGE_NORMALS: a record's two nodes are not an edge of any element")
        g = kind[pos_c] == 0
        gi = pos_c[g]
        dd, pp, qq = d[gi], p[g], q[g]
        c2 = coef[gi]
        v = (n0[first][gi] + n1[first][gi]) / 2
        bv = np.cross(dd, v)
        bl = np.linalg.norm(bv, axis=1)
        ok = bl > 1e-12 * np.linalg.norm(dd, axis=1) * np.linalg.norm(v, axis=1)
        bv = bv / np.where(ok, bl, 1.0)[:, None]
        dot = lambda x, y: np.einsum("ij,ij->i", x, y)  # noqa: E731
        pb, qb = dot(pp, bv), dot(qq, bv)
        den = pb * pb + qb * qb
        ok &= den >= EPS
        s = (dot(pp, dd - c2) * pb - dot(qq, dd + c2) * qb) / np.where(ok, den, 1.0)
        coef[gi] = c2 + np.where(ok, s, 0.0)[:, None] * bv
        kind[gi] = 3

    return Edges(np.stack([a[first], b[first]], axis=1), coef, kind, local)


def rebuild(tf: ToolFile, edges: Edges | None = None) -> np.ndarray:
    """Rule 6: (E, 8, 3) coefficients in the order c00 c10 c01 c11 c20 c02 c21 c12, each
    element's edge coefficients oriented from its own first corner (c is direction-free)."""
    edges = edges or edge_coefficients(tf)
    E = tf.n_elements
    out = np.zeros((E, 8, 3))
    X = tf.nodes[np.maximum(tf.conn, 0)]  # (E, 4, 3); a triangle's 4th is junk, not used
    c = edges.coef[np.maximum(edges.local, 0)]  # (E, 4, 3)
    # c was computed for d = x(second id) - x(first id); the rule's c is direction-free
    t = tf.nn == 3
    x00, x10, x11 = X[t, 0], X[t, 1], X[t, 2]
    c1, c2, c3 = c[t, 0], c[t, 1], c[t, 2]
    out[t, 0] = x00
    out[t, 1] = x10 - x00 - c1
    out[t, 2] = x11 - x10 + c1 - c3
    out[t, 3] = c3 - c1 - c2
    out[t, 4] = c1
    out[t, 5] = c2
    q = tf.nn == 4
    x00, x10, x11, x01 = X[q, 0], X[q, 1], X[q, 2], X[q, 3]
    c1, c2, c3, c4 = c[q, 0], c[q, 1], c[q, 2], c[q, 3]
    out[q, 0] = x00
    out[q, 1] = x10 - x00 - c1
    out[q, 2] = x01 - x00 - c4
    out[q, 3] = x11 - x10 - x01 + x00 + c1 - c2 - c3 + c4
    out[q, 4] = c1
    out[q, 5] = c4
    out[q, 6] = c3 - c1
    out[q, 7] = c2 - c4
    return out


def evaluate(coef: np.ndarray, elem: np.ndarray, eta: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """Patch point x(eta, zeta) of elements `elem` from (E, 8, 3) coefficients (a
    triangle's c21 = c12 = 0, so one polynomial serves both kinds)."""
    cf = coef[elem]
    e, z = np.asarray(eta, float)[:, None], np.asarray(zeta, float)[:, None]
    return (cf[:, 0] + cf[:, 1] * e + cf[:, 2] * z + cf[:, 3] * e * z + cf[:, 4] * e * e + cf[:, 5] * z * z
            + cf[:, 6] * e * e * z + cf[:, 7] * e * z * z)


def flat(tf: ToolFile, elem: np.ndarray, eta: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """Flat element at (eta, zeta): triangle x00 + (x10-x00) eta + (x11-x10) zeta,
    quad bilinear through x00, x10, x11, x01."""
    X = tf.nodes[np.maximum(tf.conn[elem], 0)]
    e, z = np.asarray(eta, float)[:, None], np.asarray(zeta, float)[:, None]
    tri = X[:, 0] + (X[:, 1] - X[:, 0]) * e + (X[:, 2] - X[:, 1]) * z
    quad = (X[:, 0] * (1 - e) * (1 - z) + X[:, 1] * e * (1 - z) + X[:, 2] * e * z + X[:, 3] * (1 - e) * z)
    return np.where((tf.nn[elem] == 3)[:, None], tri, quad)


def sample_grid(tf: ToolFile, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(elem, eta, zeta) of the n-division grid of every patch: triangles (i/n, j/n) with
    0 <= j <= i <= n, quads 0 <= i, j <= n."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    lo = j <= i
    te, tz = i[lo] / n, j[lo] / n
    qe, qz = i / n, j / n
    tri = np.flatnonzero(tf.nn == 3)
    quad = np.flatnonzero(tf.nn == 4)
    elem = np.concatenate([np.repeat(tri, len(te)), np.repeat(quad, len(qe))])
    eta = np.concatenate([np.tile(te, len(tri)), np.tile(qe, len(quad))])
    zeta = np.concatenate([np.tile(tz, len(tri)), np.tile(qz, len(quad))])
    return elem, eta, zeta
