"""End to end: the NUMISHEET'93 U-shape benchmark (`run_ushape`, thesis §5.2, Fig. 49).

References: the thesis' Fig. 49 statements and its arc value for a normalized edge length
of 0.52 (0.060 %, Fig. 8), recomputed here from an independent 2D Nagata curve (the
two-normal formula solved with numpy, no cadbridge code); the polyhedral (chord) error;
round trips of the written files; OpenCASCADE's IGES reader for the exported Nagata IGES.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cadbridge.io.toolfile import read_toolfile, write_toolfile
from cadbridge.ushape.benchmark import SOURCES, run_ushape

TOOLS = ("die", "punch", "blankholder")
WITH_RADIUS = ("die", "punch")
SOURCE_KEYS = [k for k, _, _ in SOURCES]


@pytest.fixture(scope="module")
def ushape(tmp_path_factory):
    out = tmp_path_factory.mktemp("ushape") / "out"
    summary = run_ushape(str(out))
    return out, summary


def nagata_arc_max_radial_error(angle: float, samples: int = 20001) -> float:
    """Max radial error (%) of the Nagata curve between two points of a unit circle
    ``angle`` apart, with the exact normals: x(t) = x0 + (d - c) t + c t^2 with
    n0 . c = n0 . d and n1 . c = -n1 . d, c in the span of n0, n1 (Nagata 2005, eq. 9-12)."""
    a0, a1 = 0.0, angle
    x0, x1 = np.array([math.cos(a0), math.sin(a0)]), np.array([math.cos(a1), math.sin(a1)])
    n0, n1 = x0, x1  # outward unit normals of the unit circle
    d = x1 - x0
    g = np.array([[n0 @ n0, n0 @ n1], [n1 @ n0, n1 @ n1]])
    alpha, beta = np.linalg.solve(g, [n0 @ d, -(n1 @ d)])
    c = alpha * n0 + beta * n1
    t = np.linspace(0.0, 1.0, samples)[:, None]
    x = x0 + (d - c) * t + c * t**2
    r = np.linalg.norm(x, axis=1)
    return float(np.max(np.abs(r - 1.0)) * 100.0)


def test_independent_arc_reference_is_the_thesis_value():
    # thesis Fig. 8 / §5.2: 0.06 % at normalized edge length 0.52 (3 elements over 90°)
    assert f"{nagata_arc_max_radial_error(math.pi / 6):.3f}" == "0.060"


@pytest.mark.parametrize("tool", WITH_RADIUS)
def test_cad_normals_same_error_in_all_three_elements(ushape, tool):
    _, s = ushape
    cad = s.tools[tool]["cad"]
    els = cad["radius_elements_max_radial_error_pct"]
    assert len(els) == 3
    assert max(els) - min(els) <= 1e-6
    assert f"{cad['max_radial_error_pct']:.3f}" == "0.060"  # the thesis' digits
    ref = nagata_arc_max_radial_error(math.pi / 6)
    assert abs(cad["max_radial_error_pct"]) == pytest.approx(ref, abs=1e-6)


@pytest.mark.parametrize("tool", WITH_RADIUS)
def test_without_planes_outer_elements_are_polyhedral(ushape, tool):
    _, s = ushape
    poly = s.tools[tool]["polyhedral"]["max_radial_error_pct"]
    # the chord of a 30° arc: (cos 15° - 1) * 100 %
    assert poly == pytest.approx((math.cos(math.pi / 12) - 1.0) * 100.0, rel=1e-3)
    els = s.tools[tool]["mwe_without_planes"]["radius_elements_max_radial_error_pct"]
    for outer in (els[0], els[-1]):
        assert abs(outer - poly) <= 1e-3 * abs(poly)
    # the middle element keeps exact-looking normals: the CAD value
    assert els[1] == pytest.approx(s.tools[tool]["cad"]["radius_elements_max_radial_error_pct"][1], abs=1e-6)


@pytest.mark.parametrize("tool", WITH_RADIUS)
def test_with_planes_mwaat_best_mwelr_worst(ushape, tool):
    _, s = ushape
    r = s.tools[tool]
    mx = {k: abs(r[k]["max_radial_error_pct"]) for k in ("mwaat_with_planes", "mwe_with_planes", "mwelr_with_planes")}
    assert mx["mwaat_with_planes"] < mx["mwe_with_planes"] < mx["mwelr_with_planes"]
    # the planes help MWE: far better than without them
    assert mx["mwe_with_planes"] < 0.5 * abs(r["mwe_without_planes"]["max_radial_error_pct"])


def test_summary_json_structure(ushape):
    out, s = ushape
    data = json.loads((out / "summary.json").read_text())
    assert set(data) == set(TOOLS) | {"_run"}
    assert data == json.loads(json.dumps(s.as_json()))
    for tool in WITH_RADIUS:
        for key in SOURCE_KEYS:
            entry = data[tool][key]
            assert set(entry) >= {"max_radial_error_pct", "max_normal_error_deg", "radius_elements_max_radial_error_pct"}
            assert len(entry["radius_elements_max_radial_error_pct"]) == 3
            assert all(isinstance(v, float) for v in entry["radius_elements_max_radial_error_pct"])
    for tool in TOOLS:
        assert data[tool]["cad_quad_vs_cad"]["max_abs_surface_error_mm"] < 0.01
    # a flat blank holder: Nagata patches are exact
    assert data["blankholder"]["cad_quad_vs_cad"]["max_abs_surface_error_mm"] < 1e-12
    assert {"seconds", "params", "files"} <= set(data["_run"])
    for f in data["_run"]["files"]:
        assert (out / f).is_file(), f


def test_summary_md_table_prints_each_maximum(ushape):
    out, s = ushape
    md = (out / "summary.md").read_text()
    assert "| tool | normals | max radial error [%] |" in md
    for tool in WITH_RADIUS:
        for key in SOURCE_KEYS + ["polyhedral"]:
            v = s.tools[tool][key]["max_radial_error_pct"]
            assert f"| {tool} | {key} | {v:+.4f} |" in md, (tool, key)
    assert "| die | cad | +0.0601 | +0.0601 / +0.0601 / +0.0601 |" in md


def test_report_figures_per_tool(ushape):
    out, _ = ushape
    for tool in TOOLS:
        assert (out / f"{tool}_normal_sources.png").is_file()
        assert (out / f"{tool}_shape_error_by_source.png").is_file()
        assert (out / tool / f"{tool}_surface_error.png").is_file()
        assert (out / tool / f"{tool}_boundary_error.png").is_file()
        assert (out / tool / f"{tool}_normal_error.png").is_file()
    for tool in WITH_RADIUS:
        png = (out / f"{tool}_section_error.png").read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
        w, h = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
        assert (w, h) == (1600, 1000)
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".")]  # no staging left


@pytest.mark.parametrize("tool", TOOLS)
def test_tool_files_round_trip_exactly(ushape, tool, tmp_path):
    out, s = ushape
    path = out / tool / f"{tool}.nagata"
    read = read_toolfile(path)
    assert read.equals(s.tool_files[tool])  # what was computed, bit for bit
    again = tmp_path / "again.nagata"
    write_toolfile(read, again)
    assert again.read_bytes() == path.read_bytes()
    assert read_toolfile(again).equals(read)
    assert read.normal_source == "cad" and read.units == "MM"


def _toolfile_nagata(td):
    """Nagata surface rebuilt from a tool file (node normals + corner overrides)."""
    from cadbridge.nagata import NagataMesh

    blocks, corners, offset = [], [], 0
    over = td.corner_normal_dict()
    for conn in (td.triangles, td.quads):
        if len(conn) == 0:
            continue
        cn = td.normals[conn].copy()
        for (e, k), n in over.items():
            if offset <= e < offset + len(conn):
                cn[e - offset, k] = n
        blocks.append(conn)
        corners.append(cn)
        offset += len(conn)
    return NagataMesh(td.nodes, blocks, corners)


@pytest.mark.parametrize("tool", TOOLS)
def test_nagata_iges_read_by_opencascade_matches_patches(ushape, tool):
    pytest.importorskip("OCP")
    from cadbridge.verify.reference import occ_read

    out, _ = ushape
    td = read_toolfile(out / tool / f"{tool}.nagata")
    nm = _toolfile_nagata(td)
    # coefficients recomputed from the file's nodes/normals are the file's coefficients
    assert np.array_equal(nm.quad_coefficients, td.quad_coefficients)
    faces = occ_read(out / tool / f"{tool}_nagata.igs")
    assert len(faces) == td.n_elements
    size = float(np.linalg.norm(np.ptp(td.nodes, axis=0)))
    rng = np.random.default_rng(5)
    u, v = rng.random(12), rng.random(12)
    u[:4], v[:4] = [0, 1, 1, 0], [0, 0, 1, 1]
    worst = 0.0
    for e, f in enumerate(faces):
        s = f.surface
        got = np.array([[s.Value(a, b).X(), s.Value(a, b).Y(), s.Value(a, b).Z()] for a, b in zip(u, v)])
        tri = e < len(td.triangles)
        eta, zeta = (u, u * v) if tri else (u, v)
        ref, _ = nm.evaluate(np.full(len(u), e), eta, zeta)
        worst = max(worst, float(np.abs(got - ref).max()))
    assert worst <= 1e-12 * size
