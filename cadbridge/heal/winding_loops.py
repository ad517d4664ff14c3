"""Trim loops that wind once round a closed surface, closed on the side they bound.

A loop on a surface closed in one direction (a full-turn surface of revolution: S(u, v0) =
S(u, v1)) may go round it once: it returns to its start in model space, but its (u, v) image
ends one period from where it began. Such a loop splits the surface into two parts, each
bounded by the loop and by one of the surface's two natural boundaries across the other
direction (u = u0 or u = u1). Only one part is a face the loop bounds: the one whose natural
boundary is missing from the loop, and that is the one of zero length where the surface has
a pole there (a cone's apex), else the shorter (a generatrix that stops a hair short of the
axis: CATIA V4's PRO19800, 0.035 mm, where the other side's rim is 28 mm long).

`close_winding_loops` closes every such outer loop explicitly on that side: a straight (u, v)
piece along the seam to the chosen boundary, that boundary across the period, and the seam
back (three NURBS lines appended to the loop). The inside/outside test, the B-rep and the
mesher then all see the same closed loop. Before, the loop was closed by the chord between
its ends, which runs along whichever boundary it ends on, and the face read as the other
part (OCC's reading agrees with the rule: the two parts' areas sum to the whole surface).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cadbridge.cad.model import Diagnostic, Model, TrimLoop
from cadbridge.nurbs.curve import NurbsCurve

__all__ = ["WindingClosure", "close_winding_loops"]

PERIOD_TOL = 1e-6
"""The loop's (u, v) ends one period apart within this fraction of the period (and the
same in the other direction within this fraction of its range)."""


@dataclass(frozen=True)
class WindingClosure:
    """One loop closed on its side: face index, DE, name, the closed direction ("u" or "v"),
    the boundary chosen (its parameter) and the lengths of the two candidate boundaries."""

    face: int
    de: int
    name: str | None
    direction: str
    side: float
    lengths: tuple[float, float]

    def __str__(self) -> str:
        other = "v" if self.direction == "u" else "u"
        return (f"face {self.face} ({self.name or 'unnamed'}, DE {self.de}): its outer loop winds once round the "
                f"surface (closed in {self.direction}); closed along {other} = {self.side:.6g}, the side whose "
                f"boundary it lacks is {min(self.lengths):.3g} long (the other {max(self.lengths):.3g})")


def _line(p, q) -> NurbsCurve:
    return NurbsCurve(1, [0.0, 0.0, 1.0, 1.0], np.array([p, q], dtype=float))


def _boundary_length(surface, direction: str, at: float, lo: float, hi: float, samples: int = 257) -> float:
    """Model-space length of the isoparametric line (other parameter = ``at``) across the
    closed ``direction`` from ``lo`` to ``hi`` (polyline of ``samples`` points)."""
    t = np.linspace(lo, hi, samples)
    fixed = np.full(samples, at)
    p = surface.evaluate(t, fixed) if direction == "u" else surface.evaluate(fixed, t)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def close_winding_loops(model: Model) -> list[WindingClosure]:
    """Close, in place, every outer trim loop of ``model`` whose (u, v) image ends one period
    from its start on a surface closed in that direction (module docstring). Returns the
    closures made; each is also a reader diagnostic of the model."""
    done = []
    for k, f in enumerate(model.faces):  # loop over faces; few are closed
        lp = f.trims.outer if f.trims is not None else None
        if lp is None or not lp.curves:
            continue
        s = f.surface
        closed = s.closed_directions()
        if not any(closed):
            continue
        c0, c1 = lp.curves[0], lp.curves[-1]
        start = np.asarray(c0.evaluate(np.array([c0.domain[0]])), dtype=float)[0, :2]
        end = np.asarray(c1.evaluate(np.array([c1.domain[1]])), dtype=float)[0, :2]
        u0, u1, v0, v1 = s.domain
        spans = (u1 - u0, v1 - v0)
        for d, name in ((0, "u"), (1, "v")):
            o = 1 - d
            if not closed[d] or closed[o]:
                continue
            if abs(abs(end[d] - start[d]) - spans[d]) > PERIOD_TOL * spans[d]:
                continue
            if abs(end[o] - start[o]) > PERIOD_TOL * spans[o]:
                continue
            lo, hi = sorted((start[d], end[d]))
            ends = (u0, u1) if o == 0 else (v0, v1)
            lengths = tuple(_boundary_length(s, name, float(a), lo, hi) for a in ends)
            side = ends[int(np.argmin(lengths))]
            p_end, p_start = end.copy(), start.copy()
            q_end, q_start = end.copy(), start.copy()
            q_end[o] = side
            q_start[o] = side
            closure = [_line(p_end, q_end), _line(q_end, q_start), _line(q_start, p_start)]
            f.trims.outer = TrimLoop(list(lp.curves) + closure, None if lp.model_curves is None else
                                     list(lp.model_curves) + [None] * len(closure))
            done.append(WindingClosure(k, f.de, f.name, name, float(side), (float(lengths[0]), float(lengths[1]))))
            model.diagnostics.append(Diagnostic(f"trim loop closed: {done[-1]}", de=f.de, entity_type=f.entity_type))
            break
    return done
