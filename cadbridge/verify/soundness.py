"""Is a converted tool sound? Its tool files measured against OpenCASCADE's reading of the CAD.

`tool_soundness(cad, tool_files)` reads the IGES file with OCC (`occ_read`, lengths in mm;
the copy the mesher reads, `cadbridge.heal.mesh_source`, so faces cadbridge re-read from
their model-space trim curves are trimmed the same way for OCC; trims from the curves the
file's 142s prefer where they all prefer the same, `_file_preference`) and the ``.nagata`` tool
files `convert` wrote (`cadbridge.io.toolfile.read_toolfile`, scaled from the file's units
to mm), and measures three things, all independent of cadbridge's own error estimates:

(a) nodes on the CAD: the distance of up to ``max_samples`` mesh nodes (evenly spread over
    the node list) to OCC's trimmed faces, relative to the model size (the diagonal of
    OCC's bounding box of the faces). Distance to one face: `GeomAPI_ProjectPointOnSurf`
    onto the face's surface within the face's (u, v) bounds, with both of OCC's searches
    (gradient and tree: each misses feet the other finds); the nearest foot that
    `BRepTopAdaptor_FClass2d` puts inside the face (IN or ON) gives the distance. Faces are
    visited in the order of their bounding-box distance until a box is farther than the
    best distance. When the best is beyond the tolerance, `BRepExtrema_DistShapeShape`
    between the point and every face whose box is near enough is measured too (the nearest
    point may be on a trim boundary), and the smaller distance counts.
(b) node normals: the angle between a node's normal (NORMALS) and OCC's surface normal
    (`GeomLProp_SLProps`, Su x Sv) at the node's foot, sign-insensitive (OCC faces may be
    reversed; the tool's side comes from the mesh winding); on a C0 knot line the nearer of
    the two one-sided normals counts (`_angle_deg`). For interior nodes only: the
    foot is strictly IN its face (not ON a trim edge), the node lies on no free mesh edge,
    no element corner overrides its normal (CORNER_NORMALS: a crease), and (checked where
    the angle exceeds the tolerance) the node is farther than ``EDGE_MARGIN_REL`` x size
    (at least 10 x the largest OCC edge tolerance) from its face's edges: a node on the
    seam of two faces that meet at a slight kink below the crease threshold has one normal
    for both, which need not be either face's own.
(c) patches bend toward the CAD: the Nagata surface at each sampled element's centre
    ((eta, zeta) = (2/3, 1/3) on a triangle, (1/2, 1/2) on a quad, from the written
    COEFFICIENTS) is no farther from OCC's faces than the flat element's centre (the mean
    of its corners), compared as the maxima over the sample (up to ``max_samples``
    elements; distances as in (a), `BRepExtrema_DistShapeShape` only on faces whose nearest
    surface foot lies outside them).

A check fails when (a) exceeds ``DIST_REL`` x size (at least the largest OCC edge
tolerance), (b) exceeds ``ANGLE_DEG``, or (c)'s Nagata maximum exceeds the flat maximum
by more than the distance tolerance. Loops over points are fine here: this is a yardstick.

``python -m cadbridge.verify.soundness CAD TOOL.nagata ...`` prints the report as JSON (the
corpus benchmark runs it in a subprocess, so an OCC crash or hang stays there).
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from OCP.BRep import BRep_Tool
from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeVertex
from OCP.BRepExtrema import BRepExtrema_DistShapeShape, BRepExtrema_IsInFace
from OCP.BRepTopAdaptor import BRepTopAdaptor_FClass2d
from OCP.Extrema import Extrema_ExtAlgo_Grad, Extrema_ExtAlgo_Tree
from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
from OCP.gp import gp_Pnt, gp_Pnt2d
from OCP.TopAbs import TopAbs_EDGE, TopAbs_IN, TopAbs_ON
from OCP.TopExp import TopExp_Explorer
from OCP.TopoDS import TopoDS

from cadbridge.verify.reference import OccFace, occ_normal, occ_read

__all__ = ["ANGLE_DEG", "DIST_REL", "SoundnessReport", "tool_soundness"]

DIST_REL = 1e-6  # node / centre distance tolerance, x model size
ANGLE_DEG = 1e-4  # node normal tolerance at interior nodes, degrees
EDGE_MARGIN_REL = 1e-4  # (b): nodes nearer than this x size to their face's edges are not interior
_UV_TOL = 1e-9  # BRepTopAdaptor_FClass2d tolerance (parameter space)


@dataclass
class SoundnessReport:
    """What `tool_soundness` measured. Distances are relative to ``size`` (mm)."""

    size: float
    to_mm: float
    tol_distance: float  # relative
    n_nodes: int = 0
    node_distance: float = float("nan")  # (a) max over the sampled nodes
    n_interior: int = 0
    normal_angle_deg: float = float("nan")  # (b) max over the sampled interior nodes
    n_centres: int = 0
    nagata_centre: float = float("nan")  # (c) max distance of the Nagata centres
    flat_centre: float = float("nan")  # (c) max distance of the flat centres
    failures: list[str] = field(default_factory=list)

    @property
    def sound(self) -> bool:
        return not self.failures

    def line(self) -> str:
        """"sound" or the failed checks with their values, one line."""
        return "sound" if self.sound else "; ".join(self.failures)


class _Faces:
    """OCC's faces of a shape with a nearest-point query (see the module docstring, (a))."""

    def __init__(self, faces: list[OccFace]):
        self.faces = faces
        self.lo = np.array([f.bbox[0] for f in faces])
        self.hi = np.array([f.bbox[1] for f in faces])
        self._proj: dict[int, tuple[GeomAPI_ProjectPointOnSurf, ...]] = {}
        self._class: dict[int, BRepTopAdaptor_FClass2d] = {}

    def _projectors(self, i: int) -> tuple[GeomAPI_ProjectPointOnSurf, ...]:
        """Both of OCC's point-surface searches on face i: each misses feet the other finds (the
        gradient search a foot on a quintic, the tree search one sheet of a surface that runs
        back over itself within 0.004 mm)."""
        if i not in self._proj:
            out = []
            for algo in (Extrema_ExtAlgo_Grad, Extrema_ExtAlgo_Tree):
                p = GeomAPI_ProjectPointOnSurf()
                p.Init(self.faces[i].surface, *self.faces[i].bounds, algo)
                out.append(p)
            self._proj[i] = tuple(out)
        return self._proj[i]

    def _state(self, i: int, u: float, v: float):
        if i not in self._class:
            self._class[i] = BRepTopAdaptor_FClass2d(self.faces[i].face, _UV_TOL)
        return self._class[i].Perform(gp_Pnt2d(u, v))

    def _project(self, i: int, x: np.ndarray) -> tuple[float, float, float, bool, bool]:
        """Distance from x to its nearest foot on face i's surface that lies inside the face
        (inf if none), the foot's (u, v), whether it is strictly inside, and whether it is the
        nearest foot on the surface at all (else the trim boundary may be nearer)."""
        feet = []
        for proj in self._projectors(i):
            proj.Perform(gp_Pnt(*map(float, x)))
            if proj.IsDone():
                feet += [(proj.Distance(k), *proj.Parameters(k)) for k in range(1, proj.NbPoints() + 1)]
        for rank, (d, u, v) in enumerate(sorted(feet)):
            state = self._state(i, u, v)
            if state in (TopAbs_IN, TopAbs_ON):
                return d, u, v, state == TopAbs_IN, rank == 0
        return float("inf"), float("nan"), float("nan"), False, False

    def _exact(self, i: int, x: np.ndarray) -> tuple[float, float, float, bool]:
        """Distance from x to the trimmed face i by `BRepExtrema_DistShapeShape` (inf on
        failure), the (u, v) of its foot and whether that is strictly inside the face (NaN,
        False when the foot is on an edge or vertex)."""
        vertex = BRepBuilderAPI_MakeVertex(gp_Pnt(*map(float, x))).Vertex()
        dss = BRepExtrema_DistShapeShape(vertex, self.faces[i].face)
        if not dss.IsDone() or dss.NbSolution() == 0:
            return float("inf"), float("nan"), float("nan"), False
        if dss.SupportTypeShape2(1) == BRepExtrema_IsInFace:
            u, v = dss.ParOnFaceS2(1)
            return dss.Value(), u, v, self._state(i, u, v) == TopAbs_IN
        return dss.Value(), float("nan"), float("nan"), False

    def edge_distance(self, i: int, x: np.ndarray) -> float:
        """Distance from x to the edges of face i (`BRepExtrema_DistShapeShape` per edge)."""
        vertex = BRepBuilderAPI_MakeVertex(gp_Pnt(*map(float, x))).Vertex()
        best = float("inf")
        exp = TopExp_Explorer(self.faces[i].face, TopAbs_EDGE)
        while exp.More():
            dss = BRepExtrema_DistShapeShape(vertex, exp.Current())
            if dss.IsDone() and dss.NbSolution() > 0:
                best = min(best, dss.Value())
            exp.Next()
        return best

    def nearest(self, x: np.ndarray, tol: float, exact: bool) -> tuple[float, int, float, float, bool]:
        """(distance, face, u, v, foot strictly inside) of the nearest point of the faces to x:
        projections first; if none is within ``tol`` (mm), `BRepExtrema_DistShapeShape` too, on
        every face whose box is near enough (``exact``) or only on those whose nearest surface
        foot lies outside the face (the nearest point may be on their trim boundary). The
        smaller distance counts."""
        box = np.linalg.norm(np.maximum(0.0, np.maximum(self.lo - x, x - self.hi)), axis=1)
        order = np.argsort(box, kind="stable")
        best = (float("inf"), -1, float("nan"), float("nan"), False)
        unsure = []  # faces whose trim boundary may be nearer than their surface foot
        for i in order:
            if box[i] > best[0]:
                break
            d, u, v, inside, first = self._project(int(i), x)
            if d < best[0]:
                best = (d, int(i), u, v, inside)
            if not first:
                unsure.append(i)
        if best[0] > tol:
            for i in order[box[order] <= best[0]] if exact else unsure:  # by box distance
                if box[i] > best[0]:
                    break
                d, u, v, inside = self._exact(int(i), x)
                if d < best[0]:
                    best = (d, int(i), u, v, inside)
        return best


