"""Triangle mesh quality against the ideal isotropic lattice (Herrero Adan & Cardoso 2020).

Applies to any triangle mesh (QIT's, gmsh's, a user's): angles, sizes and vertex valences
as frequency histograms, the Bounded Isotropic Triangulation (BIT) of the same mesh
(appendix C: Table C.1, eq. C.3) and the quality index Q (eq. 21).

Interval widths (the paper does not state them; chosen here and fixed):

* angles: bins of ``ANGLE_BIN`` = 10 degrees centred on multiples of 10; the "60 degree"
  interval is [55, 65) (docs/qit.md, choice 6: with it the valence and angle frequencies
  of the paper's examples come closest to the printed ones).
* sizes: triangle area over A_BIT = R^2 sqrt(3)/4 (the equilateral triangle of side R, the
  target size), bins of ``SIZE_BIN`` = 0.1 centred on multiples of 0.1; the BIT interval
  is [0.95, 1.05).
* valences (number of triangles at a vertex, the paper's definition): one bin per integer.

Other choices: C.3 gives complex rb, cb when t_a > s_a^2 / 8 (the boundary is too short
for a rhomboid of t_a triangles); the discriminant is clamped at 0 (rb = cb = s_a / 4, the
most compact rhomboid). rb, cb are kept real (not rounded), so the BIT valence frequencies
of Table C.1 vary smoothly with the mesh. The valence terms of eq. 21 are printed as
f_a / f_b with f_a < f_b in all three examples; a mesh with more valence-3 (or -6) vertices
than its BIT would score above 25, so each ratio is taken as min(f_a, f_b) / max(f_a, f_b).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ANGLE_BIN", "SIZE_BIN", "BitReference", "MeshQuality", "bit_reference", "mesh_quality", "q_index"]

ANGLE_BIN = 10.0  # degrees
SIZE_BIN = 0.1  # fraction of A_BIT


@dataclass(frozen=True)
class BitReference:
    """The BIT of a mesh with ``ta`` triangles and ``sa`` boundary segments (appendix C).

    rb, cb : rows and columns (eq. C.3, real); valence_freq : {valence: percent of vertices}
    (Table C.1); clamped : True where the discriminant of C.3 was negative.
    """

    ta: int
    sa: int
    rb: float
    cb: float
    valence_freq: dict[int, float]
    clamped: bool


def bit_reference(ta: int, sa: int) -> BitReference:
    """BIT rows/columns from C.3 (rb, cb = sa/4 +- sqrt(sa^2/16 - ta/2)) and its valence
    frequencies from Table C.1, in percent of the BIT's (cb+1)(rb+1) vertices."""
    disc = sa * sa / 16.0 - ta / 2.0
    clamped = disc < 0
    r = np.sqrt(max(disc, 0.0))
    rb, cb = sa / 4.0 + r, sa / 4.0 - r
    counts = {1: 2.0, 2: 2.0, 3: 2.0 * ((cb - 1) + (rb - 1)), 4: 0.0, 5: 0.0, 6: (cb - 1) * (rb - 1)}
    counts = {k: max(v, 0.0) for k, v in counts.items()}
    tot = sum(counts.values())
    freq = {k: 100.0 * v / tot for k, v in counts.items()} if tot > 0 else {k: 0.0 for k in counts}
    return BitReference(int(ta), int(sa), float(rb), float(cb), freq, bool(clamped))


def q_index(f_size: float, f_angle: float, f_v3a: float, f_v3b: float, f_v6a: float, f_v6b: float) -> float:
    """Quality index Q in percent (eq. 21) from frequencies in percent:
    Q = 25 fsa/100 + 25 fna/100 + 25 fv3a/fv3b + 25 fv6a/fv6b (valence ratios as min/max)."""

    def ratio(a: float, b: float) -> float:
        hi = max(a, b)
        return 1.0 if hi <= 0 else min(a, b) / hi

    return 25.0 * f_size / 100.0 + 25.0 * f_angle / 100.0 + 25.0 * ratio(f_v3a, f_v3b) + 25.0 * ratio(f_v6a, f_v6b)


