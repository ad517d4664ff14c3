"""The edge rule (issue 34, item 3): ``published`` is Nagata 2005 exactly, ``bounded`` (the
default) is unchanged, the tool file states its rule, the CLI takes ``--edge-rule``.

References:

* ``published``: `nagata_2005_edge` and `nagata_2005_patches` below, written from the paper
  (Nagata, T. 2005, CAGD 22, 327-347) and thesis eqs. 5 and 10, with numpy only: eq. (15)
  with its singular cases (``Delta c = 0``: parallel normals, ``Delta c = 1``: opposite
  normals; ``1 - (n0 . n1)^2 = 4 Delta c (1 - Delta c)``) for one normal at each end, and
  eq. (20) ``c = [n]^+ {d}`` with the Moore-Penrose inverse of numpy's SVD (the generalized
  inverse eqs. 21-31 compute in closed form) for several distinct normals at an end. It
  reads the tool file with tests/helpers/toolfile_reference.py (docs/toolfile.md alone), not
  with cadbridge. The same files are also rebuilt by that helper's own reading of
  docs/toolfile.md "The published rule" (`R.rebuild`), so the page says what is written.
* ``bounded``: digests of the coefficients cadbridge computed before the option existed
  (commit 03d82a1), on the cases of `grid_case`.
"""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cadbridge.io.toolfile import ToolData, ToolFileError, format_toolfile, parse_toolfile, read_toolfile
from cadbridge.nagata import NagataMesh
from tests.helpers import toolfile_reference as R

ROOT = Path(__file__).parents[2]
SAMPLES = ROOT / "iges_samples"
EPS = 1e-10  # docs/toolfile.md: eps of eq. (15)'s singular cases
SAME = 1e-12  # corner normals closer than this (componentwise) are one normal (docs/toolfile.md rule 3)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ----------------------------------------------------------------------------- the reference
def nagata_2005_edge(x0, x1, normals0: list, normals1: list) -> np.ndarray:
    """c of the edge x0 -> x1 (Nagata 2005): eq. (15) for one normal per end, else eq. (20)."""
    d = np.asarray(x1, float) - np.asarray(x0, float)
    if len(normals0) == 1 and len(normals1) == 1:
        n0, n1 = normals0[0], normals1[0]
        v, dv = (n0 + n1) / 2, (n0 - n1) / 2  # eq. 12
        d_v, d_dv = d @ v, d @ dv  # eq. 13: "d", "Delta d"
        dc = n0 @ dv  # eq. 14: "Delta c"
        c = np.zeros(3)
        if 1 - dc >= EPS:  # the v term, absent for opposite normals (Delta c = 1)
            c += d_dv / (1 - dc) * v
        if dc >= EPS:  # the Delta v term, absent for parallel normals (Delta c = 0)
            c += d_v / dc * dv
        return c
    # eq. 19: n0_k . (d - c) = 0, n1_k . (d + c) = 0  ->  [n] c = {d}; eq. 20: c = [n]^+ {d}
    n = np.array(list(normals0) + list(normals1))
    rhs = np.array([m @ d for m in normals0] + [-(m @ d) for m in normals1])
    return np.linalg.pinv(n, rcond=1e-10) @ rhs


def _distinct(normals: list) -> list:
    out: list = []
    for m in normals:
        if not any(np.max(np.abs(m - o)) <= SAME for o in out):
            out.append(m)
    return out


