"""Quality index Q (Herrero Adan & Cardoso 2020, eq. 21) and the BIT reference (appendix C)."""

import numpy as np
import pytest

from cadbridge.mesh.quality import bit_reference, mesh_quality, q_index


@pytest.mark.parametrize(
    "freqs, printed",
    [
        # Ex. 7.1 R=12: Q = 25*41/100 + 25*55/100 + 25*24/33 + 25*51/65 = 62 %
        ((41, 55, 24, 33, 51, 65), 62.0),
        # Ex. 7.1 R=5 (printed "80 %" in the text, 79.3 from its own frequencies)
        ((78, 80, 12, 18, 75, 81), 79.3),
        # Ex. 7.2: 25*54/100 + 25*77/100 + 25*9/13 + 25*80/86 = 73 %
        ((54, 77, 9, 13, 80, 86), 73.0),
    ],
)
def test_q_from_printed_frequencies(freqs, printed):
    # reference: the paper's printed Q values (section 7.1 and 7.2)
    assert q_index(*freqs) == pytest.approx(printed, abs=0.5)


def _lattice(rows, cols, r=1.0):
    """The BIT itself: a rhomboid of rows x cols rhombi of equilateral triangles of side r."""
    e1 = np.array([r, 0.0, 0.0])
    e2 = np.array([r / 2, r * np.sqrt(3) / 2, 0.0])
    idx = lambda i, j: i * (cols + 1) + j
    pts = np.array([i * e2 + j * e1 for i in range(rows + 1) for j in range(cols + 1)])
    tris = []
    for i in range(rows):
        for j in range(cols):
            tris.append([idx(i, j), idx(i, j + 1), idx(i + 1, j)])
            tris.append([idx(i, j + 1), idx(i + 1, j + 1), idx(i + 1, j)])
    return pts, np.array(tris)


def test_bit_of_a_bit_scores_100():
    # reference: appendix C -- a BIT is its own BIT (C.1-C.3 invert each other, Table C.1
    # counts its valences), so Q = 100 and rb, cb are recovered
    pts, tris = _lattice(6, 5, r=2.0)
    q = mesh_quality(pts, tris, size=2.0)
    assert sorted([q.bit.rb, q.bit.cb]) == pytest.approx([5.0, 6.0])
    assert q.f_angle == 100.0 and q.f_size == 100.0
    counts = np.bincount(q.valence)
    assert counts[1] == 2 and counts[2] == 2 and counts[3] == 2 * (4 + 5) and counts[6] == 4 * 5
    assert q.q == pytest.approx(100.0)


def test_bit_clamped_when_boundary_too_short():
    # eq. C.3 is complex when ta > sa^2/8: clamped to rb = cb = sa/4
    b = bit_reference(100, 12)
    assert b.clamped and b.rb == b.cb == 3.0


def test_distorted_lattice_scores_less():
    pts, tris = _lattice(8, 8)
    rng = np.random.default_rng(1)
    q0 = mesh_quality(pts, tris, 1.0).q
    q1 = mesh_quality(pts + rng.normal(0, 0.08, pts.shape) * [1, 1, 0], tris, 1.0).q
    assert q1 < q0 - 10


def test_quality_command_on_a_written_mesh(tmp_path, capsys):
    # reference: the BIT itself scores Q = 100 (appendix C), through a mesh file
    import json

    from cadbridge.cli import main
    from cadbridge.mesh.io import write_mesh
    from cadbridge.mesh.mesh import CellBlock, Mesh

    pts, tris = _lattice(4, 7, r=3.0)
    f = tmp_path / "bit.vtu"
    write_mesh(Mesh(pts, [CellBlock("triangle", tris)]), f)
    js = tmp_path / "q.json"
    assert main(["quality", str(f), "--size", "3", "--json", str(js)]) == 0
    out = capsys.readouterr().out
    assert "Q = 100.0 %" in out
    assert json.loads(js.read_text())["q"] == pytest.approx(100.0)
    assert main(["quality", str(f), "--size", "-1"]) == 2
