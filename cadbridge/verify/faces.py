"""`cadbridge verify`: compare our IGES reading face by face with OpenCASCADE's.

Two layers: `compare_models(model, occ_faces)` does the measuring on objects already in
memory (so tests can feed it a deliberately perturbed model), `verify(path)` reads the file
both ways and calls it, by default in a spawned subprocess so an OCC crash on a malformed
file becomes an `OccCrashError` instead of killing the caller.

Per face, at random (u, v) over the untrimmed surface domain:
  parametric  our S, Su, Sv, Suu, Suv, Svv and normal against OCC's at the same (u, v);
  geometric   used when the parametrisations differ (an analytic surface we converted to
              NURBS, a face OCC reparametrised or split): every sample point of ours is
              projected onto the paired OCC surface(s); distance and the angle between our
              normal and OCC's face normal at the foot are measured.
Positions are relative to the model size (bounding-box diagonal), derivatives relative to
the largest derivative of the same order on the face, normals in radians.

Each face also shows the file's own trim tolerance, `Face.trim_delta` (how far its 2D and 3D
trim curves disagree, in mm), and the report names the face with the largest: information
about the file, not a pass/fail criterion (OCC is not involved).
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os
from dataclasses import dataclass, field

import numpy as np

from cadbridge.cad.model import Model
from cadbridge.verify.reference import OccFace, occ_eval, occ_normal, occ_project, occ_read

__all__ = ["FaceCheck", "OccCrashError", "VerifyReport", "compare_models", "pair_faces", "run_isolated", "verify"]

_PAIR_SAMPLES = 9  # points per face used for pairing
_PAIR_TOL = 1e-6  # relative distance under which a face "coincides" for pairing by order


class OccCrashError(RuntimeError):
    """OpenCASCADE crashed (e.g. a segmentation fault) while reading the file."""


@dataclass
class FaceCheck:
    """Result for one of our faces."""

    index: int
    de: int
    entity_type: int
    surface_type: int
    name: str | None
    occ_index: list[int]
    mode: str  # "parametric" | "geometric" | "unpaired"
    pos_dev: float  # max position deviation / model size
    der_dev: float  # max relative derivative deviation (parametric mode; NaN otherwise)
    ang_dev: float  # max normal angle, radians
    orientation: str  # "forward" | "reversed" (OCC's face) | "mixed" | "-"
    n_samples: int
    passed: bool
    note: str = ""
    trim_delta: float = float("nan")  # the face's `Face.trim_delta` in mm (NaN: not both trim representations)


@dataclass
class VerifyReport:
    """Outcome of a verification: per-face checks and the faces OCC has that we lack."""

    path: str | None
    size: float
    tol_pos: float
    tol_der: float
    tol_ang: float
    faces: list[FaceCheck] = field(default_factory=list)
    n_occ_faces: int = 0
    unmatched_occ: list[int] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True if every face passed and every OCC face was paired with one of ours."""
        return bool(self.faces) and all(f.passed for f in self.faces) and not self.unmatched_occ

    def failed(self) -> list[FaceCheck]:
        """The faces that failed."""
        return [f for f in self.faces if not f.passed]

    def max_delta(self) -> FaceCheck | None:
        """The face with the largest trim delta (None if no face has one)."""
        have = [f for f in self.faces if not np.isnan(f.trim_delta)]
        return max(have, key=lambda f: f.trim_delta) if have else None

    def delta_line(self) -> str:
        """One line: the largest trim delta, its face, and how many faces have one."""
        w = self.max_delta()
        if w is None:
            return "trim delta (file's 2D/3D trim disagreement): no face has both trim representations"
        n = sum(not np.isnan(f.trim_delta) for f in self.faces)
        return (f"trim delta (file's 2D/3D trim disagreement): max {w.trim_delta:.3g} mm "
                f"({w.trim_delta / self.size:.3g} x size) on face {w.index} (DE {w.de}); {n} of {len(self.faces)} "
                f"faces have both representations")

    def format(self, max_rows: int = 60) -> str:
        """A table of faces, worst position deviation first, and a verdict line."""
        head = (f"verify {self.path or '<model>'}: {len(self.faces)} faces (OCC: {self.n_occ_faces}), "
                f"size {self.size:.6g} mm, tolerances pos {self.tol_pos:g} x size, der {self.tol_der:g} rel, "
                f"normal {self.tol_ang:g} rad")
        rows = [head, f"{'face':>5} {'DE':>6} {'type':>8} {'name':<12} {'OCC':>7} {'mode':<10} {'pos/size':>10} "
                      f"{'der rel':>10} {'angle':>10} {'delta mm':>10} {'orient':<8} result"]
        order = sorted(self.faces, key=lambda f: (f.passed, -_nz(f.pos_dev)))
        for f in order[:max_rows]:
            occ = ",".join(str(i) for i in f.occ_index[:3]) + ("…" if len(f.occ_index) > 3 else "") or "-"
            rows.append(f"{f.index:>5} {f.de:>6} {f'{f.entity_type}/{f.surface_type}':>8} {(f.name or '')[:12]:<12} "
                        f"{occ:>7} {f.mode:<10} {_e(f.pos_dev)} {_e(f.der_dev)} {_e(f.ang_dev)} {_e(f.trim_delta)} "
                        f"{f.orientation:<8} "
                        f"{'ok' if f.passed else 'FAIL'}{'  ' + f.note if f.note else ''}")
        if len(order) > max_rows:
            rows.append(f"  ... {len(order) - max_rows} more faces")
        if self.unmatched_occ:
            rows.append(f"OCC faces with no counterpart in our model: {self.unmatched_occ[:20]}"
                        + (" ..." if len(self.unmatched_occ) > 20 else ""))
        rows.append(self.delta_line())
        n_bad = len(self.failed())
        rows.append("OK" if self.ok else f"FAILED: {n_bad} face(s) out of tolerance, {len(self.unmatched_occ)} OCC face(s) unmatched")
        return "\n".join(rows)


