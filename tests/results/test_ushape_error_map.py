"""U-shape end to end (issue 9): the Nagata shape error that `cadbridge ushape` writes
(die/die_nagata.vtu, point data surface_error) mapped onto the die CAD with `cadbridge map`.
References: the die's analytic face areas (wall 75 x 20.5, radius 5 pi / 2 x 20.5, land
149 x 20.5) and the shape error's own extremes."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytestmark = pytest.mark.slow


def test_nagata_shape_error_on_the_die(tmp_path):
    """The bands of the shape error cover the die exactly (their areas add up to the analytic
    face areas, rel 1e-9), the top level is the largest error, the lines stay on the radius
    (where the error lives, between the planes' zero) and run across the whole width."""
    from cadbridge.cli import main
    from cadbridge.ushape.benchmark import run_ushape

    us = tmp_path / "ushape"
    run_ushape(str(us))
    import meshio

    err = meshio.read(us / "die" / "die_nagata.vtu").point_data["surface_error"]
    out = tmp_path / "map"
    assert main(["map", str(us / "die" / "die_nagata.vtu"), "--cad", str(us / "cad" / "die.igs"),
                 "--field", "surface_error", "-o", str(out), "--levels", "6"]) == 0
    s = json.loads((out / "summary.json").read_text())
    total = sum(b["area"] for b in s["bands"])
    assert np.isclose(total, (75.0 + 5.0 * np.pi / 2 + 149.0) * 20.5, rtol=1e-9)
    assert np.isclose(s["levels"][-1], err.max(), rtol=1e-12)
    assert s["max_joint_gap"] <= 1e-9 * 200.0
    lines = (out / "lines.csv").read_text().splitlines()[1:]
    faces = {row.split(",")[-1] for row in lines}
    assert faces <= {"1", "0 1", "1 2", "0 1 2"}  # every line touches the radius (face 1)
    assert np.all([float(row.split(",")[4]) >= 20.5 - 1e-9 for row in lines])  # across the width