def nagata_2005_patches(tf: R.ToolFile) -> np.ndarray:
    """(E, 8, 3) patch coefficients c00 c10 c01 c11 c20 c02 c21 c12 of the tool file ``tf``
    under the published rule: per mesh edge all the distinct corner normals of its elements
    at each end, `nagata_2005_edge`, then thesis eqs. 5 (triangle) and 10 (quadrilateral)."""
    cn = R.corner_normals(tf)
    local = {3: ((0, 1), (1, 2), (0, 2)), 4: ((0, 1), (1, 2), (3, 2), (0, 3))}
    at: dict = {}  # (node a, node b), a < b -> ([normals at a], [normals at b])
    for e in range(tf.n_elements):
        for i, j in local[int(tf.nn[e])]:
            a, b = int(tf.conn[e, i]), int(tf.conn[e, j])
            na, nb = cn[e, i], cn[e, j]
            if a > b:
                a, b, na, nb = b, a, nb, na
            at.setdefault((a, b), ([], []))
            at[(a, b)][0].append(na)
            at[(a, b)][1].append(nb)
    c_of = {k: nagata_2005_edge(tf.nodes[k[0]], tf.nodes[k[1]], _distinct(v[0]), _distinct(v[1]))
            for k, v in at.items()}
    out = np.zeros((tf.n_elements, 8, 3))
    for e in range(tf.n_elements):
        x = tf.nodes[tf.conn[e, : tf.nn[e]]]
        c = [c_of[tuple(sorted((int(tf.conn[e, i]), int(tf.conn[e, j]))))] for i, j in local[int(tf.nn[e])]]
        if tf.nn[e] == 3:  # thesis eq. 5
            out[e, :6] = [x[0], x[1] - x[0] - c[0], x[2] - x[1] + c[0] - c[2], c[2] - c[0] - c[1], c[0], c[1]]
        else:  # thesis eq. 10
            out[e] = [x[0], x[1] - x[0] - c[0], x[3] - x[0] - c[3], x[2] - x[1] - x[3] + x[0] + c[0] - c[1] - c[2] + c[3],
                      c[0], c[3], c[2] - c[0], c[1] - c[3]]
    return out