def _nz(x: float) -> float:
    return -1.0 if np.isnan(x) else x


def _e(x: float) -> str:
    return f"{'-':>10}" if np.isnan(x) else f"{x:10.2e}"


# ---------------------------------------------------------------------- sampling helpers
def _sample_uv(face, n: int, rng: np.random.Generator, inside_trims: bool) -> tuple[np.ndarray, np.ndarray]:
    u0, u1, v0, v1 = face.surface.domain
    if not inside_trims or face.trims is None:
        return rng.uniform(u0, u1, n), rng.uniform(v0, v1, n)
    us, vs, got = [], [], 0
    for _ in range(20):  # rejection sampling inside the trims
        u, v = rng.uniform(u0, u1, 4 * n), rng.uniform(v0, v1, 4 * n)
        keep = face.contains(u, v)
        us.append(u[keep])
        vs.append(v[keep])
        got += int(keep.sum())
        if got >= n:
            break
    u, v = np.concatenate(us)[:n], np.concatenate(vs)[:n]
    return (u, v) if len(u) else (rng.uniform(u0, u1, n), rng.uniform(v0, v1, n))


def _grid_uv(face, k: int = 3) -> tuple[np.ndarray, np.ndarray]:
    u0, u1, v0, v1 = face.surface.domain
    t = (np.arange(k) + 0.5) / k
    uu, vv = np.meshgrid(u0 + t * (u1 - u0), v0 + t * (v1 - v0), indexing="ij")
    return uu.ravel(), vv.ravel()


def _max_dist(occ: OccFace, pts: np.ndarray) -> float:
    d = occ_project(occ.surface, pts)[3]
    return float(np.inf if np.any(np.isnan(d)) else d.max())


# ---------------------------------------------------------------------- pairing
def pair_faces(model: Model, occ_faces: list[OccFace], scale: float = 1.0) -> list[list[int]]:
    """For each of our faces, the OCC faces it corresponds to (usually exactly one).

    By order when the counts match and a few sample points of each of our faces lie on the
    OCC face of the same index; otherwise each of our faces takes the OCC face (among those
    whose box is near) with the smallest maximum projection distance, and an OCC face that
    no face chose is attached to the face whose points lie closest to it (OCC split a face).
    ``scale`` converts our model units to mm.
    """
    size = max(model.size() * scale, 1e-300)
    samples = []
    for face in model.faces:
        u, v = _grid_uv(face)
        samples.append(face.surface.evaluate(u, v) * scale)
    if len(occ_faces) == len(model.faces):
        if all(_max_dist(o, p) <= _PAIR_TOL * size for o, p in zip(occ_faces, samples)):
            return [[i] for i in range(len(occ_faces))]
    margin = 1e-6 * size
    boxes = np.array([o.bbox for o in occ_faces]) if occ_faces else np.zeros((0, 2, 3))
    pairs: list[list[int]] = []
    best_dist = np.full(len(occ_faces), np.inf)
    best_face = np.full(len(occ_faces), -1)
    for i, pts in enumerate(samples):
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        near = np.nonzero(np.all(boxes[:, 0] <= hi + margin, axis=1) & np.all(boxes[:, 1] >= lo - margin, axis=1))[0]
        if len(near) == 0:
            near = np.arange(len(occ_faces))
        dists = {int(j): _max_dist(occ_faces[j], pts) for j in near}
        if not dists:
            pairs.append([])
            continue
        j = min(dists, key=dists.get)
        pairs.append([j] if np.isfinite(dists[j]) else [])
        for jj, d in dists.items():
            if d < best_dist[jj]:
                best_dist[jj], best_face[jj] = d, i
    chosen = {j for p in pairs for j in p}
    for j in range(len(occ_faces)):  # OCC pieces of a face it split: attach where they lie
        if j not in chosen and best_face[j] >= 0 and best_dist[j] <= 1e-3 * size:
            pairs[best_face[j]].append(j)
    return pairs


