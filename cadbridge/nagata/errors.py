"""Error analysis of Nagata surfaces (thesis §3.2, eqs. 14-17; §5 CAD comparison).

Analytic references: :class:`Plane`, :class:`Cylinder`, :class:`Sphere`, :class:`Torus`.

* radial error (eq. 16):  ((x - o) . n_analytical - r) / r * 100  [%]
  (o: axis point / centre / centre of the minor circle through x; for a plane the signed
  distance divided by ``Plane.scale``)
* normal error (eq. 17):  angle(n_Nagata, n_analytical)  [deg]
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cadbridge.nagata.patch import unit


class Surface(Protocol):
    def frame(self, points: NDArray) -> tuple[NDArray, NDArray, float]:
        """Centre o (M, 3), outward analytic unit normal (M, 3) and radius r at points."""
        ...


@dataclass(frozen=True)
class Plane:
    point: ArrayLike
    normal: ArrayLike
    scale: float = 1.0  # length dividing the signed distance in radial_error

    def frame(self, points: NDArray) -> tuple[NDArray, NDArray, float]:
        n = unit(np.asarray(self.normal, float))
        n = np.broadcast_to(n, points.shape)
        # o chosen so that (x - o) . n - r = signed distance, with r = scale
        o = np.asarray(self.point, float) - self.scale * n
        return o, n, self.scale


@dataclass(frozen=True)
class Cylinder:
    point: ArrayLike  # a point on the axis
    axis: ArrayLike
    radius: float

    def frame(self, points: NDArray) -> tuple[NDArray, NDArray, float]:
        a = unit(np.asarray(self.axis, float))
        w = points - np.asarray(self.point, float)
        o = np.asarray(self.point, float) + np.outer(w @ a, a)
        return o, unit(points - o), self.radius


@dataclass(frozen=True)
class Sphere:
    center: ArrayLike
    radius: float

    def frame(self, points: NDArray) -> tuple[NDArray, NDArray, float]:
        c = np.broadcast_to(np.asarray(self.center, float), points.shape)
        return c, unit(points - c), self.radius


@dataclass(frozen=True)
class Torus:
    center: ArrayLike
    axis: ArrayLike
    R: float  # major radius
    r: float  # minor radius

    def frame(self, points: NDArray) -> tuple[NDArray, NDArray, float]:
        a = unit(np.asarray(self.axis, float))
        c = np.asarray(self.center, float)
        w = points - c
        q = w - np.outer(w @ a, a)
        o = c + self.R * unit(q)  # centre of the minor circle through the point
        return o, unit(points - o), self.r


def radial_error(points: ArrayLike, surface: Surface) -> NDArray:
    """Radial error in % (thesis eq. 16; eq. 14 in 2D). points (M, 3) -> (M,)."""
    x = np.atleast_2d(np.asarray(points, float))
    o, n, r = surface.frame(x)
    return (np.einsum("ij,ij->i", x - o, n) - r) / r * 100.0


def angle_deg(a: NDArray, b: NDArray) -> NDArray:
    """Angle between unit-or-not vectors (M, 3) in degrees, accurate at small angles."""
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.einsum("ij,ij->i", a, b)))


def normal_error(normals: ArrayLike, points: ArrayLike, surface: Surface) -> NDArray:
    """Normal error in degrees (thesis eq. 17; eq. 15 in 2D). (M, 3), (M, 3) -> (M,)."""
    x = np.atleast_2d(np.asarray(points, float))
    _, n, _ = surface.frame(x)
    return angle_deg(np.atleast_2d(np.asarray(normals, float)), n)


def summarize(values: NDArray, bins: int = 10) -> dict:
    """max, min, mean and a histogram (counts, edges) of an error array."""
    counts, edges = np.histogram(values, bins=bins)
    return {
        "max": float(values.max()),
        "min": float(values.min()),
        "mean": float(values.mean()),
        "histogram": (counts, edges),
    }


@dataclass
class ErrorReport:
    """Per-point errors on the sampled grid of every patch plus summaries."""

    points: NDArray  # (M, 3)
    elem: NDArray  # (M,)
    eta: NDArray
    zeta: NDArray
    shape: NDArray  # (M,) radial error [%] or CAD shape error [length]
    normal: NDArray  # (M,) [deg]
    summary: dict = field(default_factory=dict)

    _ALIASES = {"shape_error": "shape", "radial_error": "shape", "normal_error": "normal"}

    def __getitem__(self, key: str) -> NDArray | dict:
        """Mapping access: report["shape_error"], report["normal_error"], report["points"] ..."""
        return getattr(self, self._ALIASES.get(key, key))


def patch_errors(nm, surface: Surface, n: int = 100, bins: int = 10) -> ErrorReport:
    """Radial (eq. 16) and normal (eq. 17) errors of a :class:`NagataMesh` against an
    analytic surface on a uniform grid of ``n`` divisions per parameter per patch."""
    g = nm.sample_grid(n)
    rad = radial_error(g.points, surface)
    nor = normal_error(g.normals, g.points, surface)
    return ErrorReport(
        g.points, g.elem, g.eta, g.zeta, rad, nor,
        {"radial": summarize(rad, bins), "normal": summarize(nor, bins)},
    )


def cad_errors(
    nm, project: Callable[[NDArray], tuple[NDArray, NDArray]], n: int = 20, bins: int = 10
) -> ErrorReport:
    """Errors of a :class:`NagataMesh` against a CAD model.

    ``project(points (M, 3)) -> (foot (M, 3), normal (M, 3))`` projects onto the CAD
    surfaces.  Shape error = (x - foot) . n_CAD (signed, length units); normal error =
    angle(n_Nagata, n_CAD) in degrees.
    """
    g = nm.sample_grid(n)
    foot, ncad = project(g.points)
    foot = np.asarray(foot, float)
    ncad = unit(np.asarray(ncad, float))
    # a CAD face's Su x Sv orientation is arbitrary: compare with the side the patch faces
    ncad = ncad * np.where(np.einsum("ij,ij->i", ncad, g.normals) < 0, -1.0, 1.0)[:, None]
    shape = np.einsum("ij,ij->i", g.points - foot, ncad)
    nor = angle_deg(g.normals, ncad)
    return ErrorReport(
        g.points, g.elem, g.eta, g.zeta, shape, nor,
        {"shape": summarize(shape, bins), "normal": summarize(nor, bins)},
    )
