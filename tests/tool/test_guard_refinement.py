"""Refine instead of refuse (issue 32, point 4): where the straddle or reversal guard trips,
`convert` and `cadbridge mesh` mesh again finer there (`cadbridge.tool.guard_refinement`).

References:
* OpenCASCADE: the generated tight turn (`tests.helpers.tight_turns`: one B-spline face built
  with OCP whose normal turns 130 degrees round a 0.04 mm radius between two flat sides) is
  the independent geometry. Each tool node's normal is compared with OCC's normal of that
  surface at the node's foot (GeomAPI_ProjectPointOnSurf), and the tool with
  `cadbridge.verify.soundness.tool_soundness` (OCC's reading of the IGES file).
* Analytic: the principal curvature of the turn is 1 / radius (`turn_curvature`).
* convert's own output: `cadbridge mesh` + `cadbridge nagata` make the same tools (one pipeline).
* ../shared/cad_corpus (skipped when absent): occt_PRO20359-L10_CATIAV4.igs in quad mode.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("gmsh")
pytest.importorskip("OCP")

from cadbridge.tool.build import GuardTrips, ToolQualityError, check_tools, tools_from_mesh  # noqa: E402
from cadbridge.tool.guard_refinement import GuardRefinement, refine_where_guards_trip, turn_curvature  # noqa: E402
from cadbridge.tool.meshing import mesh_for_tools, read_healed  # noqa: E402
from tests.helpers.tight_turns import hairpin_iges, hairpin_surface  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
L10 = ROOT.parent / "shared" / "cad_corpus" / "iges" / "occt_PRO20359-L10_CATIAV4.igs"
RADIUS, TURN = 0.04, 130.0
NORMAL_TOL = 1e-8  # rad: tool node normals against OCC's normal at the node's foot


@pytest.fixture(scope="module")
def turn_file(tmp_path_factory) -> Path:
    return hairpin_iges(tmp_path_factory.mktemp("turn") / "tight_turn.igs", radius=RADIUS, turn=TURN)


@pytest.fixture(scope="module")
def first_tools(turn_file):
    """The tools of the first mesh `convert` makes (quad), before any refinement."""
    model, excursions = read_healed(turn_file)
    mesh, _ = mesh_for_tools(turn_file, model, excursions=excursions, element="quad")
    return model, tools_from_mesh(mesh, model, orient=True, meshed_per_face=True, measure=False)


def test_first_mesh_trips_the_reversal_guard(first_tools):
    """The case is one for the loop: with the default sizes (the curvature rule's floor, model
    size / 400 = 0.14 mm against a 0.09 mm long turn) elements span more than 120 degrees of it."""
    _, tools = first_tools
    assert len(tools) == 1 and len(tools[0].trips.reversed) > 0


def test_turn_curvature_is_the_radius(first_tools):
    """Over every element that spans the turn the largest principal curvature found is the
    turn's 1 / radius (analytic: an extruded circular arc), so one round asks for the size
    it needs however small the turn is against the element."""
    model, tools = first_tools
    t = tools[0]
    ids = t.trips.reversed
    k = turn_curvature(t.nagata, ids, t.element_face[ids], model)
    np.testing.assert_allclose(k, 1.0 / RADIUS, rtol=1e-6)


def _occ_normals(points: np.ndarray) -> np.ndarray:
    """OCC's unit normal (N, 3) of the generated surface at the foot of each point."""
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.GeomLProp import GeomLProp_SLProps
    from OCP.gp import gp_Pnt

    surface = hairpin_surface(radius=RADIUS, turn=TURN)
    out = np.empty((len(points), 3))
    for i, x in enumerate(points):  # one OCC projection per node (the reference)
        proj = GeomAPI_ProjectPointOnSurf(gp_Pnt(*map(float, x)), surface)
        u, v = proj.LowerDistanceParameters()
        props = GeomLProp_SLProps(surface, u, v, 1, 1e-9)
        assert props.IsNormalDefined()
        out[i] = props.Normal().Coord()
    return out


def _converts_soundly(turn_file: Path, element: str, out: Path) -> None:
    from cadbridge.io.toolfile import read_toolfile
    from cadbridge.tool.pipeline import convert
    from cadbridge.verify.soundness import tool_soundness

    run = convert(str(turn_file), str(out), element=element, grid=4)
    rounds = [n for n in run.notes if n.startswith("refinement round")]
    assert rounds and rounds[-1].endswith("0 elements tripping after it"), run.notes
    assert all(not t.trips and not t.diagnosis for t in run.tools)
    for path in sorted(out.glob("*.nagata")):
        tool = read_toolfile(path)
        occ = _occ_normals(tool.nodes)
        dots = np.einsum("ij,ij->i", tool.normals, occ)
        side = np.sign(np.median(dots))  # the tool's side of the sheet (orientation is the winding's)
        angle = np.arctan2(np.linalg.norm(np.cross(tool.normals, side * occ), axis=1), side * dots)
        assert np.max(angle) <= NORMAL_TOL
    report = tool_soundness(turn_file, sorted(out.glob("*.nagata")))
    assert report.sound, report.line()


