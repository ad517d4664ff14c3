"""The sample IGES files: regeneration, contents, and the U-shape dimensions in them."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from cadbridge.verify.reference import occ_eval, occ_read
from cadbridge.ushape import FACE_LABELS, UShapeParams, blank_mesh, build_tools, tool_faces

SAMPLES_DIR = Path(__file__).resolve().parents[2] / "iges_samples"


def _load_make_samples():
    spec = importlib.util.spec_from_file_location("make_samples", SAMPLES_DIR / "make_samples.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


ms = _load_make_samples()


@pytest.fixture(scope="module")
def regenerated(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("samples")
    assert ms.main([str(out)]) == 0
    return out


@pytest.mark.parametrize("name", list(ms.SAMPLES) + list(ms.TEST_DATA))
def test_sample_regenerates_identically(regenerated: Path, name: str) -> None:
    committed = (SAMPLES_DIR if name in ms.SAMPLES else ms.TEST_DATA_DIR) / name
    assert committed.exists(), f"{name} missing: run iges_samples/make_samples.py"
    assert ms.entity_counts(regenerated / name) == ms.entity_counts(committed)
    assert (regenerated / name).read_bytes() == committed.read_bytes(), f"{name} differs: rerun make_samples.py"


def test_readme_lists_every_sample_and_counts() -> None:
    text = (SAMPLES_DIR / "README.md").read_text()
    for name in ms.SAMPLES:
        assert f"`{name}`" in text
    assert ms.counts_table(SAMPLES_DIR) in text


def test_folder_is_small() -> None:
    # the production die (written on request, git-ignored) does not count
    assert sum(p.stat().st_size for p in SAMPLES_DIR.iterdir() if not p.name.startswith("production_die")) < 2_000_000


def test_expected_entity_types() -> None:
    c = ms.entity_counts
    for tool, n in (("die", 3), ("punch", 3), ("blankholder", 1)):
        counts = c(SAMPLES_DIR / f"ushape_{tool}_nurbs.igs")
        assert counts[128] == counts[144] == n and 108 not in counts and 120 not in counts
    assert c(SAMPLES_DIR / "ushape_tools_nurbs.igs")[128] == 7
    analytic = c(SAMPLES_DIR / "ushape_tools_analytic.igs")
    assert analytic[108] == 5 and analytic[120] == 2 and 128 not in analytic
    assert c(SAMPLES_DIR / "thesis_appendix_a.igs") == {128: 1}
    assert c(SAMPLES_DIR / "placed_by_124.igs") == {124: 2, 128: 2}
    assert c(SAMPLES_DIR / "trimmed_hole.igs")[142] == 2  # outer boundary + the hole


def test_thesis_entity_data_verbatim() -> None:
    text = (SAMPLES_DIR / "thesis_appendix_a.igs").read_text()
    p_data = "".join(line[:64].strip() for line in text.splitlines() if line[72:73] == "P")
    assert p_data.startswith("128,7,1,3,1,0,0,1,0,0,0,0,0,0,0.2696129,0.50025292,0.69102833,0.81038681,1,1,1,1,0,0,1,1,")
    assert "-1.1892867,3.9613801,10,-1.250001,4.729729,10,0,1,0,1;" in p_data
    assert "NURBSURF" in text


def test_names_are_written() -> None:
    text = (SAMPLES_DIR / "ushape_tools_nurbs.igs").read_text()
    for labels in FACE_LABELS.values():
        for label in labels:
            assert f"H{label};" in text  # 406 form 15 name property


def _face_points(path: Path, index: int, n: int = 400) -> np.ndarray:
    face = occ_read(path)[index]
    u0, u1, v0, v1 = face.bounds
    rng = np.random.default_rng(1)
    return occ_eval(face.surface, rng.uniform(u0, u1, n), rng.uniform(v0, v1, n), order=0)[0]


def test_die_dimensions_in_file() -> None:
    p = UShapeParams()
    path = SAMPLES_DIR / "ushape_die_nurbs.igs"
    wall, rad, land = (_face_points(path, i) for i in range(3))
    # shoulder: quarter cylinder R5 about the axis (41, y, -5), between the wall and the land
    r = np.hypot(rad[:, 0] - 41.0, rad[:, 2] + 5.0)
    assert np.max(np.abs(r - p.die_radius)) < 1e-9
    assert rad[:, 0].min() >= 36.0 - 1e-9 and rad[:, 2].max() <= 1e-9
    assert np.all((rad[:, 1] >= -1e-9) & (rad[:, 1] <= 20.5 + 1e-9))
    assert np.max(np.abs(wall[:, 0] - 36.0)) < 1e-12 and wall[:, 2].min() >= -80 - 1e-9
    assert np.max(np.abs(land[:, 2])) < 1e-12 and land[:, 0].min() >= 41 - 1e-9 and land[:, 0].max() <= 190 + 1e-9


def test_punch_dimensions_in_file() -> None:
    p = UShapeParams()
    rad = _face_points(SAMPLES_DIR / "ushape_punch_nurbs.igs", 1)
    r = np.hypot(rad[:, 0] - 30.0, rad[:, 2] - (p.thickness + 5.0))
    assert np.max(np.abs(r - p.punch_radius)) < 1e-9
    bottom = _face_points(SAMPLES_DIR / "ushape_punch_nurbs.igs", 2)
    assert np.max(np.abs(bottom[:, 2] - p.thickness)) < 1e-12


def test_normals_face_the_sheet() -> None:
    """Su x Sv of every written surface points out of the tool, towards the blank."""
    from OCP.GeomLProp import GeomLProp_SLProps

    expect = {  # (file, face index): a point of the sheet side to look at
        ("die", 0): (-1, 0, 0), ("die", 2): (0, 0, 1), ("punch", 0): (1, 0, 0), ("punch", 2): (0, 0, -1),
        ("blankholder", 0): (0, 0, -1),
    }
    for (tool, i), direction in expect.items():
        face = occ_read(SAMPLES_DIR / f"ushape_{tool}_nurbs.igs")[i]
        u0, u1, v0, v1 = face.bounds
        props = GeomLProp_SLProps(face.surface, 0.5 * (u0 + u1), 0.5 * (v0 + v1), 1, 1e-9)
        n = np.array(props.Normal().Coord()) * (-1 if face.reversed else 1)
        assert np.allclose(n, direction, atol=1e-12), (tool, i, n)


def test_params_and_symmetry() -> None:
    p = UShapeParams()
    assert p.die_half_opening == 36.0 and p.punch_half_width == 35.0
    assert p.model_blankholder_force == pytest.approx(2.45 / 4)
    full = UShapeParams(symmetry_x=False, symmetry_y=False)
    faces = tool_faces(full)
    assert len(faces["die"]) == 6 and len(faces["punch"]) == 5 and len(faces["blankholder"]) == 2
    with pytest.raises(ValueError):
        UShapeParams(punch_radius=40.0)


def test_build_tools_are_shells() -> None:
    from OCP.TopAbs import TopAbs_FACE, TopAbs_SHELL
    from OCP.TopExp import TopExp_Explorer

    for name, shell in build_tools().items():
        assert shell.ShapeType() == TopAbs_SHELL
        exp, n = TopExp_Explorer(shell, TopAbs_FACE), 0
        while exp.More():
            n += 1
            exp.Next()
        assert n == len(FACE_LABELS[name])


def test_blank_mesh() -> None:
    p = UShapeParams()
    nodes, quads = blank_mesh(p, element_size=2.5)
    assert nodes.shape == (71 * 8, 3) and quads.shape == (70 * 7, 4)
    assert np.allclose(nodes[:, 2], p.thickness / 2)
    assert nodes[:, 0].max() == pytest.approx(175.0) and nodes[:, 1].max() == pytest.approx(17.5)
    a, b, c = nodes[quads[:, 0]], nodes[quads[:, 1]], nodes[quads[:, 2]]
    normals = np.cross(b - a, c - a)
    assert np.all(normals[:, 2] > 0)  # counter-clockwise seen from +z
    area = np.sum(np.linalg.norm(normals, axis=1))  # parallelogram = quad area (rectangles)
    assert area == pytest.approx(175.0 * 17.5)
