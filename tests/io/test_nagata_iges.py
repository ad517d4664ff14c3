"""Nagata patches -> biquadratic Bézier NURBS -> IGES 128.

References: direct evaluation of the Nagata polynomials (thesis eqs. 4 and 9, written out
here, independent of cadbridge.nagata); OpenCASCADE's IGES reader and Geom_BSplineSurface
for the written files; the IGES 5.3 fixed-format rules for the record layout.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cadbridge.io.nagata_iges import nagata_control_points, nagata_to_surfaces, write_nagata_iges
from cadbridge.nurbs.surface import NurbsSurface
from tests.helpers import occ as OCC


def nagata_eval(c: np.ndarray, eta: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """Reference: x(eta, zeta) for one patch, c (6|8, 3), eta/zeta (N,) -> (N, 3)."""
    mono = [np.ones_like(eta), eta, zeta, eta * zeta, eta**2, zeta**2, eta**2 * zeta, eta * zeta**2]
    return sum(m[:, None] * c[k] for k, m in enumerate(mono[: len(c)]))


def nagata_derivs(c: np.ndarray, eta: np.ndarray, zeta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference: x_eta, x_zeta for one patch."""
    z = np.zeros_like(eta)
    d_eta = [z, z + 1, z, zeta, 2 * eta, z, 2 * eta * zeta, zeta**2]
    d_zeta = [z, z, z + 1, eta, z, 2 * zeta, eta**2, 2 * eta * zeta]
    k = len(c)
    return (sum(m[:, None] * c[i] for i, m in enumerate(d_eta[:k])),
            sum(m[:, None] * c[i] for i, m in enumerate(d_zeta[:k])))


def random_patches(seed: int, et: int = 5, eq: int = 5, scale: float = 100.0):
    rng = np.random.default_rng(seed)
    offset = rng.normal(size=3) * 10 * scale
    tri = rng.normal(size=(et, 6, 3)) * scale
    quad = rng.normal(size=(eq, 8, 3)) * scale
    tri[:, 0] += offset
    quad[:, 0] += offset
    return tri, quad


