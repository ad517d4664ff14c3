"""Trim-loop excursions: stretches of a trim loop that run back beside themselves.

A face whose trim edge follows a neighbour's folded edge (`cadbridge.heal.folds`) inherits the fold
in its own (u, v): in `occt_OCC131-2_ANSA9.igs`, FACE(401)'s loop runs down curve 5 (1-based)
to v = 1.8286, turns back up to v = 1.8449 and down again (a Z of two hairpins), its strands
0.03-0.25 mm apart in model space. The loop is simple (OCC's CheckSelfIntersection agrees),
but the finger and the notch it encloses are far narrower than any element, so a mesher
that follows the loop puts elements across them (gmsh: inside out).

`find_excursions` finds such stretches on the exact trim curves: the loop is sampled at exact
curve parameters (64 per knot span) and mapped through the surface, S(c(t)); an excursion is
a pair of loop points X, Y whose model-space chord |XY| is at most ``width`` while the loop
runs ``arc(X -> Y) > RATIO x |XY|`` between them (a neighbour pair has arc ~ |XY|). Among the
candidate pairs (a KD-tree's pairs within ``width``) the one with the largest
``arc - RATIO x |XY|`` is taken: it covers the whole retrace with the shortest chord.
``width`` defaults to max(4 x the face's trim tolerance delta, 1e-3 x model size): below the
file's own accuracy, or far below any element a forming mesh uses.

`heal_excursions` cuts each excursion out of its loop: the curve holding X ends at X (its
domain shortened, the exact curve kept), a straight (u, v) segment joins X to Y, the curve
holding Y starts at Y. The loop cadbridge classifies with then has no sliver; the removed
(u, v) area is reported (it is the sliver's signed area, finger minus notch).

Limitations: a real slot narrower than ``width`` and longer than ``RATIO / 2 x`` its width
would be cut as well (no such slot is in the samples or the corpus; the tests check that only
FACE(401) of ANSA9 has an excursion).
"""

from __future__ import annotations

import copy
import math

from dataclasses import dataclass, field

import numba
import numpy as np
from scipy.spatial import cKDTree

from cadbridge.cad.model import Face, Model, TrimLoop
from cadbridge.iges.errors import IgesError
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.cad.trims import segment_distance

__all__ = ["Excursion", "find_excursions", "heal_excursions", "loop_crossing", "crossing_error", "MAX_CROSSINGS", "GAP_REL", "JUMP_REL", "RATIO", "COS_SAME_WAY", "MIN_LENGTH", "SAMPLES_PER_SPAN"]

RATIO = 20.0
"""An excursion's loop length between X and Y exceeds RATIO x its chord |XY|."""
COS_SAME_WAY = 0.5
"""... and the loop leaves Y within 60 degrees of the direction it came into X (a Z, not a U)."""
MIN_LENGTH = 1e-4
"""Excursions shorter than this x model size are left alone (no mesher resolves them)."""
SAMPLES_PER_SPAN = 64
"""Exact curve samples per knot span (the candidates' resolution along the loop)."""
MAX_PAIRS = 5_000_000
"""Sample pairs within the width an excursion search looks at, about, at most (`_best_pair`)."""