def _edge_tolerance(faces: list[OccFace]) -> float:
    """Largest OCC tolerance of the faces' edges (mm)."""
    tol = 0.0
    for f in faces:
        exp = TopExp_Explorer(f.face, TopAbs_EDGE)
        while exp.More():
            tol = max(tol, BRep_Tool.Tolerance_s(TopoDS.Edge_s(exp.Current())))
            exp.Next()
    return tol


def _angle_deg(face: OccFace, u: float, v: float, normal: np.ndarray) -> float:
    """Sign-insensitive angle (degrees) between ``normal`` and OCC's normal of ``face`` at
    (u, v). On a knot line where the surface is only C0 the normal has two values, one from
    each side (four where two knot lines cross): OCC's normal is also taken 1e-9 x the face's
    parameter range to either side in u, in v and diagonally, and the nearest of the nine
    counts (over 1e-9 of the range a smooth normal turns by far less than the tolerance)."""
    u0, u1, v0, v1 = face.bounds
    hu, hv = 1e-9 * (u1 - u0), 1e-9 * (v1 - v0)
    du, dv = np.meshgrid([0.0, -hu, hu], [0.0, -hv, hv])
    us, vs = u + du.ravel(), v + dv.ravel()
    n = occ_normal(face.surface, us, vs)
    c = np.abs(n @ np.asarray(normal, dtype=float))
    c = c[np.isfinite(c)]
    return float(np.degrees(np.arccos(min(1.0, c.max())))) if len(c) else float("nan")


