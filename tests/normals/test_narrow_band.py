"""Class: a face narrower than the chord sag of its elements (an element standing on its face).

bug32596's counterbore has a cylinder band 0.40 mm wide (radius 7.14) between the plate's
top and the counterbore's floor. gmsh's triangles span the band rim to rim. Such an
element's centroid lies 0.18 inside the cylinder (its chord sag) and 0.13 above the floor's
plane, so the nearest-face rule gave it the floor: its corners took the plane's normal
(along the axis), and the patch stood on its face (normal error 90 degrees, surface error
0.40 = the flat error). The mesher says which face it meshed each element on
(``cell_data["element_face"]``); the element keeps that face.

Sample: the same step in a 40 x 40 x 5 plate (cadquery, OCC's IGES writer), hole radius
6.35, counterbore radius 7.145, 0.4 deep. Reference: the analytic cylinder: the corner
normals of the band's elements are radial, and their patches stay on radius 7.145.
"""

from __future__ import annotations

import numpy as np
import pytest

R_HOLE, R_BORE, DEPTH, TOP = 6.35, 7.145, 0.4, 2.5
SIZE = 4.0  # chords of ~4 on the band: centroids up to 0.19 inside the cylinder, 0.13 above the floor


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    cq = pytest.importorskip("cadquery")
    from cadbridge.ushape.geometry import export_iges

    path = tmp_path_factory.mktemp("band") / "counterbore.igs"
    solid = (cq.Workplane("XY").box(40, 40, 2 * TOP).faces(">Z").workplane()
             .cboreHole(2 * R_HOLE, 2 * R_BORE, DEPTH).val().wrapped)
    export_iges(solid, path)
    return path


def test_elements_across_a_narrow_band_keep_the_band(plate, tmp_path):
    from cadbridge import convert
    from cadbridge.io.toolfile import read_toolfile

    convert(str(plate), str(tmp_path), element="tri", size=SIZE)
    (tf,) = tmp_path.glob("*.nagata")
    t = read_toolfile(tf)
    x = t.nodes
    r = np.hypot(x[:, 0], x[:, 1])
    on_band = (np.abs(r - R_BORE) < 1e-6) & (x[:, 2] > TOP - DEPTH - 1e-6) & (x[:, 2] < TOP + 1e-6)
    tri = t.triangles
    z = x[tri, 2]
    across = np.flatnonzero(on_band[tri].all(axis=1) & (z.max(axis=1) - z.min(axis=1) > 0.9 * DEPTH))
    assert len(across) >= 6  # the sample has what it is for: elements spanning the band rim to rim

    # corner normals radial (the analytic cylinder's), not along the axis (the floor's)
    cn = t.corner_normal_blocks()[0][across]  # (A, 3, 3)
    radial = x[tri[across]] * np.array([1.0, 1.0, 0.0])
    radial /= np.linalg.norm(radial, axis=2, keepdims=True)
    assert np.all(np.abs(np.einsum("ijk,ijk->ij", cn, radial)) > 1 - 1e-9)

    # the patches follow the cylinder; the flat elements cut it by their chord sag
    nm = t.nagata_mesh()
    g = np.linspace(0, 1, 9)
    eta, zeta = [a.ravel() for a in np.meshgrid(g, g)]
    keep = zeta <= eta
    eta, zeta = eta[keep], zeta[keep]
    elem = np.repeat(across, len(eta))
    p, _ = nm.evaluate(elem, np.tile(eta, len(across)), np.tile(zeta, len(across)))
    err = np.abs(np.hypot(p[:, 0], p[:, 1]) - R_BORE)
    c = x[tri[across]]
    flat = c[:, 0][:, None] + (c[:, 1] - c[:, 0])[:, None] * eta[None, :, None] + \
        (c[:, 2] - c[:, 1])[:, None] * zeta[None, :, None]
    sag = np.abs(np.hypot(flat[..., 0], flat[..., 1]) - R_BORE).max()
    assert sag > 0.05  # the chords do cut the cylinder
    assert err.max() < 0.05 * sag
