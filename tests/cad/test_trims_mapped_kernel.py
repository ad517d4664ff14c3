"""The compiled path of exactly mapped trim curves (`cadbridge.cad.trims._kernel_form`: a
`MappedCurve`'s 2D base NURBS curve and its packed map, `_tcurve_ders_one`).

References:
- derivatives: the chain rule written out here in numpy over the base curve's own
  `NurbsCurve.derivatives` and the `ArcMap` objects (y = M c + b, n_k = pre_k(y_k),
  uv_j = post_j(n_src_j));
- trim decisions: `LoopBoundary.contains` on the numpy path (the same polygon, the curves'
  own ``derivatives``), which the compiled path must reproduce point for point.
Files: the analytic U-shape sample, the real SolidWorks part (39 mapped curves, skipped
when ../shared/iges_real is absent) and the analytic production die (when generated).
"""

import copy
from pathlib import Path

import numpy as np
import pytest

from cadbridge.iges import read_iges
from cadbridge.cad.analytic import MappedCurve
from cadbridge.cad.model import Face, Trim, TrimLoop
from cadbridge.cad.trims import LoopBoundary, curve_ders, project_to_trims

ROOT = Path(__file__).parents[2]
FILES = [ROOT / "iges_samples" / "ushape_tools_analytic.igs",
         ROOT.parent / "shared" / "iges_real" / "occt_bug22566_SolidWorks2010.igs"]
DIE = ROOT / "iges_samples" / "production_die_analytic.igs"


def mapped_faces(path):
    if not path.is_file():
        pytest.skip(f"{path} not present")
    out = [f for f in read_iges(path).faces if f.trims is not None and any(
        isinstance(c, MappedCurve) for lp in ([f.trims.outer] if f.trims.outer else []) + list(f.trims.inner)
        for c in lp.curves)]
    assert out
    return out


def mapped_loops(path):
    if not path.is_file():
        pytest.skip(f"{path} not present")
    out = []
    for f in read_iges(path).faces:
        t = f.trims
        for loop in ([] if t is None else ([t.outer] if t.outer else []) + list(t.inner)):
            if any(isinstance(c, MappedCurve) for c in loop.curves):
                out.append(loop)
    assert out
    return out


def chain(c: MappedCurve, t: np.ndarray) -> np.ndarray:
    """(N, 3, 2) derivatives of the mapped curve by the chain rule, over NurbsCurve.derivatives."""
    base = c.base.derivatives(t, 2)[:, :, :2]
    y = base @ c.m.T
    y[:, 0] += c.b

    def scalar(m, v):
        if m is None:
            return v
        f0, f1, f2 = m(v[:, 0], 2)
        return np.column_stack([f0, f1 * v[:, 1], f2 * v[:, 1] ** 2 + f1 * v[:, 2]])

    nat = np.stack([scalar(c.pre[k], y[:, :, k]) for k in (0, 1)], axis=2)
    return np.stack([scalar(m, nat[:, :, src]) for src, m in c.post], axis=2)


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.stem)
def test_compiled_derivatives_equal_chain_rule(path):
    rng = np.random.default_rng(1)
    n = 0
    for loop in mapped_loops(path):
        for c in loop.curves:
            if not isinstance(c, MappedCurve):
                continue
            t0, t1 = c.domain
            t = np.concatenate([rng.uniform(t0, t1, 40), [t0, t1], c.sample_parameters(3)])
            ref = chain(c, t)
            got = curve_ders(c, t, 2)
            scale = np.abs(ref).max(axis=(0, 2))  # per derivative order
            assert np.all(np.abs(got - ref).max(axis=2) <= 1e-13 * scale + 1e-300), c
            n += 1
    assert n > 0


class Plain:
    """A trim curve seen through its own ``derivatives`` only (no compiled form)."""

    def __init__(self, c):
        self.c, self.domain, self.degree, self.knots = c, c.domain, c.degree, c.knots

    def derivatives(self, t, order: int = 1) -> np.ndarray:
        return self.c.derivatives(t, order)

    def sample_parameters(self, per_span: int = 16) -> np.ndarray:
        return self.c.sample_parameters(per_span)


def decisions_agree(loops, per_loop: int, rng) -> int:
    """Points near each loop's curves (0 .. 1e-3 of the loop size off a curve point, both
    sides): compiled and numpy ``contains`` give the same inside / on flags."""
    checked = 0
    for loop in loops:
        bd = LoopBoundary(loop.curves)
        if bd._packed() is None:
            continue
        k = rng.integers(0, len(bd.a), per_loop)
        s = rng.random(per_loop)
        mid = bd.a[k] + s[:, None] * (bd.b[k] - bd.a[k])
        uv = mid + rng.normal(size=(per_loop, 2)) * (10.0 ** rng.uniform(-9, -3, per_loop))[:, None] * bd.size
        tol = 1e-7 * bd.size
        fast = bd.contains(uv, tol)
        ref = copy.copy(bd)  # the same polygon, decided on the numpy path
        ref.curves, ref._pack, ref._grids = [Plain(c) for c in bd.curves], None, {}
        slow = ref.contains(uv, tol)
        assert np.array_equal(fast[0], slow[0]) and np.array_equal(fast[1], slow[1])
        checked += per_loop
    return checked


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.stem)
def test_compiled_trim_decisions_equal_numpy(path):
    assert decisions_agree(mapped_loops(path), 400, np.random.default_rng(2)) > 0


@pytest.mark.slow
def test_compiled_trim_decisions_equal_numpy_analytic_die():
    loops = mapped_loops(DIE)
    rng = np.random.default_rng(3)
    assert decisions_agree([loops[i] for i in rng.choice(len(loops), 150, replace=False)], 200, rng) > 0


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.stem)
def test_project_to_trims_compiled_equals_numpy(path):
    """Nearest points of the trim loops: the compiled pairs kernel against the numpy steps
    (`curve_newton` and the curves' own derivatives), points up to 5 % of the face off it."""
    rng = np.random.default_rng(4)
    for face in mapped_faces(path):
        t = face.trims
        plain = Face(surface=face.surface, de=face.de, trims=Trim(
            TrimLoop([Plain(c) for c in t.outer.curves]) if t.outer else None,
            [TrimLoop([Plain(c) for c in lp.curves]) for lp in t.inner]))
        b = face.surface.bbox()
        size = float(np.linalg.norm(b[1] - b[0]))
        u0, u1, v0, v1 = face.surface.domain
        uv = rng.uniform([u0, v0], [u1, v1], (60, 2))
        pts = face.surface.evaluate(uv[:, 0], uv[:, 1]) + rng.normal(size=(60, 3)) * 0.05 * size
        fast = project_to_trims(face, pts)
        slow = project_to_trims(plain, pts)
        assert np.array_equal(fast[4], slow[4])
        ok = fast[4]
        assert np.all(np.abs(fast[3][ok] - slow[3][ok]) <= 1e-12 * size)
        assert np.all(np.abs(fast[2][ok] - slow[2][ok]) <= 1e-9 * size)
