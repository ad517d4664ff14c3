"""Parameter-space trims over a surface of revolution (120) whose circular-arc generatrix
(100) the writer parametrised from the arc's start instead of by its angle.

IGES 5.3 (4.3, entity 100) parametrises a circular arc by the angle T, from the start
angle to the end angle; a 142's parameter-space curve over a 120 gives (s, t) = (that
generatrix parameter, rotation angle) (4.18). SolidWorks 2010 writes s measured from the
arc's start point (s = T - T1, so s runs over [0, T2 - T1]): read by the standard, a loop
meant for the arc's second half trims its first half. On
`occt_bug22566_SolidWorks2010.igs` the closing sphere caps DE 41, 157 and 197 then lie
inside the tube they should close (OCC's reader does the same: its faces 0, 3, 4 span
y -115 .. -105 where the model-space curves bound y -125 .. -115), meeting the cylinders
at 180-degree knife edges, while the model-space curves of the same 142s bound the right
cap.

`repair_arc_start` decides this on the file's own data: when the loops read by the
standard miss their model-space curves by more than ``DISAGREE_REL`` x size and the same
curves read from the arc's start agree within ``AGREE_REL`` x size, the second reading
trims the face (exactly: the same `ArcMap`, only its origin moved), and the reader notes
it. Any other disagreement is left to the reader's rules (`Builder.mapped_trims`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from cadbridge.cad.analytic import ArcMap, MappedLoops, ParamMap, map_loops
from cadbridge.nurbs.curve import NurbsCurve

__all__ = ["ArcRepair", "arc_start_map", "close_at_poles", "repair_arc_start"]


@dataclass(frozen=True)
class ArcRepair:
    """A face `repair_arc_start` re-read.

    miss_standard   largest distance of a loop vertex, read with the generatrix parameter as
                    the angle, to the nearest end of the loop's model-space pieces
    miss_repaired   the same read from the arc's start
    mapped          the loops of the repaired reading
    poles_closed    loops of that reading closed by a degenerate edge at a pole (`close_at_poles`)
    """

    miss_standard: float
    miss_repaired: float
    mapped: MappedLoops
    poles_closed: int = 0

    def note(self, size: float) -> str:
        """The reader's diagnostic for the face (one line)."""
        return (f"parameter-space curves over the revolution surface measure the generatrix arc from its start "
                f"point, not by its angle (IGES 5.3, entity 100): read by the angle they miss the model-space "
                f"curves by {self.miss_standard:.3g} at a loop vertex ({self.miss_standard / size:.3g} x the "
                f"surface size) and trim the other part of the arc; read from the start their vertices lie on "
                f"them within {self.miss_repaired:.3g}, so that reading trims the face"
                + (" (its loop closed by the degenerate edge at the pole that the file leaves out)"
                   if self.poles_closed else ""))

    @staticmethod
    def delta_note(size: float, agree_rel: float, diagnostic):
        """For the reader's deferred delta of the face: ``note(delta)`` that adds
        ``diagnostic(message)`` when the whole loops (not only their vertices) miss the
        model-space curves by more than ``agree_rel`` x size."""

        def note(d: float) -> None:
            if d > agree_rel * size:
                diagnostic(f"the parameter-space loops read from the arc's start still miss the model-space "
                           f"curves by {d:.3g} ({d / size:.3g} x the surface size) between their vertices")

        return note


def arc_start_map(pm: ParamMap) -> ParamMap | None:
    """``pm`` (a 120's `revolution_map`) with its generatrix parameter read from the arc's start
    (s = T - T1) instead of by the angle T; None when the generatrix is no arc or starts at
    angle 0 (both readings are the same)."""
    arc = pm.pcurve_pre[0] if pm.kind == "revolution" else None
    if not isinstance(arc, ArcMap) or pm.pcurve_affine is None:
        return None
    if abs(np.remainder(arc.start_in + np.pi, 2 * np.pi) - np.pi) <= 1e-12:
        return None
    alt = ArcMap(0.0, arc.sweep, arc.start_out)
    m, b = pm.pcurve_affine

    def pc(st: np.ndarray) -> np.ndarray:
        y = np.asarray(st, dtype=float) @ np.asarray(m).T + b
        y[:, 0] = alt(y[:, 0], 0)[0]
        return y

    return dataclasses.replace(pm, pcurve_fn=pc, pcurve_pre=(alt, pm.pcurve_pre[1]))


