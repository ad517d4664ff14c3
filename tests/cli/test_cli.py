"""End to end: the `cadbridge` command (in-process through `cadbridge.cli.main`, one real
console-script run).

References: the sample files' documented contents (iges_samples/README.md: entity counts,
names, sizes), OpenCASCADE through `verify`, gmsh reading the written mesh back, meshio
reading the VTUs back, the tool-file/CSV/IGES readers (round trips), analytic geometry
(a flat blank holder is reproduced exactly).
"""

from __future__ import annotations

import io
import re
import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest

from cadbridge import cli
from cadbridge.cli import EXIT_BAD_INPUT, EXIT_CHECK_FAILED, EXIT_OK, Progress, build_parser, main

SAMPLES = Path(__file__).resolve().parents[2] / "iges_samples"
SUMMARY_ROW = re.compile(
    r"^\s+(?P<tool>\S+)\s+(?P<source>\S+)\s+(?P<nodes>\d+)\s+(?P<elems>\d+)\s+(?P<shape>\S+)\s+(?P<boundary>\S+)"
    r"\s+(?P<flat>\S+)\s+(?P<normal>\S+)°$"
)


PROGRESS_LINE = re.compile(cli.PROGRESS_LINE)


def run(capsys, *argv: str) -> tuple[int, str, str]:
    """Exit code, stdout and stderr without the progress lines (off a terminal `Progress`
    writes one line per stage; the tests of those lines are under "progress")."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, "".join(ln for ln in err.splitlines(keepends=True) if not PROGRESS_LINE.match(ln))


def tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def summary_rows(out: str) -> list[dict]:
    return [m.groupdict() for m in map(SUMMARY_ROW.match, out.splitlines()) if m]


# ----------------------------------------------------------------------------- help
SUBCOMMANDS = ("inspect", "verify", "mesh", "normals", "nagata", "convert", "ushape")


@pytest.mark.parametrize("command", SUBCOMMANDS)
def test_every_subcommand_help_shows_an_example(command, capsys):
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args([command, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "example:" in out
    assert re.search(rf"^\s+cadbridge {command} ", out, re.M)


def test_console_script_runs(tmp_path):
    exe = Path(sys.executable).parent / "cadbridge"
    if not exe.exists():
        pytest.skip("console script not installed")
    r = subprocess.run([str(exe), "inspect", str(SAMPLES / "thesis_appendix_a.igs")], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0 and "NURBSURF" in r.stdout and r.stderr == ""


# ----------------------------------------------------------------------------- inspect
def test_inspect_prints_counts_faces_units_box_names(capsys):
    code, out, _ = run(capsys, "inspect", SAMPLES / "ushape_die_nurbs.igs")
    assert code == EXIT_OK
    # README entity table: 102: 6, 126: 24, 128: 3, 142: 3, 144: 3, 314: 1, 406: 3
    for et, n in {102: 6, 126: 24, 128: 3, 142: 3, 144: 3, 314: 1, 406: 3}.items():
        assert re.search(rf"^\s+{et}\s+.*\s{n}$", out, re.M), et
    assert re.search(r"^units\s+MM", out, re.M)
    assert re.search(r"^faces\s+3$", out, re.M)
    # die wall x = 36, land to x = 190, y in [0, 20.5], wall down to z = -80, land at z = 0
    m = re.search(r"bounding box\s+min \(([^)]*)\)\s+max \(([^)]*)\)", out)
    lo, hi = (np.array([float(v) for v in g.split(",")]) for g in m.groups())
    np.testing.assert_allclose(lo, [36, 0, -80], atol=1e-6)
    np.testing.assert_allclose(hi, [190, 20.5, 0], atol=1e-6)
    assert re.search(r"^names\s+DIELAND, DIERAD, DIEWALL$", out, re.M)


# ----------------------------------------------------------------------------- verify
def test_verify_ok_on_a_sample(capsys):
    code, out, _ = run(capsys, "verify", SAMPLES / "thesis_appendix_a.igs", "--samples", "50")
    assert code == EXIT_OK and out.rstrip().endswith("OK")


def test_verify_fails_on_a_perturbed_file(tmp_path, capsys):
    """A copy of placed_by_124.igs whose 124 matrix has one rotation coefficient edited
    (R11 0.866 -> 0.966: no longer a rotation): our reading and OpenCASCADE's differ."""
    text = (SAMPLES / "placed_by_124.igs").read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("124,0.8660254037844387,"))
    bad = tmp_path / "perturbed.igs"
    bad.write_text(text.replace(line, line.replace("124,0.8660254037844387,", "124,0.9660254037844387,", 1)))
    code, out, _ = run(capsys, "verify", bad, "--samples", "50")
    assert code == EXIT_CHECK_FAILED
    assert "FAIL" in out and "SPHERE" in out


