"""What a tool writes: its tool file data (`tool_data`), the files of its folder (tool file,
VTU, CSV grid, coefficient listing, Nagata IGES, plots) and the atomic output folder
(`staged_output`: everything is written into a temporary folder beside the output and
moved into place at the end, so an error never leaves partial output behind).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from cadbridge.tool.build import CadProjector, corner_overrides, element_blocks, grid_rows, sample_divisions, ToolResult

__all__ = ['LISTING_MAX_ELEMENTS', 'OutputFolderError', 'error_map_jobs', 'staged_output', 'tool_data', 'tool_pictures',
           'write_error_maps', 'write_tool_outputs']


def tool_data(tool: ToolResult, units: str, cad: str | None = None):
    """The `cadbridge.io.toolfile.ToolData` of a tool (what its ``.nagata`` file holds)."""
    from cadbridge.io.toolfile import ToolData

    nm, mesh = tool.nagata, tool.mesh
    blocks = element_blocks(mesh)  # triangles first (see build_tool)
    tri = [b for b, c in zip(blocks, mesh.cells) if c.type == "triangle"]
    quad = [b for b, c in zip(blocks, mesh.cells) if c.type == "quad"]
    ce, cl, cn = corner_overrides(tool.normals, blocks, tool.corner_normals)
    return ToolData(
        name=tool.name,
        units=units,
        nodes=mesh.nodes,
        normals=tool.normals,
        triangles=np.concatenate(tri) if tri else np.zeros((0, 3), dtype=np.int64),
        quads=np.concatenate(quad) if quad else np.zeros((0, 4), dtype=np.int64),
        corner_element=ce,
        corner_local=cl,
        corner_normals=cn,
        edge_nodes=nm.edge_normals[0],
        edge_normals=np.stack([nm.edge_normals[1], nm.edge_normals[2]], 1),
        tri_coefficients=nm.tri_coefficients if tri else None,
        quad_coefficients=nm.quad_coefficients if quad else None,
        source=cad or "",
        normal_source=tool.normal_source,
        edge_rule=nm.edge_rule,
    )

LISTING_MAX_ELEMENTS = 50_000

def write_tool_outputs(tool: ToolResult, folder: Path, units: str, cad: str | None, report: bool,
                       projector: CadProjector | None = None, listings: bool | None = None,
                       pictures: bool = True) -> list[str]:
    """Tool file, and with ``report`` the VTUs, PNGs and the per-patch listings (CSV grid,
    coefficient listing, Nagata IGES); ``listings`` None: only for tools of at most
    `LISTING_MAX_ELEMENTS` elements (True / False: always / never). ``pictures`` False leaves
    the PNGs out (the caller draws them, `tool_pictures`, e.g. beside this in a forked
    process: `cadbridge.common.fork_jobs`).

    Returns the names of the files written (relative to ``folder``).
    """
    from cadbridge.io.toolfile import write_toolfile

    name, nm, mesh = tool.name, tool.nagata, tool.mesh
    blocks = element_blocks(mesh)
    tooldata = tool_data(tool, units, cad)
    tri_c, quad_c = tooldata.tri_coefficients, tooldata.quad_coefficients
    write_toolfile(tooldata, folder / f"{name}.nagata")
    files = [f"{name}.nagata"]
    if not report:
        return files

    from cadbridge.io.csvgrid import write_coefficients_listing, write_grid_csv
    from cadbridge.io.nagata_iges import write_nagata_iges
    from cadbridge.io.vtu import write_mesh_vtu, write_surface_vtu

    g = tool.grid
    names = ("surface_error", "boundary_error", "flat_surface_error", "normal_error")
    errors = {k: g[k] for k in names if k in g}
    # point index within its patch, 1-based like the thesis' "Excel" file (grid points of a
    # patch are consecutive)
    elem = np.asarray(g["element"])
    if listings is None:
        listings = nm.n_elements <= LISTING_MAX_ELEMENTS
    if listings:
        first = np.searchsorted(elem, elem)
        write_grid_csv(folder / f"{name}_grid.csv", elem + 1, np.arange(len(elem)) - first + 1, g["points"],
                       g["normals"], errors or None)
        write_coefficients_listing(folder / f"{name}_coefficients.txt", tri_c, quad_c)
        write_nagata_iges(tri_c, quad_c, folder / f"{name}_nagata.igs", units=units)
        files += [f"{name}_grid.csv", f"{name}_coefficients.txt", f"{name}_nagata.igs"]

    verts, tris, (pe, peta, pzeta) = nm.refined_triangulation(_vtu_divisions(nm, tool.stats.get("grid")),
                                                                return_params=True)
    _, vnorm = nm.evaluate(pe, peta, pzeta)
    surface_data = {"normal": vnorm, "element": pe.astype(np.int32)}
    at = grid_rows(g, pe, peta, pzeta) if errors else None
    if at is not None and all(k in g for k in names) and "face" in g:
        # the VTU's vertices are points of the error grid (same divisions, as on big models
        # where the sample budget sets both to 2): its errors, not a second measurement
        surface_data.update({k: np.asarray(g[k])[at] for k in names}, face_id=np.asarray(g["face"])[at].astype(np.int32))
    elif projector is not None and tool.element_face is not None:
        from cadbridge.tool.accuracy import tool_errors

        err = tool_errors(nm, pe, peta, pzeta, tool.element_face, projector.model, projector.project)
        surface_data.update(surface_error=err.surface, boundary_error=err.boundary,
                            flat_surface_error=err.flat_surface, normal_error=err.normal,
                            face_id=err.face.astype(np.int32))
    write_surface_vtu(folder / f"{name}_nagata.vtu", verts, tris, point_data=surface_data)

    mesh_data = {"normal": tool.normals}
    if tool.node_face is not None:
        mesh_data["face_id"] = np.asarray(tool.node_face, dtype=np.int32)
        mesh_data["distance"] = tool.node_distance
    write_mesh_vtu(folder / f"{name}_mesh.vtu", mesh.nodes, [(c.type, b) for c, b in zip(mesh.cells, blocks)],
                   point_data=mesh_data, field_data={"normal_source": tool.normal_source})
    files += [f"{name}_nagata.vtu", f"{name}_mesh.vtu"]
    if pictures:
        for name_png, job in tool_pictures(tool, folder, units):
            job()
            files.append(name_png)
    return files


def _vtu_divisions(nm, grid: int | None) -> int:
    """Divisions per patch of the Nagata VTU: n = 4 (fewer on big tools, `sample_divisions`),
    or n + 1 where that divides the error grid's ``grid`` divisions and n does not (5 for the
    default grid of 10 on small tools), so the VTU's vertices are grid points and carry the grid's
    errors instead of a second measurement against the CAD (`grid_rows`; i / 5 and 2i / 10
    are the same double). On the production die's seven 50-element pilot tools that second
    measurement took 0.3-0.7 s of CPU each."""
    n = min(4, sample_divisions(nm, 4))
    return n + 1 if grid and grid % n and grid % (n + 1) == 0 else n


def tool_pictures(tool: ToolResult, folder: Path, units: str) -> list[tuple[str, Callable[[], object]]]:
    """The report pictures of ``tool`` as (file name relative to ``folder``, job that draws
    it): the three error histograms and the two error maps (`write_error_maps`); none when
    its grid carries no errors. Each job writes its own file atomically."""
    from cadbridge.io.plots import plot_error_histogram

    g, name = tool.grid, tool.name
    names = ("surface_error", "boundary_error", "flat_surface_error", "normal_error")
    errors = {k: g[k] for k in names if k in g}
    if not errors:
        return []
    u = units.lower()
    out = [
        (f"{name}_surface_error.png", partial(
            plot_error_histogram, folder / f"{name}_surface_error.png",
            {f"Nagata ({tool.normal_source})": np.abs(errors["surface_error"]),
             "flat mesh": np.abs(errors["flat_surface_error"])},
            xlabel=f"|surface error| [{u}]", title=f"{name}: distance to the underlying CAD surfaces")),
        (f"{name}_boundary_error.png", partial(
            plot_error_histogram, folder / f"{name}_boundary_error.png", {tool.normal_source: errors["boundary_error"]},
            xlabel=f"boundary error [{u}]", title=f"{name}: distance to the trimmed CAD faces")),
        (f"{name}_normal_error.png", partial(
            plot_error_histogram, folder / f"{name}_normal_error.png", {tool.normal_source: errors["normal_error"]},
            xlabel="normal error [deg]", title=f"{name}: Nagata normal error vs CAD")),
    ]
    return out + error_map_jobs(tool, folder, units)


def write_error_maps(tool: ToolResult, folder: Path, units: str) -> list[str]:
    """``{tool}_shape_error_map.png`` and ``{tool}_normal_error_map.png`` drawn here
    (`error_map_jobs`). Returns the names written (relative to ``folder``)."""
    files = []
    for name, job in error_map_jobs(tool, folder, units):
        job()
        files.append(name)
    return files


def error_map_jobs(tool: ToolResult, folder: Path, units: str) -> list[tuple[str, Callable[[], object]]]:
    """``{tool}_shape_error_map.png`` and ``{tool}_normal_error_map.png``: the tool shaded by
    each element's largest |surface error| / normal error on the sample grid
    (``tool.grid``), the worst elements numbered as in the tool file
    (`cadbridge.io.error_map`), as (name relative to ``folder``, job that draws it); none
    when the grid carries no errors.

    Cost (wall time, 2 cores shared with other jobs, load about 4.5): on the production die's
    main tool (85 898 elements) 2.1-2.2 s a picture once matplotlib is loaded, 3.3 s the
    first; 0.3-0.9 s a picture on a tool of 50 elements (matplotlib's fixed cost: text
    and PNG encoding). The die's whole report stage went from 22.6 s to 30.2 s with 8 tools
    (two runs at different loads, 2026-12-06; docs/production_die.md, "Error maps").
    """
    from cadbridge.io.error_map import element_max, plot_error_map

    g, nm, name, u = tool.grid, tool.nagata, tool.name, units.lower()
    size = float(np.linalg.norm(np.ptp(nm.nodes, axis=0)))
    jobs = []
    # not labelled: round-off (a flat tool's shape error is ~1e-16 x its size)
    for key, stem, label, unit, negligible, what in (
            ("surface_error", "shape_error_map", f"element's largest |surface error| [{u}]", u, 1e-12 * size,
             "Nagata shape error vs the CAD surface"),
            ("normal_error", "normal_error_map", "element's largest normal error [deg]", "deg", 1e-9,
             "Nagata normal error vs the CAD normal")):
        if key not in g:
            continue
        values = element_max(g["element"], g[key], nm.n_elements)
        jobs.append((f"{name}_{stem}.png", partial(
            plot_error_map, folder / f"{name}_{stem}.png", nm, values, label=label, unit=unit, length_unit=u,
            negligible=negligible, title=f"{name}: {what} ({nm.n_elements} element{'s' * (nm.n_elements != 1)}, "
                                         f"{tool.normal_source} normals)")))
    return jobs


class OutputFolderError(OSError):
    """The output folder cannot be made or written (its parent is a file, read-only, ...)."""


@contextmanager
def staged_output(output: str | os.PathLike) -> Iterator[Path]:
    """Write into a temporary folder beside ``output``; move the files into place only on
    success. On an error the temporary folder is removed and ``output`` is left as it was
    (not created if it did not exist)."""
    output = Path(output)
    parent = output.resolve().parent
    created_parent = not parent.exists()
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{output.name}.", dir=parent))
    except OSError as e:  # named after the output folder asked for, not the staging folder
        raise OutputFolderError(e.errno, f"cannot write the output folder there ({e.strerror.lower()})",
                                str(output)) from None
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if created_parent:
            try:
                parent.rmdir()
            except OSError:
                pass
        raise
    if not output.exists():
        os.replace(tmp, output)  # the usual case: one rename
        return
    for p in sorted(tmp.rglob("*")):
        rel = p.relative_to(tmp)
        if p.is_dir():
            (output / rel).mkdir(parents=True, exist_ok=True)
        else:
            os.replace(p, output / rel)
    shutil.rmtree(tmp, ignore_errors=True)