# ---------------------------------------------------------------------- comparison
def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles between unit vectors (N, 3), robust near 0 (atan2 of |a x b| and a . b)."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))


def _parametric(face, occ: OccFace, u, v, scale: float, size: float) -> tuple[float, float, float]:
    ders = face.surface.derivatives(u, v, order=2) * scale
    pos, d1, d2 = occ_eval(occ.surface, u, v, order=2)
    pos_dev = float(np.max(np.linalg.norm(ders[:, 0, 0] - pos, axis=1))) / size
    ours = {"Su": ders[:, 1, 0], "Sv": ders[:, 0, 1], "Suu": ders[:, 2, 0], "Suv": ders[:, 1, 1], "Svv": ders[:, 0, 2]}
    theirs = {"Su": d1[:, 0], "Sv": d1[:, 1], "Suu": d2[:, 0], "Suv": d2[:, 1], "Svv": d2[:, 2]}
    der_dev = 0.0
    for group in (("Su", "Sv"), ("Suu", "Suv", "Svv")):
        # relative to the largest derivative of the same order on the face, so a kind that is
        # zero (Svv of a ruled surface) is compared with the scale of its siblings, not with 0
        ref = max(float(np.max(np.linalg.norm(d[k], axis=1))) for d in (ours, theirs) for k in group)
        if ref > 0:
            for k in group:
                der_dev = max(der_dev, float(np.max(np.linalg.norm(ours[k] - theirs[k], axis=1))) / ref)
    n_occ = occ_normal(occ.surface, u, v)
    n_ours = face.surface.normal(u, v)
    ok = ~np.isnan(n_occ[:, 0])  # OCC leaves the normal undefined at poles: skip those
    ang = float(np.max(_angle(n_ours[ok], n_occ[ok]))) if np.any(ok) else 0.0
    return pos_dev, der_dev, ang


def _geometric(face, occs: list[OccFace], u, v, scale: float, size: float) -> tuple[float, float]:
    pts = face.surface.evaluate(u, v) * scale
    n_ours = face.surface.normal(u, v)
    best = np.full(len(pts), np.inf)
    ang = np.full(len(pts), np.nan)
    for occ in occs:
        pu, pv, _, dist = occ_project(occ.surface, pts)
        n_occ = occ_normal(occ.surface, np.nan_to_num(pu), np.nan_to_num(pv))
        if occ.reversed:  # compare with OCC's face normal
            n_occ = -n_occ
        better = ~np.isnan(dist) & (dist < best)
        best[better] = dist[better]
        a = _angle(n_ours, n_occ)
        ang[better] = a[better]
    pos_dev = float(np.max(best)) / size
    return pos_dev, float(np.nanmax(ang)) if np.any(~np.isnan(ang)) else np.nan