def test_tight_turn_converts_after_refinement_quad(turn_file, tmp_path):
    _converts_soundly(turn_file, "quad", tmp_path / "out")


@pytest.mark.slow
def test_tight_turn_converts_after_refinement_tri(turn_file, tmp_path):
    _converts_soundly(turn_file, "tri", tmp_path / "out")


def _cli(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "cadbridge", "-q", *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600)


@pytest.mark.slow
def test_mesh_then_nagata_is_convert(turn_file, tmp_path):
    """One pipeline with refinement: `cadbridge mesh` writes the refined mesh, on which
    `cadbridge nagata` builds convert's tools (same elements; values within 1e-12 x size)."""
    from cadbridge.io.toolfile import read_toolfile

    assert _cli("convert", str(turn_file), "-o", str(tmp_path / "convert")).returncode == 0
    mesh = tmp_path / f"{turn_file.stem}.msh"
    assert _cli("mesh", str(turn_file), "-o", str(mesh)).returncode == 0
    assert _cli("nagata", str(mesh), "--cad", str(turn_file), "-o", str(tmp_path / "steps")).returncode == 0
    want = sorted((tmp_path / "convert").glob("*.nagata"))
    got = sorted((tmp_path / "steps").glob("*.nagata"))
    assert [p.name for p in want] == [p.name for p in got] and want
    a, b = read_toolfile(want[0]), read_toolfile(got[0])
    tol = 1e-12 * np.linalg.norm(np.ptp(a.nodes, axis=0))
    for name in ("triangles", "quads", "corner_element", "corner_local"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    for name in ("nodes", "normals", "corner_normals"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and np.all(np.abs(x - y) <= tol), name


def test_nothing_trips_nothing_changes():
    """Without a tripping element the first mesh and tools come back as they are and no
    mesh is made again (the tool files of passing inputs stay bit-identical)."""
    none = GuardTrips(*(np.zeros(0, dtype=np.int64),) * 3)
    tools, mesh = [SimpleNamespace(trips=none)], object()

    def remesh(*_):
        raise AssertionError("remeshed without a tripping element")

    out = refine_where_guards_trip(mesh, tools, ["note"], None, remesh=remesh, build=remesh)
    assert out.mesh is mesh and out.tools is tools and out.rounds == 0 and out.converged and out.failure == ""


def test_the_guards_message_says_the_rounds():
    """The guards' message stays the current one, with what the refinement did appended."""
    assert GuardRefinement(None, [], [], rounds=3, converged=False).failure == "after 3 refinement rounds"
    assert GuardRefinement(None, [], [], rounds=1, converged=False).failure == "after 1 refinement round"
    assert (GuardRefinement(None, [], [], rounds=0, converged=False, failed_round="x").failure
            == "refinement round 1 failed: x")
    tool = SimpleNamespace(name="t", diagnosis=["the CAD normal reverses inside elements 2"])
    with pytest.raises(ToolQualityError, match=r"reverses inside elements 2 \(after 2 refinement rounds; nothing"):
        check_tools([tool], refinement="after 2 refinement rounds")


@pytest.mark.skipif(not L10.is_file(), reason="../shared/cad_corpus not present")
def test_corpus_l10_quad(tmp_path):
    """occt_PRO20359-L10_CATIAV4.igs, --element quad: its reversing element is a zero-area
    triangle the node merge leaves where the crease line ends 0.001 mm from the trim (its
    third node is in no other element, so its normal's side is that sliver's winding); a
    finer mesh does not cure it. convert either converts soundly or stops with the guard's
    one line saying what the refinement did; never an internal error."""
    out = tmp_path / "out"
    res = _cli("convert", str(L10), "-o", str(out))
    err = res.stderr.strip().splitlines()
    if res.returncode == 0:
        from cadbridge.verify.soundness import tool_soundness

        report = tool_soundness(L10, sorted(out.glob("*.nagata")))
        assert report.sound, report.line()
        return
    assert res.returncode == 1 and len(err) == 1, err
    assert "the CAD normal reverses inside elements" in err[0] and "refinement round" in err[0], err[0]
    assert "CADBRIDGE_DEBUG" not in err[0] and not out.exists()