def test_verify_does_not_see_a_perturbed_control_point(tmp_path, capsys):
    """verify compares two readers of the same file: an edited control point moves the
    surface for both, so it passes (it is not a check of the geometry's intent)."""
    text = (SAMPLES / "thesis_appendix_a.igs").read_text()
    bad = tmp_path / "moved_pole.igs"
    bad.write_text(text.replace("\n-2.804053,-5.16892,0,", "\n-2.904053,-5.16892,0,", 1))
    assert bad.read_text() != text
    code, _, _ = run(capsys, "verify", bad, "--samples", "30")
    assert code == EXIT_OK


# ----------------------------------------------------------------------------- mesh
def test_mesh_writes_a_file_gmsh_reads(tmp_path, capsys):
    gmsh = pytest.importorskip("gmsh")
    out = tmp_path / "die.msh"
    code, text, _ = run(capsys, "mesh", SAMPLES / "ushape_die_nurbs.igs", "-o", out, "--structured")
    assert code == EXIT_OK
    n_nodes, n_el = map(int, re.search(r"(\d+) nodes, (\d+) elements", text).groups())
    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(out))
        tags, _, _ = gmsh.model.mesh.getNodes()
        types, elems, _ = gmsh.model.mesh.getElements(dim=2)
    finally:
        gmsh.finalize()
    assert len(tags) == n_nodes
    assert sum(len(e) for e in elems) == n_el
    assert set(types) <= {2, 3}  # triangles / quadrangles


# ----------------------------------------------------------------------------- normals
@pytest.fixture(scope="module")
def die_mesh(tmp_path_factory):
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.mesh.io import write_mesh

    path = tmp_path_factory.mktemp("mesh") / "die.msh"
    write_mesh(mesh_cad(SAMPLES / "ushape_die_nurbs.igs", element="quad", structured=True), path)
    return path


def test_normals_cad_vtu(die_mesh, tmp_path, capsys):
    out = tmp_path / "n.vtu"
    code, _, _ = run(capsys, "normals", die_mesh, "--cad", SAMPLES / "ushape_die_nurbs.igs", "-o", out)
    assert code == EXIT_OK
    m = meshio.read(out)
    assert {"normal", "face_id", "distance"} <= set(m.point_data)
    n = m.point_data["normal"]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    assert np.max(m.point_data["distance"]) < 1e-9  # gmsh put the nodes on the CAD
    assert set(np.unique(m.point_data["face_id"])) == {0, 1, 2}
    # the land (z = 0) faces +z; analytic normal of a plane
    land = np.abs(m.points[:, 2]) < 1e-9
    flat = np.abs(n[land & (m.points[:, 0] > 41 + 1e-6)])
    assert len(flat) and np.allclose(flat, [0, 0, 1], atol=1e-12)


def test_normals_mwe_without_cad(die_mesh, tmp_path, capsys):
    out = tmp_path / "mwe.vtu"
    code, text, _ = run(capsys, "normals", die_mesh, "--method", "mwe", "-o", out)
    assert code == EXIT_OK and "mwe" in text
    m = meshio.read(out)
    np.testing.assert_allclose(np.linalg.norm(m.point_data["normal"], axis=1), 1.0, atol=1e-12)


def test_normals_cad_method_needs_cad(die_mesh, tmp_path, capsys):
    code, _, err = run(capsys, "normals", die_mesh, "-o", tmp_path / "x.vtu")
    assert code == EXIT_BAD_INPUT
    assert err.count("\n") == 1 and "--cad" in err
    assert not (tmp_path / "x.vtu").exists()


