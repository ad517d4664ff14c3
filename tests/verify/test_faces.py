"""`cadbridge verify`: our IGES reader against OpenCASCADE, face by face."""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from cadbridge.verify.reference import occ_read
from cadbridge.verify.faces import OccCrashError, _segfault, compare_models, run_isolated, verify

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "iges_samples"
REAL = ROOT.parent / "shared" / "iges_real"

read_iges = pytest.importorskip("cadbridge.iges").read_iges

CHAINED = ROOT / "tests" / "data" / "iges" / "placed_by_chained_124.igs"  # OCC 7.9 ignores a 124's own 124
SAMPLE_FILES = sorted(p.name for p in SAMPLES.glob("*.igs") if not p.name.startswith("production_die"))


@pytest.mark.parametrize("name", SAMPLE_FILES)
def test_every_sample_verifies(name: str) -> None:
    report = verify(SAMPLES / name, isolate=False)
    assert report.ok, report.format()
    assert len(report.faces) == report.n_occ_faces


def test_chained_124_our_reading_follows_the_standard() -> None:
    spec = importlib.util.spec_from_file_location("make_samples", SAMPLES / "make_samples.py")
    ms = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ms)
    model = read_iges(CHAINED)
    (face,) = model.faces
    bs = ms.quarter_cylinder()
    rot = {k: (np.array(ms._rotation(*v[:2])), np.array(v[2])) for k, v in ms.PLACEMENTS.items()}
    (r1, t1), (r2, t2) = rot["T1"], rot["T2"]
    u = np.linspace(0.0, np.pi / 2, 9)
    v = np.linspace(0.0, 20.5, 9)
    raw = np.array([bs.Value(a, b).Coord() for a, b in zip(u, v)])
    expected = (r1 @ (r2 @ raw.T + t2[:, None]) + t1[:, None]).T  # T1(T2(x))
    assert np.allclose(face.surface.evaluate(u, v), expected, atol=1e-12)
    report = verify(CHAINED, isolate=False)
    assert not report.ok and report.faces[0].mode == "geometric"  # OCC's placement differs


def test_perturbed_model_fails_on_the_right_face() -> None:
    path = SAMPLES / "ushape_die_nurbs.igs"
    model = read_iges(path)
    occ = occ_read(path)
    assert compare_models(model, occ).ok
    target = 1  # the shoulder radius
    s = model.faces[target].surface
    cp = np.array(s.control_points)
    cp[1, 0] += [0.0, 0.0, 1e-3]  # move one control point by 1 micrometre
    moved = type(s)(s.degree_u, s.degree_v, s.knots_u, s.knots_v, cp, s.weights, s.domain)
    model.faces[target] = dataclasses.replace(model.faces[target], surface=moved)
    report = compare_models(model, occ)
    assert not report.ok
    assert [f.index for f in report.failed()] == [target]
    bad = report.failed()[0]
    assert bad.de == model.faces[target].de and bad.pos_dev > 1e-9
    assert "FAIL" in report.format()


def test_missing_face_is_reported() -> None:
    path = SAMPLES / "ushape_tools_nurbs.igs"
    model = read_iges(path)
    del model.faces[3]
    report = compare_models(model, occ_read(path))
    assert not report.ok and report.unmatched_occ == [3]
    assert all(f.passed for f in report.faces)


def test_isolated_verify_matches_in_process() -> None:
    path = SAMPLES / "torus_patch.igs"
    a = verify(path, isolate=True)
    b = verify(path, isolate=False)
    assert a.ok and b.ok and a.faces[0].pos_dev == b.faces[0].pos_dev


def test_crash_in_subprocess_is_reported() -> None:
    with pytest.raises(OccCrashError, match="crash.igs"):
        run_isolated(_segfault, "x", what="crash.igs")


def test_unit_conversion(tmp_path: Path) -> None:
    """A file in inches: OCC converts to mm, we scale by Units.to_mm; both must agree."""
    text = (SAMPLES / "thesis_appendix_a.igs").read_text()
    inch = tmp_path / "inch.igs"
    inch.write_text(text.replace("1.0,2,2HMM,", "1.0,1,2HIN,"))
    report = verify(inch, isolate=False)
    assert report.ok, report.format()
    assert report.size == pytest.approx(25.4 * read_iges(SAMPLES / "thesis_appendix_a.igs").size())


REAL_FILES = sorted(REAL.glob("*.ig*s")) if REAL.is_dir() else []


@pytest.mark.skipif(not REAL_FILES, reason="../shared/iges_real not present")
@pytest.mark.parametrize("path", REAL_FILES, ids=lambda p: p.name)
def test_real_files(path: Path) -> None:
    report = verify(path, isolate=False)
    assert report.ok, report.format()
