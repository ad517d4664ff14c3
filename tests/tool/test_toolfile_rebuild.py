"""Issue #13 acceptance, "Coefficients": every tool file `cadbridge convert` writes describes
one surface, and its COEFFICIENTS are the ones rebuilt by the rule of docs/toolfile.md
("Rebuilding the coefficients") within 1e-9 x model size.

The reference is `tests/helpers/toolfile_reference.py`, a reader written from docs/toolfile.md alone
(numpy only; it imports neither cadbridge.io.toolfile nor cadbridge.nagata) that reads only
what the file says. Model size = diagonal of the node bounding box of the tool file.

The rule itself is checked on a hand-written tool file against analytic answers and an SVD
pseudo-inverse (numpy.linalg.pinv) of the orthogonality equations p.(d - c) = 0, q.(d + c) = 0.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from tests.helpers import toolfile_reference as R

ROOT = Path(__file__).parents[2]
SAMPLES = ROOT / "iges_samples"
DOC = ROOT / "docs" / "toolfile.md"
REL = 1e-9  # x model size


# ----------------------------------------------------------------------------- helpers
def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _fmt(v) -> str:
    return " ".join(repr(float(x)) for x in v)


def _write(path: Path, nodes, normals, elements, corner=(), coef=None, name="hand") -> Path:
    """A tool file laid out by hand after docs/toolfile.md (not by cadbridge's writer)."""
    et = sum(1 for e in elements if len(e) == 3)
    eq = len(elements) - et
    out = ["CADBRIDGE-NAGATA-TOOL 1", f"NAME {name}", "UNITS MM", "SOURCE", "NORMAL_SOURCE cad",
           f"COUNTS {len(nodes)} {et} {eq} {len(corner)} {0 if coef is None else 1}", f"NODES {len(nodes)}"]
    out += [f"{i + 1} {_fmt(x)}" for i, x in enumerate(nodes)]
    out += [f"NORMALS {len(normals)}"] + [f"{i + 1} {_fmt(n)}" for i, n in enumerate(normals)]
    out += [f"ELEMENTS {len(elements)}"] + [f"{i + 1} {len(e)} " + " ".join(map(str, e)) for i, e in enumerate(elements)]
    out += [f"CORNER_NORMALS {len(corner)}"] + [f"{e} {j} {_fmt(n)}" for e, j, n in corner]
    if coef is not None:
        rows = [f"{e + 1} {k + 1} {_fmt(coef[e, k])}" for e in range(len(elements)) for k in range(len(elements[e]) * 2)]
        out += [f"COEFFICIENTS {len(rows)}"] + rows
    out.append("END")
    path.write_text("\n".join(out) + "\n")
    return path


def _pinv_c(d, P, Q) -> np.ndarray:
    """Minimum-norm least-squares c of p.(d - c) = 0 (p in P), q.(d + c) = 0 (q in Q) by SVD."""
    A = np.vstack([P, Q])
    b = np.concatenate([P @ d, -(Q @ d)])
    return np.linalg.pinv(A) @ b


def _edge_points(coef, elem, kind_nn, t):
    """Points of the patch of `elem` along each of its local edges at parameters t, each
    edge oriented from its first to its second corner (docs: triangle (1,2) (2,3) (1,3),
    quad (1,2) (2,3) (4,3) (1,4)); returns {(a, b) local corners: (len(t), 3)}."""
    one, zero = np.ones_like(t), np.zeros_like(t)
    if kind_nn == 3:
        param = {(0, 1): (t, zero), (1, 2): (one, t), (0, 2): (t, t)}
    else:
        param = {(0, 1): (t, zero), (1, 2): (one, t), (3, 2): (t, one), (0, 3): (zero, t)}
    e = np.full(len(t), elem)
    return {k: R.evaluate(coef, e, *v) for k, v in param.items()}


def check_tool_file(path: Path) -> dict:
    """Everything a tool file must satisfy, from what the file says only.

    1. rebuilt COEFFICIENTS == written, within 1e-9 x model size;
    2. the rebuilt and the written surfaces agree on a 6-division grid of every patch;
    3. the written patches interpolate their corner nodes;
    4. one surface: along every mesh edge shared by two or more elements, the written
       patches give the same points (at t = 1/4, 1/2, 3/4, in the edge's node direction).
    Returns counts for the caller's assertions."""
    tf = R.read(path)
    assert tf.coefficients is not None, f"{path}: COUNTS K = 0, no COEFFICIENTS to compare"
    size = R.model_size(tf)
    tol = REL * size
    edges = R.edge_coefficients(tf)
    rebuilt = R.rebuild(tf, edges)
    dev = np.abs(rebuilt - tf.coefficients).max(axis=(1, 2))
    worst = int(np.argmax(dev)) if len(dev) else 0
    assert dev.max(initial=0) <= tol, (
        f"{path.name}: element {worst + 1} coefficients differ from the documented rule by {dev[worst]:.3g} "
        f"(> {tol:.3g} = 1e-9 x size {size:.6g}); written {tf.coefficients[worst].tolist()}, rebuilt {rebuilt[worst].tolist()}")
    elem, eta, zeta = R.sample_grid(tf, 6)
    xs_w = R.evaluate(tf.coefficients, elem, eta, zeta)
    xs_r = R.evaluate(rebuilt, elem, eta, zeta)
    assert np.abs(xs_w - xs_r).max(initial=0) <= tol
    # 3. corners
    for j, (e_, z_) in enumerate([(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]):
        sel = np.flatnonzero(tf.nn > j)
        x = R.evaluate(tf.coefficients, sel, np.full(len(sel), e_), np.full(len(sel), z_))
        assert np.abs(x - tf.nodes[tf.conn[sel, j]]).max(initial=0) <= tol, f"{path.name}: corner {j + 1} off its node"
    # 4. shared edges: evaluate every element along every local edge, oriented by node id
    t = np.array([0.25, 0.5, 0.75])
    pts: dict[tuple[int, int], list[np.ndarray]] = {}
    E = tf.n_elements
    for nn, pairs in ((3, R.TRI_EDGES), (4, R.QUAD_EDGES)):
        els = np.flatnonzero(tf.nn == nn)
        if not len(els):
            continue
        one, zero = np.ones(len(t)), np.zeros(len(t))
        param = ({(0, 1): (t, zero), (1, 2): (one, t), (0, 2): (t, t)} if nn == 3 else
                 {(0, 1): (t, zero), (1, 2): (one, t), (3, 2): (t, one), (0, 3): (zero, t)})
        for (a, b) in pairs:
            e = np.repeat(els, len(t))
            u, v = param[(a, b)]
            x = R.evaluate(tf.coefficients, e, np.tile(u, len(els)), np.tile(v, len(els))).reshape(len(els), len(t), 3)
            na, nb = tf.conn[els, a], tf.conn[els, b]
            flip = na > nb
            x[flip] = x[flip, ::-1]  # orient from the smaller node id
            key = np.minimum(na, nb) * (len(tf.nodes) + 1) + np.maximum(na, nb)
            for k, xx in zip(key.tolist(), x):
                pts.setdefault(k, []).append(xx)
    shared = 0
    gap = 0.0
    for k, lst in pts.items():
        if len(lst) > 1:
            shared += 1
            gap = max(gap, max(float(np.abs(x - lst[0]).max()) for x in lst[1:]))
    assert gap <= tol, f"{path.name}: neighbouring patches part by {gap:.3g} along a shared edge (> {tol:.3g})"
    return {"elements": E, "triangles": tf.n_tri, "edges": len(edges.coef), "shared": shared,
            "kinds": np.bincount(edges.kind, minlength=4), "size": size, "deviation": float(dev.max(initial=0))}


# ----------------------------------------------------------------------------- rule, by hand
R_ARC, PHI = 7.0, 0.35  # arc of radius 7 from angle -PHI to +PHI in the xz plane


def _arc():
    x0 = R_ARC * np.array([-np.sin(PHI), 0, np.cos(PHI)])
    x1 = R_ARC * np.array([np.sin(PHI), 0, np.cos(PHI)])
    # the quadratic through x0, x1 tangent to the circle there: c = (0, 0, -2 R sin(phi) tan(phi))
    c = np.array([0.0, 0.0, -2 * R_ARC * np.sin(PHI) * np.tan(PHI)])
    return x0, x1, c


@pytest.fixture
def hand_file(tmp_path):
    """Three parts in one file:
    A. crease edge (nodes 1-2) on a circular arc, shared by triangles 1 and 2 with 2 + 2
       different normals (each tilted by +-alpha about the arc's tangent);
    B. one-end-multiple edge (nodes 5-6): triangles 3 and 4 share it, their normals at
       node 5 differ (3 keeps the node normal, tilted towards d; 4 has the radial normal,
       smaller |n . d|), at node 6 both take the radial normal;
    C. quad 5 (nodes 9-12) whose edge 9-10 is inflected: both normals tilt against +x."""
    x0, x1, _ = _arc()
    al = 0.6
    rad0, rad1 = _unit(x0), _unit(x1)
    ey = np.array([0.0, 1.0, 0.0])
    pA, pB = np.cos(al) * rad0 + np.sin(al) * ey, np.cos(al) * rad0 - np.sin(al) * ey
    qA, qB = np.cos(al) * rad1 + np.sin(al) * ey, np.cos(al) * rad1 - np.sin(al) * ey
    d = x1 - x0
    tilted = _unit(rad0 - 0.5 * _unit(d))  # |n . d| larger than the radial normal's
    off = np.array([0.0, 0.0, 30.0])
    a, b = 0.3, 0.1
    nodes = [x0, x1, [0, -3, 7], [0, 3, 7],  # A
             x0 + off, x1 + off, [0, -3, 37], [0, 3, 37],  # B
             [20, 0, 0], [21, 0, 0], [21, 1, 0], [20, 1, 0]]  # C
    normals = [pA, qA, [0, 0, 1], [0, 0, 1],
               tilted, rad1, [0, 0, 1], [0, 0, 1],
               [-np.sin(a), 0, np.cos(a)], [-np.sin(b), 0, np.cos(b)], [0, 0, 1], [0, 0, 1]]
    elements = [(1, 2, 3), (1, 2, 4), (5, 6, 7), (5, 6, 8), (9, 10, 11, 12)]
    corner = [(2, 1, pB), (2, 2, qB), (4, 1, rad0)]
    path = _write(tmp_path / "hand.nagata", np.array(nodes, float), np.array([_unit(n) for n in normals]),
                  elements, corner)
    return path, dict(pA=pA, pB=pB, qA=qA, qB=qB, rad0=rad0, rad1=rad1, tilted=tilted, a=a, b=b)


def test_rule_on_hand_written_file(hand_file):
    path, n = hand_file
    tf = R.read(path)
    assert tf.coefficients is None and tf.n_tri == 4 and tf.n_elements == 5
    edges = R.edge_coefficients(tf)
    c_of = {tuple(p): (c, k) for p, c, k in zip(edges.nodes.tolist(), edges.coef, edges.kind)}
    x0, x1, c_arc = _arc()
    d = x1 - x0

    # A. crease: generalized inverse with m = 2 normals per end == analytic arc == SVD pinv
    c, kind = c_of[(0, 1)]
    assert kind == 2
    np.testing.assert_allclose(c, c_arc, atol=1e-12 * R_ARC)
    np.testing.assert_allclose(c, _pinv_c(d, np.array([n["pA"], n["pB"]]), np.array([n["qA"], n["qB"]])),
                               atol=1e-12 * R_ARC)

    # B. one end multiple: smallest |n . d| (the radial one, of the later element 4), then
    # the two-normal formula == the arc tangent to the radial normals (analytic)
    c, kind = c_of[(4, 5)]
    assert kind == 1
    assert abs(n["rad0"] @ d) < abs(n["tilted"] @ d)
    np.testing.assert_allclose(c, c_arc, atol=1e-12 * R_ARC)

    # C. inflected edge (d.n0)(d.n1) > 0: f2 = 0, so c is along v = (n0+n1)/2, with the
    # value that balances the two tangency residuals n0.(d - c) = n1.(d + c)
    n0, n1 = tf.normals[8], tf.normals[9]
    dq = tf.nodes[9] - tf.nodes[8]
    assert (dq @ n0) * (dq @ n1) > 0
    c, kind = c_of[(8, 9)]
    assert kind == 0
    v = (n0 + n1) / 2
    assert np.linalg.norm(np.cross(c, v)) <= 1e-14
    assert abs(n0 @ (dq - c) - n1 @ (dq + c)) <= 1e-14
    # analytic: c = (sin b - sin a) / (1 + cos(a - b)) v
    np.testing.assert_allclose(c, (np.sin(n["b"]) - np.sin(n["a"])) / (1 + np.cos(n["a"] - n["b"])) * v, atol=1e-14)
    # ... whereas the same chord with the second normal mirrored (not inflected) gets the
    # exact solution of both orthogonality equations (SVD pinv, c in the plane of d and v)
    m1 = np.array([np.sin(n["b"]), 0, np.cos(n["b"])])
    c2 = R.two_normal(dq[None], n0[None], m1[None])[0]
    np.testing.assert_allclose(c2, _pinv_c(dq, n0[None], m1[None]), atol=1e-14)
    assert abs(n0 @ (dq - c2)) < 1e-14 and abs(m1 @ (dq + c2)) < 1e-14

    # rule 6: rebuilt patches carry these edge curves (x(t) = x0 + (d - c) t + c t^2)
    coef = R.rebuild(tf, edges)
    t = np.linspace(0, 1, 5)
    for elem, (a_, b_), (ia, ib) in [(0, (0, 1), (0, 1)), (3, (0, 1), (4, 5)), (4, (0, 1), (8, 9))]:
        c, _ = c_of[(ia, ib)]
        xa, xb = tf.nodes[ia], tf.nodes[ib]
        want = xa + np.outer(t, xb - xa - c) + np.outer(t * t, c)
        got = _edge_points(coef, elem, tf.nn[elem], t)[(a_, b_)]
        np.testing.assert_allclose(got, want, atol=1e-12 * R_ARC)
    # the crease edge: both triangles give the same arc-tangent quadratic
    np.testing.assert_allclose(_edge_points(coef, 0, 3, t)[(0, 1)], _edge_points(coef, 1, 3, t)[(0, 1)], atol=1e-13)


def test_two_normal_bounded_cases():
    """Rule 4's bounded cases: opposite normals (1 - dc < eps) give f1 = 0; equal normals
    (dc < eps) give f2 = 0: a flat chord between two equal normals orthogonal to it is
    straight (c = 0, the exact planar answer)."""
    d = np.array([[2.0, 0, 0]])
    z = np.array([[0, 0, 1.0]])
    assert np.all(R.two_normal(d, z, z) == 0)
    # opposite normals, both orthogonal to d: f1 = 0, f2 = dd/dc = 0 (d . v = 0): c = 0
    assert np.all(np.abs(R.two_normal(d, z, -z)) < 1e-15)


def test_reader_validates(tmp_path, hand_file):
    path, _ = hand_file
    good = path.read_text()
    R.read(path)
    cases = {
        "version": good.replace("CADBRIDGE-NAGATA-TOOL 1", "CADBRIDGE-NAGATA-TOOL 3"),
        "v2 counts": good.replace("CADBRIDGE-NAGATA-TOOL 1", "CADBRIDGE-NAGATA-TOOL 2"),  # 5 COUNTS, no section
        "quad first": good.replace("1 3 1 2 3\n", "1 4 1 2 3 4\n", 1),
        "twice": good.replace("CORNER_NORMALS 3\n2 1", "CORNER_NORMALS 3\n2 2", 1),
        "no END": good.replace("END\n", ""),
        "id": good.replace("\n3 0.0 -3.0 7.0", "\n4 0.0 -3.0 7.0", 1),
        "count": good.replace("NODES 12", "NODES 11"),
    }
    for what, text in cases.items():
        p = tmp_path / f"bad_{what.replace(' ', '_')}.nagata"
        p.write_text(text)
        with pytest.raises(R.ToolFileError):
            R.read(p)
    # trailing "\r" is tolerated
    p = tmp_path / "crlf.nagata"
    p.write_bytes(good.replace("\n", "\r\n").encode())
    assert R.read(p).n_elements == 5


def test_document_example_reads_and_is_flat(tmp_path):
    """The "Complete example" of docs/toolfile.md, cut from the page: it reads, corner 4 of
    quad 2 (node 3) takes its CORNER_NORMALS record, and its COEFFICIENTS (said to be those
    of the flat interpolation) evaluate to the flat elements (independent formulas)."""
    text = DOC.read_text()
    m = re.search(r"```\n(CADBRIDGE-NAGATA-TOOL 2\n.*?\nEND\n)```", text, re.S)
    assert m, "no complete example in docs/toolfile.md"
    p = tmp_path / "example.nagata"
    p.write_text(m.group(1))
    tf = R.read(p)
    assert (tf.name, tf.units, tf.n_tri, tf.n_elements) == ("punch upper", "MM", 1, 2)
    cn = R.corner_normals(tf)
    np.testing.assert_array_equal(cn[1, 3], [0.07452, 0.0, 0.99721953])
    np.testing.assert_array_equal(cn[1, 0], tf.normals[1])
    elem, eta, zeta = R.sample_grid(tf, 4)
    np.testing.assert_allclose(R.evaluate(tf.coefficients, elem, eta, zeta), R.flat(tf, elem, eta, zeta), atol=1e-12)


# ----------------------------------------------------------------------------- convert outputs
FAST = [
    ("multiple_knots.igs", "tri", False),
    ("multiple_knots.igs", "quad", False),
    ("trimmed_hole.igs", "tri", False),
    ("sphere_patch.igs", "tri", False),
    ("ushape_tools_nurbs.igs", "quad", True),
]


def _convert(tmp_path: Path, name: str, element: str, structured: bool) -> list[Path]:
    from cadbridge.tool.pipeline import convert

    out = tmp_path / "out"
    convert(str(SAMPLES / name), str(out), element=element, structured=structured)
    files = sorted(out.glob("*.nagata"))
    assert files, f"convert wrote no tool file for {name}"
    return files


@pytest.mark.parametrize("name,element,structured", FAST, ids=[f"{n[:-4]}-{e}" for n, e, _ in FAST])
def test_convert_coefficients_follow_the_rule(tmp_path, name, element, structured):
    files = _convert(tmp_path, name, element, structured)
    kinds = np.zeros(4, dtype=int)
    for f in files:
        r = check_tool_file(f)
        tf = R.read(f)
        assert (tf.n_tri == tf.n_elements) if element == "tri" else (tf.n_tri == 0), f"{f.name}: element kinds"
        kinds += r["kinds"]
    if name == "multiple_knots.igs":
        # its C0 knot line is a crease inside the face: crease edges use the generalized inverse
        assert kinds[2] > 0, f"no crease edge in {name} ({element}): {kinds}"
    if name == "ushape_tools_nurbs.igs":
        assert sorted(f.stem for f in files) == ["bholder", "die", "pch"]
    if name == "trimmed_hole.igs":
        # the hole's free edges carry EDGE_NORMALS (the trim circle's conormals): rule 4b
        assert len(R.read(files[0]).edge_nodes) > 0 and kinds[3] > 0, kinds


ALL = sorted(p for p in SAMPLES.glob("*.igs") if not p.name.startswith("production_die"))


@pytest.mark.slow
@pytest.mark.parametrize("element", ["tri", "quad"])
@pytest.mark.parametrize("path", ALL, ids=[p.stem for p in ALL])
def test_convert_all_samples_follow_the_rule(tmp_path, path, element):
    for f in _convert(tmp_path, path.name, element, False):
        check_tool_file(f)
