"""Element count estimated before meshing (`cadbridge.mesh.element_count`), and the refusal
of a size that would explode.

References: analytic areas of the sample faces (iges_samples/README.md: a 100 x 60 plate with
a hole R10; a sphere patch R10 over 90 degrees of longitude and 0..60 degrees of latitude),
and the element count of gmsh's own mesh of the plate at a moderate size.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest

from cadbridge.iges import read_iges
from cadbridge.mesh.element_count import MAX_ELEMENTS, check_element_count, estimated_elements, face_areas
from cadbridge.mesh.mesh import MeshError

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "iges_samples"


@pytest.mark.parametrize("name, area", [
    ("trimmed_hole.igs", 100.0 * 60.0 - math.pi * 10.0 ** 2),
    ("sphere_patch.igs", 10.0 ** 2 * (math.pi / 2) * math.sin(math.radians(60.0))),
])
def test_face_areas_against_analytic(name, area):
    assert face_areas(read_iges(SAMPLES / name)).sum() == pytest.approx(area, rel=0.01)


@pytest.mark.parametrize("element", ["tri", "quad"])
def test_estimate_against_gmsh(element):
    """gmsh's mesh of the plate at size 4 has about as many elements as estimated: the
    estimate is from below (curvature refines), within a factor 1.6."""
    from cadbridge.mesh.generate import mesh_cad

    model = read_iges(SAMPLES / "trimmed_hole.igs")
    est = float(estimated_elements(model, 4.0, element).sum())
    n = mesh_cad(SAMPLES / "trimmed_hole.igs", element=element, size=4.0).n_elements
    assert 0.8 * est <= n <= 1.6 * est, (n, est)


def test_size_far_too_small_is_refused_with_the_number():
    model = read_iges(SAMPLES / "trimmed_hole.igs")
    check_element_count(model, 1.0)  # about 5 700 quads: fine
    with pytest.raises(MeshError) as info:
        check_element_count(model, 1e-3)
    msg = str(info.value)
    # 5 686 / 1e-6 = 5.7e9 quads, all on the plate (DE 1)
    assert "about 5.7e+09 elements" in msg and "DE 1" in msg and f"{MAX_ELEMENTS:.0e}" in msg
    least = float(msg.rsplit(" ", 1)[1])
    check_element_count(model, least * 1.01)  # the size it suggests is within the limit


def test_convert_refuses_before_meshing(tmp_path):
    """`cadbridge convert --size` far too small: exit 2, one line with the estimate, nothing
    written (before: gmsh meshed for minutes towards 10^10 elements)."""
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "cadbridge", "-q", "convert", str(SAMPLES / "trimmed_hole.igs"),
                        "-o", str(out), "--size", "0.001"], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "would make about 5.7e+09 elements" in lines[0], r.stderr
    assert not out.exists()
