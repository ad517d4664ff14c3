"""A refinement round that keeps the first mesh where it asks for nothing finer
(`cadbridge.mesh.gmsh.kept` through `mesh_cad`'s ``keep``).

Reference: the first mesh itself (the kept surfaces must come back element for element, at
the same coordinates) and the mesh's own topology (conforming: no mesh edge on three
elements, the same free edges as the first mesh, i.e. the model's boundary)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cadbridge.mesh.generate import mesh_cad
from cadbridge.mesh.sizing import SizeField
from cadbridge.mesh.topology import edge_table

SAMPLE = Path(__file__).parents[3] / "iges_samples" / "ushape_die_nurbs.igs"


def _elements_by_surface(mesh) -> dict[int, list]:
    """{gmsh surface: sorted element corner coordinates}."""
    ent = np.asarray(mesh.cell_data["element_entity"])
    x = np.concatenate([mesh.nodes[np.asarray(b.data)].reshape(len(b.data), -1) for b in mesh.cells])
    return {int(s): sorted(map(tuple, np.sort(x[ent == s].reshape(-1, 3, 3), axis=1).reshape(-1, 9).tolist()))
            for s in np.unique(ent)}


@pytest.mark.parametrize("radius", [4.0, 12.0])
def test_a_round_keeps_the_first_mesh_away_from_its_marks(radius):
    keep: dict = {}
    first = mesh_cad(SAMPLE, element="tri", curvature_elements=12, keep=keep)
    assert "snapshot" in keep and not keep["snapshot"]["subdivided"]
    centre = first.nodes[np.argmax(first.nodes[:, 0])]  # a corner of the die's far end
    marks = SizeField(centre[None], [0.25], h_min=0.25, h_max=100.0, gradation=0.3)

    def finer(xyz):
        return np.linalg.norm(np.asarray(xyz) - centre, axis=1) < radius

    pts = np.vstack([first.nodes, centre[None]])
    again = mesh_cad(SAMPLE, element="tri", curvature_elements=12, background_sizes=(pts, marks(pts)),
                     min_size=0.25, keep={**keep, "finer": finer})
    note = [n for n in again.notes if "meshed again" in n]
    assert len(note) == 1, again.notes
    a, b = _elements_by_surface(first), _elements_by_surface(again)
    assert a.keys() == b.keys()
    kept = [s for s in a if a[s] == b[s]]
    redone = [s for s in a if a[s] != b[s]]
    assert f"meshed again {len(redone)} of {len(a)} surfaces" in note[0] and kept and redone
    assert all(len(b[s]) > len(a[s]) for s in redone)  # finer where the marks are
    # the re-meshed surfaces are those within reach of the marks (plus their neighbours across
    # a re-meshed curve): a kept surface has no node in the ball
    ent = np.asarray(first.cell_data["element_entity"])
    for s in kept:
        corners = np.concatenate([first.nodes[np.asarray(blk.data)] for blk in first.cells])[ent == s].reshape(-1, 3)
        assert np.all(np.linalg.norm(corners - centre, axis=1) >= radius)
    # conforming: no mesh edge on three elements, and every free edge of a kept surface's
    # elements in the round (the model's boundary there) is a free edge of the first mesh
    tb = edge_table(again)
    assert np.all(tb.counts <= 2)

    def free_edges(mesh, table, surfaces):
        ent = np.asarray(mesh.cell_data["element_entity"])
        on = np.isin(ent[table.elems[table.ptr[:-1]]], surfaces) & (table.counts == 1)
        return {tuple(sorted(map(tuple, np.round(mesh.nodes[e], 9).tolist()))) for e in table.edges[on]}

    ta = edge_table(first)
    assert free_edges(again, tb, kept) == free_edges(first, ta, kept)


def test_a_snapshot_of_other_geometry_is_not_used(tmp_path):
    """A round on another file (another signature) meshes everything: no note, nothing kept."""
    keep: dict = {}
    mesh_cad(SAMPLE, element="tri", curvature_elements=12, keep=keep)
    other = SAMPLE.with_name("ushape_punch_nurbs.igs")
    again = mesh_cad(other, element="tri", curvature_elements=12, keep={**keep, "finer": lambda x: np.zeros(len(x), bool)})
    assert not [n for n in again.notes if "meshed again" in n]