# ----------------------------------------------------------------------------- nagata
def test_nagata_writes_tool_file_and_report(die_mesh, tmp_path, capsys):
    from cadbridge.io.csvgrid import read_coefficients_listing, read_grid_csv
    from cadbridge.io.toolfile import read_toolfile

    out = tmp_path / "die_tool"
    code, text, err = run(capsys, "nagata", die_mesh, "--cad", SAMPLES / "ushape_die_nurbs.igs", "-o", out)
    assert code == EXIT_OK and err == ""  # nothing but progress lines on stderr
    rows = summary_rows(text)
    assert [r["tool"] for r in rows] == ["die"]
    files = {p.name for p in out.iterdir()}
    assert files == {"die.nagata", "die_nagata.vtu", "die_mesh.vtu", "die_grid.csv", "die_coefficients.txt",
                     "die_surface_error.png", "die_boundary_error.png", "die_normal_error.png", "die_nagata.igs",
                     "die_shape_error_map.png", "die_normal_error_map.png"}
    td = read_toolfile(out / "die.nagata")
    assert td.normal_source == "cad" and len(td.quads) == int(rows[0]["elems"])
    surf = meshio.read(out / "die_nagata.vtu")
    assert {"normal", "surface_error", "boundary_error", "flat_surface_error", "normal_error", "face_id"} <= set(
        surf.point_data)
    assert np.max(np.abs(surf.point_data["surface_error"])) <= float(rows[0]["shape"]) * 1.5 + 1e-12
    mesh_vtu = meshio.read(out / "die_mesh.vtu")
    assert {"normal", "face_id", "distance"} <= set(mesh_vtu.point_data)
    np.testing.assert_array_equal(mesh_vtu.point_data["normal"], td.normals)
    assert "normal_source" in mesh_vtu.field_data
    grid = read_grid_csv(out / "die_grid.csv")
    assert float(rows[0]["shape"]) == pytest.approx(np.max(np.abs(grid["surface_error"])), rel=1e-3)
    assert float(rows[0]["boundary"]) == pytest.approx(np.max(grid["boundary_error"]), rel=1e-3)
    assert float(rows[0]["flat"]) == pytest.approx(np.max(np.abs(grid["flat_surface_error"])), rel=1e-3)
    _, quad_c = read_coefficients_listing(out / "die_coefficients.txt")
    np.testing.assert_array_equal(quad_c, td.quad_coefficients)


