"""Class: a narrow face whose boundary curves bend within it (chords that cut the face).

trj10_b2 (Open CASCADE 4.0 STEP) has a ring 2 mm wide around a boss of radius 28, and a neck
0.6 mm wide between a straight edge and two arcs. gmsh's curvature rule gives the ring's
circles 12 segments a turn, 6 at the twice-the-size mesh before the all-quad subdivision:
chords 29 long whose sag (1.4) is most of the ring's width. The polygon no longer holds the
ring, the elements cross its circles, and the subdivision's new nodes (on the surface nearest
the elements' centres and edge midpoints) land off the face: up to 3 mm in trj10_b2, and the
guards refuse. Such a curve now gets the node count that keeps each chord's sag below a
quarter of the face's width (`cadbridge.mesh.gmsh.narrow_faces`).

Sample: a boss of radius 28 on a plate, bored to radius 26 (cadquery, OCC's STEP writer; its IGES writer splits the circles in three, and gmsh's
segments then happen to stay inside): its
top is the ring. Reference: the analytic circles and the ring's width.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

R_OUT, R_IN, TOP = 28.0, 26.0, 10.0


@pytest.fixture(scope="module")
def ring(tmp_path_factory):
    cq = pytest.importorskip("cadquery")

    path = tmp_path_factory.mktemp("ring") / "ring.step"
    solid = (cq.Workplane("XY").box(80, 80, 4).faces(">Z").workplane().circle(R_OUT).extrude(TOP - 2)
             .faces(">Z").workplane().hole(2 * R_IN, 6))
    cq.exporters.export(solid, str(path))
    return path


def test_the_ring_circles_get_chords_that_stay_inside_the_ring(ring):
    """At the quad pass' sizes (twice 14, 6 elements a turn) only the ring's two circles get a
    count, and their chords sag less than a quarter of its width (analytic: R (1 - cos(pi / N)))."""
    gmsh = pytest.importorskip("gmsh")
    from cadbridge.mesh.gmsh.narrow_faces import SAG_FRACTION, narrow_curve_counts

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Geometry.OCCSewFaces", 1)
        gmsh.model.occ.importShapes(str(ring))
        gmsh.model.occ.synchronize()
        surfaces = [t for _, t in gmsh.model.getEntities(2)]
        counts = narrow_curve_counts(gmsh, surfaces, size=28.0, curvature_elements=6, min_size=1.4)
        radius = {}
        for c in counts:
            lo, hi = gmsh.model.getParametrizationBounds(1, c)
            x = np.asarray(gmsh.model.getValue(1, c, np.linspace(lo[0], hi[0], 5).tolist())).reshape(-1, 3)
            radius[c] = (float(np.hypot(x[:, 0], x[:, 1]).mean()), float(np.ptp(x[:, 2])), float(x[0, 2]))
    finally:
        gmsh.finalize()
    assert sorted(round(r) for r, _, _ in radius.values()) == [R_IN, R_OUT]
    assert all(dz < 1e-9 and abs(z - TOP) < 1e-9 for _, dz, z in radius.values())  # the top's circles
    for c, (r, _, _) in radius.items():
        assert r * (1 - math.cos(math.pi / counts[c])) <= SAG_FRACTION * (R_OUT - R_IN) + 1e-9
    assert r * (1 - math.cos(math.pi / 6)) > R_OUT - R_IN - 1.0  # gmsh's own 6 a turn: sag 1.9 of 2


def test_quads_on_a_narrow_ring_convert(ring, tmp_path):
    """convert in quads at size 14 (before: exit 1, Nagata worse than flat on 16 elements, whose
    corner normals stood more than 60 degrees off): the tool's nodes lie on the analytic solid,
    and the ring's nodes between its circles."""
    from cadbridge import convert
    from cadbridge.io.toolfile import read_toolfile

    convert(str(ring), str(tmp_path), element="quad", size=14.0)
    (tf,) = tmp_path.glob("*.nagata")
    x = read_toolfile(tf).nodes
    r = np.hypot(x[:, 0], x[:, 1])
    top = np.abs(x[:, 2] - TOP) < 1e-9
    assert np.count_nonzero(top) > 30
    assert np.all((r[top] > R_IN - 1e-4) & (r[top] < R_OUT + 1e-4))  # (circle nodes within 2e-6)