def repair_arc_start(pm: ParamMap, loops: list, has_outer: bool, res: MappedLoops, size: float,
                     disagree_rel: float, agree_rel: float) -> ArcRepair | None:
    """The repaired reading of the parameter-space loops of a face over a 120 whose generatrix
    is an arc, or None: keep the standard reading ``res`` (mapped through ``pm``).

    loops  the raw loops (per edge (parameter-space pieces, model-space pieces))
    size   the surface's box diagonal (model units)

    Decided on the loop vertices, exactly evaluated (two vectorised evaluations per reading,
    `_vertex_miss`; the whole trim delta is left to the reader's deferred measure, as for
    every face whose parameter-space curves are preferred): re-read when a vertex of the
    standard reading lies farther than ``disagree_rel`` x size from every end of the loop's
    model-space pieces while, read from the arc's start, every vertex lies within
    ``agree_rel`` x size of one and every loop closes (`close_at_poles` closing gaps at a pole)."""
    alt = arc_start_map(pm)
    if alt is None:
        return None
    miss = _vertex_miss(pm, res.surface, loops)
    if not miss > disagree_rel * size:
        return None
    miss2 = _vertex_miss(alt, res.surface, loops)
    if not miss2 <= agree_rel * size:
        return None
    try:
        res2 = map_loops(alt, loops, has_outer, True)
    except ValueError:
        return None
    n_open = sum(not c for c in res2.closed())
    res2 = close_at_poles(res2, agree_rel * size)
    if not all(res2.closed()):
        return None
    return ArcRepair(miss, miss2, res2, n_open)


def _end_points(c: NurbsCurve) -> np.ndarray:
    """The points at both ends of ``c``'s domain, (2, dim): the end control points when the
    knot vector is clamped there (no evaluation), else evaluated."""
    p, k = c.degree, np.asarray(c.knots)
    if c.domain[0] == k[0] == k[p] and c.domain[1] == k[-1] == k[-1 - p]:
        return np.asarray(c.control_points)[[0, -1]]
    return np.asarray(c.evaluate(np.array(c.domain, dtype=float)))


def _vertex_miss(pm: ParamMap, surface, loops: list) -> float:
    """Largest distance of a loop vertex (a parameter-space piece's end, through ``pm``) to the
    nearest end of its loop's model-space pieces, over all loops with both; NaN without any.
    In a file that is right the vertices are the model pieces' ends (a loop split elsewhere
    in one representation than in the other reads as a miss: then nothing is re-read)."""
    worst = np.nan
    for raw in loops:
        mcs = [c for _, m in raw if m is not None for c in m]
        pcs = [c for pc, _ in raw if pc is not None for c in pc]
        if not mcs or not pcs:
            continue
        st = np.vstack([_end_points(c)[:, :2] for c in pcs])
        uv = pm.uv_fn(pm.pcurve_fn(st), None, None)
        x = surface.evaluate(uv[:, 0], uv[:, 1])
        ends = np.vstack([_end_points(m) for m in mcs])
        d = float(np.linalg.norm(x[:, None, :] - ends[None, :, :], axis=2).min(axis=1).max())
        worst = d if np.isnan(worst) else max(worst, d)
    return worst


def close_at_poles(res: MappedLoops, tol: float, samples: int = 9) -> MappedLoops:
    """``res`` with each loop's gap from its end back to its start closed by a straight (u, v)
    segment where the whole segment maps to one model point within ``tol`` (a pole: the
    degenerate edge a writer may leave out, as DE 351 of the SolidWorks file does; OCC's
    ShapeFix_Wire adds such degenerated edges too). Loops with any other gap stay open.
    The new piece has edge index -1: no edge of the file, so no trim delta is measured on it."""
    if all(res.closed()):
        return res
    loops, ends = [], []
    for lp, (a, b), ok in zip(res.loops, res.ends, res.closed()):
        if not ok:
            t = np.linspace(0.0, 1.0, samples)
            seg = (1.0 - t)[:, None] * b[None, :] + t[:, None] * a[None, :]  # end (b) -> start (a)
            p = res.surface.evaluate(seg[:, 0], seg[:, 1])
            if np.max(np.linalg.norm(p - p[:1], axis=1)) <= tol:
                line = NurbsCurve(1, np.array([0.0, 0.0, 1.0, 1.0]), np.array([b, a], dtype=float))
                lp = list(lp) + [(-1, line, False)]
                b = a
        loops.append(lp)
        ends.append((a, b))
    return dataclasses.replace(res, loops=loops, ends=ends)