def test_nagata_off_cad_mesh_stops_and_writes_nothing(die_mesh, tmp_path, capsys):
    out = tmp_path / "never"
    code, text, err = run(capsys, "nagata", die_mesh, "--cad", SAMPLES / "sphere_patch.igs", "-o", out)
    assert code == EXIT_CHECK_FAILED
    assert text == "" and err.count("\n") == 1 and err.startswith("cadbridge nagata: error:")
    assert "further than" in err
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == []  # no staging folder left behind
    # an existing output folder is left exactly as it was
    out.mkdir()
    (out / "keep.txt").write_text("old")
    before = tree(out)
    code, _, _ = run(capsys, "nagata", die_mesh, "--cad", SAMPLES / "sphere_patch.igs", "-o", out)
    assert code == EXIT_CHECK_FAILED and tree(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["never"]


@pytest.mark.parametrize("argv, code", [
    (["nagata", "{bad}", "--cad", "{die}", "-o", "{out}"], EXIT_BAD_INPUT),  # mesh is not a mesh
    (["nagata", "{mesh}", "--cad", "{bad}", "-o", "{out}"], EXIT_BAD_INPUT),  # CAD is not IGES
    (["nagata", "{mesh}", "-o", "{out}"], EXIT_BAD_INPUT),  # --method cad without --cad
    (["nagata", "{missing}", "--method", "mwe", "-o", "{out}"], EXIT_BAD_INPUT),
    (["convert", "{bad}", "-o", "{out}"], EXIT_BAD_INPUT),
    (["convert", "{garbage}", "-o", "{out}"], EXIT_BAD_INPUT),
    (["inspect", "{bad}"], EXIT_BAD_INPUT),
])
def test_bad_input_one_line_and_nothing_written(argv, code, die_mesh, tmp_path, capsys):
    bad = tmp_path / "notes.igs"
    bad.write_text("these are my notes, not an IGES file\n")
    garbage = tmp_path / "garbage.igs"
    garbage.write_bytes(bytes(range(256)) * 8)
    subs = {"bad": bad, "garbage": garbage, "die": SAMPLES / "ushape_die_nurbs.igs", "mesh": die_mesh,
            "out": tmp_path / "out", "missing": tmp_path / "missing.msh"}
    got, out, err = run(capsys, *[a.format(**subs) for a in argv])
    assert got == code
    assert err.count("\n") == 1 and ": error: " in err, err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["garbage.igs", "notes.igs"]


def test_file_system_errors_name_the_path_in_words(tmp_path, capsys):
    """A missing input and an output folder that cannot be made: one line naming the path the
    user gave, exit 2, no Python error name or "[Errno N]" (reference: the paths given)."""
    missing = tmp_path / "missing.stp"
    code, _, err = run(capsys, "convert", str(missing), "-o", str(tmp_path / "out"))
    assert code == EXIT_BAD_INPUT
    assert err.strip().endswith(f"error: {missing}: no such file or directory"), err
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    out = blocker / "out"
    code, _, err = run(capsys, "convert", str(SAMPLES / "trimmed_hole.igs"), "-o", str(out))
    assert code == EXIT_BAD_INPUT
    assert err.strip().splitlines()[-1].endswith(f"error: {out}: cannot write the output folder there (file exists)"), err
    assert "Errno" not in err and "Error:" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


# ----------------------------------------------------------------------------- convert
def _samples():
    for p in sorted(q for q in SAMPLES.glob("*.igs") if not q.name.startswith("production_die")):
        yield pytest.param(p, id=p.stem)


@pytest.mark.parametrize("sample", list(_samples()))
def test_convert_every_sample(sample, tmp_path, capsys):
    from cadbridge.iges import read_iges

    out = tmp_path / "out"
    code, text, err = run(capsys, "convert", sample, "-o", out)
    assert code == EXIT_OK, err
    rows = summary_rows(text)
    assert rows, text
    size = read_iges(sample).size()
    for r in rows:
        assert r["source"] == "cad"
        shape, normal = float(r["shape"]), float(r["normal"])
        assert np.isfinite(shape) and np.isfinite(normal)
        assert 0 <= shape < 0.01 * size  # the Nagata surface stays on the CAD
        assert 0 <= normal <= 180
        assert (out / f"{r['tool']}.nagata").is_file()
        assert (out / f"{r['tool']}_surface_error.png").is_file()
        assert (out / f"{r['tool']}_boundary_error.png").is_file()
        assert (out / f"{r['tool']}_normal_error.png").is_file()
        if r["tool"] in ("bholder", "plate"):  # flat plates: Nagata is exact
            assert shape < 1e-12 * size and normal < 1e-9
    written = int(re.match(r"wrote (\d+) files", text).group(1))
    assert written == len(list(out.iterdir()))


# ----------------------------------------------------------------------------- ushape
def test_ushape_cli_prints_table_and_findings(tmp_path, capsys, monkeypatch):
    """The command layer only (the run itself is tests/ushape/test_benchmark.py): the table and the
    findings are printed, the output folder named."""
    import cadbridge.ushape.benchmark as bm

    calls = {}

    def fake_run(output, **kw):
        calls.update(kw, output=output)
        return bm.UShapeSummary(tools={"die": {"polyhedral": {"max_radial_error_pct": -3.4}}},
                                run={"files": ["summary.md"], "seconds": 0.5})

    monkeypatch.setattr(bm, "run_ushape", fake_run)
    code, out, _ = run(capsys, "ushape", "-o", tmp_path / "u")
    assert code == EXIT_OK
    assert "| die | polyhedral | -3.4000 | - | - |" in out
    assert "wrote 1 files" in out and calls["output"] == str(tmp_path / "u")
    assert calls["grid"] == 20 and calls["progress"] is not None


# ----------------------------------------------------------------------------- progress
def test_progress_off_a_terminal_writes_plain_lines(monkeypatch):
    """Off a terminal (a log, a pipe): one plain line per stage, a line within a stage only
    every `log_every` seconds, and the closing line; no carriage returns."""
    buf = io.StringIO()
    p = Progress("cadbridge test", stream=buf)
    p.stage("projecting")
    p.update(5, 10)  # within log_every of the stage line: not written
    monkeypatch.setattr(Progress, "log_every", 0.0)
    p.update(6, 10)
    p.close()
    lines = buf.getvalue().splitlines()
    assert "\r" not in buf.getvalue() and len(lines) == 3
    assert lines[0].startswith("cadbridge test [ 1] projecting") and "60%" in lines[1]
    assert lines[2].startswith("cadbridge test: done in") and all(PROGRESS_LINE.match(ln) for ln in lines)


def test_progress_in_a_log_keeps_the_whole_stage():
    """A terminal line is cut to its width; a log line keeps what the stage says (the
    refinement notes run to a few hundred characters)."""
    text = "refinement round 1 of at most 3: meshing again finer at 84 elements (" + "x" * 200 + ")"
    buf, tty = io.StringIO(), io.StringIO()
    Progress("cadbridge test", stream=buf).stage(text)
    Progress("cadbridge test", enabled=True, stream=tty).stage(text)
    assert text in buf.getvalue()
    assert text not in tty.getvalue() and text[:60] in tty.getvalue()


def test_quiet_silences_progress(tmp_path, capsys):
    code = main(["--quiet", "convert", str(SAMPLES / "ushape_blankholder_nurbs.igs"), "-o", str(tmp_path / "o")])
    assert code == EXIT_OK and capsys.readouterr().err == ""
    Progress.quiet = False
    code = main(["convert", str(SAMPLES / "ushape_blankholder_nurbs.igs"), "-o", str(tmp_path / "p")])
    err = capsys.readouterr().err.splitlines()
    assert code == EXIT_OK and err and all(PROGRESS_LINE.match(ln) for ln in err)
    assert any("writing" in ln for ln in err) and err[-1].startswith("cadbridge convert: done in")


def test_progress_on_a_terminal_draws_stages():
    buf = io.StringIO()
    with Progress("cadbridge test", enabled=True, stream=buf) as p:
        p.stage("die: projecting nodes")
        p.update(10, 10)
    text = buf.getvalue()
    assert "\r" in text and "die: projecting nodes" in text and "100%" in text
    assert text.endswith("\n") and "done in" in text


def test_progress_follows_convert_stages(tmp_path):
    from cadbridge.tool.pipeline import convert

    buf = io.StringIO()
    with Progress("convert", enabled=True, stream=buf) as p:
        convert(str(SAMPLES / "ushape_blankholder_nurbs.igs"), str(tmp_path / "o"), progress=p)
    text = buf.getvalue()
    for stage in ("reading", "meshing", "projecting nodes", "Nagata patches", "errors vs CAD", "writing"):
        assert stage in text, stage


def test_nagata_inconsistent_orientation_names_elements_or_reorients(die_mesh, tmp_path, capsys):
    """A mesh with one element's winding reversed: `nagata` stops with a one-line message
    naming the two elements (nothing written); with --orient it re-orients and the normals
    agree with the untouched mesh's (reference: the same run on the consistent mesh)."""
    from cadbridge.io.toolfile import read_toolfile
    from cadbridge.mesh.io import read_mesh, write_mesh
    from cadbridge.mesh.mesh import CellBlock, Mesh

    mesh = read_mesh(die_mesh)
    quads = mesh.quads.copy()
    quads[1] = quads[1][::-1]
    bad = tmp_path / "flipped.msh"
    write_mesh(Mesh(nodes=mesh.nodes, cells=[CellBlock("quad", quads)]), bad)
    out = tmp_path / "out"
    code, text, err = run(capsys, "nagata", bad, "--cad", SAMPLES / "ushape_die_nurbs.igs", "-o", out)
    assert code == EXIT_BAD_INPUT and err.count("\n") == 1
    assert "inconsistent element orientation" in err and "--orient" in err
    assert not out.exists()
    code, _, _ = run(capsys, "nagata", bad, "--cad", SAMPLES / "ushape_die_nurbs.igs", "-o", out, "--orient",
                     "--no-report")
    assert code == 0
    ref = tmp_path / "ref"
    assert run(capsys, "nagata", die_mesh, "--cad", SAMPLES / "ushape_die_nurbs.igs", "-o", ref, "--no-report")[0] == 0
    a, b = (read_toolfile(next(d.glob("*.nagata"))) for d in (out, ref))
    assert np.allclose(np.einsum("ij,ij->i", a.normals, b.normals), 1.0, atol=1e-12)


def test_unexpected_library_error_is_one_line_exit_2(monkeypatch, capsys, tmp_path):
    """An error the library did not anticipate still gives one line and exit 2, no traceback
    (reference: the exception raised by the patched call)."""
    import cadbridge.tool.pipeline as pipeline

    def boom(*a, **k):
        raise ValueError("errors 'cad' has non-finite values at [59302]\nsecond line")

    monkeypatch.setattr(pipeline, "convert", boom)
    code, out, err = run(capsys, "convert", SAMPLES / "trimmed_hole.igs", "-o", tmp_path / "o")
    assert code == EXIT_BAD_INPUT
    assert err.count("\n") == 1 and "ValueError: errors 'cad' has non-finite values" in err
    assert "Traceback" not in err and "CADBRIDGE_DEBUG" in err
