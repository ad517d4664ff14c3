"""Parameter-space trim loops that wind round the axis of a surface of revolution more than once.

Class of defect: a damaged number in a 142's parameter-space curve (an angle 6.28 written
6.28E6) over a 120 surface of revolution made its trim loop wind a million turns; the
reader wrapped every angle into the face's range, and the trim loop's refinement
(`cadbridge.cad.trims.LoopBoundary`) halved its edges without end (convert gave no answer
in 60 s). A loop covers one turn at most: one that winds more is unusable, and the face is
trimmed by the file's model-space curves instead (a diagnostic says so).

Reference: the undamaged file (iges_samples/ushape_tools_analytic.igs, made by
iges_samples/make_samples.py): the damaged face's trim loop, from the model-space curves,
runs through the same points of model space as the intact face's, on two faces.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from cadbridge.iges import read_iges_string

SAMPLE = Path(__file__).resolve().parents[2] / "iges_samples" / "ushape_tools_analytic.igs"


def _damaged(text: str, line_de: int) -> str:
    """``text`` with the y2 (angle) field of the 110 line at DE ``line_de`` times 10^6 (the
    record laid out again on the same number of P lines)."""
    lines = text.splitlines()
    rows = [i for i, ln in enumerate(lines) if ln[72:73] == "P" and int(ln[64:72]) == line_de]
    fields = "".join(lines[i][:64] for i in rows).rstrip().rstrip(";").split(",")
    assert fields[0].strip() == "110" and float(fields[5]) != 0.0
    fields[5] = fields[5].strip() + "E6"
    chunks = re.findall(r".{1,64}(?:,|;)", ",".join(f.strip() for f in fields) + ";")
    assert len(chunks) == len(rows)
    for i, c in zip(rows, chunks):
        lines[i] = c.ljust(64) + lines[i][64:]
    return "\n".join(lines) + "\n"


def _loop_points(face, n=400) -> np.ndarray:
    """Model-space points (M, 3) along the face's outer trim loop."""
    pts = []
    for c in face.trims.outer.curves:
        t = np.linspace(*c.domain, n)
        uv = c.evaluate(t)[:, :2]
        pts.append(face.surface.evaluate(uv[:, 0], uv[:, 1]))
    return np.vstack(pts)


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance from a point of ``a`` to the nearest point of ``b``."""
    from scipy.spatial import cKDTree

    return float(cKDTree(b).query(a)[0].max())


@pytest.mark.parametrize("face_de, line_de", [(21, 35), (97, 111)])
def test_winding_pcurve_falls_back_to_model_space(face_de, line_de):
    text = SAMPLE.read_text()
    intact = {f.de: f for f in read_iges_string(text, "ok.igs").faces}[face_de]
    model = read_iges_string(_damaged(text, line_de), "bad.igs")
    face = {f.de: f for f in model.faces}[face_de]
    notes = [d.message for d in model.diagnostics if d.de == face_de]
    assert any("winds" in n and "model-space curves" in n for n in notes), notes
    a, b = _loop_points(face), _loop_points(intact)
    size = model.size()
    # the loops pass through the same points (sampling density ~ loop length / 400)
    assert _distance(a, b) < 2e-2 * size and _distance(b, a) < 2e-2 * size
    # and the sampled loop points lie on the intact loop's curves to round-off where they coincide
    assert np.median(np.linalg.norm(a[:, None] - b[None], axis=2).min(axis=1)) < 1e-6 * size
