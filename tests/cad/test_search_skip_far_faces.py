"""`project_points` skips the checks (restarts) of candidate pairs whose face lies farther
(box / slab bound) than a known foot inside a face: the result must be bit for bit that of
the search with every check run. Reference: the same search with the skip disabled
(`_known_distance` replaced by +inf, so no pair is hopeless), on the production die sample
(1 102 trimmed faces, fillets meeting at trim edges) and the U-shape tools."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import cadbridge.cad.search as search
from cadbridge.iges import read_iges
from cadbridge.cad.search import index_for, project_points

SAMPLES = Path(__file__).resolve().parents[2] / "iges_samples"
REAL = Path(__file__).resolve().parents[3] / "shared" / "iges_real"
FIELDS = ("face", "u", "v", "foot", "distance", "normal", "status", "candidates")


def _points_near_faces(model, n_per_face: int, seed: int) -> np.ndarray:
    """Points on random faces at random (u, v), pushed off along the normal by up to 1 % of
    the model size (both sides), some beyond trim edges (the (u, v) ignore the trims)."""
    rng = np.random.default_rng(seed)
    size = model.size()
    pts = []
    for f in rng.choice(len(model.faces), size=min(len(model.faces), 60), replace=False):
        s = model.faces[f].surface
        u0, u1, v0, v1 = s.domain
        u, v = rng.uniform(u0, u1, n_per_face), rng.uniform(v0, v1, n_per_face)
        off = rng.uniform(-0.01, 0.01, n_per_face) * size
        off[: n_per_face // 4] = rng.uniform(-1e-6, 1e-6, n_per_face // 4) * size  # near the model: chord sags
        pts.append(s.evaluate(u, v) + off[:, None] * s.normal(u, v))
    return np.concatenate(pts)


def _both(model, pts, monkeypatch):
    idx = index_for(model)
    skipped = []
    finish = search._Pairs.finish

    def counting(self, rows):
        r = np.flatnonzero(rows) if rows.dtype == bool else rows
        skipped.append(len(r))
        return finish(self, rows)

    monkeypatch.setattr(search._Pairs, "finish", counting)
    fast = project_points(pts, model, index=idx)
    n_fast = sum(skipped)
    skipped.clear()
    monkeypatch.setattr(search, "_known_distance", lambda n, pairs: np.full(n, np.inf))
    full = project_points(pts, model, index=idx)
    return fast, full, n_fast, sum(skipped)


@pytest.mark.parametrize("path, per_face", [
    pytest.param(SAMPLES / "production_die_nurbs.igs", 12, marks=pytest.mark.slow),  # read + index: 10 s
    (SAMPLES / "ushape_tools_nurbs.igs", 300),
    (REAL / "occt_bearing_EuclidQuantum.iges", 40),
], ids=lambda x: getattr(x, "name", str(x)))
def test_skipping_hopeless_checks_changes_nothing(path, per_face, monkeypatch):
    if not path.is_file():
        pytest.skip(f"{path} absent")
    model = read_iges(path)
    pts = _points_near_faces(model, per_face, seed=11)
    fast, full, rows_fast, rows_full = _both(model, pts, monkeypatch)
    for f in FIELDS:
        a, b = getattr(fast, f), getattr(full, f)
        assert a.dtype == b.dtype and a.shape == b.shape, f
        assert a.tobytes() == b.tobytes(), f  # bit for bit, NaN included
    assert rows_fast < rows_full  # the skip did happen: fewer pairs were checked
