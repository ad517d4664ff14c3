"""Outputs of big tools (issue 8, production die): the per-patch listings only up to
`cadbridge.tool.outputs.LISTING_MAX_ELEMENTS` elements unless ``full_report``.

References: the tool file read back (its COEFFICIENTS equal the listing's), the file list of
a run with the listings.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import cadbridge.tool.outputs as O
import cadbridge.tool.pipeline as P
from cadbridge.io.csvgrid import read_coefficients_listing
from cadbridge.io.toolfile import read_toolfile

SAMPLES = Path(__file__).resolve().parents[2] / "iges_samples"


def test_listings_above_the_limit_only_with_full_report(tmp_path, monkeypatch):
    cad = SAMPLES / "ushape_die_nurbs.igs"
    full = P.convert(cad, tmp_path / "full", element="quad")
    names = set(full.files)
    assert {"die_grid.csv", "die_coefficients.txt", "die_nagata.igs"} <= names
    monkeypatch.setattr(O, "LISTING_MAX_ELEMENTS", 10)  # the die has 185 quads: now a "big" tool
    small = P.convert(cad, tmp_path / "small", element="quad")
    assert set(small.files) == names - {"die_grid.csv", "die_coefficients.txt", "die_nagata.igs"}
    assert not (tmp_path / "small" / "die_grid.csv").exists()
    assert any("--full-report" in n for n in small.notes)
    again = P.convert(cad, tmp_path / "again", element="quad", full_report=True)
    assert set(again.files) == names and not any("--full-report" in n for n in again.notes)
    # the tool file is the same either way, and holds the listing's coefficients
    a, b = read_toolfile(tmp_path / "full" / "die.nagata"), read_toolfile(tmp_path / "small" / "die.nagata")
    np.testing.assert_array_equal(a.quad_coefficients, b.quad_coefficients)
    _, quad = read_coefficients_listing(tmp_path / "full" / "die_coefficients.txt")
    np.testing.assert_array_equal(quad, a.quad_coefficients)
