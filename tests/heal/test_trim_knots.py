"""Trim curves made C1 at C0 knots beside short pieces, for the mesher's copy
(`cadbridge.heal.trim_knots`). References: an analytic curve, the cubic graph y = x^3 - x (every
point of the rewritten curve on it), OpenCASCADE's IGES reader (the edges it makes of a trim
loop, the face's area) and the analytic area under that graph."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cadbridge.iges import read_iges, write_iges
from cadbridge.cad.model import Face, Trim, TrimLoop
from cadbridge.nurbs import edits
from cadbridge.nurbs.construct import composite_curve, line, plane_surface
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.heal.trim_knots import has_c0_knots, smooth_short_knots, smoothed_curve
from tests.helpers import occ as OCC

SAMPLES = Path(__file__).parents[2] / "iges_samples"
S = 10.0  # model scale: the graph over x in [0, S]
# C0 knots at x whose steps shrink tenfold towards x = S (pieces 0.22, 0.022, 0.0022 long
# there): the chain of C0 knots OCC's writer leaves in a trim curve
CUTS = [0.989, 0.9989, 0.9999]


def _graph_chain(speeds: bool = False) -> NurbsCurve:
    """S (t, t^3 - t), t in [0, 1], as one cubic with C0 knots at CUTS (knot insertion: the
    same curve, C-infinity at them); ``speeds``: each piece put on a parameter length of 1
    instead, so the speed jumps at the knots (the point set is still the graph)."""
    # power basis y = -t + t^3 -> Bezier ordinates 0, -1/3, -2/3, 0
    c = NurbsCurve(3, [0, 0, 0, 0, 1, 1, 1, 1], S * np.array([[0, 0], [1 / 3, -1 / 3], [2 / 3, -2 / 3], [1, 0]]))
    c = edits.refine_curve(c, np.repeat(CUTS, 3))
    if not speeds:
        return c
    ends = [0.0, *CUTS, 1.0]
    pieces = [edits.reparametrize_curve(edits.restrict_curve(c, a, b), (k, k + 1.0)) for k, (a, b) in enumerate(zip(ends[:-1], ends[1:]))]
    return composite_curve(pieces)


def _c0_knots(c) -> int:
    _, mult = np.unique(c.knots, return_counts=True)
    return int(np.count_nonzero(mult[1:-1] >= c.degree))


def _off_graph(x: np.ndarray) -> float:
    u = x[:, 0] / S
    return float(np.abs(x[:, 1] / S - (u ** 3 - u)).max())


def test_smoothed_curve_stays_on_the_graph_and_loses_the_short_c0_knots():
    """The two knots beside the 0.022 and 0.0022 pieces go; the one between the long piece
    and the 0.22 one (both longer than 0.05) stays; every point stays on y = x^3 - x (the
    curve is C1 at its knots: the fix moves nothing beyond rounding)."""
    c = _graph_chain()
    assert _c0_knots(c) == 3
    assert _off_graph(c.evaluate(np.linspace(c.domain[0], c.domain[1], 2001))) < 1e-13
    s = smoothed_curve(c, shorter=0.05, max_move=1e-9)
    assert s is not None
    assert _c0_knots(s) == 1
    x = s.evaluate(np.linspace(s.domain[0], s.domain[1], 20001))
    assert _off_graph(x) < 1e-13
    assert np.allclose(x[0], [0, 0], atol=1e-12) and np.allclose(x[-1], [S, 0], atol=1e-12)
    # the parameters stay (OCC pairs them with the model-space curve's): same points at same t
    t = np.linspace(0.0, 1.0, 2001)
    assert s.domain == c.domain and np.abs(s.evaluate(t) - c.evaluate(t)).max() < 1e-13


def test_a_speed_jump_stays():
    """The same graph with the speed jumping at the knots (each piece on a parameter length
    of 1): C1 on those parameters would move the short pieces by far more than 1e-6."""
    assert smoothed_curve(_graph_chain(speeds=True), shorter=0.05, max_move=1e-6) is None


def test_corner_rational_and_moving_knots_stay():
    """A 90-degree corner beside a short piece is a vertex (not smoothed); a knot whose
    tangents differ by 1 degree would move the curve by ~1e-6: above a 1e-9 allowance it
    stays, below 1e-3 it goes; a rational curve is left alone."""
    def cubic(a, b):
        return edits.elevate_curve(line(a, b), 2)

    corner = composite_curve([cubic((0, 0, 0), (1, 0, 0)), cubic((1, 0, 0), (1, 0.001, 0))])
    assert smoothed_curve(corner, shorter=0.05, max_move=1.0) is None
    a = math.radians(1.0)
    short = edits.reparametrize_curve(cubic((1, 0, 0), (1 + 0.001 * math.cos(a), 0.001 * math.sin(a), 0)), (0.0, 0.001))
    bent = composite_curve([cubic((0, 0, 0), (1, 0, 0)), short])  # unit speed on both sides
    assert smoothed_curve(bent, shorter=0.05, max_move=1e-9) is None
    assert smoothed_curve(bent, shorter=0.05, max_move=1e-3) is not None
    w = NurbsCurve(bent.degree, bent.knots, bent.control_points, np.linspace(1.0, 2.0, len(bent.control_points)))
    assert smoothed_curve(w, shorter=0.05, max_move=1.0) is None


def _region_file(tmp_path):
    """A planar face z = 0: the region between y = -S and the graph, x in [0, S]; its loop
    (bottom, right side, graph backwards, left side) written by cadbridge's writer with both
    2D and 3D trim curves."""
    surf = plane_surface((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (-1.0, 11.0), (-11.0, 1.0))
    g = edits.reverse_curve(_graph_chain())
    loop2 = [line((0, -S), (S, -S)), line((S, -S), (S, 0)), g, line((0, 0), (0, -S))]
    loop3 = [NurbsCurve(c.degree, c.knots, np.column_stack([c.control_points, np.zeros(len(c.control_points))]),
                        c.weights, c.domain) for c in loop2]
    face = Face(surface=surf, de=1, name="REGION", trims=Trim(TrimLoop(loop2, model_curves=loop3)))
    path = tmp_path / "region.igs"
    write_iges([face], path)
    return path


def _occ_faces(path) -> list[tuple[int, float]]:
    """(wires, area) of every face OpenCASCADE reads from ``path``, in its order."""
    from OCP.TopAbs import TopAbs_WIRE
    from OCP.TopExp import TopExp_Explorer

    out = []
    for face in OCC.read_faces(path):
        wires = TopExp_Explorer(face, TopAbs_WIRE)
        n = 0
        while wires.More():
            n += 1
            wires.Next()
        out.append((n, OCC.area(face)))
    return out


def _occ_face(path):
    """(edges, area) of the first face OpenCASCADE reads from ``path``."""
    face = OCC.read_faces(path)[0]
    return len(OCC.edges(face)), OCC.area(face)


def test_occ_reads_fewer_edges_and_the_same_face(tmp_path):
    """OpenCASCADE cuts the graph at each C0 knot (3 lines + 4 graph edges); after the
    rewrite it makes 3 + 2 edges, and the face's area is still S^2 (1 - 1/4) = 0.75 S^2."""
    pytest.importorskip("OCP")
    path = _region_file(tmp_path)
    assert has_c0_knots(read_iges(path))
    n0, area0 = _occ_face(path)
    text, n = smooth_short_knots(path.read_text(encoding="latin-1"), shorter=0.05)
    assert n == 1  # the graph's parameter-space curve (OCC builds the edges from it)
    out = tmp_path / "smoothed.igs"
    out.write_text(text, encoding="latin-1")
    n1, area1 = _occ_face(out)
    assert (n0, n1) == (7, 5)
    exact = 0.75 * S * S
    assert abs(area0 - exact) < 1e-9 * exact and abs(area1 - exact) < 1e-9 * exact
    # cadbridge reads the copy with the graph still on y = x^3 - x
    g = read_iges(out).faces[0].trims.outer.model_curves[2]
    assert _off_graph(g.evaluate(np.linspace(g.domain[0], g.domain[1], 2001))) < 1e-13


