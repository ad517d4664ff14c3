"""`cadbridge quality`: the quality report of any triangle mesh (Herrero Adan & Cardoso 2020).

    cadbridge quality MESH --size R [--json report.json]

Prints Q (eq. 21), its inputs against the BIT (appendix C), and the angle / size / valence
histograms (bins in `cadbridge.mesh.quality`); quads are split into two triangles each.
"""

from __future__ import annotations

import argparse
import json

__all__ = ["cmd_quality", "register"]


def format_report(q) -> str:
    """Plain-text report of a `cadbridge.mesh.quality.MeshQuality`."""
    from cadbridge.mesh.quality import ANGLE_BIN, SIZE_BIN

    b = q.bit
    lines = [
        f"triangles {q.n_triangles}, vertices {q.n_vertices}, boundary segments {q.n_boundary_segments}, "
        f"target size R = {q.size:g}",
        f"Q = {q.q:.1f} %  (eq. 21: sizes {q.f_size:.1f} %, angles {q.f_angle:.1f} %, "
        f"valence 3 {q.valence_freq(3):.1f} / {b.valence_freq[3]:.1f} %, valence 6 {q.valence_freq(6):.1f} / "
        f"{b.valence_freq[6]:.1f} % of the BIT)",
        f"BIT: rb = {b.rb:.2f}, cb = {b.cb:.2f}" + (" (C.3 clamped)" if b.clamped else ""),
        f"angles [deg, bins of {ANGLE_BIN:g}]: " + ", ".join(f"{k:g}: {v:.1f}%" for k, v in sorted(q.angle_hist.items())),
        f"sizes [x A_BIT, bins of {SIZE_BIN:g}]: " + ", ".join(f"{k:g}: {v:.1f}%" for k, v in sorted(q.size_hist.items())),
        "valences: " + ", ".join(f"{k}: {v:.1f}%" for k, v in sorted(q.valence_hist.items())),
    ]
    return "\n".join(lines)


def cmd_quality(args: argparse.Namespace) -> int:
    import numpy as np

    from cadbridge.common.errors import UsageError
    from cadbridge.common.progress import say
    from cadbridge.common.atomic import atomic_write
    from cadbridge.mesh.io import read_mesh
    from cadbridge.mesh.quality import mesh_quality

    if not (args.size > 0 and np.isfinite(args.size)):
        raise UsageError(f"--size must be a positive number, got {args.size}")
    mesh = read_mesh(args.mesh)
    tris = [mesh.triangles] if len(mesh.triangles) else []
    if len(mesh.quads):
        qd = mesh.quads
        tris += [qd[:, [0, 1, 2]], qd[:, [0, 2, 3]]]
    if not tris:
        raise UsageError(f"{args.mesh}: no triangles or quads")
    q = mesh_quality(mesh.nodes, np.concatenate(tris), args.size)
    say(format_report(q))
    if args.json:
        data = dict(q.summary(), angle_hist=q.angle_hist, size_hist=q.size_hist,
                    valence_hist={str(k): v for k, v in q.valence_hist.items()},
                    bit={"rb": q.bit.rb, "cb": q.bit.cb, "clamped": q.bit.clamped,
                         "valence_freq": {str(k): v for k, v in q.bit.valence_freq.items()}})
        data = {k: (float(v) if isinstance(v, (np.floating, np.integer)) else v) for k, v in data.items()}
        with atomic_write(args.json) as fh:
            json.dump(data, fh, indent=1)
        say(f"wrote {args.json}")
    return 0


def register(sub, fmt) -> None:
    """Add the `quality` subcommand to the cadbridge parser."""
    p = sub.add_parser("quality", help="mesh quality against the ideal isotropic lattice (Q, histograms)",
                       formatter_class=fmt,
                       epilog="example:\n  cadbridge quality die.msh --size 5 --json die_quality.json")
    p.add_argument("mesh", help="mesh file readable by meshio (triangles; quads are split)")
    p.add_argument("--size", type=float, required=True, help="target edge length R the sizes are measured against")
    p.add_argument("--json", default=None, help="also write the report as JSON")
    p.set_defaults(func=cmd_quality)
