"""Real IGES files from seven CAD systems (../shared/iges_real, OCCT test data): we read each
without error, and OpenCASCADE's IGES reader is the reference for the face count and for
the geometry (our face points lie on OCC's faces)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cadbridge.iges import read_iges
from tests.helpers import occ as OCC

REAL = Path(__file__).parents[2].parent / "shared" / "iges_real"
FILES = sorted(REAL.glob("*.ig*")) if REAL.is_dir() else []

pytestmark = pytest.mark.skipif(not FILES, reason=f"{REAL} not present")


@pytest.mark.parametrize("path", FILES, ids=[p.name for p in FILES])
def test_real_file(path: Path):
    """Face count equals OCC's (faces we would skip with a diagnostic are counted: ours +
    skipped == OCC's; none are skipped in these seven files now). Three
    random (u, v) per face lie on the corresponding OCC face within 1e-9 x model size:
    paired by order, OCC's surface evaluated at the same (u, v) (OCC keeps the 128
    parametrisation); failing that (analytic surfaces, which OCC parametrises its own way),
    the distance to the nearest OCC surface by orthogonal projection. Both readers work in the file's units
    (all seven files are in mm, which is OCC's default unit)."""
    m = read_iges(path)
    assert len(m.faces) > 0
    assert m.units.to_mm == 1.0
    pytest.importorskip("OCP")
    occ = OCC.read_surfaces(path)  # location applied
    skipped = sum("face skipped" in d.message for d in m.diagnostics)
    assert len(m.faces) + skipped == len(occ)
    size = m.size()
    rng = np.random.default_rng(0)
    paired = len(m.faces) == len(occ)
    for k, face in enumerate(m.faces):
        u0, u1, v0, v1 = face.surface.domain
        u, v = u0 + (u1 - u0) * rng.random(3), v0 + (v1 - v0) * rng.random(3)
        for uu, vv, x in zip(u, v, face.surface.evaluate(u, v)):
            d = np.inf
            if paired:
                p = occ[k].Value(float(uu), float(vv))
                d = float(np.linalg.norm([p.X() - x[0], p.Y() - x[1], p.Z() - x[2]]))
            if d > 1e-9 * size:  # OCC ordered differently: nearest OCC surface
                d = min(OCC.surface_distance(s, x) for s in occ)
            assert d <= 1e-9 * size, (face.de, face.entity_type, d, size)


def test_real_files_details():
    """Spot checks against the files' own text: ANSA trimmed faces (144 over 128, degrees
    (2,3)/(1,3)), C3D subfigure instances (4 instances x 10 faces, named 'Bann' by 406),
    SolidWorks colour 314 and Euclid 213 trimmed faces."""
    by = {p.name: p for p in FILES}
    ansa = read_iges(by["occt_OCC131-2_ANSA9.igs"])
    assert [f.entity_type for f in ansa.faces] == [144] * 3
    assert all(f.trims is not None and f.trims.outer is not None for f in ansa.faces)
    assert {(f.surface.degree_u, f.surface.degree_v) for f in ansa.faces} <= {(2, 3), (1, 3), (3, 2), (3, 1)}
    c3d = read_iges(by["occt_bug33327_C3D.igs"])
    assert len(c3d.faces) == 40 and {f.name for f in c3d.faces} == {"Bann"}
    assert c3d.entity_counts[408] == 6 and c3d.entity_counts[308] == 3
    sw = read_iges(by["occt_bug22566_SolidWorks2010.igs"])
    assert sw.faces[0].color is not None and sw.system == "SolidWorks 2010"
    eu = read_iges(by["occt_bearing_EuclidQuantum.iges"])
    assert len(eu.faces) == 213 and all(f.trims is not None for f in eu.faces)
    assert 402 in {t for t, _, _ in eu.raw.values()}