def test_nothing_to_smooth_leaves_the_text(tmp_path):
    """A file whose trim curves have no C0 knots comes back unchanged."""
    surf = plane_surface((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0), (0.0, 1.0))
    pts = [(0.1, 0.1), (0.9, 0.1), (0.9, 0.9), (0.1, 0.9)]
    loop = [edits.elevate_curve(line(a, b), 2) for a, b in zip(pts, pts[1:] + pts[:1])]
    path = tmp_path / "square.igs"
    write_iges([Face(surface=surf, de=1, trims=Trim(TrimLoop(loop)))], path)
    text = path.read_text(encoding="latin-1")
    assert not has_c0_knots(read_iges(path))
    assert smooth_short_knots(text, shorter=0.05) == (text, 0)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["production_die_analytic.igs", "production_die_nurbs.igs"])
def test_the_dies_copies_keep_every_face(tmp_path, name):
    """The mesher's copy of each production die, read by OpenCASCADE (the reference): the same
    faces, each with the same number of wires and its area within 1e-6 (a copy with the pieces
    reparametrized to equal speeds lost a 181.8 mm hole of the NURBS die's face 0: 1.4 %)."""
    from cadbridge.heal.mesh_source import write_mesh_source

    path = SAMPLES / name
    if not path.is_file():
        pytest.skip("the production die is generated by iges_samples/make_samples.py (git-ignored)")
    pytest.importorskip("OCP")
    copy = write_mesh_source(path, read_iges(path), tmp_path)
    assert copy != path  # both dies have short C0 trim pieces to smooth
    before, after = _occ_faces(path), _occ_faces(copy)
    assert len(before) == len(after) == 1102
    assert [w for w, _ in before] == [w for w, _ in after]
    rel = max(abs(a - b) / a for (_, a), (_, b) in zip(before, after))
    assert rel < 1e-6
