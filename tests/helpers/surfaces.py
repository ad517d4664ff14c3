"""NURBS test surfaces with known geometry: the rational quadratic circle arc, surfaces of
revolution about z built from it (exact cylinders, spheres, tori: closest points and normals in
closed form), and wavy random B-spline / NURBS patches."""

from __future__ import annotations

import math

import numpy as np

from cadbridge.nurbs.surface import NurbsSurface


def circle_arc(a0: float, a1: float, nseg: int | None = None):
    """Rational quadratic unit-circle arc from angle a0 to a1: (ctrl (n, 2), weights (n,), knots)."""
    if nseg is None:
        nseg = max(1, math.ceil(abs(a1 - a0) / (math.pi / 2) - 1e-12))
    d = (a1 - a0) / nseg
    ctrl, w = [], []
    for k in range(nseg):
        s, m = a0 + k * d, a0 + (k + 0.5) * d
        if k == 0:
            ctrl.append((math.cos(s), math.sin(s)))
            w.append(1.0)
        ctrl.append((math.cos(m) / math.cos(d / 2), math.sin(m) / math.cos(d / 2)))
        w.append(math.cos(d / 2))
        e = s + d
        ctrl.append((math.cos(e), math.sin(e)))
        w.append(1.0)
    knots = [0.0] * 3
    for k in range(1, nseg):
        knots += [k / nseg] * 2
    knots += [1.0] * 3
    return np.array(ctrl), np.array(w), np.array(knots)


def revolved(profile_xz, profile_w, profile_knots, profile_degree, a0=0.0, a1=2 * math.pi) -> NurbsSurface:
    """Surface of revolution about z of a profile in the xz-plane; u = angle direction, v = profile."""
    cc, cw, ck = circle_arc(a0, a1)
    prof = np.asarray(profile_xz, float)
    cp = np.empty((len(cc), len(prof), 3))
    cp[..., 0] = cc[:, None, 0] * prof[None, :, 0]
    cp[..., 1] = cc[:, None, 1] * prof[None, :, 0]
    cp[..., 2] = prof[None, :, 1]
    w = cw[:, None] * np.asarray(profile_w, float)[None, :]
    return NurbsSurface(2, profile_degree, ck, profile_knots, cp, w)


def cylinder(r=2.0, z0=-1.0, z1=3.0, a0=0.0, a1=2 * math.pi) -> NurbsSurface:
    return revolved([(r, z0), (r, z1)], [1, 1], [0, 0, 1, 1], 1, a0, a1)


def sphere(r=1.5, a0=0.0, a1=2 * math.pi, p0=-math.pi / 2, p1=math.pi / 2) -> NurbsSurface:
    pc, pw, pk = circle_arc(p0, p1)
    return revolved(r * pc, pw, pk, 2, a0, a1)


def torus(rmaj=3.0, rmin=1.0, a0=0.0, a1=2 * math.pi, p0=-math.pi, p1=math.pi) -> NurbsSurface:
    pc, pw, pk = circle_arc(p0, p1)
    prof = np.column_stack([rmaj + rmin * pc[:, 0], rmin * pc[:, 1]])
    return revolved(prof, pw, pk, 2, a0, a1)


def random_surface(rng, rational: bool, p=3, q=2, nu=7, nv=6, size=10.0, amp=0.25) -> NurbsSurface:
    """A wavy random B-spline/NURBS patch over [0, size]^2 with random interior knots."""

    def knots(n, d):
        inner = np.sort(rng.uniform(0.1, 0.9, n - d - 1))
        return np.concatenate([np.zeros(d + 1), inner, np.ones(d + 1)])

    gx, gy = np.meshgrid(np.linspace(0, size, nu), np.linspace(0, size, nv), indexing="ij")
    cp = np.stack([gx + rng.uniform(-0.3, 0.3, gx.shape), gy + rng.uniform(-0.3, 0.3, gy.shape),
                   rng.uniform(-amp * size, amp * size, gx.shape)], axis=-1)
    w = rng.uniform(0.5, 2.0, (nu, nv)) if rational else None
    return NurbsSurface(p, q, knots(nu, p), knots(nv, q), cp, w)
