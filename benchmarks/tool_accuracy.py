"""Tool-file accuracy against OpenCASCADE (issue #13, "Every sample"): a script, not a test.

For every file of iges_samples/*.igs and ../shared/iges_real/*, in tri and in quad:

1. run ``cadbridge convert FILE -o TMP --element E`` as a subprocess with a timeout (exit
   code, wall time, last stderr line on failure). If convert refuses a tool as worse than
   its flat mesh (exit 1), the row says so and, with ``--retry-allow-worse`` (default on),
   the file is converted again with ``--allow-worse`` to measure it anyway (such a row never
   passes);
2. read every written tool file with the independent reader ``tests/helpers/toolfile_reference.py``
   (written from docs/toolfile.md alone), sample every patch on an ``--div``-division grid
   (default 4: 15 points per triangle, 25 per quad), evaluate the Nagata point from the
   file's COEFFICIENTS and the flat element point (triangle x00 + (x10-x00) eta +
   (x11-x10) zeta, quad bilinear) at the same (eta, zeta);
3. measure both against OpenCASCADE: the IGES read by ``IGESControl_Reader``
   (``cadbridge.verify.reference.occ_read``: OCC's reader and surfaces, none of cadbridge's
   geometry); each element goes to the OCC face nearest its flat centroid
   (``BRepExtrema_DistShapeShape`` vertex vs a compound of all faces, ``SupportOnShape2``; when the
   support is an edge or a vertex, the adjacent face whose surface is nearest the centroid),
   and each sample's surface error is its distance to that face's untrimmed surface
   (``GeomAPI_ProjectPointOnSurf`` on ``BRep_Tool.Surface``, location applied). If the
   element's corner nodes are not on that face's surface (1e-6 x size), e.g. an element
   along a sharp face border whose chord centroid is nearer the neighbour face, the element
   goes instead to the face, among those nearest its centroid and its corners, whose surface
   holds the corners best; the row counts such elements (and those on no single face).
   A sample whose foot is on the border of that surface's parameter domain lies beyond the
   surface (e.g. an element whose centroid is nearest one face but which runs over its
   neighbour): it is measured to the trimmed faces (``BRepExtrema_DistShapeShape`` to the
   compound of all faces) where that is smaller; the row counts such samples. So is every
   sample of an element whose corners lie on no single OCC face (OCC's faces split the
   surface otherwise there, or its reading differs from the tool's by more than 1e-6 x size):
   no one untrimmed surface holds it (on the bearing's quad mesh such an element measured
   3.7e-5 mm to the best face's surface with a normal part of 0, its corners 5.4e-4 off it).

Pass: max Nagata surface error <= 0.25 x max flat surface error, or both below 1e-9 x size
(size = diagonal of the tool file's node box, the largest over the file's tools).

At most ``--max-samples`` samples per (file, element type) (default 200 000): beyond that,
every k-th element is measured (k = ceil(samples / cap)), and the row says how many
elements were measured. OCC calls are Python loops (this is a benchmark).

    python benchmarks/tool_accuracy.py [--only SUBSTRING] [--timeout 600] [--div 4]
        [--max-samples 200000] [--elements tri quad] [--no-real] [--no-samples]

Prints a Markdown table and writes it to benchmarks/results/tool_accuracy.md.
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.helpers import toolfile_reference as R  # noqa: E402

SAMPLES = ROOT / "iges_samples"
REAL = ROOT.parent / "shared" / "iges_real"
RESULTS = ROOT / "benchmarks" / "results"
UNIT_MM = {"MM": 1.0, "CM": 10.0, "M": 1000.0, "IN": 25.4, "INCH": 25.4, "FT": 304.8, "UM": 1e-3, "MICRON": 1e-3}


@dataclass
class Row:
    file: str
    element: str
    exit_code: int | None = None
    convert_s: float = 0.0
    message: str = ""
    tools: list[str] = field(default_factory=list)
    elements: int = 0
    measured: int = 0
    samples: int = 0
    nagata: float = float("nan")
    flat: float = float("nan")
    size: float = float("nan")
    measure_s: float = 0.0
    refused: bool = False
    unassigned: int = 0
    nagata_normal: float = float("nan")  # max |(x - foot) . n|: the normal part only
    flat_normal: float = float("nan")
    no_projection: int = 0  # samples OCC found no projection for
    foot_on_border: int = 0  # Nagata samples whose foot is on the border of the surface's domain
    worst_nagata: tuple = (0.0, False, 0.0)  # (distance, foot on border, normal part) of the worst sample
    rebuild_dev: float = float("nan")  # max |rebuilt - written COEFFICIENTS| / size over the tools
    reassigned: int = 0  # elements whose corners are not on the face nearest their centroid
    straddling: int = 0  # elements whose corners lie on no single face (within 1e-6 x size)
    node_gap: float = 0.0  # max distance of an element's corner nodes to its face's surface
    exit_code_first: int | None = None  # of the plain convert, when a retry with --allow-worse followed
    beyond_border: int = 0  # samples beyond their face's surface border measured to the trimmed faces
    cpu: tuple = (float("nan"), float("nan"))  # (CPU s of the first convert, 1-min load average after it)

    def _ok(self, nag: float, flat: float) -> bool:
        if self.exit_code != 0 or self.refused or self.unassigned or self.no_projection or not self.rebuild_dev <= 1e-9:
            return False
        if not (np.isfinite(nag) and np.isfinite(flat)):
            return False
        tol = 1e-9 * self.size
        if nag <= tol and flat <= tol:
            return True
        return bool(nag <= 0.25 * flat)

    @property
    def ratio(self) -> float:
        return self.nagata / self.flat if self.flat > 0 else float("nan")

    @property
    def ratio_normal(self) -> float:
        return self.nagata_normal / self.flat_normal if self.flat_normal > 0 else float("nan")

    @property
    def passed(self) -> bool:
        return self._ok(self.nagata, self.flat)

    @property
    def passed_normal(self) -> bool:
        return self._ok(self.nagata_normal, self.flat_normal)


def cadbridge_cmd() -> list[str]:
    exe = Path(sys.executable).with_name("cadbridge")
    if exe.exists():
        return [str(exe)]
    found = shutil.which("cadbridge")
    if found:
        return [found]
    return [sys.executable, "-c", "import sys; from cadbridge.cli import main; sys.exit(main())"]


LAST_CPU = [float("nan"), float("nan")]  # CPU seconds of the last convert subprocess, 1-min load after it


def run_convert(cad: Path, out: Path, element: str, timeout: float, extra: list[str]) -> tuple[int | None, float, str]:
    cmd = cadbridge_cmd() + ["convert", str(cad), "-o", str(out), "--element", element] + extra
    t0 = time.perf_counter()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        LAST_CPU[0] = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
        LAST_CPU[1] = os.getloadavg()[0]
    except subprocess.TimeoutExpired as exc:
        err = (exc.stderr or b"")
        err = err.decode(errors="replace") if isinstance(err, bytes) else err
        last = [ln for ln in err.splitlines() if ln.strip()]
        return None, time.perf_counter() - t0, f"timeout after {timeout:.0f} s" + (f" (last: {last[-1].strip()[:200]})" if last else "")
    dt = time.perf_counter() - t0
    lines = [ln for ln in (p.stderr or "").replace("\r", "\n").splitlines() if ln.strip()]
    return p.returncode, dt, (lines[-1].strip() if lines and p.returncode != 0 else "")


class OccReference:
    """OCC faces of one IGES file, nearest-face lookup and point-to-surface distances."""

    def __init__(self, cad: Path) -> None:
        from OCP.TopAbs import TopAbs_FACE
        from OCP.TopExp import TopExp
        from OCP.TopTools import TopTools_IndexedDataMapOfShapeListOfShape, TopTools_IndexedMapOfShape

        from OCP.BRep import BRep_Tool
        from OCP.TopExp import TopExp_Explorer
        from OCP.TopLoc import TopLoc_Location
        from OCP.TopoDS import TopoDS

        from cadbridge.verify.reference import occ_read_shape

        self.shape = occ_read_shape(cad)
        fmap = TopTools_IndexedMapOfShape()
        TopExp.MapShapes_s(self.shape, TopAbs_FACE, fmap)
        self._face_index = fmap  # face -> 1-based index, the index used below (minus 1)
        # distances are taken to a compound of the faces, not to the shape: for a solid,
        # BRepExtrema_DistShapeShape gives 0 for a point inside it (the flat centroid of a
        # convex part, e.g. a chord of a cylinder)
        from OCP.BRep import BRep_Builder
        from OCP.TopoDS import TopoDS_Compound

        builder, self.faces_compound = BRep_Builder(), TopoDS_Compound()
        builder.MakeCompound(self.faces_compound)
        for i in range(1, fmap.Extent() + 1):
            builder.Add(self.faces_compound, fmap.FindKey(i))
        self.surfaces = []
        for i in range(1, fmap.Extent() + 1):
            face = TopoDS.Face_s(fmap.FindKey(i))
            loc = TopLoc_Location()
            surf = BRep_Tool.Surface_s(face, loc)
            if not loc.IsIdentity():
                surf = surf.Transformed(loc.Transformation())
            self.surfaces.append(surf)
        self._anc = {}
        for kind_name in ("EDGE", "VERTEX"):
            from OCP import TopAbs

            m = TopTools_IndexedDataMapOfShapeListOfShape()
            TopExp.MapShapesAndAncestors_s(self.shape, getattr(TopAbs, f"TopAbs_{kind_name}"), TopAbs_FACE, m)
            self._anc[kind_name] = m
        self._proj = {}
        self._sas = {}

    def _projector(self, k: int):
        from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf

        from cadbridge.verify.reference import _finite_bounds

        if k not in self._proj:
            s = self.surfaces[k]
            p = GeomAPI_ProjectPointOnSurf()
            p.Init(s, *_finite_bounds(s))
            self._proj[k] = p
        return self._proj[k]

    def _analyser(self, k: int):
        """OCC's ShapeAnalysis_Surface of face k's surface (its own point projection)."""
        from OCP.ShapeAnalysis import ShapeAnalysis_Surface

        if k not in self._sas:
            self._sas[k] = ShapeAnalysis_Surface(self.surfaces[k])
        return self._sas[k]

    def distance(self, k: int, x: np.ndarray, normal_part: bool = False):
        """Distance (M,) of points x (M, 3) to the untrimmed surface of face k (inf where OCC
        finds no projection). With ``normal_part``, also |(x - foot) . n(foot)| (M,) and
        whether the foot is on the border of the surface's parameter domain (M,)."""
        from OCP.GeomLProp import GeomLProp_SLProps
        from OCP.gp import gp_Pnt

        from cadbridge.verify.reference import _finite_bounds

        p = self._projector(k)
        out = np.full(len(x), np.inf)
        npart = np.full(len(x), np.inf)
        edge = np.zeros(len(x), dtype=bool)
        if normal_part:
            props = GeomLProp_SLProps(self.surfaces[k], 1, 1e-12)
            u0, u1, v0, v1 = _finite_bounds(self.surfaces[k])
            eu, ev = 1e-9 * max(1.0, abs(u1 - u0)), 1e-9 * max(1.0, abs(v1 - v0))
        sas = self._analyser(k)
        for i, xx in enumerate(x):
            pnt = gp_Pnt(float(xx[0]), float(xx[1]), float(xx[2]))
            p.Perform(pnt)
            if p.IsDone() and p.NbPoints() > 0:
                out[i] = p.LowerDistance()
                u, v = p.LowerDistanceParameters()
                f = np.array(p.NearestPoint().Coord())
                # GeomAPI's extrema can stop in another local minimum (on the bearing's planar
                # degree-(3, 1) face DE 3399 it found 3.7e-5 mm for a point lying on the surface):
                # OCC's ShapeAnalysis_Surface projection too, the nearer foot kept
                uv = sas.ValueOfUV(pnt, 1e-13 * max(1.0, float(np.abs(xx).max())))
                f2 = np.array(self.surfaces[k].Value(uv.X(), uv.Y()).Coord())
                d2 = float(np.linalg.norm(xx - f2))
                if d2 < out[i]:
                    out[i], u, v, f = d2, uv.X(), uv.Y(), f2
                if normal_part:
                    props.SetParameters(u, v)
                    if props.IsNormalDefined():
                        npart[i] = abs(float(np.dot(xx - f, props.Normal().Coord())))
                    else:
                        npart[i] = out[i]
                    edge[i] = min(u - u0, u1 - u) <= eu or min(v - v0, v1 - v) <= ev
        miss = np.flatnonzero(~np.isfinite(out))
        if len(miss):  # no foot (e.g. at the pole of a surface of revolution): BRepExtrema instead
            out[miss] = self._surface_face_distance(k, x[miss])
            npart[miss] = out[miss]  # the whole distance: no foot, no normal
            edge[miss] = True  # a pole is a border of the parameter domain
            self.pole_feet += len(miss)
        if normal_part:
            return out, npart, edge
        return out

    pole_feet = 0  # points GeomAPI_ProjectPointOnSurf found no foot for (measured by BRepExtrema)

    def _surface_face_distance(self, k: int, x: np.ndarray) -> np.ndarray:
        """Distance (M,) of points x (M, 3) to the untrimmed surface of face k as a face over its
        whole (finite) parameter domain (BRepExtrema_DistShapeShape), where the projection
        finds no foot."""
        from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakeVertex
        from OCP.BRepExtrema import BRepExtrema_DistShapeShape
        from OCP.gp import gp_Pnt

        from cadbridge.verify.reference import _finite_bounds

        cache = self.__dict__.setdefault("_surface_faces", {})
        if k not in cache:
            cache[k] = BRepBuilderAPI_MakeFace(self.surfaces[k], *_finite_bounds(self.surfaces[k]), 1e-7).Face()
        out = np.full(len(x), np.inf)
        for i, xx in enumerate(x):
            d = BRepExtrema_DistShapeShape(BRepBuilderAPI_MakeVertex(gp_Pnt(*map(float, xx))).Vertex(), cache[k])
            if d.IsDone() and d.NbSolution() > 0:
                out[i] = d.Value()
        return out

    def trimmed_distance(self, x: np.ndarray, near: int | None = None) -> np.ndarray:
        """Distance (M,) of points x (M, 3) to the trimmed faces (BRepExtrema_DistShapeShape
        to the compound of all faces; with ``near`` = k, of face k and the faces sharing an
        edge or a vertex with it, which is where a sample whose foot is on face k's domain
        border lies)."""
        from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeVertex
        from OCP.BRepExtrema import BRepExtrema_DistShapeShape
        from OCP.gp import gp_Pnt

        target = self.faces_compound if near is None else self._neighbour_compound(near)
        out = np.full(len(x), np.inf)
        for i, xx in enumerate(x):
            v = BRepBuilderAPI_MakeVertex(gp_Pnt(*map(float, xx))).Vertex()
            d = BRepExtrema_DistShapeShape(v, target)
            if d.IsDone() and d.NbSolution() > 0:
                out[i] = d.Value()
            if near is None:
                continue
            # a face beyond the neighbours can still be nearer (narrow faces: a neighbour's
            # neighbour): every face whose bounding box lies within the distance found is
            # measured too, so the result is the distance to all trimmed faces
            lo, hi = self._boxes()
            gap = np.linalg.norm(np.maximum(0.0, np.maximum(lo - xx, xx - hi)), axis=1)
            for f in np.flatnonzero(gap < out[i]):
                if int(f) in self._neighbour_ids[near]:
                    continue
                d = BRepExtrema_DistShapeShape(v, self._face_index.FindKey(int(f) + 1))
                if d.IsDone() and d.NbSolution() > 0:
                    out[i] = min(out[i], d.Value())
        return out

    def _boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding boxes (``BRepBndLib``) of the faces: lo, hi (F, 3)."""
        if not hasattr(self, "_box_lo"):
            from OCP.BRepBndLib import BRepBndLib
            from OCP.Bnd import Bnd_Box

            lo, hi = [], []
            for i in range(1, self._face_index.Extent() + 1):
                b = Bnd_Box()
                BRepBndLib.AddOptimal_s(self._face_index.FindKey(i), b, False, True)  # exact: see verify.reference.occ_read
                x0, y0, z0, x1, y1, z1 = b.Get()
                lo.append((x0, y0, z0))
                hi.append((x1, y1, z1))
            self._box_lo, self._box_hi = np.array(lo), np.array(hi)
        return self._box_lo, self._box_hi

    def _neighbour_compound(self, k: int):
        """Compound of face k (0-based) and the faces sharing an edge or a vertex with it."""
        from OCP.BRep import BRep_Builder
        from OCP.TopAbs import TopAbs_EDGE, TopAbs_VERTEX
        from OCP.TopExp import TopExp_Explorer
        from OCP.TopoDS import TopoDS_Compound

        cache = self.__dict__.setdefault("_neighbours", {})
        if k not in cache:
            face = self._face_index.FindKey(k + 1)
            ids = {k}
            for kind, name in ((TopAbs_EDGE, "EDGE"), (TopAbs_VERTEX, "VERTEX")):
                m = self._anc[name]
                ex = TopExp_Explorer(face, kind)
                while ex.More():
                    idx = m.FindIndex(ex.Current())
                    if idx > 0:
                        for f in m.FindFromIndex(idx):
                            ids.add(self._face_index.FindIndex(f) - 1)
                    ex.Next()
            builder, comp = BRep_Builder(), TopoDS_Compound()
            builder.MakeCompound(comp)
            for i in sorted(i for i in ids if i >= 0):
                builder.Add(comp, self._face_index.FindKey(i + 1))
            cache[k] = comp
            self.__dict__.setdefault("_neighbour_ids", {})[k] = ids
        return cache[k]

    def faces_holding(self, corners: np.ndarray, nn: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
        """For elements with corner points ``corners`` (E, 4, 3) (the first ``nn`` (E,) valid),
        the OCC face whose untrimmed surface holds all corners best and that largest corner
        distance: (face (E,) 0-based, -1 if none; gap (E,)). Candidates are the faces whose
        bounding box (``BRepBndLib``) holds the corners within ``tol``; no BRepExtrema."""
        self._boxes()
        valid = np.arange(corners.shape[1])[None, :] < nn[:, None]  # (E, 4)
        clo = np.where(valid[..., None], corners, np.inf).min(axis=1)
        chi = np.where(valid[..., None], corners, -np.inf).max(axis=1)
        best = np.full(len(corners), -1, dtype=np.int64)
        gap = np.full(len(corners), np.inf)
        for f in range(len(self._box_lo)):  # loop over faces, vectorised over elements
            els = np.flatnonzero(np.all(clo >= self._box_lo[f] - tol, axis=1) & np.all(chi <= self._box_hi[f] + tol, axis=1))
            if not len(els):
                continue
            pts = corners[els][valid[els]]  # (P, 3)
            d = self.distance(f, pts)
            owner = np.repeat(np.arange(len(els)), nn[els])
            g = np.full(len(els), -np.inf)
            np.maximum.at(g, owner, d)
            better = g < gap[els]
            gap[els[better]] = g[better]
            best[els[better]] = f
        return best, gap

    def nearest_face(self, x: np.ndarray) -> int:
        """Index (0-based, TopExp.MapShapes order) of the face nearest to point x; -1 if none."""
        from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeVertex
        from OCP.BRepExtrema import BRepExtrema_DistShapeShape
        from OCP.TopAbs import TopAbs_EDGE, TopAbs_FACE, TopAbs_VERTEX
        from OCP.gp import gp_Pnt

        v = BRepBuilderAPI_MakeVertex(gp_Pnt(*map(float, x))).Vertex()
        d = BRepExtrema_DistShapeShape(v, self.faces_compound)
        if not d.IsDone() or d.NbSolution() == 0:
            return -1
        best, best_d = -1, np.inf
        for s in range(1, d.NbSolution() + 1):
            sup = d.SupportOnShape2(s)
            t = sup.ShapeType()
            if t == TopAbs_FACE:
                cands = [self._face_index.FindIndex(sup) - 1]
            elif t in (TopAbs_EDGE, TopAbs_VERTEX):
                m = self._anc["EDGE" if t == TopAbs_EDGE else "VERTEX"]
                idx = m.FindIndex(sup)
                cands = []
                if idx > 0:
                    for f in m.FindFromIndex(idx):
                        cands.append(self._face_index.FindIndex(f) - 1)
            else:
                cands = []
            for c in cands:
                if c < 0:
                    continue
                dd = float(self.distance(c, x[None])[0])
                if dd < best_d:
                    best, best_d = c, dd
        return best


def _reference(cad: Path, row: Row) -> OccReference:
    """OCC's reading of ``cad``; where cadbridge's reader re-read faces (`cadbridge.heal.mesh_source`:
    parameter-space trims that contradict the file's own model-space curves), OCC reads a
    copy whose 142s of those faces prefer their model-space curves, as the mesher does: the
    CAD is then what the file's model-space curves say, read by OCC. Only that: the mesher's
    copy also smooths short C0 trim pieces (`cadbridge.heal.trim_knots`), which the reference
    must not see."""
    import tempfile

    import cadbridge
    from cadbridge.heal.mesh_source import reread_faces, write_mesh_source

    model = cadbridge.read_iges(cad)
    with tempfile.TemporaryDirectory(prefix="cadbridge-ref-") as tmp:
        src = write_mesh_source(cad, model, tmp, smooth=False)
        occ = OccReference(src)
    if src != cad:
        des = ", ".join(str(d) for d in reread_faces(model))
        row.message = "; ".join(x for x in (row.message, f"OCC reads the faces DE {des} from their model-space "
                                            "curves (142 PREF 2), as the mesher does") if x)
    return occ


def measure(row: Row, cad: Path, out: Path, div: int, max_samples: int) -> None:
    t0 = time.perf_counter()
    files = sorted(out.glob("*.nagata"))
    row.tools = [f.stem for f in files]
    tfs = [R.read(f) for f in files]
    row.elements = sum(tf.n_elements for tf in tfs)
    if not tfs:
        row.message = row.message or "no tool file written"
        return
    devs = []
    for tf in tfs:  # acceptance "Coefficients": written == rebuilt by the documented rule
        if tf.coefficients is None:
            devs.append(np.inf)
        else:
            devs.append(float(np.abs(R.rebuild(tf) - tf.coefficients).max(initial=0)) / R.model_size(tf))
    row.rebuild_dev = max(devs)
    per = [R.sample_grid(tf, div) for tf in tfs]
    total = sum(len(p[0]) for p in per)
    stride = max(1, math.ceil(total / max_samples))
    occ = _reference(cad, row)
    nag_max = flat_max = nag_n = flat_n = 0.0
    row.size = 0.0
    for tf, (elem, eta, zeta) in zip(tfs, per):
        scale = UNIT_MM.get(tf.units.upper())
        if scale is None:
            raise SystemExit(f"{cad}: tool units {tf.units!r} unknown to this benchmark")
        row.size = max(row.size, R.model_size(tf) * scale)
        keep_elem = np.arange(0, tf.n_elements, stride)
        row.measured += len(keep_elem)
        sel = np.isin(elem, keep_elem)
        elem, eta, zeta = elem[sel], eta[sel], zeta[sel]
        xn = R.evaluate(tf.coefficients if tf.coefficients is not None else R.rebuild(tf), elem, eta, zeta) * scale
        xf = R.flat(tf, elem, eta, zeta) * scale
        row.samples += len(elem)
        X = tf.nodes[np.maximum(tf.conn[keep_elem], 0)] * scale
        cent = np.where((tf.nn[keep_elem] == 3)[:, None], X[:, :3].mean(axis=1), X.mean(axis=1))
        face_of = {}
        across: set[int] = set()
        ontol = 1e-6 * R.model_size(tf) * scale  # a corner node "on" a surface (nodes are CAD points)
        # each element to the face whose surface holds its corners (box candidates, OCC's
        # projection); BRepExtrema's nearest face only for elements no face holds
        held, held_gap = occ.faces_holding(np.pad(X, ((0, 0), (0, 4 - X.shape[1]), (0, 0))),
                                           np.asarray(tf.nn[keep_elem]), ontol + 1e-9 * row.size)
        for e, c, xe, k0, g0 in zip(keep_elem, cent, X, held, held_gap):
            if k0 >= 0 and g0 <= ontol:
                face_of[int(e)] = int(k0)
                row.node_gap = max(row.node_gap, float(g0))
                continue
            k = occ.nearest_face(c)
            corners = xe[: tf.nn[e]]
            gap = float(np.max(occ.distance(k, corners))) if k >= 0 else np.inf
            if gap <= ontol:
                face_of[int(e)] = k
                row.node_gap = max(row.node_gap, gap)
                continue
            # the flat centroid is nearer another face than the element's own (the element
            # runs along a face border): take, among the faces nearest its centroid and its
            # corners, the one whose surface holds all corners (smallest max distance)
            cands = {k} | {occ.nearest_face(x) for x in corners}
            cands.discard(-1)
            best = min(cands, key=lambda f: float(np.max(occ.distance(f, corners))), default=-1)
            if best != k:
                row.reassigned += 1
            gap = float(np.max(occ.distance(best, corners))) if best >= 0 else np.inf
            if gap > ontol:
                row.straddling += 1  # corners on no single face: measured against `best`
                row.node_gap = max(row.node_gap, gap)
                across.add(int(e))
            face_of[int(e)] = best
        fa = np.array([face_of[int(e)] for e in elem])
        # an element whose corners lie on no single OCC face (OCC splits the surface there
        # otherwise than the tool's faces, or its reading differs) has no one untrimmed surface
        # to be measured against: its samples take the distance to the trimmed faces, if smaller
        off_one = np.isin(elem, np.fromiter(across, dtype=np.int64, count=len(across)))
        row.unassigned += sum(1 for v in face_of.values() if v < 0)
        for k in np.unique(fa):
            if k < 0:
                continue
            s = fa == k
            dn, pn, en = occ.distance(int(k), xn[s], normal_part=True)
            df, pf, ef = occ.distance(int(k), xf[s], normal_part=True)
            # a foot on the border of the surface's domain: the sample lies beyond the surface,
            # where the CAD is the neighbouring face (an element whose centroid is nearest one
            # face but runs over another): the distance to the trimmed faces, if smaller
            for d_, e_, x_ in ((dn, en, xn[s]), (df, ef, xf[s])):
                b = np.flatnonzero(e_ | off_one[s])
                if len(b):
                    dt = occ.trimmed_distance(x_[b], near=int(k))
                    row.beyond_border += int(np.count_nonzero(dt < d_[b]))
                    d_[b] = np.minimum(d_[b], dt)
            nag_max, flat_max = max(nag_max, float(dn.max())), max(flat_max, float(df.max()))
            nag_n, flat_n = max(nag_n, float(pn.max())), max(flat_n, float(pf.max()))
            row.no_projection += int(np.count_nonzero(~np.isfinite(dn)) + np.count_nonzero(~np.isfinite(df)))
            row.foot_on_border += int(np.count_nonzero(en))
            if dn.max() > row.worst_nagata[0]:
                i = int(np.argmax(dn))
                row.worst_nagata = (float(dn[i]), bool(en[i]), float(pn[i]))
    row.nagata, row.flat = nag_max, flat_max
    row.nagata_normal, row.flat_normal = nag_n, flat_n
    if occ.pole_feet:
        row.message = "; ".join(x for x in (row.message, f"{occ.pole_feet} points without a projection foot (poles) "
                                            "measured by BRepExtrema to their untrimmed surface") if x)
    row.measure_s = time.perf_counter() - t0


def _e(x: float) -> str:
    return f"{x:.3e}" if np.isfinite(x) else "-"


def _r(x: float) -> str:
    return f"{x:.3f}" if np.isfinite(x) else "-"


def table(rows: list[Row], div: int, max_samples: int, args_cpu: bool = False) -> str:
    head = ("| file | element | tools | elements (measured) | samples | Nagata max dist [mm] | flat max dist [mm] | "
            "ratio | pass | corner-node gap [mm] | rebuild dev / size | Nagata max normal part [mm] | flat max normal part [mm] | ratio (normal part) | "
            "convert [s] | measure [s] | note |")
    out = [head, "|" + "---|" * 17]
    for r in rows:
        notes = []
        if args_cpu and np.isfinite(r.cpu[0]):
            notes.append(f"convert CPU {r.cpu[0]:.1f} s (load {r.cpu[1]:.1f})")
        if r.refused:
            notes.append(f"convert exit {r.exit_code_first}: {r.message}; measured with --allow-worse")
        elif r.exit_code != 0:
            notes.append(f"exit {r.exit_code}: {r.message}")
        elif r.message:
            notes.append(r.message)
        if r.unassigned:
            notes.append(f"{r.unassigned} elements with no OCC face")
        if r.reassigned:
            notes.append(f"{r.reassigned} elements to the face holding their corners, not the one nearest the centroid")
        if r.straddling:
            notes.append(f"{r.straddling} elements with corners on no single face (measured to the trimmed faces where nearer)")
        if r.beyond_border:
            notes.append(f"{r.beyond_border} samples beyond their face's surface border or on such elements measured to the trimmed faces")
        if r.no_projection:
            notes.append(f"{r.no_projection} samples without an OCC projection")
        if r.exit_code == 0 and np.isfinite(r.nagata) and r.worst_nagata[1]:
            notes.append("worst Nagata sample's foot on the surface's domain border")
        meas = (f"{r.elements} ({r.measured})" if r.measured != r.elements else f"{r.elements}") if r.elements else "-"
        out.append(
            f"| {r.file} | {r.element} | {', '.join(r.tools) or '-'} | {meas} | {r.samples or '-'} | "
            f"{_e(r.nagata)} | {_e(r.flat)} | {_r(r.ratio)} | {'yes' if r.passed else 'NO'} | "
            f"{_e(r.node_gap) if r.elements else '-'} | {_e(r.rebuild_dev)} | "
            f"{_e(r.nagata_normal)} | {_e(r.flat_normal)} | {_r(r.ratio_normal)}{'' if r.passed_normal else ' (no)'} | "
            f"{r.convert_s:.1f} | {r.measure_s:.1f} | {'; '.join(notes).replace('|', '/')} |")
    n_pass = sum(r.passed for r in rows)
    n_pass_n = sum(r.passed_normal for r in rows)
    out.append("")
    out.append(
        f"{n_pass} of {len(rows)} pass on the distance ({n_pass_n} on the normal part): Nagata <= 0.25 x flat, or "
        "both <= 1e-9 x size, and the written COEFFICIENTS equal the rebuilt ones within 1e-9 x size (rebuild dev: "
        "max deviation / node-box diagonal, independent reader tests/helpers/toolfile_reference.py). Corner-node gap: max "
        "distance of an element's corner nodes (CAD points) to the OCC surface it is measured against, a floor of "
        "both errors (the file's own edge/surface gaps, or elements across faces). dist = distance (GeomAPI_ProjectPointOnSurf) to the untrimmed OCC surface of the "
        "face nearest the element's flat centroid (BRepExtrema_DistShapeShape), or, for a sample whose foot is on that "
        "surface's domain border (it lies beyond the surface), the distance to the trimmed faces where smaller; normal part = |(x - foot) . n(foot)|, "
        "which ignores how far a sample lies beyond the border of the surface's parameter domain. "
        f"Grid {div} divisions per patch; at most {max_samples} samples per row (every k-th element beyond).")
    return "\n".join(out)


def merge_table(old: str, new: str) -> str:
    """``old``'s table with the rows of ``new`` put in place of (or beside) the rows of the
    same (file, element), rows sorted as before; the text before the table is kept, the pass
    count under it recomputed over the merged rows."""
    def split(text):
        lines = text.splitlines()
        start = next(i for i, ln in enumerate(lines) if ln.startswith("| file |"))
        end = start + 2
        while end < len(lines) and lines[end].startswith("| "):
            end += 1
        return lines[:start], lines[start:start + 2], lines[start + 2:end], lines[end:]

    pre, head, old_rows, _ = split(old)
    _, _, new_rows, post = split(new)
    key = lambda ln: tuple(c.strip() for c in ln.split("|")[1:3])  # noqa: E731
    rows = {key(ln): ln for ln in old_rows}
    rows.update({key(ln): ln for ln in new_rows})
    merged = list(rows.values())
    n_pass = sum(ln.split("|")[9].strip() == "yes" for ln in merged)
    n_pass_n = sum("(no)" not in ln.split("|")[14] for ln in merged)
    foot = [ln for ln in post if ln.strip()]
    if foot:
        foot[0] = f"{n_pass} of {len(merged)} pass on the distance ({n_pass_n} on the normal part):" + \
            foot[0].split(" pass on the distance", 1)[1].split(":", 1)[1]
    return "\n".join(pre + head + merged + [""] + foot)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", default=None, help="only files whose name contains this")
    ap.add_argument("--timeout", type=float, default=600.0)
    ap.add_argument("--div", type=int, default=4)
    ap.add_argument("--max-samples", type=int, default=200_000)
    ap.add_argument("--elements", nargs="+", default=["tri", "quad"], choices=["tri", "quad"])
    ap.add_argument("--no-real", action="store_true")
    ap.add_argument("--no-samples", action="store_true")
    ap.add_argument("--no-retry-allow-worse", action="store_true",
                    help="do not re-run a refused conversion with --allow-worse to measure it")
    ap.add_argument("--output", default=str(RESULTS / "tool_accuracy.md"))
    ap.add_argument("--cpu", action="store_true", help="note each convert's CPU time and the load average in the row")
    ap.add_argument("--merge", action="store_true",
                    help="replace only the measured (file, element) rows of an existing --output table, keep the rest")
    args = ap.parse_args(argv)
    files = []
    if not args.no_samples:
        files += sorted(SAMPLES.glob("*.igs"))
    if not args.no_real and REAL.is_dir():
        files += sorted(p for p in REAL.iterdir() if p.suffix.lower() in (".igs", ".iges"))
    if args.only:
        files = [f for f in files if args.only in f.name]
    rows: list[Row] = []
    for cad in files:
        for el in args.elements:
            row = Row(cad.name, el)
            with tempfile.TemporaryDirectory(prefix="tool_acc_") as tmp:
                out = Path(tmp) / "out"
                row.exit_code, row.convert_s, row.message = run_convert(cad, out, el, args.timeout, [])
                row.exit_code_first = row.exit_code
                row.cpu = tuple(LAST_CPU)
                if row.exit_code == 1 and not args.no_retry_allow_worse:
                    row.refused = True
                    code, dt, msg = run_convert(cad, out, el, args.timeout, ["--allow-worse"])
                    row.exit_code = code
                    if code != 0:
                        row.refused = False
                        row.message += f" / with --allow-worse: exit {code}: {msg}"
                if row.exit_code == 0:
                    try:
                        measure(row, cad, out, args.div, args.max_samples)
                    except Exception as exc:  # a measurement failure is a finding, reported in the row
                        row.message = f"measurement failed: {type(exc).__name__}: {exc}"
                        row.nagata = float("nan")
            rows.append(row)
            print(f"{row.file:42s} {el:4s} exit {row.exit_code} {row.convert_s:7.1f} s  nagata {row.nagata:.3e} "
                  f"flat {row.flat:.3e} ratio {row.ratio:.4f} {'pass' if row.passed else 'FAIL'} {row.message[:150]}",
                  flush=True)
    text = table(rows, args.div, args.max_samples, args.cpu)
    print()
    print(text)
    if args.merge and Path(args.output).is_file():
        text = merge_table(Path(args.output).read_text(), text)
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Path(args.output).write_text(text + "\n")
    return 0 if all(r.passed for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
