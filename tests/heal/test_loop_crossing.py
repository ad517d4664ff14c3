"""Class 'trim loop that crosses itself' (IGES 5.3 4.34: trim loops are simple closed curves).

At a crossing the loop splits into two lobes. When the smaller lobe's model-space loop length
is within the face's trim tolerance width (`default_width`: max(4 x trim delta, 1e-3 x model
size)) the crossing is a tolerance artefact: `heal_excursions` cuts the lobe off at the
crossing point (the loop then runs through it), `inspect` lists it. Otherwise the face has no
sound reading: `convert` exits 2 with one line naming the face's DE and its loop field.
References: a hand-made figure-eight (real crossing), a hand-made square with a 1e-5 fish
tail at one corner (artefact), and occt_bug8363_f45_OpenCASCADE.igs (OCC:
BRepCheck_SelfIntersectingWire), whose 16-edge loop runs 0.027 mm back down at one corner
and up again across itself: a lobe of 0.055 mm loop length, below the file's own 2D/3D trim
disagreement of 0.057 mm, so an artefact.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.helpers.iges_fixtures import bilinear_128, make_iges

from cadbridge.cli import EXIT_BAD_INPUT, main
from cadbridge.heal.loop_excursions import MIN_LENGTH, default_width, find_excursions, heal_excursions, loop_crossing
from cadbridge.iges import IgesError, read_iges, read_iges_string

ROOT = Path(__file__).resolve().parents[2]
BUG8363 = ROOT.parent / "shared" / "cad_corpus" / "iges" / "occt_bug8363_f45_OpenCASCADE.igs"


def _face_with_loop(uv: list[tuple[float, float]]) -> str:
    """A unit square plane trimmed by the closed degree-1 (u, v) polyline ``uv``."""
    k = len(uv) - 1
    knots = [0.0] + [float(i) for i in range(k + 1)] + [float(k)]
    pts = ",".join(f"{u!r},{v!r},0.0" for u, v in uv)
    loop = (f"126,{k},1,0,0,1,0,{','.join(map(repr, knots))},{','.join(['1.0'] * (k + 1))},{pts},0.0,{float(k)!r},"
            "0.,0.,1.;")
    return make_iges([{"params": bilinear_128()},  # DE 1
                      {"params": loop, "status": "00010500"},  # DE 3
                      {"params": "142,1,1,3,0,1;", "status": "00010000"},  # DE 5
                      {"params": "144,1,1,0,5;"}])  # DE 7


FIGURE_EIGHT = [(0.1, 0.1), (0.9, 0.9), (0.9, 0.1), (0.1, 0.9), (0.1, 0.1)]
# a square whose bottom edge overshoots the corner (0.9, 0.1) by 2e-4 and comes back below
# it: the right edge crosses the bottom edge there, enclosing a triangle of legs 2e-4
EPS = 2e-4
FISH_TAIL = [(0.1, 0.1), (0.9 + EPS, 0.1), (0.9, 0.1 - EPS), (0.9, 0.9), (0.1, 0.9), (0.1, 0.1)]


def test_figure_eight_refused_by_convert(tmp_path, capsys):
    cad = tmp_path / "eight.igs"
    cad.write_text(_face_with_loop(FIGURE_EIGHT))
    out = tmp_path / "out"
    assert main(["--quiet", "convert", str(cad), "-o", str(out)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert ("eight.igs (DE 7, entity 144, field PTO): face (DE 7): its outer trim loop crosses itself at (u, v) = "
            "(0.5, 0.5)") in err[0] and "wider than the trim tolerance" in err[0]
    assert "Error" not in err[0] and not out.exists()
    assert main(["inspect", str(cad)]) == 0  # inspect reads it and says so
    assert "its outer trim loop crosses itself" in capsys.readouterr().out


def test_figure_eight_is_an_iges_error_in_heal():
    m = read_iges_string(_face_with_loop(FIGURE_EIGHT), "eight.igs")
    with pytest.raises(IgesError) as info:
        heal_excursions(m)
    e = info.value
    assert e.filename == "eight.igs" and e.de == 7 and e.entity_type == 144 and e.field == "PTO"
    assert "wide on average" in e.message and "IGES 5.3 4.34" in e.message


def test_fish_tail_cut_at_the_crossing():
    m = read_iges_string(_face_with_loop(FISH_TAIL))
    f = m.faces[0]
    [e] = find_excursions(m)
    assert e.kind == "crossing" and e.face_de == 7 and e.loop == 0
    assert np.allclose(e.start, [0.9, 0.1, 0.0], atol=1e-12) and e.length == pytest.approx((2 + 2 ** 0.5) * EPS)
    assert f.contains(np.array([0.9 + EPS / 4]), np.array([0.1 - EPS / 4])).tolist() == [True]  # in the tail
    assert "trim loop crosses itself at (0.9, 0.1, 0)" in str(e)
    [done] = heal_excursions(m)
    assert done.cut == e.cut
    lp = f.trims.outer
    assert loop_crossing(f, 0, lp, default_width(f, m.size()), 0.0) is None  # the healed loop is simple
    corner = np.array([[0.9, 0.1]])
    ends = np.vstack([c.evaluate(np.array(c.domain))[:, :2] for c in lp.curves])
    assert np.abs(ends - corner).sum(axis=1).min() <= 1e-12  # the loop runs through the corner
    # inside / outside as the square's: the tail's triangle is gone
    assert f.contains(np.array([0.5, 0.9 + EPS / 4]), np.array([0.5, 0.1 - EPS / 4])).tolist() == [True, False]


@pytest.mark.skipif(not BUG8363.is_file(), reason="shared/cad_corpus not present")
def test_bug8363_lobe_is_a_tolerance_artefact():
    m = read_iges(BUG8363)
    [e] = find_excursions(m)
    assert e.kind == "crossing" and e.face_de == 1 and e.cut[0][0] == 1 and e.cut[1][0] == 2  # curves 2 and 3
    assert e.length < 0.06 < m.faces[0].trim_delta * 4  # lobe length below the file's trim tolerance
    [done] = heal_excursions(m)
    f = m.faces[0]
    size = m.size()  # the cut leaves no crossing a mesh could see (the chord: within the samples' accuracy)
    assert loop_crossing(f, 0, f.trims.outer, default_width(f, size), MIN_LENGTH * size) is None


def _brute_crossings(a: np.ndarray, b: np.ndarray) -> set[tuple[int, int]]:
    """Every pair of edges of the closed polygon tested (O(M^2)), with the predicate
    `_proper_crossings` documents: the independent reference of its broad phase."""
    m, out = len(a), set()
    for i in range(m):
        for j in range(i + 2, m):
            if i == 0 and j == m - 1:
                continue

            def side(p, q, r):
                return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])

            s1, s2 = side(a[i], b[i], a[j]), side(a[i], b[i], b[j])
            s3, s4 = side(a[j], b[j], a[i]), side(a[j], b[j], b[i])
            if s1 * s2 <= 0 and s3 * s4 <= 0 and not (s1 == 0 and s2 == 0):
                out.add((i, j))
    return out


def test_proper_crossings_finds_what_testing_every_pair_finds():
    """The broad phase (a grid of cells one mean edge length wide, each edge listed in the
    cells its pieces cross) keeps every pair that meets: random star polygons with long edges
    (most vertices dropped) and grid-snapped ones (exact touches and shared vertices), against
    the all-pairs test. The pairs come sorted along the loop; with a limit, they are all the
    pairs of the edges up to the one where the limit is reached."""
    from cadbridge.heal.loop_excursions import _proper_crossings

    rng = np.random.default_rng(7)
    checked = with_hits = 0
    for _ in range(120):
        n = int(rng.integers(4, 120))
        t = np.sort(rng.uniform(0, 2 * np.pi, n))
        r = 1 + 0.4 * rng.standard_normal(n)
        uv = np.column_stack([r * np.cos(t), r * np.sin(t)])
        if rng.uniform() < 0.4:
            uv = uv[rng.uniform(size=n) < 0.3]
        if rng.uniform() < 0.4:
            uv = np.round(uv * 4) / 4
        uv = uv[np.linalg.norm(uv - np.roll(uv, 1, axis=0), axis=1) > 0]
        if len(uv) < 4:
            continue
        a, b = uv, np.roll(uv, -1, axis=0)
        got = _proper_crossings(a, b)
        brute = _brute_crossings(a, b)
        assert {tuple(map(int, p)) for p in got} == brute
        assert [tuple(p) for p in got.tolist()] == sorted(tuple(p) for p in got.tolist())
        # skipped edges (pole or seam jumps) and a limit: the first pairs of the rest, in order
        skip = rng.uniform(size=len(a)) < 0.1
        rest = sorted(p for p in brute if not (skip[p[0]] or skip[p[1]]))
        part = _proper_crossings(a, b, skip=skip, limit=3)
        assert [tuple(p) for p in part.tolist()][:3] == rest[:3]
        assert len(part) >= min(3, len(rest))
        if len(part):  # complete up to its last edge i
            assert [tuple(p) for p in part.tolist()] == [p for p in rest if p[0] <= part[-1, 0]]
        checked += 1
        with_hits += len(got) > 0
    assert checked > 80 and with_hits > 20  # the case is not vacuous