def _spread(n: int, k: int) -> np.ndarray:
    """Up to k indices evenly spread over range(n)."""
    return np.arange(n) if n <= k else np.unique(np.linspace(0, n - 1, k).round().astype(np.int64))


def _tool_arrays(tools, to_mm: float):
    """Nodes, normals, the interior-candidate mask and the (Nagata, flat) element centres of
    all tools, in mm."""
    from cadbridge.nagata.patch import quad_eval, tri_eval

    nodes, normals, candidate, nag, flat = [], [], [], [], []
    for t in tools:
        ok = np.ones(len(t.nodes), dtype=bool)
        elems = [t.triangles, t.quads]
        edges = np.concatenate([np.stack([e, np.roll(e, -1, axis=1)], axis=2).reshape(-1, 2) for e in elems if len(e)]
                               or [np.zeros((0, 2), dtype=np.int64)])
        if len(edges):
            key, count = np.unique(np.sort(edges, axis=1), axis=0, return_counts=True)
            ok[key[count == 1].ravel()] = False  # nodes on free mesh edges
        corner_node = np.array([(t.triangles[e] if e < len(t.triangles) else t.quads[e - len(t.triangles)])[c]
                                for e, c in zip(t.corner_element, t.corner_local)], dtype=np.int64)
        ok[corner_node] = False  # a crease: the node has more than one normal
        nodes.append(t.nodes * to_mm)
        normals.append(t.normals)
        candidate.append(ok)
        if t.tri_coefficients is not None and len(t.triangles):
            m = len(t.triangles)
            nag.append(tri_eval(t.tri_coefficients, np.full(m, 2 / 3), np.full(m, 1 / 3), order=0)[0] * to_mm)
            flat.append(t.nodes[t.triangles].mean(axis=1) * to_mm)
        if t.quad_coefficients is not None and len(t.quads):
            m = len(t.quads)
            nag.append(quad_eval(t.quad_coefficients, np.full(m, 0.5), np.full(m, 0.5), order=0)[0] * to_mm)
            flat.append(t.nodes[t.quads].mean(axis=1) * to_mm)
    cat = lambda a, w: np.concatenate(a) if a else np.zeros((0,) + w)  # noqa: E731
    return cat(nodes, (3,)), cat(normals, (3,)), cat(candidate, ()).astype(bool), cat(nag, (3,)), cat(flat, (3,))


