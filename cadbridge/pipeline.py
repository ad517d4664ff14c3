"""The whole chain for one CAD file or mesh: normals -> Nagata patches -> tool files + report.

Everything is computed first and written last, into a temporary folder beside the output
that is moved into place at the end, so an error never leaves partial output behind.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cadbridge.mesh.mesh import CellBlock, Mesh

__all__ = ["ToolResult", "RunResult", "build_tool", "convert", "nagata_from_mesh", "tool_groups"]


@dataclass
class ToolResult:
    """One tool: its mesh, normals, Nagata surface and error statistics."""

    name: str
    mesh: Mesh
    normals: np.ndarray  # (N, 3)
    corner_normals: list[np.ndarray]  # per block (E_b, k_b, 3)
    normal_source: str
    nagata: object  # cadbridge.nagata.NagataMesh
    grid: dict  # sample grid: points, normals, element, eta, zeta, shape_error, normal_error, face
    stats: dict  # max/mean shape and normal errors
    node_face: np.ndarray | None = None
    node_distance: np.ndarray | None = None


@dataclass
class RunResult:
    output: Path
    tools: list[ToolResult] = field(default_factory=list)
    files: list[str] = field(default_factory=list)

    def summary(self) -> str:
        lines = [f"wrote {len(self.files)} files to {self.output}"]
        lines.append(f"  {'tool':<16}{'source':<8}{'nodes':>7}{'elems':>7}{'max |shape err|':>17}{'max normal err':>16}")
        for t in self.tools:
            s = t.stats
            lines.append(
                f"  {t.name:<16}{t.normal_source:<8}{len(t.mesh.nodes):>7}{t.mesh.n_elements:>7}"
                f"{s.get('max_abs_shape_error', float('nan')):>17.3e}{s.get('max_normal_error_deg', float('nan')):>15.4f}°"
            )
        return "\n".join(lines)


def _blocks(mesh: Mesh) -> list[np.ndarray]:
    return [np.asarray(b.data) for b in mesh.cells]


def tool_groups(mesh: Mesh, model, element_face: list[np.ndarray]) -> dict[str, list[np.ndarray]]:
    """Split the mesh into tools: one per connected component of elements.

    Die, punch and blank holder are separate bodies, so each is a component of the mesh.
    A tool is named after its faces' IGES names (406 form 15 / DE labels): the common name
    when all agree, else their common prefix (e.g. DIEWALL, DIERAD, DIELAND -> "DIE"), else
    the mesh name with a number. Returns {tool name: [bool mask per block]}.
    """
    from cadbridge.mesh.topology import connected_components

    n, labels = connected_components(mesh)
    offsets = np.cumsum([0] + [len(b.data) for b in mesh.cells])
    ef = np.concatenate(element_face) if element_face else np.zeros(0, dtype=np.int64)
    groups: dict[str, list[np.ndarray]] = {}
    for k in range(n):
        sel = labels == k
        names = sorted({model.faces[f].name for f in np.unique(ef[sel]) if f >= 0 and model.faces[f].name})
        prefix = os.path.commonprefix(names).rstrip("_- ") if names else ""
        name = (names[0] if len(names) == 1 else prefix if len(prefix) >= 2 else "") or (
            mesh.name if n == 1 else f"{mesh.name}_{k + 1}")
        base, i = name, 2
        while name in groups:
            name, i = f"{base}_{i}", i + 1
        groups[name] = [sel[offsets[b] : offsets[b + 1]] for b in range(len(mesh.cells))]
    return groups


def _submesh(mesh: Mesh, masks: list[np.ndarray], name: str) -> tuple[Mesh, np.ndarray]:
    """Elements selected by ``masks`` with their nodes renumbered; also the old node ids."""
    blocks = [(b.type, np.asarray(b.data)[m]) for b, m in zip(mesh.cells, masks) if np.any(m)]
    used = np.unique(np.concatenate([d.ravel() for _, d in blocks]))
    new = np.full(len(mesh.nodes), -1, dtype=np.int64)
    new[used] = np.arange(len(used))
    sub = Mesh(nodes=mesh.nodes[used], cells=[CellBlock(t, new[d]) for t, d in blocks], name=name)
    return sub, used


def build_tool(
    name: str,
    mesh: Mesh,
    normals: np.ndarray,
    corner_normals: list[np.ndarray],
    source: str,
    *,
    model=None,
    grid: int = 10,
    node_face=None,
    node_distance=None,
) -> ToolResult:
    """Nagata patches over ``mesh`` with the given normals and their errors against the CAD."""
    from cadbridge.nagata import NagataMesh

    blocks = _blocks(mesh)
    nm = NagataMesh(mesh.nodes, blocks, corner_normals)
    g = nm.sample_grid(grid)
    sample = {"points": g.points, "normals": g.normals, "element": g.elem, "eta": g.eta, "zeta": g.zeta}
    stats: dict = {}
    if model is not None:
        from cadbridge.nagata.errors import cad_errors

        err = cad_errors(nm, _cad_projector(model), grid)
        sample["shape_error"] = err.shape
        sample["normal_error"] = err.normal
        stats["max_abs_shape_error"] = float(np.max(np.abs(err.shape)))
        stats["mean_abs_shape_error"] = float(np.mean(np.abs(err.shape)))
        stats["max_normal_error_deg"] = float(np.max(err.normal))
        stats["mean_normal_error_deg"] = float(np.mean(err.normal))
    return ToolResult(name, mesh, normals, corner_normals, source, nm, sample, stats, node_face, node_distance)


def _cad_projector(model):
    """``points (M, 3) -> (foot (M, 3), normal (M, 3))`` on the CAD model."""
    from cadbridge.nurbs.search import project_points

    def project(points):
        p = project_points(points, model)
        return p.foot, p.normal

    return project


def _corner_overrides(nodes_normals: np.ndarray, blocks: list[np.ndarray], corners: list[np.ndarray]):
    """(element, local corner, normal) where a corner normal differs from its node normal."""
    elems, locs, nrms = [], [], []
    offset = 0
    for b, c in zip(blocks, corners):
        diff = np.any(c != nodes_normals[b], axis=2)
        e, k = np.nonzero(diff)
        elems.append(e + offset)
        locs.append(k)
        nrms.append(c[e, k])
        offset += len(b)
    if not elems:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    return np.concatenate(elems), np.concatenate(locs), np.concatenate(nrms)


def _write_tool_outputs(tool: ToolResult, folder: Path, units: str, cad: str | None, report: bool,
                        model=None) -> list[str]:
    """Tool file, and with ``report`` the VTUs, CSV grid, coefficient listing, IGES and PNGs."""
    from cadbridge.io.toolfile import ToolData, write_toolfile

    files = []
    blocks = _blocks(tool.mesh)
    kinds = [b.type for b in tool.mesh.cells]
    # tool-file numbering: all triangles, then all quadrilaterals (blocks in order within each)
    order = [i for i, k in enumerate(kinds) if k == "triangle"] + [i for i, k in enumerate(kinds) if k == "quad"]
    tri = [blocks[i] for i in order if kinds[i] == "triangle"]
    quad = [blocks[i] for i in order if kinds[i] == "quad"]
    ce, cl, cn = _corner_overrides(tool.normals, [blocks[i] for i in order], [tool.corner_normals[i] for i in order])
    nm = tool.nagata
    tri_c = nm.tri_coefficients if tri else None
    quad_c = nm.quad_coefficients if quad else None
    tooldata = ToolData(
        name=tool.name,
        units=units,
        nodes=tool.mesh.nodes,
        normals=tool.normals,
        triangles=np.concatenate(tri) if tri else np.zeros((0, 3), dtype=np.int64),
        quads=np.concatenate(quad) if quad else np.zeros((0, 4), dtype=np.int64),
        corner_element=ce,
        corner_local=cl,
        corner_normals=cn,
        tri_coefficients=tri_c,
        quad_coefficients=quad_c,
        source=cad or "",
        normal_source=tool.normal_source,
    )
    path = folder / f"{tool.name}.nagata"
    write_toolfile(tooldata, path)
    files.append(path.name)
    if not report:
        return files

    from cadbridge.io.csvgrid import write_coefficients_listing, write_grid_csv
    from cadbridge.io.nagata_iges import write_nagata_iges
    from cadbridge.io.plots import plot_error_histogram
    from cadbridge.io.vtu import write_mesh_vtu, write_surface_vtu

    g = tool.grid
    errors = {k: g[k] for k in ("shape_error", "normal_error") if k in g}
    # point index within its patch, 1-based like the thesis' "Excel" file
    elem = np.asarray(g["element"])
    starts = np.r_[0, np.flatnonzero(np.diff(elem)) + 1]
    point = np.arange(len(elem)) - np.repeat(starts, np.diff(np.r_[starts, len(elem)])) + 1
    write_grid_csv(folder / f"{tool.name}_grid.csv", elem + 1, point, g["points"], g["normals"], errors or None)
    write_coefficients_listing(folder / f"{tool.name}_coefficients.txt", tri_c, quad_c)
    write_nagata_iges(tri_c, quad_c, folder / f"{tool.name}_nagata.igs", units=units)
    verts, tris, (pe, peta, pzeta) = nm.refined_triangulation(4, return_params=True)
    _, vnorm = nm.evaluate(pe, peta, pzeta)
    pdata = {"normal": vnorm, "element": pe.astype(np.int32)}
    if model is not None:
        from cadbridge.nurbs.search import project_points

        pr = project_points(verts, model)
        ncad = pr.normal * np.where(np.einsum("ij,ij->i", pr.normal, vnorm) < 0, -1.0, 1.0)[:, None]
        pdata["shape_error"] = np.einsum("ij,ij->i", verts - pr.foot, ncad)
        pdata["normal_error"] = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", vnorm, ncad), -1, 1)))
        pdata["face_id"] = pr.face.astype(np.int32)
    write_surface_vtu(folder / f"{tool.name}_nagata.vtu", verts, tris, point_data=pdata)
    pdata_mesh = {"normal": tool.normals}
    if tool.node_face is not None:
        pdata_mesh["face_id"] = np.asarray(tool.node_face, dtype=np.int32)
        pdata_mesh["distance"] = tool.node_distance
    write_mesh_vtu(
        folder / f"{tool.name}_mesh.vtu",
        tool.mesh.nodes,
        [(b.type, np.asarray(b.data)) for b in tool.mesh.cells],
        point_data=pdata_mesh,
        field_data={"normal_source": tool.normal_source},
    )
    files += [f"{tool.name}_grid.csv", f"{tool.name}_coefficients.txt", f"{tool.name}_nagata.igs",
              f"{tool.name}_nagata.vtu", f"{tool.name}_mesh.vtu"]
    if errors:
        plot_error_histogram(folder / f"{tool.name}_shape_error.png", {tool.normal_source: np.abs(errors["shape_error"])},
                             xlabel=f"|shape error| [{units.lower()}]", title=f"{tool.name}: Nagata shape error vs CAD")
        plot_error_histogram(folder / f"{tool.name}_normal_error.png", {tool.normal_source: errors["normal_error"]},
                             xlabel="normal error [deg]", title=f"{tool.name}: Nagata normal error vs CAD")
        files += [f"{tool.name}_shape_error.png", f"{tool.name}_normal_error.png"]
    return files


class _Staging:
    """Write into a temporary folder beside ``output``; move into place only on success."""

    def __init__(self, output: str | os.PathLike) -> None:
        self.output = Path(output)

    def __enter__(self) -> Path:
        parent = self.output.resolve().parent
        parent.mkdir(parents=True, exist_ok=True)
        self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.output.name}.", dir=parent))
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            return
        self.output.mkdir(parents=True, exist_ok=True)
        for p in sorted(self.tmp.rglob("*")):
            rel = p.relative_to(self.tmp)
            if p.is_dir():
                (self.output / rel).mkdir(parents=True, exist_ok=True)
            else:
                os.replace(p, self.output / rel)
        shutil.rmtree(self.tmp, ignore_errors=True)


def _normals(mesh: Mesh, model, method: str, *, tolerance=None, flip=False, allow_far=False):
    """(node normals, corner normals per block, node face ids | None, node distances | None, element faces | None)."""
    blocks = _blocks(mesh)
    if method == "cad":
        from cadbridge.normals.cad import cad_normals

        cn = cad_normals(mesh, model, tolerance=tolerance, flip=flip, allow_far=allow_far)
        return cn.normals, cn.corner_normals, cn.face, cn.distance, cn.element_face
    from cadbridge.normals.estimators import estimate_normals

    n = estimate_normals(mesh.nodes, blocks, method=method)
    if flip:
        n = -n
    return n, [n[b] for b in blocks], None, None, None


def _tools_from_mesh(mesh, model, method, name, grid, tolerance, flip, allow_far) -> list[ToolResult]:
    normals, corners, node_face, node_dist, elem_face = _normals(
        mesh, model, method, tolerance=tolerance, flip=flip, allow_far=allow_far
    )
    if model is not None and elem_face is None:
        from cadbridge.nurbs.search import project_points

        cent = np.concatenate([mesh.nodes[b].mean(axis=1) for b in _blocks(mesh)])
        ef = project_points(cent, model).face
        offs = np.cumsum([0] + [len(b.data) for b in mesh.cells])
        elem_face = [ef[offs[i] : offs[i + 1]] for i in range(len(mesh.cells))]
    groups = tool_groups(mesh, model, elem_face) if model is not None else {"": None}
    tools = []
    for gname, masks in groups.items():
        tname = name or gname or mesh.name or "tool"
        tname = tname.lower() if gname.isupper() and not name else tname
        if masks is None or all(m.all() for m in masks):
            tools.append(build_tool(tname, mesh, normals, corners, method, model=model, grid=grid,
                                    node_face=node_face, node_distance=node_dist))
            continue
        sub, used = _submesh(mesh, masks, tname)
        sub_corners = [c[m] for c, m in zip(corners, masks) if np.any(m)]
        tools.append(build_tool(
            tname if not name else f"{name}_{gname.lower()}", sub, normals[used], sub_corners, method, model=model,
            grid=grid, node_face=None if node_face is None else node_face[used],
            node_distance=None if node_dist is None else node_dist[used],
        ))
    return tools


def nagata_from_mesh(
    mesh_path: str,
    *,
    cad: str | None = None,
    output: str,
    method: str = "cad",
    name: str | None = None,
    report: bool = True,
    tolerance: float | None = None,
    flip: bool = False,
    allow_far: bool = False,
    grid: int = 10,
) -> RunResult:
    """`cadbridge nagata`: tool file(s) + report from a user mesh (and the CAD)."""
    from cadbridge.mesh.io import read_mesh

    model = None
    if cad is not None:
        from cadbridge.iges import read_iges

        model = read_iges(cad)
    elif method == "cad":
        raise ValueError("--method cad needs --cad FILE.igs")
    mesh = read_mesh(mesh_path)
    mesh.name = Path(mesh_path).stem
    tools = _tools_from_mesh(mesh, model, method, name, grid, tolerance, flip, allow_far)
    units = model.units.name if model is not None else "MM"
    result = RunResult(Path(output), tools)
    with _Staging(output) as tmp:
        for t in tools:
            result.files += _write_tool_outputs(t, tmp, units, cad, report, model)
    return result


def convert(
    cad: str,
    output: str,
    *,
    element: str = "quad",
    size: float | None = None,
    structured: bool = False,
    radius_divisions: int = 3,
    length_divisions: int | None = None,
    method: str = "cad",
    grid: int = 10,
    flip: bool = False,
    tolerance: float | None = None,
) -> RunResult:
    """`cadbridge convert`: mesh the CAD with gmsh, exact normals, Nagata, tool files, report."""
    from cadbridge.iges import read_iges
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.mesh.io import write_mesh

    model = read_iges(cad)  # fails early, before anything is meshed or written, on a bad file
    mesh = mesh_cad(cad, element=element, size=size, structured=structured,
                    radius_divisions=radius_divisions, length_divisions=length_divisions)
    mesh.name = Path(cad).stem
    tools = _tools_from_mesh(mesh, model, method, None, grid, tolerance, flip, False)
    result = RunResult(Path(output), tools)
    with _Staging(output) as tmp:
        write_mesh(mesh, tmp / f"{mesh.name}_mesh.msh")
        result.files.append(f"{mesh.name}_mesh.msh")
        for t in tools:
            result.files += _write_tool_outputs(t, tmp, model.units.name, cad, True, model)
    return result
