"""QIT's strip step (QitOptions.strip_opt, docs/qit.md choice 19) face by face on a real
file: each face meshed alone with the paper's construction and as shipped; faces meshed /
refused / reverted, and how Q, the smallest and the largest angle move per face.

    python benchmarks/qit_strip_faces.py [--file iges_samples/production_die_nurbs.igs]
                                         [--size 10] [--every 4]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cadbridge.iges import read_iges  # noqa: E402
from cadbridge.mesh.qit.mesher import QitError, QitOptions, qit_mesh  # noqa: E402
from cadbridge.mesh.quality import mesh_quality  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--file", default=str(ROOT / "iges_samples" / "production_die_nurbs.igs"))
    ap.add_argument("--size", type=float, default=10.0)
    ap.add_argument("--every", type=int, default=4, help="mesh every n-th face")
    args = ap.parse_args()
    model = read_iges(args.file)
    R = args.size
    faces = list(range(0, len(model.faces), args.every))
    res = {}
    for name, kw in (("paper", {"strip_opt": False}), ("shipped", {})):
        t0 = time.perf_counter()
        out, refused, reverted = {}, 0, 0
        for f in faces:
            reps: list = []
            try:
                m = qit_mesh(model, R, QitOptions(size=R, **kw), faces=[f], reports=reps)
            except QitError:
                refused += 1
                continue
            q = mesh_quality(m.nodes, m.triangles, R)
            out[f] = (q.q, q.angles.min(), q.angles.max())
            reverted += sum(r.strip_reverted for r in reps)
        res[name] = out
        print(f"{name}: {len(faces)} faces, {len(out)} meshed, {refused} refused, {reverted} strip steps reverted, "
              f"mean Q {np.mean([v[0] for v in out.values()]):.2f} %, {time.perf_counter() - t0:.1f} s")
    common = sorted(set(res["paper"]) & set(res["shipped"]))
    a = np.array([res["paper"][f] for f in common])
    b = np.array([res["shipped"][f] for f in common])
    dq, dmin, dmax = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1], b[:, 2] - a[:, 2]
    print(f"per face, shipped - paper: Q {dq.min():+.2f} .. {dq.max():+.2f} (lower on {np.sum(dq < -1e-9)}, "
          f"higher on {np.sum(dq > 1e-9)}); smallest angle lower on {np.sum(dmin < -1e-9)} faces; "
          f"largest angle higher on {np.sum(dmax > 1e-9)} faces, by {max(dmax.max(), 0):.2f} deg at most")


if __name__ == "__main__":
    main()