def _file_preference(path) -> int | None:
    """OCC's read.surfacecurve.mode that reads an IGES file's trims as its 142 curves say, where
    they all say the same: -2 (parameter space) where every PREF is 1, -3 (model space) where
    every one is 2; None (OCC's default) otherwise, and for other formats. OCC's default may
    take the other curve: on ANSA's OCC131-1 (PREF 1, a loop of 112 parametric splines 0.004
    mm from its model-space curves) it bounds the face by the model-space curves, up to 0.004
    mm inside the one the file prefers, which OCC builds, valid by BRepCheck, when told to."""
    from cadbridge.formats import cad_format

    if str(path).lower().endswith(".brep") or cad_format(path) != "iges":
        return None
    from cadbridge.iges import IgesError
    from cadbridge.iges.reader import curve_preferences

    try:
        prefs = set(curve_preferences(path).values())
    except IgesError:
        return None
    return {frozenset({1}): -2, frozenset({2}): -3}.get(frozenset(prefs))


def tool_soundness(cad: str | os.PathLike, tool_files: list[str | os.PathLike], *, max_samples: int = 2000
                   ) -> SoundnessReport:
    """Checks (a), (b), (c) of the module docstring for the tool files ``convert`` wrote from ``cad``."""
    from cadbridge.formats import read_cad
    from cadbridge.heal.mesh_source import mesh_source
    from cadbridge.io.toolfile import read_toolfile

    model = read_cad(cad)
    with mesh_source(cad, model) as src:
        faces = occ_read(src, surface_curves=_file_preference(src))
    to_mm = float(model.units.to_mm)
    if not faces:
        return SoundnessReport(float("nan"), to_mm, DIST_REL, failures=["OCC reads no face"])
    lo = np.min([f.bbox[0] for f in faces], axis=0)
    hi = np.max([f.bbox[1] for f in faces], axis=0)
    size = float(np.linalg.norm(hi - lo))
    tol = max(DIST_REL, _edge_tolerance(faces) / size)
    rep = SoundnessReport(size, to_mm, tol)
    occ = _Faces(faces)
    margin = max(EDGE_MARGIN_REL * size, 10 * _edge_tolerance(faces))
    nodes, normals, candidate, nag, flat = _tool_arrays([read_toolfile(p) for p in tool_files], to_mm)

    pick = _spread(len(nodes), max_samples)
    dist = np.empty(len(pick))
    angles = []
    for k, j in enumerate(pick):
        d, i, u, v, inside = occ.nearest(nodes[j], tol * size, exact=True)
        dist[k] = d
        if inside and candidate[j]:
            a = _angle_deg(faces[i], u, v, normals[j])
            if a > ANGLE_DEG and occ.edge_distance(i, nodes[j]) < margin:
                continue  # on a trim edge after all (a face seam the mesh runs along)
            if np.isfinite(a):
                angles.append(a)
    rep.n_nodes = len(pick)
    rep.node_distance = float(dist.max()) / size if len(pick) else float("nan")
    rep.n_interior = len(angles)
    rep.normal_angle_deg = float(max(angles)) if angles else float("nan")

    pick = _spread(len(nag), max_samples)
    rep.n_centres = len(pick)
    if len(pick):
        rep.nagata_centre = max(occ.nearest(nag[j], tol * size, exact=False)[0] for j in pick) / size
        rep.flat_centre = max(occ.nearest(flat[j], tol * size, exact=False)[0] for j in pick) / size

    if not len(nodes):
        rep.failures.append("no nodes in the tool files")
    if rep.node_distance > tol:
        rep.failures.append(f"nodes off the CAD: {rep.node_distance:.2e} x size (tolerance {tol:.0e})")
    if rep.normal_angle_deg > ANGLE_DEG:
        rep.failures.append(f"node normals off OCC's: {rep.normal_angle_deg:.2e} deg (tolerance {ANGLE_DEG:.0e})")
    if rep.n_centres and rep.nagata_centre > rep.flat_centre + tol:
        rep.failures.append(f"Nagata centres farther than flat: {rep.nagata_centre:.2e} > {rep.flat_centre:.2e} x size")
    if not rep.n_centres:
        rep.failures.append("no patch coefficients in the tool files")
    return rep


def main(argv: list[str] | None = None) -> int:
    """``python -m cadbridge.verify.soundness CAD TOOL.nagata ...``: the report as JSON on stdout."""
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) < 2:
        print("usage: python -m cadbridge.verify.soundness CAD TOOL.nagata [TOOL.nagata ...]", file=sys.stderr)
        return 2
    rep = tool_soundness(argv[0], [Path(p) for p in argv[1:]])
    print()  # OCC's reader prints to stdout too: the JSON is the last line
    print(json.dumps({**asdict(rep), "sound": rep.sound, "line": rep.line()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