@dataclass(frozen=True)
class Excursion:
    """One excursion of a trim loop.

    face_de, face_name : the face (top-level DE, name); loop : 0 the outer loop, i >= 1 hole i-1.
    cut : ((curve index, parameter) of X, (curve index, parameter) of Y), 0-based curve indices.
    start, end : X and Y in model space, (3,); chord : |XY|; length : loop length X -> Y
    (model units); uv_area : signed (u, v) area of the loop stretch X -> Y closed by the chord
    (counter-clockwise positive; ~0 for a Z, finger and notch cancel)."""

    face_de: int
    face_name: str | None
    loop: int
    cut: tuple[tuple[int, float], tuple[int, float]]
    start: np.ndarray
    end: np.ndarray
    chord: float
    length: float
    uv_area: float
    stretch_uv: np.ndarray = field(repr=False, default=None)  # (K, 2) exact loop samples X -> Y
    stretch_xyz: np.ndarray = field(repr=False, default=None)  # (K, 3) S(stretch_uv)
    rest_xyz: np.ndarray = field(repr=False, default=None)  # (R, 3) the rest of the loop, Y -> X
    kind: str = "excursion"  # or "crossing": the lobe a loop encloses where it crosses itself (X = Y)

    def in_stretch(self, xyz: np.ndarray) -> np.ndarray:
        """Whether points (N, 3) on the loop's edge (mesh nodes) lie on the cut stretch, strictly
        between X and Y: nearer its polyline than the rest of the loop's polyline. (N,) bool."""
        xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
        return _polyline_distance(xyz, self.stretch_xyz) < _polyline_distance(xyz, self.rest_xyz)

    def __str__(self) -> str:
        x = self.start
        if self.kind == "crossing":
            return (f"{self.face_name or 'face'} (DE {self.face_de}) loop {self.loop}: trim loop crosses itself at "
                    f"({x[0]:.6g}, {x[1]:.6g}, {x[2]:.6g}), enclosing a lobe of {self.length:.3g} loop length (a "
                    f"tolerance artefact); lobe cut off at the crossing (curve {self.cut[0][0] + 1} to curve "
                    f"{self.cut[1][0] + 1}, 1-based)")
        return (f"{self.face_name or 'face'} (DE {self.face_de}) loop {self.loop}: trim loop runs back beside "
                f"itself for {self.length:.3g} within {self.chord:.3g} at ({x[0]:.6g}, {x[1]:.6g}, {x[2]:.6g}); "
                f"cut out (curve {self.cut[0][0] + 1} to curve {self.cut[1][0] + 1}, 1-based)")


def _loops(face: Face) -> list[TrimLoop | None]:
    t = face.trims
    if t is None:
        return []
    return [t.outer] + list(t.inner)