@dataclass
class MeshQuality:
    """Quality report of one triangle mesh.

    angles (3E,) degrees; areas (E,); valence (N,) triangles per used vertex;
    angle_hist / size_hist / valence_hist : {bin centre: percent}; f_angle, f_size : percent
    in the 60-degree / A_BIT interval; bit : `BitReference`; q : eq. 21 in percent;
    size : the target edge length R the sizes are measured against.
    """

    size: float
    n_triangles: int
    n_vertices: int
    n_boundary_segments: int
    angles: np.ndarray
    areas: np.ndarray
    valence: np.ndarray
    f_angle: float
    f_size: float
    bit: BitReference
    q: float
    angle_hist: dict[float, float] = field(default_factory=dict)
    size_hist: dict[float, float] = field(default_factory=dict)
    valence_hist: dict[int, float] = field(default_factory=dict)

    def valence_freq(self, k: int) -> float:
        return self.valence_hist.get(int(k), 0.0)

    def summary(self) -> dict:
        """Plain numbers for tables/JSON: Q, its four terms' inputs, angle and size spread."""
        rel = self.areas / (self.size**2 * np.sqrt(3.0) / 4.0)
        return {
            "q": self.q,
            "triangles": self.n_triangles,
            "vertices": self.n_vertices,
            "f_size": self.f_size,
            "f_angle": self.f_angle,
            "f_v3": self.valence_freq(3),
            "f_v3_bit": self.bit.valence_freq[3],
            "f_v6": self.valence_freq(6),
            "f_v6_bit": self.bit.valence_freq[6],
            "angle_min": float(self.angles.min()),
            "angle_max": float(self.angles.max()),
            "angle_std": float(self.angles.std()),
            "size_rel_std": float(rel.std()),
            "size_rel_min": float(rel.min()),
            "size_rel_max": float(rel.max()),
        }


def _hist(values: np.ndarray, width: float) -> dict[float, float]:
    k = np.floor(values / width + 0.5).astype(np.int64)
    ks, cnt = np.unique(k, return_counts=True)
    return {float(round(a * width, 10)): 100.0 * c / len(values) for a, c in zip(ks, cnt)}


def triangle_angles(nodes: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Interior angles (E, 3) in degrees, angle i at vertex i."""
    p = nodes[tris]  # (E, 3, 3)
    out = np.empty(tris.shape)
    for i in range(3):
        a = p[:, (i + 1) % 3] - p[:, i]
        b = p[:, (i + 2) % 3] - p[:, i]
        c = np.linalg.norm(np.cross(a, b), axis=1)
        out[:, i] = np.degrees(np.arctan2(c, np.einsum("ij,ij->i", a, b)))
    return out


def boundary_segments(tris: np.ndarray) -> int:
    """Number of edges used by exactly one triangle."""
    e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    _, cnt = np.unique(e, axis=0, return_counts=True)
    return int(np.sum(cnt == 1))


def mesh_quality(nodes: np.ndarray, tris: np.ndarray, size: float) -> MeshQuality:
    """Quality report (histograms, BIT, Q) of triangles ``tris`` (E, 3) on ``nodes`` (N, 3)
    against the target edge length ``size`` (R, model units)."""
    nodes = np.asarray(nodes, dtype=float)
    tris = np.asarray(tris, dtype=np.int64)
    if tris.ndim != 2 or tris.shape[1] != 3 or len(tris) == 0:
        raise ValueError(f"mesh_quality needs (E, 3) triangles, got shape {tris.shape}")
    if not size > 0:
        raise ValueError(f"size must be positive, got {size!r}")
    ang = triangle_angles(nodes, tris).ravel()
    p = nodes[tris]
    areas = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    a_bit = size * size * np.sqrt(3.0) / 4.0
    rel = areas / a_bit
    used, val = np.unique(tris, return_counts=True)
    sa = boundary_segments(tris)
    bit = bit_reference(len(tris), sa)
    f_angle = 100.0 * np.mean((ang >= 60.0 - ANGLE_BIN / 2) & (ang < 60.0 + ANGLE_BIN / 2))
    f_size = 100.0 * np.mean((rel >= 1.0 - SIZE_BIN / 2) & (rel < 1.0 + SIZE_BIN / 2))
    ks, cnt = np.unique(val, return_counts=True)
    vh = {int(k): 100.0 * c / len(val) for k, c in zip(ks, cnt)}
    q = q_index(f_size, f_angle, vh.get(3, 0.0), bit.valence_freq[3], vh.get(6, 0.0), bit.valence_freq[6])
    return MeshQuality(float(size), len(tris), len(used), sa, ang, areas, val, float(f_angle), float(f_size), bit,
                       float(q), _hist(ang, ANGLE_BIN), _hist(rel, SIZE_BIN), vh)