def map_params(kind: str, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The documented (u, v) -> (eta, zeta) maps."""
    return (u, u * v) if kind == "tri" else (u, v)


# ------------------------------------------------------------------------- exact conversion
@pytest.mark.parametrize("seed", range(4))
def test_surfaces_equal_polynomials(seed):
    tri, quad = random_patches(seed)
    surfs = nagata_to_surfaces(tri, quad)
    assert len(surfs) == len(tri) + len(quad)
    rng = np.random.default_rng(100 + seed)
    u, v = rng.random(200), rng.random(200)
    u[:4], v[:4] = [0, 1, 1, 0], [0, 0, 1, 1]  # corners of the square too
    for kind, coefs, offset in (("tri", tri, 0), ("quad", quad, len(tri))):
        for e, c in enumerate(coefs):
            s = surfs[offset + e]
            assert (s.degree_u, s.degree_v, s.shape, s.rational) == (2, 2, (3, 3), False)
            assert s.domain == (0.0, 1.0, 0.0, 1.0)
            eta, zeta = map_params(kind, u, v)
            ref = nagata_eval(c, eta, zeta)
            size = np.abs(c).sum(axis=0).max()  # bound on |x| over the patch
            assert np.abs(s.evaluate(u, v) - ref).max() <= 1e-14 * size
            # tangents: S_u, S_v by the chain rule of the map
            der = s.derivatives(u, v, order=1)
            xe, xz = nagata_derivs(c, eta, zeta)
            su_ref, sv_ref = (xe + v[:, None] * xz, u[:, None] * xz) if kind == "tri" else (xe, xz)
            assert np.abs(der[:, 1, 0] - su_ref).max() <= 1e-13 * size
            assert np.abs(der[:, 0, 1] - sv_ref).max() <= 1e-13 * size


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    log_scale=st.integers(-6, 6),
    uv=st.lists(st.tuples(st.floats(0, 1), st.floats(0, 1)), min_size=1, max_size=20),
)
def test_conversion_property(seed, log_scale, uv):
    """Any coefficients at any scale, any parameters in the square."""
    tri, quad = random_patches(seed, 1, 1, scale=10.0**log_scale)
    u, v = np.array(uv).T
    t_s, q_s = nagata_to_surfaces(tri, quad)
    for s, kind, c in ((t_s, "tri", tri[0]), (q_s, "quad", quad[0])):
        size = np.abs(c).sum(axis=0).max()
        ref = nagata_eval(c, *map_params(kind, u, v))
        assert np.abs(s.evaluate(u, v) - ref).max() <= 1e-14 * size


def test_corners_and_collapsed_edge_are_exact():
    tri, quad = random_patches(7)
    nets = nagata_control_points(tri, quad)
    et = len(tri)
    # the triangle's u = 0 edge: all three control points are exactly c00
    assert np.array_equal(nets[:et, 0, :, :], np.broadcast_to(tri[:, None, 0], (et, 3, 3)))
    # corner control points are exactly the patch corners x00, x10, x11 (x01 for quads)
    assert np.array_equal(nets[:, 0, 0], np.concatenate([tri[:, 0], quad[:, 0]]))
    x10 = lambda c: c[:, 0] + c[:, 1] + c[:, 4]  # noqa: E731
    assert np.allclose(nets[:et, 2, 0], x10(tri), rtol=0, atol=1e-12 * 1000)
    assert np.allclose(nets[:et, 2, 2], tri.sum(1), rtol=0, atol=1e-12 * 1000)
    assert np.allclose(nets[et:, 2, 2], quad.sum(1), rtol=0, atol=1e-12 * 1000)
    assert np.allclose(nets[et:, 0, 2], quad[:, 0] + quad[:, 2] + quad[:, 5], rtol=0, atol=1e-12 * 1000)
    # evaluation on the collapsed edge: one point up to the rounding of sum_j N_j(v) = 1
    s = nagata_to_surfaces(tri[:1], None)[0]
    pts = s.evaluate(np.zeros(7), np.linspace(0, 1, 7))
    assert np.abs(pts - tri[0, 0]).max() <= 4 * np.finfo(float).eps * np.abs(tri[0, 0]).max()


def test_orientation_matches_patch_normal():
    """S_u x S_v points along x_eta x x_zeta (maps keep orientation)."""
    tri, quad = random_patches(11, 3, 3)
    surfs = nagata_to_surfaces(tri, quad)
    u, v = np.full(5, 0.6), np.linspace(0.1, 0.9, 5)
    for s, kind, c in zip(surfs, ["tri"] * 3 + ["quad"] * 3, list(tri) + list(quad)):
        xe, xz = nagata_derivs(c, *map_params(kind, u, v))
        n_ref = np.cross(xe, xz)
        n_ref /= np.linalg.norm(n_ref, axis=1, keepdims=True)
        assert np.allclose(s.normal(u, v), n_ref, atol=1e-9)


def test_empty_and_bad_input():
    assert nagata_to_surfaces(None, None) == []
    assert len(nagata_to_surfaces(np.zeros((0, 6, 3)), np.zeros((2, 8, 3)) + 1.0)) == 2
    with pytest.raises(ValueError, match=r"\(n, 6, 3\)"):
        nagata_to_surfaces(np.zeros((2, 8, 3)), None)


# ------------------------------------------------------------------------- IGES file layout
def parse_iges(path) -> tuple[dict, list[NurbsSurface], list[tuple[str, int]]]:
    """A strict little reader of our own output: checks the fixed format, rebuilds surfaces."""
    lines = open(path, encoding="ascii").read().split("\n")
    assert lines[-1] == ""
    lines = lines[:-1]
    assert all(len(ln) == 80 for ln in lines)
    sections: dict[str, list[str]] = {}
    for ln in lines:
        sections.setdefault(ln[72], []).append(ln)
    assert list(sections) == ["S", "G", "D", "P", "T"]
    for letter, recs in sections.items():
        assert [int(r[73:]) for r in recs] == list(range(1, len(recs) + 1)), letter
    t = sections["T"][0]
    assert t[:32] == "S{:7d}G{:7d}D{:7d}P{:7d}".format(*(len(sections[k]) for k in "SGDP"))
    d = sections["D"]
    p = sections["P"]
    surfaces, labels = [], []
    for i in range(0, len(d), 2):
        f1 = [d[i][k : k + 8] for k in range(0, 72, 8)]
        f2 = [d[i + 1][k : k + 8] for k in range(0, 72, 8)]
        assert int(f1[0]) == 128 and int(f2[0]) == 128 and int(f2[4]) == 0
        start, count = int(f1[1]), int(f2[3])
        body = p[start - 1 : start - 1 + count]
        assert all(int(r[64:72]) == i + 1 for r in body)  # DE back pointer
        assert all(r[64] == " " for r in body)
        text = "".join(r[:64].rstrip() for r in body)
        assert text.endswith(";")
        tok = text[:-1].split(",")
        assert all("." in x or "E" in x for x in tok[10:])  # every real is explicit
        k1, k2, m1, m2 = map(int, tok[1:5])
        assert tok[5:10] == ["0", "0", "1", "0", "0"]  # open, open, polynomial, nonperiodic x2
        vals = [float(x) for x in tok[10:]]
        nu, nv = k1 + 1, k2 + 1
        a = 0
        ku = vals[a : a + nu + m1 + 1]; a += nu + m1 + 1  # noqa: E702
        kv = vals[a : a + nv + m2 + 1]; a += nv + m2 + 1  # noqa: E702
        w = np.array(vals[a : a + nu * nv]).reshape(nv, nu).T; a += nu * nv  # noqa: E702
        cp = np.array(vals[a : a + 3 * nu * nv]).reshape(nv, nu, 3).transpose(1, 0, 2); a += 3 * nu * nv  # noqa: E702
        dom = vals[a : a + 4]
        assert a + 4 == len(vals)
        surfaces.append(NurbsSurface(m1, m2, ku, kv, cp, w, dom))
        labels.append((f2[7].strip(), int(f2[8])))
    g = "".join(r[:72].rstrip() for r in sections["G"])
    return {"global": g}, surfaces, labels


def test_iges_records_and_exact_values(tmp_path):
    tri, quad = random_patches(3, 4, 3)
    path = tmp_path / "nagata.igs"
    write_nagata_iges(tri, quad, path)
    info, back, labels = parse_iges(path)
    ours = nagata_to_surfaces(tri, quad)
    assert len(back) == len(ours)
    assert all(a.same_as(b) for a, b in zip(ours, back))  # floats round-trip bit-for-bit
    assert labels == [("NTRI", i) for i in range(1, 5)] + [("NQUAD", i) for i in range(5, 8)]
    g = info["global"]
    assert g.startswith("1H,,1H;,") and ",2,2HMM," in g and ",11,0," in g  # units flag 2 = MM, IGES 5.3


def test_iges_names_units_and_atomicity(tmp_path):
    tri, quad = random_patches(4, 1, 1)
    path = tmp_path / "n.igs"
    write_nagata_iges(tri, quad, path, units="m", names=["PUNCH_T1", "PUNCH_Q1"])
    info, _, labels = parse_iges(path)
    assert labels == [("PUNCH_T1", 1), ("PUNCH_Q1", 2)] and ",6,1HM," in info["global"]
    before = path.read_bytes()
    with pytest.raises(ValueError, match="8 printable"):
        write_nagata_iges(tri, quad, path, names=["TOO_LONG_NAME", "X"])
    bad = tri.copy()
    bad[0, 0, 0] = np.inf
    with pytest.raises(ValueError, match="finite"):
        write_nagata_iges(bad, quad, path)
    with pytest.raises(ValueError, match="unknown IGES unit"):
        write_nagata_iges(tri, quad, path, units="parsec")
    assert path.read_bytes() == before and os.listdir(tmp_path) == ["n.igs"]


# ------------------------------------------------------------------------- OpenCASCADE


def test_opencascade_reads_and_agrees(tmp_path):
    pytest.importorskip("OCP")
    tri, quad = random_patches(9, 6, 5)
    path = tmp_path / "occ.igs"
    write_nagata_iges(tri, quad, path)
    occ = OCC.read_surfaces(path)
    assert len(occ) == len(tri) + len(quad)
    rng = np.random.default_rng(1)
    u, v = rng.random(30), rng.random(30)
    u[:2], v[:2] = [0.0, 1.0], [0.7, 1.0]
    kinds = ["tri"] * len(tri) + ["quad"] * len(quad)
    for s, kind, c in zip(occ, kinds, list(tri) + list(quad)):
        assert s.DynamicType().Name() == "Geom_BSplineSurface"
        assert (s.UDegree(), s.VDegree(), s.NbUPoles(), s.NbVPoles()) == (2, 2, 3, 3)
        assert not s.IsURational() and not s.IsVRational()
        ref = nagata_eval(c, *map_params(kind, u, v))
        got = np.array([[s.Value(a, b).X(), s.Value(a, b).Y(), s.Value(a, b).Z()] for a, b in zip(u, v)])
        size = np.abs(c).sum(axis=0).max()
        assert np.abs(got - ref).max() <= 1e-12 * size


def test_opencascade_collapsed_edge(tmp_path):
    """OCC sees the triangle's u = 0 edge as one point (its poles coincide exactly)."""
    pytest.importorskip("OCP")
    tri, _ = random_patches(12, 2, 0)
    path = tmp_path / "tri.igs"
    write_nagata_iges(tri, None, path)
    occ = OCC.read_surfaces(path)
    assert len(occ) == 2
    for s, c in zip(occ, tri):
        poles = [s.Pole(1, j) for j in (1, 2, 3)]  # OCC poles are 1-based
        assert all([p.X(), p.Y(), p.Z()] == c[0].tolist() for p in poles)


def test_batch_text_is_the_generic_writers(monkeypatch):
    """Reference: `cadbridge.iges.writer.iges_text` of the `NurbsSurface` s of
    `nagata_to_surfaces` (the generic per-face writer): the batch text of
    `bezier_iges_text` that `write_nagata_iges` writes is the same, character for
    character, over magnitudes from 1e-3 to 1e4 and both element kinds."""
    import cadbridge.iges.writer as w
    from cadbridge.cad.model import Face, Units

    monkeypatch.setattr(w.time, "strftime", lambda fmt: "20261202.120000")
    rng = np.random.default_rng(7)
    for et, eq in ((0, 1), (1, 0), (13, 29)):
        tri = rng.normal(size=(et, 6, 3)) * 10.0 ** rng.uniform(-3, 4, size=(et, 1, 1))
        quad = rng.normal(size=(eq, 8, 3)) * 10.0 ** rng.uniform(-3, 4, size=(eq, 1, 1))
        labels = [("NTRI", k + 1) for k in range(et)] + [("NQUAD", et + k + 1) for k in range(eq)]
        faces = [Face(surface=s, de=0) for s in nagata_to_surfaces(tri, quad)]
        generic = w.iges_text(faces, units=Units(), labels=labels, filename="t.igs", description="d")
        batch = w.bezier_iges_text(nagata_control_points(tri, quad), units=Units(), labels=labels,
                                   filename="t.igs", description="d")
        assert batch == generic
