"""Curvatures of one NURBS surface from its analytic first and second derivatives.

With S_u, S_v, S_uu, S_uv, S_vv at (u, v) and the unit normal n = S_u x S_v / |S_u x S_v|:

    first fundamental form   E = S_u.S_u,  F = S_u.S_v,  G = S_v.S_v
    second fundamental form  L = S_uu.n,   M = S_uv.n,   N = S_vv.n

The normal curvature in the parameter direction (du, dv) is

    k_n = (L du^2 + 2 M du dv + N dv^2) / (E du^2 + 2 F du dv + G dv^2)     (Euler / Meusnier)

and the principal curvatures are the eigenvalues of the shape operator W = I^-1 II:
mean H = (E N - 2 F M + G L) / (2 (E G - F^2)), Gaussian K = (L N - M^2) / (E G - F^2),
k1,2 = H +- sqrt(H^2 - K) (do Carmo §3.3). Signs follow n = S_u x S_v: a curvature is
positive where the surface bends towards n. Lengths in model units, curvature in 1/length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["FundamentalForms", "fundamental_forms", "normal_curvature", "principal_curvatures"]


@dataclass
class FundamentalForms:
    """Per point (N,): E, F, G (first form), L, M, N (second form); su, sv, n (N, 3)."""

    E: NDArray
    F: NDArray
    G: NDArray
    L: NDArray
    M: NDArray
    N: NDArray
    su: NDArray
    sv: NDArray
    n: NDArray


def fundamental_forms(surface: NurbsSurface, u: ArrayLike, v: ArrayLike, side_u=None, side_v=None) -> FundamentalForms:
    """First and second fundamental forms at (u, v) (N,), from analytic derivatives."""
    u = np.atleast_1d(np.asarray(u, dtype=float))
    v = np.atleast_1d(np.asarray(v, dtype=float))
    der = surface.derivatives(u, v, order=2, side_u=side_u, side_v=side_v)  # (N, 3, 3, 3)
    su, sv = der[:, 1, 0], der[:, 0, 1]
    suu, suv, svv = der[:, 2, 0], der[:, 1, 1], der[:, 0, 2]
    n = np.cross(su, sv)
    ln = np.linalg.norm(n, axis=1)
    n = n / np.where(ln > 0, ln, 1.0)[:, None]
    dot = lambda a, b: np.einsum("ij,ij->i", a, b)  # noqa: E731
    return FundamentalForms(dot(su, su), dot(su, sv), dot(sv, sv), dot(suu, n), dot(suv, n), dot(svv, n), su, sv, n)


def normal_curvature(surface: NurbsSurface, u: ArrayLike, v: ArrayLike, du: ArrayLike, dv: ArrayLike,
                     forms: FundamentalForms | None = None) -> NDArray:
    """Signed normal curvature (N,) [1/length] at (u, v) in the parameter direction (du, dv)."""
    f = forms or fundamental_forms(surface, u, v)
    du = np.asarray(du, dtype=float)
    dv = np.asarray(dv, dtype=float)
    num = f.L * du * du + 2 * f.M * du * dv + f.N * dv * dv
    den = f.E * du * du + 2 * f.F * du * dv + f.G * dv * dv
    return num / np.where(den > 0, den, np.inf)


def principal_curvatures(surface: NurbsSurface, u: ArrayLike, v: ArrayLike,
                         directions: bool = False, forms: FundamentalForms | None = None):
    """Principal curvatures k1 >= k2 (N,) [1/length] at (u, v) (N,); with ``directions``
    also the unit principal directions d1, d2 (N, 3) in model space (tangent to the surface).

    At umbilics (k1 = k2, e.g. planes, spheres) any tangent direction is principal: d1 is
    then S_u / |S_u|. Degenerate points (S_u x S_v = 0) give NaN curvatures.
    """
    f = forms or fundamental_forms(surface, u, v)
    det = f.E * f.G - f.F ** 2
    bad = ~(det > 1e-300)
    det = np.where(bad, 1.0, det)
    H = (f.E * f.N - 2 * f.F * f.M + f.G * f.L) / (2 * det)
    K = (f.L * f.N - f.M ** 2) / det
    root = np.sqrt(np.maximum(H * H - K, 0.0))
    k1, k2 = H + root, H - root
    k1 = np.where(bad, np.nan, k1)
    k2 = np.where(bad, np.nan, k2)
    if not directions:
        return k1, k2
    # eigenvector of W = I^-1 II for k1: (II - k I) (a, b) = 0 -> take the better-conditioned row
    r1 = np.stack([f.M - k1 * f.F, -(f.L - k1 * f.E)], axis=1)  # from row 1: (L - kE) a + (M - kF) b = 0
    r2 = np.stack([f.N - k1 * f.G, -(f.M - k1 * f.F)], axis=1)  # row 2: (M - kF) a + (N - kG) b = 0
    ab = np.where((np.linalg.norm(r1, axis=1) >= np.linalg.norm(r2, axis=1))[:, None], r1, r2)
    umb = np.linalg.norm(ab, axis=1) <= 1e-12 * (np.abs(k1) + 1e-300) * np.sqrt(f.E * f.G + 1e-300)
    ab = np.where(umb[:, None] | ~np.isfinite(ab), np.array([1.0, 0.0]), ab)
    d1 = ab[:, :1] * f.su + ab[:, 1:] * f.sv
    d1 /= np.linalg.norm(d1, axis=1)[:, None]
    d2 = np.cross(f.n, d1)
    return k1, k2, d1, d2
