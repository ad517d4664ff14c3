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

from cadbridge.iges.analytic import ArcMap, MappedLoops, ParamMap, map_loops
from cadbridge.iges.trimcheck import loop_deltas
from cadbridge.nurbs.curve import NurbsCurve

__all__ = ["ArcRepair", "arc_start_map", "close_at_poles", "repair_arc_start"]


@dataclass(frozen=True)
class ArcRepair:
    """What `repair_arc_start` found for one face.

    delta_standard  max |S(c2d(t)) - C3d| with the generatrix parameter read as the angle
    delta_repaired  the same with it read from the arc's start, or None when not tried
    mapped          the loops of the repaired reading (None: keep the standard reading)
    poles_closed    loops of that reading closed by a degenerate edge at a pole (`close_at_poles`)
    """

    delta_standard: float
    delta_repaired: float | None = None
    mapped: MappedLoops | None = None
    poles_closed: int = 0

    def note(self, size: float) -> str:
        """The reader's diagnostic for a repaired face (one line)."""
        return (f"parameter-space curves over the revolution surface measure the generatrix arc from its start "
                f"point, not by its angle (IGES 5.3, entity 100): read by the angle they miss the model-space "
                f"curves by {self.delta_standard:.3g} ({self.delta_standard / size:.3g} x the surface size) and trim the "
                f"other part of the arc; read from the start they agree within {self.delta_repaired:.3g}, "
                f"so that reading trims the face"
                + (f" (its loop closed by the degenerate edge at the pole that the file leaves out)"
                   if self.poles_closed else ""))


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


def repair_arc_start(pm: ParamMap, loops: list, has_outer: bool, res: MappedLoops, pairs: list,
                     size: float, mapped_pairs, disagree_rel: float, agree_rel: float) -> ArcRepair | None:
    """Decide the reading of the parameter-space loops ``res`` (mapped by the standard through
    ``pm``) of a face over a 120 with an arc generatrix; None when ``pm`` has no such arc.

    loops        the raw loops (per edge (parameter-space pieces, model-space pieces))
    pairs        ``mapped_pairs(res, loops)``: what the trim delta compares (not None)
    size         the surface's box diagonal (model units)
    mapped_pairs the reader's `Builder._mapped_pairs`

    The standard reading stays unless its delta exceeds ``disagree_rel`` x size and the
    reading from the arc's start closes every loop and agrees within ``agree_rel`` x size.
    Also None (nothing measured: the reader's deferred delta stays) when every loop's
    vertices lie on its model-space curves (`_vertices_off`)."""
    alt = arc_start_map(pm)
    if alt is None or not _vertices_off(pm, res, loops, disagree_rel * size):
        return None
    d = float(loop_deltas([(res.surface, pairs)])[0])
    if np.isnan(d) or d <= disagree_rel * size:
        return ArcRepair(d)
    try:
        res2 = map_loops(alt, loops, has_outer, True)
    except ValueError:
        return ArcRepair(d)
    n_open = sum(not c for c in res2.closed())
    res2 = close_at_poles(res2, agree_rel * size)
    pairs2 = mapped_pairs(res2, loops)
    if pairs2 is None or not all(res2.closed()):
        return ArcRepair(d)
    d2 = float(loop_deltas([(res2.surface, pairs2)])[0])
    if np.isnan(d2) or d2 > agree_rel * size:
        return ArcRepair(d, d2)
    return ArcRepair(d, d2, res2, n_open)


def _end_points(c: NurbsCurve) -> np.ndarray:
    """The points at both ends of ``c``'s domain, (2, dim): the end control points when the
    knot vector is clamped there (no evaluation), else evaluated."""
    p, k = c.degree, np.asarray(c.knots)
    if c.domain[0] == k[0] == k[p] and c.domain[1] == k[-1] == k[-1 - p]:
        return np.asarray(c.control_points)[[0, -1]]
    return np.asarray(c.evaluate(np.array(c.domain, dtype=float)))


def _vertices_off(pm: ParamMap, res: MappedLoops, loops: list, tol: float) -> bool:
    """Whether some loop vertex of the standard reading (a parameter-space piece's end, through
    ``pm``) lies farther than ``tol`` from every end of the loop's model-space pieces: the
    cheap test before the trim delta (two vectorised evaluations per face). In a file that is
    right the vertices are the model curves' ends; where they are not (pieces split
    elsewhere), the full check only costs time."""
    for raw in loops:
        mcs = [c for _, m in raw if m is not None for c in m]
        pcs = [c for pc, _ in raw if pc is not None for c in pc]
        if not mcs or not pcs:
            continue
        st = np.vstack([_end_points(c)[:, :2] for c in pcs])
        uv = pm.uv_fn(pm.pcurve_fn(st), None, None)
        x = res.surface.evaluate(uv[:, 0], uv[:, 1])
        ends = np.vstack([_end_points(m) for m in mcs])
        d = np.linalg.norm(x[:, None, :] - ends[None, :, :], axis=2).min(axis=1)
        if float(d.max()) > tol:
            return True
    return False


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