def compare_models(
    model: Model,
    occ_faces: list[OccFace],
    *,
    n_samples: int = 200,
    tol_pos: float = 1e-9,
    tol_der: float = 1e-8,
    tol_ang: float = 1e-9,
    seed: int = 0,
    inside_trims: bool = False,
    path: str | None = None,
) -> VerifyReport:
    """Measure our model against OCC's faces (see the module docstring). Returns a report."""
    scale = model.units.to_mm if model.units is not None else 1.0
    size = model.size() * scale if model.faces else 1.0
    report = VerifyReport(path=path, size=size, tol_pos=tol_pos, tol_der=tol_der, tol_ang=tol_ang, n_occ_faces=len(occ_faces))
    if not model.faces:
        report.unmatched_occ = list(range(len(occ_faces)))
        return report
    pairs = pair_faces(model, occ_faces, scale)
    rng = np.random.default_rng(seed)
    for i, (face, js) in enumerate(zip(model.faces, pairs)):
        u, v = _sample_uv(face, n_samples, rng, inside_trims)
        delta = face.trim_delta  # the first access computes all faces' deltas in one pass
        common = dict(index=i, de=face.de, entity_type=face.entity_type, surface_type=face.surface_type,
                      name=face.name, occ_index=list(js), n_samples=len(u),
                      trim_delta=np.nan if delta is None else float(delta) * scale)
        if not js:
            report.faces.append(FaceCheck(**common, mode="unpaired", pos_dev=np.nan, der_dev=np.nan, ang_dev=np.nan,
                                          orientation="-", passed=False, note="no OCC face matches"))
            continue
        occs = [occ_faces[j] for j in js]
        flags = {o.reversed for o in occs}
        orient = "mixed" if len(flags) > 1 else ("reversed" if flags.pop() else "forward")
        par = None
        if len(occs) == 1:
            par = _parametric(face, occs[0], u, v, scale, size)
            if par[0] <= tol_pos and par[1] <= tol_der and par[2] <= tol_ang:
                report.faces.append(FaceCheck(**common, mode="parametric", pos_dev=par[0], der_dev=par[1], ang_dev=par[2],
                                              orientation=orient, passed=True))
                continue
        geo_pos, geo_ang = _geometric(face, occs, u, v, scale, size)
        geo_ok = geo_pos <= tol_pos and not (geo_ang > tol_ang)
        if par is not None and not geo_ok and par[0] <= geo_pos:
            # same parametrisation but out of tolerance: report the parametric numbers
            report.faces.append(FaceCheck(**common, mode="parametric", pos_dev=par[0], der_dev=par[1], ang_dev=par[2],
                                          orientation=orient, passed=False))
            continue
        note = "" if par is None else "parametrisation differs from OCC's"
        if len(occs) > 1:
            note = f"OCC split the face into {len(occs)}"
        report.faces.append(FaceCheck(**common, mode="geometric", pos_dev=geo_pos, der_dev=np.nan, ang_dev=geo_ang,
                                      orientation=orient, passed=geo_ok, note=note))
    used = {j for js in pairs for j in js}
    report.unmatched_occ = [j for j in range(len(occ_faces)) if j not in used]
    return report


def _verify_here(path: str, kwargs: dict) -> VerifyReport:
    from cadbridge.formats import read_cad  # the reader under test (IGES or STEP)

    model = read_cad(path)
    return compare_models(model, occ_read(path), path=path, **kwargs)


def verify(
    path: str | os.PathLike,
    *,
    n_samples: int = 200,
    tol_pos: float = 1e-9,
    tol_der: float = 1e-8,
    tol_ang: float = 1e-9,
    seed: int = 0,
    inside_trims: bool = False,
    isolate: bool = True,
    timeout: float | None = None,
) -> VerifyReport:
    """Read ``path`` with cadbridge and with OCC and compare every face (see `compare_models`).

    With ``isolate`` (default) the work runs in a spawned subprocess: a crash of OCC's
    reader raises `OccCrashError` naming the file; reader errors (IgesError, OccReadError)
    propagate unchanged.
    """
    path = os.fspath(path)
    kwargs = dict(n_samples=n_samples, tol_pos=tol_pos, tol_der=tol_der, tol_ang=tol_ang, seed=seed, inside_trims=inside_trims)
    if not isolate:
        return _verify_here(path, kwargs)
    return run_isolated(_verify_here, path, kwargs, what=path, timeout=timeout)


def run_isolated(fn, *args, what: str = "", timeout: float | None = None):
    """Call ``fn(*args)`` in a spawned subprocess and return its result.

    A hard crash of the child (segmentation fault, abort) raises `OccCrashError` mentioning
    ``what``; exceptions raised by ``fn`` propagate. ``fn`` must be importable (module level).
    """
    with cf.ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn"), initializer=_quiet_stdout) as pool:
        fut = pool.submit(fn, *args)
        try:
            return fut.result(timeout=timeout)
        except cf.process.BrokenProcessPool as exc:
            raise OccCrashError(f"{what}: the verification process died (OpenCASCADE crashed reading the file?)") from exc


def _quiet_stdout() -> None:
    """In the child: send file descriptor 1 to /dev/null. OpenCASCADE's reader prints to it,
    and the child inherits the caller's stdout (a terminal, a pipe, pytest-xdist's channel):
    only the result travels back, through the executor."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.close(devnull)


def _segfault(*_args) -> None:
    """Kill the current process with SIGSEGV (the tests use it to check `run_isolated`)."""
    import signal

    os.kill(os.getpid(), signal.SIGSEGV)