def _samples(face: Face, loop: TrimLoop) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Loop samples: curve index (M,), parameter (M,), uv (M, 2), xyz (M, 3); each curve's
    last sample dropped (the next curve starts there), the loop not closed."""
    ci, ts, uvs = [], [], []
    for i, c in enumerate(loop.curves):
        t = c.sample_parameters(SAMPLES_PER_SPAN)[:-1]
        ci.append(np.full(len(t), i))
        ts.append(t)
        uvs.append(c.evaluate(t)[:, :2])
    uv = np.concatenate(uvs)
    xyz = face.surface.evaluate(uv[:, 0], uv[:, 1])
    return np.concatenate(ci), np.concatenate(ts), uv, xyz


def _best_pair(xyz: np.ndarray, uv: np.ndarray, width: float) -> tuple[int, int, float, float] | None:
    """Indices (i, j) along the closed sample loop with the stretch i -> j (forward, wrapping)
    an excursion: model-space chord <= width, arc > RATIO x chord both in model space and in
    (u, v) (a loop that folds only in model space, along a folded surface's edge, is straight
    in its own (u, v): that is `cadbridge.heal.folds`' case, not a trim defect), arc - RATIO x chord
    largest; with the chord and the arc. None if there is none."""
    n = len(xyz)

    def arcs(p):
        seg = np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1)
        return np.concatenate([[0.0], np.cumsum(seg)])  # s[k]: arc from sample 0 to k; s[n] the loop

    s, q = arcs(xyz), arcs(uv)
    tree = cKDTree(xyz)
    # a loop sampled densely against ``width`` (trj6_b1: 82 944 samples 0.0004 apart, width
    # 26.5) has billions of pairs within it: the pairs are then taken on every k-th sample
    # (still exact curve points), k so that about `MAX_PAIRS` are left, and k samples no
    # farther apart than width / 8 (where the samples are sparse against the width, as on
    # a Z a few samples wide, every one counts)
    count = tree.count_neighbors(tree, width) if n * (n - 1) > 2 * MAX_PAIRS else n  # ordered pairs, self included
    stride = 1
    if count - n > 2 * MAX_PAIRS:
        gaps = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
        spacing = float(np.median(gaps[gaps > 0])) if np.any(gaps > 0) else width
        stride = max(1, min(math.ceil(math.sqrt((count - n) / (2 * MAX_PAIRS))), int(width / (8.0 * spacing))))
    sel = np.arange(0, n, stride)
    pairs = (tree if stride == 1 else cKDTree(xyz[sel])).query_pairs(width, output_type="ndarray")
    if len(pairs) == 0:
        return None
    a, b = sel[pairs[:, 0]], sel[pairs[:, 1]]  # a < b
    d = np.linalg.norm(xyz[a] - xyz[b], axis=1)
    fwd = s[b] - s[a]
    # the excursion is the shorter way round (the rest of the loop is the face itself)
    use_fwd = fwd <= s[n] - fwd
    arc = np.where(use_fwd, fwd, s[n] - fwd)
    qf = q[b] - q[a]
    uv_arc = np.where(use_fwd, qf, q[n] - qf)
    uv_d = np.linalg.norm(uv[a] - uv[b], axis=1)
    # a Z, not a U: the loop leaves Y in the direction it came into X (a U-turn -- a slit, or two
    # boundary curves meeting tangentially at a cusp corner -- leaves the opposite way)
    tan = np.roll(xyz, -1, axis=0) - np.roll(xyz, 1, axis=0)
    tan /= np.maximum(np.linalg.norm(tan, axis=1), 1e-300)[:, None]
    same_way = np.einsum("ij,ij->i", tan[a], tan[b]) > COS_SAME_WAY
    score = np.where(same_way & (uv_arc > RATIO * uv_d), arc - RATIO * d, -np.inf)
    k = int(np.argmax(score))
    if not score[k] > 0:
        return None
    i, j = (int(a[k]), int(b[k])) if use_fwd[k] else (int(b[k]), int(a[k]))
    return i, j, float(d[k]), float(arc[k])


def default_width(face: Face, size: float) -> float:
    """The excursion width of a face: max(4 x its trim tolerance delta, 1e-3 x model size)."""
    delta = face.trim_delta
    return max(4.0 * (delta or 0.0), 1e-3 * size)


def find_excursions(model: Model, width: float | None = None, faces: list[int] | None = None,
                    crossings: list[str] | None = None) -> list[Excursion]:
    """The excursions of the trim loops of ``model`` (one per loop at most; `heal_excursions`
    cuts repeatedly), for the face indices ``faces`` (default all): a lobe where the loop
    crosses itself (`loop_crossing`) or a stretch running back beside itself. ``width`` in
    model units (default `default_width` per face). Loops that really cross themselves
    (which `heal_excursions` refuses) are described in ``crossings`` if given. Plain data;
    the model is not changed."""
    out = []
    size = model.size()
    for fi in range(len(model.faces)) if faces is None else faces:
        f = model.faces[fi]
        w = default_width(f, size) if width is None else width
        for li, lp in enumerate(_loops(f)):
            if lp is None or not lp.curves:
                continue
            e = loop_crossing(f, li, lp, w, MIN_LENGTH * size)
            if isinstance(e, str):
                if crossings is not None:
                    crossings.append(e)
                continue
            if e is None:
                e = _loop_excursion(f, li, lp, w, MIN_LENGTH * size)
            if e is not None:
                out.append(e)
    return out


def crossing_error(model: Model, f: Face, li: int, message: str) -> IgesError:
    """The refusal of a face whose loop ``li`` really crosses itself (`loop_crossing`'s message):
    an IgesError naming the file, the face's DE and (for a 144) the loop's pointer field."""
    fld = ("PTO" if li == 0 else f"PTI({li})") if f.entity_type == 144 else None
    return IgesError(message, filename=model.source, de=f.de, entity_type=f.entity_type, field=fld)


def _polygon(f: Face, lp: TrimLoop) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The loop's `cadbridge.cad.trims.LoopBoundary` vertices (exact curve points, cached on the
    loop) as curve index, parameter, uv, xyz like `_samples`; None when the curves do not join
    end to start (1e-6 x the loop's (u, v) span): some files list a loop's curves in another
    order, which the parity test of the trims does not mind but which has no arc along the loop."""
    bd = lp.boundary
    real = bd.curve >= 0
    gaps = ~real
    if np.any(np.linalg.norm(bd.b[gaps] - bd.a[gaps], axis=1) > 1e-6 * bd.size):
        return None
    uv = bd.a[real]
    return bd.curve[real], bd.ta[real], uv, f.surface.evaluate(uv[:, 0], uv[:, 1])


def _hairpins_both_ways(uv: np.ndarray, xyz: np.ndarray, width: float) -> bool:
    """Whether the closed polygon (uv (M, 2), xyz (M, 3)) turns back by more than 150 degrees
    within 2 x ``width`` of model-space arc both to the left and to the right somewhere: a Z
    has two such hairpins of opposite sense (a necessary condition, on the polygon, that
    narrows the loops the dense check looks at)."""
    m = len(uv)
    if m < 4:
        return False
    d = np.roll(uv, -1, axis=0) - uv  # edge k: vertex k -> k + 1
    turn = np.arctan2(np.roll(d, 1, axis=0)[:, 0] * d[:, 1] - np.roll(d, 1, axis=0)[:, 1] * d[:, 0],
                      np.einsum("ij,ij->i", np.roll(d, 1, axis=0), d))  # at vertex k, (M,)
    turn = np.where(np.linalg.norm(d, axis=1) > 0, turn, 0.0)
    seg = np.linalg.norm(np.roll(xyz, -1, axis=0) - xyz, axis=1)
    s = np.concatenate([[0.0], np.cumsum(np.tile(seg, 2))])  # twice round: windows may wrap
    th = np.concatenate([[0.0], np.cumsum(np.tile(turn, 2))])
    k = np.arange(m)
    j = np.searchsorted(s, s[k] + 2.0 * width, side="right") - 1
    # at least the next vertex, at most once round the loop (a window longer than the loop:
    # a loop small against ``width``, e.g. a hole in a model that one far point makes large)
    j = np.clip(j, k + 1, k + m - 1)
    w = th[j + 1] - th[k]  # turning at vertices k..j
    lim = np.radians(150.0)
    return bool(np.any(w > lim) and np.any(w < -lim))


def _loop_excursion(f: Face, li: int, lp: TrimLoop, width: float, min_length: float) -> Excursion | None:
    poly = _polygon(f, lp)
    # the polygon narrows the candidates; the cut is chosen on dense exact curve samples
    if poly is None or not _hairpins_both_ways(poly[2], poly[3], width):
        return None
    ci, ts, uv, xyz = _samples(f, lp)
    best = _best_pair(xyz, uv, width)
    if best is None:
        return None
    i, j, d, arc = best
    if arc < min_length:
        return None
    idx = np.arange(i, j + 1) if i <= j else np.concatenate([np.arange(i, len(uv)), np.arange(0, j + 1)])
    p = uv[idx]
    area = 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))
    n = len(uv)
    rest = np.arange(j, j + n - len(idx) + 2) % n  # Y -> X the other way round
    return Excursion(f.de, f.name, li, ((int(ci[i]), float(ts[i])), (int(ci[j]), float(ts[j]))),
                     xyz[i].copy(), xyz[j].copy(), d, arc, area, uv[idx].copy(), xyz[idx].copy(), xyz[rest].copy())


