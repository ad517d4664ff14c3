"""`cadbridge convert` on faces with singular points (issue 32, point 5): a cone apex, a sphere
pole and a revolved profile meeting its axis at 50 degrees (iges_samples/cone_apex.igs,
hemisphere_pole.igs, revolved_apex.igs), in both element types.

Before: the cone stopped in gmsh ("The 1D mesh seems not to be forming a closed loop", exit 2)
and, meshed, in an internal error ("surface error could not be measured") or "mesh straddles a
crease" (the apex node's normal was the limit along one arbitrary generatrix, reversed in the
elements on the other side); the revolved profile converted with a 7 mm surface error.

References: analytic geometry (the apex node's normal is the axis; the Nagata surface stays
within 0.2 % of the model size of the exact surface and below the flat mesh's error) and the
outputs themselves (no NaN in any file written).
"""

from __future__ import annotations

import re
from pathlib import Path

import meshio
import numpy as np
import pytest

from cadbridge.cli import EXIT_OK, main
from cadbridge.io.toolfile import read_toolfile

SAMPLES = Path(__file__).parents[2] / "iges_samples"
APEX = {"cone_apex.igs": (0.0, 0.0, 20.0), "hemisphere_pole.igs": (0.0, 0.0, 10.0), "revolved_apex.igs": (0.0, 0.0, 15.0)}
SIZE = {"cone_apex.igs": 34.0, "hemisphere_pole.igs": 30.0, "revolved_apex.igs": 52.0}  # bounding-box diagonals, rounded down


def _no_nan_written(out: Path) -> None:
    """No NaN (or inf) in any text file, any VTU array or the tool files' numbers."""
    for p in sorted(out.iterdir()):
        if p.suffix in (".vtu",):
            m = meshio.read(p)
            arrays = [m.points] + list(m.point_data.values()) + [a for v in m.cell_data.values() for a in v]
            assert all(np.all(np.isfinite(np.asarray(a, dtype=float))) for a in arrays), p.name
        elif p.suffix in (".nagata", ".txt", ".csv", ".md", ".igs", ".msh"):
            text = p.read_text(errors="replace")
            assert not re.search(r"(?i)\b(nan|inf|infinity)\b", text), p.name


def _convert(tmp_path: Path, name: str, element: str, capsys) -> Path:
    out = tmp_path / f"{Path(name).stem}_{element}"
    code = main(["convert", str(SAMPLES / name), "-o", str(out), "--element", element])
    _, err = capsys.readouterr()
    assert code == EXIT_OK, err
    return out


def _check(out: Path, name: str) -> None:
    _no_nan_written(out)
    (tool,) = sorted(out.glob("*.nagata"))
    t = read_toolfile(tool)
    i = int(np.argmin(np.linalg.norm(t.nodes - np.array(APEX[name]), axis=1)))
    assert np.linalg.norm(t.nodes[i] - np.array(APEX[name])) < 1e-9
    n = t.normals[i]
    assert abs(abs(n[2]) - 1.0) < 1e-14 and np.hypot(n[0], n[1]) < 1e-12  # the axis
    conn = [c for c in list(t.triangles) + list(t.quads)]
    at = {e for e, c in enumerate(conn) if i in c}
    assert not at & set(np.asarray(t.corner_element).tolist())  # one normal in all its elements
    m = meshio.read(next(out.glob("*_nagata.vtu")))
    surf, flat = np.abs(m.point_data["surface_error"]).max(), np.abs(m.point_data["flat_surface_error"]).max()
    assert surf < 2e-3 * SIZE[name] and surf < flat


@pytest.mark.parametrize("element", ["quad", "tri"])
def test_cone_apex_converts(tmp_path, capsys, element) -> None:
    _check(_convert(tmp_path, "cone_apex.igs", element, capsys), "cone_apex.igs")


@pytest.mark.slow
@pytest.mark.parametrize("element", ["quad", "tri"])
@pytest.mark.parametrize("name", ["hemisphere_pole.igs", "revolved_apex.igs"])
def test_pole_and_revolved_apex_convert(tmp_path, capsys, name, element) -> None:
    _check(_convert(tmp_path, name, element, capsys), name)
