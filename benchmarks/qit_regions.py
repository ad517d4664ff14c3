"""Where QIT's triangles miss the BIT intervals: Q's four terms and the size / angle hits by
region, for the paper's examples (Herrero Adan & Cardoso 2020, appendix D).

Regions (by triangle centroid): the edge strip (within 2 R of the mesh boundary, 3D
distance to its boundary segments), the doubly curved corner of Ex. 7.1 (x < 30 mm, outside
the strip) and the interior (the rest). "size ok": area in [0.95, 1.05) A_BIT; "angles ok":
all three angles in [55, 65) degrees (the intervals of cadbridge.mesh.quality). Run with the
paper's construction alone (strip_opt=False) and as shipped.

    python benchmarks/qit_regions.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # cadbridge, and the shared test geometry (tests/helpers)

from cadbridge.mesh.qit.mesher import QitOptions, qit_mesh  # noqa: E402
from tests.helpers.qit_examples import example_71, example_72  # noqa: E402
from cadbridge.mesh.quality import ANGLE_BIN, SIZE_BIN, mesh_quality  # noqa: E402
from cadbridge.cad.model import Face, Model  # noqa: E402


def _boundary_edges(tris: np.ndarray) -> np.ndarray:
    e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    return u[c == 1]


def _seg_dist(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree

    mid = 0.5 * (a + b)
    k = min(16, len(mid))
    _, nn = cKDTree(mid).query(p, k=k)
    nn = nn.reshape(len(p), k)
    aa, ab = a[nn], b[nn] - a[nn]
    t = np.clip(np.einsum("kij,kij->ki", p[:, None] - aa, ab) / np.einsum("kij,kij->ki", ab, ab), 0, 1)
    return np.linalg.norm(p[:, None] - (aa + t[..., None] * ab), axis=2).min(axis=1)


def regions(name: str, label: str, model, R: float, opt: QitOptions) -> list[str]:
    m = qit_mesh(model, R, opt)
    x, t = m.nodes, m.triangles
    q = mesh_quality(x, t, R)
    s = q.summary()
    be = _boundary_edges(t)
    c = x[t].mean(axis=1)
    d = _seg_dist(c, x[be[:, 0]], x[be[:, 1]])
    rel = q.areas / (R * R * np.sqrt(3) / 4)
    ang = q.angles.reshape(-1, 3)
    ok_s = (rel >= 1 - SIZE_BIN / 2) & (rel < 1 + SIZE_BIN / 2)
    ok_a = ((ang >= 60 - ANGLE_BIN / 2) & (ang < 60 + ANGLE_BIN / 2)).all(axis=1)
    reg = np.where(d < 2 * R, "edge strip", "interior")
    if name.startswith("Ex. 7.1"):
        reg = np.where((reg == "interior") & (c[:, 0] < 30), "corner x < 30", reg)
    out = [f"| {name} | {label} | {q.q:.2f} | {q.f_size:.1f} | {q.f_angle:.1f} | "
           f"{s['f_v3']:.1f} / {s['f_v3_bit']:.1f} | {s['f_v6']:.1f} / {s['f_v6_bit']:.1f} | "
           f"{s['angle_min']:.1f} / {s['angle_max']:.1f} | "
           + ", ".join(f"{r}: {int((reg == r).sum())} tris, size ok {100 * ok_s[reg == r].mean():.0f} %, "
                       f"angles ok {100 * ok_a[reg == r].mean():.0f} %"
                       for r in ("edge strip", "corner x < 30", "interior") if (reg == r).any()) + " |"]
    return out


def main() -> None:
    m71 = Model(faces=[Face(example_71(), de=1)])
    m72 = Model(faces=[Face(s, de=2 * i + 1) for i, s in enumerate(example_72())])
    lines = ["| case | QIT | Q [%] | f_sa | f_na | f_v3 / BIT | f_v6 / BIT | angle min / max | by region |",
             "|---|---|---:|---:|---:|---|---|---|---|"]
    for name, model, R in (("Ex. 7.1, R = 12", m71, 12.0), ("Ex. 7.1, R = 5", m71, 5.0), ("Ex. 7.2, R = 5", m72, 5.0)):
        for label, kw in (("paper", {"strip_opt": False}), ("shipped", {})):
            lines += regions(name, label, model, R, QitOptions(size=R, **kw))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