def _polyline_distance(p: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance of points (N, 3) to the open polyline (M, 3), (N,); all pairs (a few hundred
    mesh nodes of one face against one loop)."""
    return segment_distance(p[:, None, :], line[None, :-1], line[None, 1:]).min(axis=1)


def _restricted(c, t0: float, t1: float):
    """``c`` on the domain [t0, t1] (the same exact curve, fewer of it): a `NurbsCurve`, or a
    trim curve mapped exactly from an analytic surface's parametrisation
    (`cadbridge.cad.analytic.MappedCurve` &c., whose domain is its base curve's)."""
    if isinstance(c, NurbsCurve):
        return NurbsCurve(c.degree, c.knots, c.control_points, c.weights, domain=(t0, t1))
    out = copy.copy(c)
    for k in [k for k in vars(out) if k.startswith("_")]:  # caches of the whole curve
        del out.__dict__[k]
    out.base = _restricted(c.base, t0, t1)
    return out


def _segment(a: np.ndarray, b: np.ndarray) -> NurbsCurve:
    """The straight (u, v) segment a -> b as a degree-1 curve on [0, 1]."""
    return NurbsCurve(1, [0.0, 0.0, 1.0, 1.0], np.array([a, b], dtype=float))


def cut_loop(lp: TrimLoop, e: Excursion) -> TrimLoop:
    """``lp`` with the stretch X -> Y of ``e`` replaced by the (u, v) chord X -> Y.

    The loop is rotated to start at the curve holding Y, so X's curve comes last: [Y's curve
    from Y, ..., X's curve up to X, chord]. Model-space counterparts are dropped (the healed
    loop has none for the chord); the face keeps the trim tolerance measured before."""
    (cx, tx), (cy, ty) = e.cut
    curves = lp.curves
    n = len(curves)
    x_uv = curves[cx].evaluate(np.array([tx]))[0, :2]
    y_uv = curves[cy].evaluate(np.array([ty]))[0, :2]
    out: list[NurbsCurve] = []
    if cx == cy and tx < ty:  # X and Y on one curve, Y after X: the stretch inside it
        c = curves[cx]
        if ty < c.domain[1]:
            out.append(_restricted(c, ty, c.domain[1]))
        out += [curves[(cx + k) % n] for k in range(1, n)]
        if tx > c.domain[0]:
            out.append(_restricted(c, c.domain[0], tx))
    else:
        cy_c = curves[cy]
        if ty < cy_c.domain[1]:
            out.append(_restricted(cy_c, ty, cy_c.domain[1]))
        k = (cy + 1) % n
        while k != cx:
            out.append(curves[k])
            k = (k + 1) % n
        cx_c = curves[cx]
        if tx > cx_c.domain[0]:
            out.append(_restricted(cx_c, cx_c.domain[0], tx))
    out.append(_segment(x_uv, y_uv))
    return TrimLoop(out, None)


def _proper_crossings(a: np.ndarray, b: np.ndarray, *, skip: np.ndarray | None = None,
                      limit: int | None = None) -> np.ndarray:
    """Pairs (i, j), i < j, of the closed polygon's edges a[k] -> b[k] ((M, 2) each) that meet
    (each edge's ends on both sides of the other, or on it; collinear pairs left out),
    neighbours and the edges ``skip`` (M,) bool excluded, (K, 2), sorted along the loop (by i,
    then j). ``limit``: only the pairs of the edges i up to the first at which ``limit`` pairs
    are found (a loop that retraces itself meets itself everywhere: trj6_b1, 82 944 samples,
    strands within 2e-5 of each other).

    Broad phase: a uniform grid of cells one mean edge length wide (`_crossing_kernel`,
    compiled). On the analytic production die's 1 173 loops (up to 8 448 edges) the KD-tree
    broad phase it replaces (scipy, over points a mean edge length apart along each edge, its
    pairs made unique with numpy) took 5.6 s; the grid takes 0.3 s."""
    m = len(a)
    use = np.ones(m, dtype=bool) if skip is None else ~np.asarray(skip, dtype=bool)
    if not np.any(use):
        return np.zeros((0, 2), dtype=np.int64)
    a = np.ascontiguousarray(a, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    length = np.linalg.norm(b - a, axis=1)
    positive = use & (length > 0)
    cell = float(np.mean(length[positive])) if np.any(positive) else 1.0
    key = _crossing_kernel(a, b, use, cell, 0 if limit is None else max(1, int(limit)))
    return np.column_stack([key // m, key % m])


@numba.njit(cache=True, nogil=True)
def _piece_cells(a, b, k, q, n, x0, y0, cell):  # pragma: no cover - compiled
    """The grid cells (i0, i1, j0, j1) of the box of piece q of n of edge k (`_crossing_kernel`)."""
    px = a[k, 0] + (b[k, 0] - a[k, 0]) * q / n
    py = a[k, 1] + (b[k, 1] - a[k, 1]) * q / n
    qx = a[k, 0] + (b[k, 0] - a[k, 0]) * (q + 1) / n
    qy = a[k, 1] + (b[k, 1] - a[k, 1]) * (q + 1) / n
    return (np.int64((min(px, qx) - x0) / cell), np.int64((max(px, qx) - x0) / cell),
            np.int64((min(py, qy) - y0) / cell), np.int64((max(py, qy) - y0) / cell))


@numba.njit(cache=True, nogil=True)
def _crossing_kernel(a, b, use, cell, limit):  # pragma: no cover - compiled
    """`_proper_crossings` on a uniform grid of cells of side ``cell``: each used edge is cut
    into pieces of at most ``cell`` and listed in the cells of each piece's box (2 x 2 at
    most); edge i is tested against the edges j > i + 1 listed in its cells. Edges in loop
    order, so the pairs come sorted by i; stops after the first edge i at which ``limit``
    pairs (0: no limit) are found. Returns the keys i * M + j (K,) int64."""
    m = a.shape[0]
    x0, y0, x1, y1 = np.inf, np.inf, -np.inf, -np.inf
    for k in range(m):
        if use[k]:
            x0 = min(x0, a[k, 0], b[k, 0])
            y0 = min(y0, a[k, 1], b[k, 1])
            x1 = max(x1, a[k, 0], b[k, 0])
            y1 = max(y1, a[k, 1], b[k, 1])
    ny = np.int64((y1 - y0) / cell) + 2
    pieces = np.zeros(m, dtype=np.int64)
    first = np.zeros(m + 1, dtype=np.int64)  # edge k's entries: first[k]:first[k + 1]
    for k in range(m):
        if use[k]:
            pieces[k] = max(1, np.int64(math.ceil(math.hypot(b[k, 0] - a[k, 0], b[k, 1] - a[k, 1]) / cell)))
            for q in range(pieces[k]):
                i0, i1, j0, j1 = _piece_cells(a, b, k, q, pieces[k], x0, y0, cell)
                first[k + 1] += (i1 - i0 + 1) * (j1 - j0 + 1)
    first = np.cumsum(first)
    keys = np.empty(first[m], dtype=np.int64)  # each entry's cell, edges in loop order
    owner = np.empty(first[m], dtype=np.int64)
    for k in range(m):
        e = first[k]
        for q in range(pieces[k]):
            i0, i1, j0, j1 = _piece_cells(a, b, k, q, pieces[k], x0, y0, cell)
            for ix in range(i0, i1 + 1):
                for iy in range(j0, j1 + 1):
                    keys[e] = ix * ny + iy
                    owner[e] = k
                    e += 1
    order = np.argsort(keys, kind="mergesort")
    cell_keys = keys[order]
    cell_edges = owner[order]
    seen = np.full(m, -1, dtype=np.int64)  # the last edge i that tested edge j
    out = np.empty(64, dtype=np.int64)
    count = 0
    for i in range(m):
        if not use[i]:
            continue
        start = count
        for s in range(first[i], first[i + 1]):
            lo = np.searchsorted(cell_keys, keys[s], side="left")
            hi = np.searchsorted(cell_keys, keys[s], side="right")
            for t in range(lo, hi):
                j = cell_edges[t]
                if j <= i + 1 or seen[j] == i or (i == 0 and j == m - 1):
                    continue
                seen[j] = i
                s1 = (b[i, 0] - a[i, 0]) * (a[j, 1] - a[i, 1]) - (b[i, 1] - a[i, 1]) * (a[j, 0] - a[i, 0])
                s2 = (b[i, 0] - a[i, 0]) * (b[j, 1] - a[i, 1]) - (b[i, 1] - a[i, 1]) * (b[j, 0] - a[i, 0])
                s3 = (b[j, 0] - a[j, 0]) * (a[i, 1] - a[j, 1]) - (b[j, 1] - a[j, 1]) * (a[i, 0] - a[j, 0])
                s4 = (b[j, 0] - a[j, 0]) * (b[i, 1] - a[j, 1]) - (b[j, 1] - a[j, 1]) * (b[i, 0] - a[j, 0])
                if s1 * s2 <= 0 and s3 * s4 <= 0 and not (s1 == 0 and s2 == 0):
                    if count == out.shape[0]:
                        grown = np.empty(2 * count, dtype=np.int64)
                        grown[:count] = out
                        out = grown
                    out[count] = i * m + j
                    count += 1
        out[start:count] = np.sort(out[start:count])
        if 0 < limit <= count:
            break
    return out[:count]


GAP_REL = 1e-2
"""`loop_crossing` looks at loops whose curves join end to start within GAP_REL x their (u, v) span."""
JUMP_REL = 0.1
"""A sample edge longer than JUMP_REL x the loop's (u, v) span (samples are 64 per knot span) is
a jump along a pole or across a seam: its crossings are not the loop's."""
MAX_CROSSINGS = 64
"""Crossings of one loop looked at (the first ones along the loop)."""


def loop_crossing(f: Face, li: int, lp: TrimLoop, width: float, min_length: float) -> Excursion | str | None:
    """Where loop ``li`` of face ``f`` crosses (or touches) itself in (u, v), on the exact curve
    samples (64 per knot span), if that matters. Each crossing splits the loop into two lobes;
    of the smaller one, L is its model-space loop length and 2 A / L its mean width (A: its
    model-space vector area). A lobe with L < ``min_length`` is below any mesh and left alone.
    A mean width above ``width`` is a real crossing (a figure eight): a message saying where
    comes back. Where the loop crosses itself at one place only and that lobe has L <=
    ``width``, the lobe is a tolerance artefact: an `Excursion` (kind "crossing", X and Y the
    crossing point on the two strands) that `cut_loop` cuts off. Thin lobes otherwise (a
    strand retraced beside itself, crossing it again and again) are left as they are. None
    when nothing is to be done."""
    bd = lp.boundary
    gap = bd.curve < 0
    if np.any(np.linalg.norm(bd.b[gap] - bd.a[gap], axis=1) > GAP_REL * bd.size):
        return None  # curves that do not join end to start (another order, a seam jump): no path along the loop
    ci, ts, uv, xyz = _samples(f, lp)
    keep = np.linalg.norm(uv - np.roll(uv, 1, axis=0), axis=1) > 0  # repeated samples: no edge between
    ci, ts, uv, xyz = ci[keep], ts[keep], uv[keep], xyz[keep]
    n = len(uv)
    if n < 4:
        return None
    nxt = np.roll(np.arange(n), -1)
    seg = np.linalg.norm(xyz[nxt] - xyz, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    jump = np.linalg.norm(uv[nxt] - uv, axis=1) > JUMP_REL * bd.size  # a pole or seam jump, not a strand
    hits = _proper_crossings(uv, uv[nxt], skip=jump, limit=MAX_CROSSINGS)
    found = []  # (length, i, j, s, r, crossing point uv, xyz, lobe sample indices)
    for i, j in hits[:MAX_CROSSINGS]:
        i, j = int(i), int(j)
        # crossing point: uv[i] + s (uv[i+1] - uv[i]) = uv[j] + r (uv[j+1] - uv[j])
        di, dj = uv[nxt[i]] - uv[i], uv[nxt[j]] - uv[j]
        try:
            s_, r_ = np.linalg.solve(np.column_stack([di, -dj]), uv[j] - uv[i])
        except np.linalg.LinAlgError:
            continue
        inner = float(cum[j] - cum[i + 1] + (1 - s_) * seg[i] + r_ * seg[j])  # lobe i -> j
        outer = float(cum[n] - inner)  # lobe j -> i (the rest)
        length = min(inner, outer)
        if length < min_length or not length > 0:
            continue
        if inner > outer:  # the smaller lobe runs j -> i: X on edge j, Y on edge i
            i, j, s_, r_ = j, i, r_, s_
            lobe = np.concatenate([np.arange(i + 1, n), np.arange(0, j + 1)])
        else:
            lobe = np.arange(i + 1, j + 1)
        p_uv = uv[i] + s_ * (uv[nxt[i]] - uv[i])
        p_xyz = f.surface.evaluate(p_uv[:1], p_uv[1:])[0]
        ring = np.vstack([p_xyz, xyz[lobe]]) - p_xyz
        mean_width = float(np.linalg.norm(np.cross(ring, np.roll(ring, -1, axis=0)).sum(axis=0))) / length
        if mean_width > width:
            which = "outer" if li == 0 else f"inner {li}"
            return (f"{f.name or 'face'} (DE {f.de}): its {which} trim loop crosses itself at (u, v) = "
                    f"({p_uv[0]:.6g}, {p_uv[1]:.6g}), ({p_xyz[0]:.6g}, {p_xyz[1]:.6g}, {p_xyz[2]:.6g}) in model "
                    f"space; the smaller lobe it encloses is {length:.3g} long and {mean_width:.3g} wide on "
                    f"average, wider than the trim tolerance {width:.3g} (IGES 5.3 4.34: trim loops are simple "
                    f"closed curves)")
        found.append((length, i, j, s_, r_, p_uv, p_xyz, lobe))
    if not found or max(np.linalg.norm(q[6] - found[0][6]) for q in found) > min_length:
        return None  # no crossing, or several apart: strands retraced beside each other, left as they are
    length, i, j, s_, r_, p_uv, p_xyz, lobe = min(found, key=lambda q: q[0])
    if length > width:
        return None

    def at(k: int, frac: float) -> tuple[int, float]:  # (curve, parameter) a fraction along sample edge k
        t1 = ts[nxt[k]] if ci[nxt[k]] == ci[k] else lp.curves[int(ci[k])].domain[1]
        return int(ci[k]), float(ts[k] + frac * (t1 - ts[k]))

    rest = np.setdiff1d(np.arange(n), lobe)
    p = np.vstack([p_uv, uv[lobe]])
    uv_area = 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))
    return Excursion(f.de, f.name, li, (at(i, s_), at(j, r_)), p_xyz, p_xyz.copy(), 0.0, length, uv_area,
                     stretch_uv=np.vstack([p_uv, uv[lobe], p_uv]), stretch_xyz=np.vstack([p_xyz, xyz[lobe], p_xyz]),
                     rest_xyz=np.vstack([p_xyz, xyz[rest], p_xyz]), kind="crossing")


def heal_excursions(model: Model, width: float | None = None, max_cuts: int = 4) -> list[Excursion]:
    """Cut every excursion (`find_excursions`) out of its loop, in place: each loop is cut
    until it has none (at most ``max_cuts`` times). Each face's trim tolerance is read before
    (it is measured on the file's curves). Returns the excursions cut, in order. Raises
    IgesError (`crossing_error`) for a loop that really crosses itself (both lobes longer
    than the width): no sound reading of that face exists."""
    done = []
    size = model.size()
    for f in model.faces:
        if f.trims is None:
            continue
        w = default_width(f, size) if width is None else width  # reads trim_delta first
        for li in range(1 + len(f.trims.inner)):
            for _ in range(max_cuts):
                lp = f.trims.outer if li == 0 else f.trims.inner[li - 1]
                if lp is None or not lp.curves:
                    break
                e = loop_crossing(f, li, lp, w, MIN_LENGTH * size)
                if isinstance(e, str):
                    raise crossing_error(model, f, li, e)
                if e is None:
                    e = _loop_excursion(f, li, lp, w, MIN_LENGTH * size)
                if e is None:
                    break
                new = cut_loop(lp, e)
                if li == 0:
                    f.trims.outer = new
                else:
                    f.trims.inner[li - 1] = new
                done.append(e)
    return done