# ----------------------------------------------------------------------------- cases
def grid_case(seed: int, m: int = 6):
    """An m x m grid of 10 x 10 (triangles left, quadrilaterals right) with random heights and
    random unit normals: (nodes, [tri, quad], node normals, corner normals per block, edge
    normals). The corner normals add a crease along column m // 2 (another normal on its
    right side), one corner with its own normal (an edge with several normals at one end
    only) and conormals on the boundary edges of the first row."""
    rng = np.random.default_rng(seed)
    g = np.linspace(0.0, 10.0, m + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    nodes = np.stack([X.ravel(), Y.ravel(), rng.normal(scale=0.5, size=X.size)], 1)
    nid = lambda i, j: i * (m + 1) + j  # noqa: E731
    tri, quad = [], []
    for i in range(m):
        for j in range(m):
            a, b, c, d = nid(i, j), nid(i + 1, j), nid(i + 1, j + 1), nid(i, j + 1)
            if j < m // 2:
                tri += [[a, b, c], [a, c, d]]
            else:
                quad.append([a, b, c, d])
    tri, quad = np.array(tri), np.array(quad)
    normals = _unit(rng.normal(size=(len(nodes), 3)) + np.array([0.0, 0.0, 1.5]))
    corner = [normals[tri].copy(), normals[quad].copy()]
    k = m // 2
    side_b = _unit(rng.normal(size=(m + 1, 3)) + np.array([0.0, 0.0, 1.0]))
    for blk, conn in enumerate((tri, quad)):
        right = nodes[conn][:, :, 0].mean(axis=1) > g[k]
        for e in np.flatnonzero(right):
            for lc in range(conn.shape[1]):
                i, j = divmod(int(conn[e, lc]), m + 1)
                if i == k:
                    corner[blk][e, lc] = side_b[j]
    n_half = nid(1, 1)
    e = int(np.flatnonzero((tri == n_half).any(axis=1))[0])
    corner[0][e, int(np.flatnonzero(tri[e] == n_half)[0])] = _unit(normals[n_half] + [0.3, -0.2, 0.1])
    pairs = np.array([[nid(i, 0), nid(i + 1, 0)] for i in range(m)])
    p, q = _unit(rng.normal(size=(m, 3))), _unit(rng.normal(size=(m, 3)))
    return nodes, [tri, quad], normals, corner, (pairs, p, q)


def _tooldata(nodes, blocks, normals, corner, en, nm) -> ToolData:
    """The tool file data of a `grid_case` (corner overrides where a corner differs from its node)."""
    ce, cl, cv = [], [], []
    off = 0
    for conn, c in zip(blocks, corner):
        e, k = np.nonzero(np.any(c != normals[conn], axis=2))
        ce.append(e + off), cl.append(k), cv.append(c[e, k])
        off += len(conn)
    return ToolData(name="grid", units="MM", nodes=nodes, normals=normals, triangles=blocks[0], quads=blocks[1],
                    corner_element=np.concatenate(ce), corner_local=np.concatenate(cl),
                    corner_normals=np.concatenate(cv), edge_nodes=en[0], edge_normals=np.stack([en[1], en[2]], 1),
                    tri_coefficients=nm.tri_coefficients, quad_coefficients=nm.quad_coefficients,
                    edge_rule=nm.edge_rule)


def _size(nodes) -> float:
    return float(np.linalg.norm(nodes.max(axis=0) - nodes.min(axis=0)))


# ----------------------------------------------------------------------------- published
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("creases", [False, True])
def test_published_equals_nagata_2005_on_random_patches(tmp_path, seed, creases):
    """Random patches with random normals (eq. 15 unbounded: |c| up to many times the model
    size) and, with ``creases``, crease edges, an edge with several normals at one end and
    conormal records: the written coefficients equal `nagata_2005_patches` within
    1e-12 x size, and the conormals change nothing."""
    nodes, blocks, normals, corner, en = grid_case(seed)
    nm = NagataMesh(nodes, blocks, corner if creases else normals, edge_normals=en if creases else None,
                    edge_rule="published")
    if creases:
        assert len(nm.crease_edges) > len(nm.half_crease_edges) > 0
        plain = NagataMesh(nodes, blocks, corner, edge_rule="published")
        assert np.array_equal(plain.tri_coefficients, nm.tri_coefficients)  # EDGE_NORMALS change nothing
        assert np.array_equal(plain.quad_coefficients, nm.quad_coefficients)
    path = tmp_path / "grid.nagata"
    path.write_text(format_toolfile(_tooldata(nodes, blocks, normals, corner if creases else
                                              [normals[b] for b in blocks], en, nm)))
    tf = R.read(path)
    assert tf.edge_rule == "published"
    ref = nagata_2005_patches(tf)
    size = _size(nodes)
    assert np.max(np.abs(tf.coefficients - ref)) <= 1e-12 * size
    assert np.max(np.abs(tf.coefficients - R.rebuild(tf))) <= 1e-12 * size  # docs/toolfile.md's wording
    # the published rule is not the bounded one here: the test can tell them apart
    bounded = NagataMesh(nodes, blocks, corner if creases else normals, edge_normals=en if creases else None)
    assert np.max(np.abs(bounded.tri_coefficients - nm.tri_coefficients)) > 1e-3 * size


def test_published_singular_cases():
    """Eq. (15)'s singular cases: parallel normals give c = 0 exactly, opposite normals keep
    the Delta v term only (which is 0: d . v = 0 with v = 0), nearly parallel normals keep both."""
    x0, x1 = np.zeros(3), np.array([1.0, 0.2, -0.1])
    n = _unit([0.1, 0.2, 1.0])
    nm = lambda a, b: NagataMesh(np.array([x0, x1, [0.0, 1.0, 0.0]]), np.array([[0, 1, 2]]),  # noqa: E731
                                 np.array([a, b, n]), edge_rule="published").tri_edge_coefficients[0, 0]
    assert np.array_equal(nm(n, n), np.zeros(3))
    assert np.array_equal(nm(n, -n), nagata_2005_edge(x0, x1, [n], [-n]))
    m = _unit(n + [1e-4, 0.0, 0.0])
    np.testing.assert_allclose(nm(n, m), nagata_2005_edge(x0, x1, [n], [m]), rtol=1e-9)
    assert np.linalg.norm(nm(n, m)) > 10 * np.linalg.norm(x1 - x0)  # unbounded, as published


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    """`cadbridge convert --edge-rule published` and the default on multiple_knots.igs (creases,
    curved boundary edges with EDGE_NORMALS records)."""
    out = tmp_path_factory.mktemp("edge_rule")
    runs = {}
    for rule in ("published", "bounded"):
        r = subprocess.run([sys.executable, "-m", "cadbridge", "--quiet", "convert", str(SAMPLES / "multiple_knots.igs"),
                            "-o", str(out / rule), "--size", "10"] + (["--edge-rule", rule] if rule != "bounded" else []),
                           capture_output=True, text=True, cwd=ROOT, timeout=600)
        assert r.returncode == 0, r.stderr
        runs[rule] = (out / rule, r.stdout)
    return runs


def test_convert_published_equals_nagata_2005(converted):
    """The tool file `cadbridge convert --edge-rule published` writes: its COEFFICIENTS equal
    `nagata_2005_patches` of its own NODES / NORMALS / ELEMENTS / CORNER_NORMALS within
    1e-12 x size (crease edges and EDGE_NORMALS records included)."""
    folder, _ = converted["published"]
    (path,) = folder.glob("*.nagata")
    tf = R.read(path)
    assert tf.edge_rule == "published" and len(tf.corner_element) and len(tf.edge_nodes)
    ref = nagata_2005_patches(tf)
    assert np.max(np.abs(tf.coefficients - ref)) <= 1e-12 * R.model_size(tf)
    assert np.max(np.abs(tf.coefficients - R.rebuild(tf))) <= 1e-12 * R.model_size(tf)


def test_convert_summary_gives_both_rules(converted):
    """The summary gives the shape error of both rules, the same numbers whichever rule the
    tool file uses, and the tool file's rule is the measured one."""
    pub, bnd = converted["published"][1], converted["bounded"][1]
    line = lambda out: next(ln for ln in out.splitlines() if "shape err by edge rule" in ln)  # noqa: E731
    nums = lambda ln: dict((w.split()[0], float(w.split()[1])) for w in ln.split(": ", 2)[2].split(", "))  # noqa: E731
    assert "published" in line(pub) and "(tool file)" in line(pub).split("published")[1][:25]
    a, b = nums(line(pub)), nums(line(bnd))
    assert a.keys() == b.keys() == {"bounded", "published"}
    for rule in a:
        assert a[rule] == pytest.approx(b[rule], rel=1e-3)
    assert a["bounded"] != a["published"]


# ----------------------------------------------------------------------------- bounded
BOUNDED_DIGESTS = ['f219b4e135b93b16', '6d9f100120fa7326', '96dc18e4279a27d2', '52376fb56839e1b8',
                   '4f5b5c6e5f9eb3c4', '4bf76648179281a1']
# before --edge-rule (03d82a1), but for the crease edges whose generalized-inverse curve turned
# back (since 2026-12-07 they take the normals most orthogonal to them, `test_sharp.py`
# hairpin test): 1 edge of seed 1 and 2 of seed 2 with corner normals; before that rule the
# fourth and sixth digests were '4f8fe445d0ba1c31', '05e0876328dcdb1b' and the file's 'c72f3f3995a7ba19'.
# Then also those bent more than 100 degrees (`test_sharp.py` standing-element test): one more
# edge of seed 1 with corner normals (|c| = 1.5 |d|, end tangents 119 degrees apart), whose
# digest was 'fd7f89e971ea2b3d' and the file's (the same mesh) '4cb10491741b3c07'
BOUNDED_FILE_DIGEST = "3877700be006f012"  # format_toolfile text of seed 1, before the EDGE_RULE line


def test_bounded_is_unchanged():
    """The default rule gives the bit-identical coefficients of the code before the option
    (stored digests, per-node normals and corner normals with creases and conormals), and its
    tool file is the same text but for the EDGE_RULE line."""
    got = []
    for seed in (0, 1, 2):
        nodes, blocks, normals, corner, en = grid_case(seed)
        for nm in (NagataMesh(nodes, blocks, normals), NagataMesh(nodes, blocks, corner, edge_normals=en)):
            assert nm.edge_rule == "bounded"
            got.append(hashlib.sha256(nm.tri_coefficients.tobytes() + nm.quad_coefficients.tobytes()).hexdigest()[:16])
    assert got == BOUNDED_DIGESTS
    nodes, blocks, normals, corner, en = grid_case(1)
    nm = NagataMesh(nodes, blocks, corner, edge_normals=en)
    td = ToolData(name="grid", units="MM", nodes=nodes, normals=normals, triangles=blocks[0], quads=blocks[1],
                  edge_nodes=en[0], edge_normals=np.stack([en[1], en[2]], 1), tri_coefficients=nm.tri_coefficients,
                  quad_coefficients=nm.quad_coefficients)
    text = format_toolfile(td)
    assert "\nEDGE_RULE bounded\n" in text
    old = text.replace("EDGE_RULE bounded\n", "")
    assert hashlib.sha256(old.encode()).hexdigest()[:16] == BOUNDED_FILE_DIGEST


# ----------------------------------------------------------------------------- the tool file
def test_header_names_the_rule_and_reads_back(tmp_path):
    """EDGE_RULE follows NORMAL_SOURCE; reading gives the rule back, and the file's NagataMesh
    rebuilds the written coefficients with it; a file without the line reads as bounded; a
    bad value is an error naming the line."""
    nodes, blocks, normals, corner, en = grid_case(0)
    for rule in ("published", "bounded"):
        nm = NagataMesh(nodes, blocks, corner, edge_normals=en, edge_rule=rule)
        text = format_toolfile(_tooldata(nodes, blocks, normals, corner, en, nm))
        lines = text.splitlines()
        assert lines[lines.index(next(ln for ln in lines if ln.startswith("NORMAL_SOURCE"))) + 1] == f"EDGE_RULE {rule}"
        back = parse_toolfile(text)
        assert back.edge_rule == rule
        rebuilt = back.nagata_mesh()
        assert np.array_equal(rebuilt.tri_coefficients, back.tri_coefficients)
        assert np.array_equal(rebuilt.quad_coefficients, back.quad_coefficients)
    old = text.replace("EDGE_RULE bounded\n", "")
    assert parse_toolfile(old).edge_rule == "bounded"
    (tmp_path / "old.nagata").write_text(old)
    assert read_toolfile(tmp_path / "old.nagata").edge_rule == "bounded"
    with pytest.raises(ToolFileError, match=r"line 6, section header: EDGE_RULE must be one of bounded, published"):
        parse_toolfile(text.replace("EDGE_RULE bounded", "EDGE_RULE smooth"))
    with pytest.raises(ToolFileError, match="edge_rule"):
        format_toolfile(ToolData(name="x", units="MM", nodes=np.zeros((1, 3)), normals=[[0, 0, 1.0]],
                                 edge_rule="smooth"))


# ----------------------------------------------------------------------------- CLI
@pytest.mark.parametrize("command", [["nagata", "m.msh", "--method", "mwe"], ["convert", "x.igs"], ["ushape"]])
def test_cli_accepts_the_option(command):
    from cadbridge.cli import build_parser

    for rule in ("bounded", "published"):
        args = build_parser().parse_args(command + ["-o", "out", "--edge-rule", rule])
        assert args.edge_rule == rule
    assert build_parser().parse_args(command + ["-o", "out"]).edge_rule == "bounded"


@pytest.mark.parametrize("command", [["nagata", "m.msh", "--method", "mwe"], ["convert", "x.igs"], ["ushape"]])
def test_cli_bad_rule_is_one_line_usage_error(tmp_path, command):
    r = subprocess.run([sys.executable, "-m", "cadbridge", *command, "-o", str(tmp_path / "o"), "--edge-rule", "smooth"],
                       capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert r.returncode == 2
    assert r.stderr.splitlines() == [f"cadbridge {command[0]}: error: --edge-rule must be one of bounded, published, "
                                     f"got 'smooth'"]
    assert not (tmp_path / "o").exists()


def test_cli_nagata_published_without_cad(tmp_path):
    """`cadbridge nagata MESH --method mwe --edge-rule published`: estimated normals (one per
    node), eq. 15 as published on every edge."""
    from cadbridge.mesh import CellBlock, Mesh, write_mesh

    nodes, blocks, *_ = grid_case(2)
    write_mesh(Mesh(nodes=nodes, cells=[CellBlock("triangle", blocks[0]), CellBlock("quad", blocks[1])], name="g"),
               tmp_path / "g.msh")
    r = subprocess.run([sys.executable, "-m", "cadbridge", "--quiet", "nagata", str(tmp_path / "g.msh"), "--method",
                        "mwe", "-o", str(tmp_path / "out"), "--edge-rule", "published", "--no-report"],
                       capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stderr
    (path,) = (tmp_path / "out").glob("*.nagata")
    tf = R.read(path)
    assert tf.edge_rule == "published"
    assert np.max(np.abs(tf.coefficients - nagata_2005_patches(tf))) <= 1e-12 * R.model_size(tf)
