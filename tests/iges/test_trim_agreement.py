"""Faces whose 2D and 3D trim curves contradict each other (`cadbridge.iges.trimcheck.check_trim_agreement`).

Class of defect: a damaged number in a surface's boundary poles (here a pole moved 10^6
times farther) leaves the file's model-space trim curves where they were, far off the
surface its parameter-space trims run on. cadbridge projected onto one boundary while gmsh
meshed the other, and on the quarter cylinder gmsh's surface mesher never returned.
`cadbridge convert` now refuses such a face before meshing, naming it.

Reference: the sample files as made (iges_samples/make_samples.py), whose 2D and 3D trims
agree to round-off, and the same files with one boundary pole moved; the real files of the
corpus all stay below 1.7e-3 x the model size (benchmarks: see CONTRADICTION).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from cadbridge.iges import IgesError, read_iges_string
from cadbridge.iges.trimcheck import CONTRADICTION, check_trim_agreement

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "iges_samples"
FILES = ["trimmed_hole.igs", "rational_quarter_cylinder.igs", "sphere_patch.igs"]


def _moved_pole(text: str, de: int = 3, factor_exp: int = 6) -> str:
    """``text`` with the last pole's largest coordinate of the 128 at DE ``de`` (a corner, on the boundary) times
    10^factor_exp (its
    record's reals located by counting the 128's fields: K1, K2, M1, M2, ..., knots, weights)."""
    lines = text.splitlines()
    rows = [i for i, ln in enumerate(lines) if ln[72:73] == "P" and int(ln[64:72]) == de]
    fields = []  # (line index, start, end) of every field of the record
    for i in rows:
        for m in re.finditer(r"[^,;]+", lines[i][:64]):
            if m.group(0).strip():
                fields.append((i, m.start(), m.end()))
    head = [float(lines[i][a:b]) for i, a, b in fields[:5]]
    k1, k2, m1, m2 = (int(x) for x in head[1:5])
    last_x = 10 + (k1 + m1 + 2) + (k2 + m2 + 2) + (k1 + 1) * (k2 + 1) + 3 * ((k1 + 1) * (k2 + 1) - 1)
    last_x = max(range(last_x, last_x + 3), key=lambda j: abs(float(lines[fields[j][0]][fields[j][1]:fields[j][2]])))
    i, a, b = fields[last_x]
    tok = lines[i][a:b].strip()
    em = re.search(r"[EeDd]([-+]?\d+)$", tok)
    new = f"{tok[:em.start()]}E{int(em.group(1)) + factor_exp}" if em else f"{tok}E{factor_exp}"
    line = lines[i][:64]
    line = (line[:a] + line[a:b].replace(tok, new) + line[b:]).rstrip()
    assert len(line) <= 64
    lines[i] = line.ljust(64) + lines[i][64:]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("name", FILES)
def test_sample_trims_agree(name):
    check_trim_agreement(read_iges_string((SAMPLES / name).read_text(), name))


@pytest.mark.parametrize("name", FILES)
def test_moved_boundary_pole_is_refused(name):
    model = read_iges_string(_moved_pole((SAMPLES / name).read_text()), name)  # still reads
    with pytest.raises(IgesError) as info:
        check_trim_agreement(model)
    err = info.value
    assert err.de == 1 and err.entity_type == 144 and str(err).startswith(f"{name} (DE 1, entity 144)")
    assert model.faces[0].trim_delta > CONTRADICTION * model.size()


def test_convert_refuses_before_meshing(tmp_path):
    """The quarter cylinder with a pole moved: exit 2, one line naming the face, nothing
    written (gmsh's surface mesher did not return on it)."""
    bad = tmp_path / "qcyl.igs"
    bad.write_text(_moved_pole((SAMPLES / "rational_quarter_cylinder.igs").read_text()))
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "cadbridge", "-q", "convert", str(bad), "-o", str(out)],
                       capture_output=True, text=True, cwd=ROOT, timeout=600)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "trim curves disagree" in lines[0], r.stderr
    assert not out.exists()
