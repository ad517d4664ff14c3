"""The NUMISHEET'93 U-shape benchmark run as in the thesis §5.2 (Figs. 48 and 49).

For each tool (die, punch, blank holder): build the CAD (OCP), write it as NURBS IGES, read
it back with cadbridge, mesh it with gmsh (quadrilaterals, 3 elements over each radius and 1
along the length, one element per plane: the thesis' model "with planes"), take node normals
from the CAD and from the MWE, MWAAT and MWELR estimators (MWE also on the radius elements
alone: "without planes"), build Nagata patches for each, and measure the radial error along
the cross-section A-A through the tool radius (eq. 16 against the exact radius axis).

A finer unstructured triangular variant of each tool with CAD normals is checked against the
CAD by projection (shape and normal error). Everything is written into one output folder:
CAD, meshes, the blank shell mesh, tool files, report files, ``summary.md`` and
``summary.json``.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from cadbridge.ushape.geometry import UShapeParams, blank_mesh, export_iges, tool_faces

__all__ = ["SectionResult", "UShapeSummary", "run_ushape", "section_errors"]

#: The normal sources compared in Fig. 49: (key, estimator method, use the planes?)
SOURCES: tuple[tuple[str, str, bool], ...] = (
    ("cad", "cad", True),
    ("mwe_without_planes", "mwe", False),
    ("mwe_with_planes", "mwe", True),
    ("mwaat_with_planes", "mwaat", True),
    ("mwelr_with_planes", "mwelr", True),
)


@dataclass
class SectionResult:
    """Radial and normal errors along the cross-section A-A through a tool radius.

    s               (K,) position along the section, arc angle from the first tangent line
                    (= arc length / R, "normalized arc length")
    radial_error    (K,) eq. 16 in %, signed: + farther from the axis than the radius
    normal_error    (K,) eq. 17 in degrees
    element         (K,) index 0..n-1 of the radius element each sample lies on, in order
                    along the section
    """

    s: np.ndarray
    radial_error: np.ndarray
    normal_error: np.ndarray
    element: np.ndarray

    def extreme(self, values: np.ndarray) -> float:
        """The signed value of largest magnitude."""
        return float(values[np.argmax(np.abs(values))])

    def as_dict(self) -> dict:
        per_el = [self.extreme(self.radial_error[self.element == k]) for k in range(int(self.element.max()) + 1)]
        return {
            "max_radial_error_pct": self.extreme(self.radial_error),
            "max_normal_error_deg": float(self.normal_error.max()),
            "radius_elements_max_radial_error_pct": per_el,
        }


@dataclass
class UShapeSummary:
    """What `run_ushape` measured.

    tools  {tool: {source: {...}}}: per source of node normals (`SOURCES`) the section errors
           (`SectionResult.as_dict`), plus "polyhedral" (flat elements along the same section),
           "cad_quad_vs_cad" and "cad_fine_tri_vs_cad" (whole Nagata surface against the CAD).
           Tools without a radius (the blank holder) have only the last two.
    run    output folder, seconds, parameters, files written.

    tool_files {tool: `ToolData`} of the tool files written (CAD normals, structured quads).

    ``as_json()`` is what summary.json holds: the tools at the top level and the run data
    under "_run" (a key no tool name can take).
    """

    tools: dict = field(default_factory=dict)
    run: dict = field(default_factory=dict)
    tool_files: dict = field(default_factory=dict, repr=False)  # {tool: ToolData written}

    def as_json(self) -> dict:
        return {**self.tools, "_run": self.run}

    def table(self) -> str:
        """The summary as a Markdown table (also printed by `cadbridge ushape`)."""
        lines = [
            "| tool | normals | max radial error [%] | radius elements e1 / e2 / e3 [%] | max normal error [°] |",
            "|---|---|---:|---|---:|",
        ]
        for tool, by_source in self.tools.items():
            for src, r in by_source.items():
                if "radius_elements_max_radial_error_pct" in r:
                    els = " / ".join(f"{e:+.4f}" for e in r["radius_elements_max_radial_error_pct"])
                    lines.append(f"| {tool} | {src} | {r['max_radial_error_pct']:+.4f} | {els} | {r['max_normal_error_deg']:.4f} |")
                elif "max_abs_surface_error_mm" in r:
                    lines.append(
                        f"| {tool} | {src} | surface {r['max_abs_surface_error_mm']:.2e} mm, boundary "
                        f"{r['max_boundary_error_mm']:.2e} mm | - | {r['max_normal_error_deg']:.4f} |"
                    )
                else:  # the polyhedral reference
                    lines.append(f"| {tool} | {src} | {r['max_radial_error_pct']:+.4f} | - | - |")
        return "\n".join(lines)

    def findings(self, tool: str = "die") -> list[str]:
        """The thesis' Fig. 49 statements, checked on ``tool`` (one line each)."""
        r = self.tools.get(tool, {})
        if "cad" not in r:
            return []
        cad = r["cad"]["radius_elements_max_radial_error_pct"]
        poly = r["polyhedral"]["max_radial_error_pct"]
        wo = r["mwe_without_planes"]["radius_elements_max_radial_error_pct"]
        best = {k: abs(r[k]["max_radial_error_pct"]) for k in ("mwe_with_planes", "mwaat_with_planes", "mwelr_with_planes")}
        order = " < ".join(f"{k.split('_')[0].upper()} {v:.4f} %" for k, v in sorted(best.items(), key=lambda kv: kv[1]))
        return [
            f"CAD normals: max radial error {max(cad, key=abs):+.4f} % in each of the three radius elements "
            f"(spread {max(cad) - min(cad):.1e} %)",
            f"MWE without planes: outer elements {wo[0]:+.4f} / {wo[-1]:+.4f} % vs polyhedral {poly:+.4f} %",
            f"with planes, max |radial error|: {order}",
        ]


def _radius_axis(tool: str, p: UShapeParams) -> tuple[np.ndarray, float]:
    """Centre (x, z) of the tool radius' circle and the radius (see geometry.tool_faces)."""
    if tool == "die":
        return np.array([p.die_half_opening + p.die_radius, -p.die_radius]), p.die_radius
    return np.array([p.punch_half_width - p.punch_radius, p.thickness + p.punch_radius]), p.punch_radius


def section_errors(nm, elements: np.ndarray, centre_xz: np.ndarray, radius: float, y: float,
                   samples: int = 101) -> SectionResult:
    """Errors of the Nagata patches ``elements`` (quads on a cylindrical radius with axis
    along y) along the plane y = ``y``.

    Each quad has one parametric direction along y (its straight edges); the section is the
    iso-line of the other direction at the parameter where the patch crosses y (found by
    bisection on the straight edge, exact for the translational patches of a cylinder).
    """
    corners = nm.quad_elements[nm.element_local[elements]]
    x = nm.nodes[corners]  # (E, 4, 3): x00 x10 x11 x01
    eta_along_y = np.abs(x[:, 1, 1] - x[:, 0, 1]) > np.abs(x[:, 3, 1] - x[:, 0, 1])
    t = np.linspace(0.0, 1.0, samples)
    # parameter across y where the patch meets the plane: linear along the straight edge
    y0 = x[:, 0, 1]
    y1 = np.where(eta_along_y, x[:, 1, 1], x[:, 3, 1])
    c = (y - y0) / (y1 - y0)
    el = np.repeat(elements, samples)
    tt = np.tile(t, len(elements))
    cc = np.repeat(c, samples)
    along = np.repeat(eta_along_y, samples)
    eta = np.where(along, cc, tt)
    zeta = np.where(along, tt, cc)
    pts, nrm = nm.evaluate(el, eta, zeta)
    rel = pts[:, [0, 2]] - centre_xz
    r = np.linalg.norm(rel, axis=1)
    radial = (r - radius) / radius * 100.0
    # exact normal of the cylinder: radial in the xz plane (sign-free comparison)
    n_exact = np.column_stack([rel[:, 0] / r, np.zeros(len(r)), rel[:, 1] / r])
    normal_err = np.degrees(np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", nrm, n_exact)), 0.0, 1.0)))
    # position along the section: angle about the axis from the first tangent point
    ang = np.arctan2(rel[:, 1], rel[:, 0])
    s = ang - ang.min()
    # number the elements in their order along the section
    el_pos = np.repeat(np.arange(len(elements)), samples)
    mean_ang = np.bincount(el_pos, weights=ang) / samples
    rank = np.empty(len(elements), dtype=np.int64)
    rank[np.argsort(mean_ang)] = np.arange(len(elements))
    el_rank = rank[el_pos]
    o = np.lexsort((s, el_rank))
    return SectionResult(s[o], radial[o], normal_err[o], el_rank[o])


def _flat_normals_toward(mesh, toward_z: float):
    """Reverse the winding of ``mesh`` if its flat elements face away from z = toward_z."""
    from cadbridge.mesh.mesh import CellBlock, Mesh
    from cadbridge.mesh.topology import element_normals

    n = element_normals(mesh)
    cent = np.concatenate([mesh.nodes[np.asarray(b.data)].mean(axis=1) for b in mesh.cells])
    score = np.sum(n[:, 2] * np.sign(toward_z - cent[:, 2]))
    if score >= 0:
        return mesh
    return Mesh(nodes=mesh.nodes, cells=[CellBlock(b.type, np.asarray(b.data)[:, ::-1]) for b in mesh.cells], name=mesh.name)


def _estimated(mesh_nodes, quads, method, sub_elements=None):
    """Node normals by a polyhedral estimator over ``quads`` (or only ``quads[sub_elements]``,
    renumbered): (nodes, quads, normals, original node ids)."""
    from cadbridge.normals.estimators import estimate_normals

    if sub_elements is None:
        used, q = np.arange(len(mesh_nodes)), quads
    else:
        used, inv = np.unique(quads[sub_elements], return_inverse=True)
        q = inv.reshape(-1, 4)
    nodes = mesh_nodes[used]
    return nodes, q, estimate_normals(nodes, [q], method=method), used


def _tool_sources(tool, mesh, cn, on_radius, p, projector, grid, edge_rule="bounded"):
    """Fig. 49 for one tool: per normal source the section errors (tools with a radius),
    the node-normal angles to the CAD normals and the shape errors of the whole Nagata
    surface against the CAD. Returns (results, sections, element boundaries, angles,
    shape errors)."""
    from cadbridge.nagata import NagataMesh
    from cadbridge.nagata.errors import angle_deg

    quads = mesh.quads
    rad_el = np.flatnonzero(on_radius)
    has_radius = len(rad_el) > 0
    centre, radius = _radius_axis(tool, p) if has_radius else (None, None)
    y_mid = 0.5 * (p.y_range[0] + p.y_range[1])
    results, sections, angles, shape = {}, {}, {}, {}
    boundaries = None
    for key, method, planes in SOURCES:
        if not planes and not has_radius:
            continue
        if method == "cad":
            nodes, q, nrm, used = mesh.nodes, quads, cn.normals, np.arange(len(mesh.nodes))
        else:
            nodes, q, nrm, used = _estimated(mesh.nodes, quads, method, None if planes else rad_el)
            angles[key] = angle_deg(nrm, cn.normals[used])
        nm = NagataMesh(nodes, q, nrm, edge_rule=edge_rule)
        if planes:  # the whole tool against the CAD
            g = nm.sample_grid(grid)
            foot, ncad = projector(g.points)
            ncad = ncad * np.where(np.einsum("ij,ij->i", ncad, g.normals) < 0, -1.0, 1.0)[:, None]
            shape[key] = np.abs(np.einsum("ij,ij->i", g.points - foot, ncad))
        if has_radius:
            # the radius elements: numbered as in the mesh with planes, first ones without
            sec = section_errors(nm, rad_el if planes else np.arange(len(rad_el)), centre, radius, y_mid)
            results[key] = sec.as_dict()
            sections[key.replace("_", " ")] = (sec.s, sec.radial_error)
            boundaries = [float(sec.s[sec.element == k].max()) for k in range(int(sec.element.max()))]
    poly = None
    if has_radius:
        poly = _polyhedral_section(mesh.nodes, quads[rad_el], centre, radius, y_mid)
        results["polyhedral"] = {"max_radial_error_pct": float(poly[1][np.argmax(np.abs(poly[1]))])}
    return results, sections, boundaries, poly, angles, shape


def run_ushape(output: str, *, params: UShapeParams | None = None, grid: int = 20, fine_size: float = 4.0,
               progress=None, mesher: str = "gmsh", edge_rule: str = "bounded") -> UShapeSummary:
    """Run the benchmark into ``output`` (created; files are moved in only on success).

    mesher: "gmsh" or "qit" for the unstructured triangle variant (``fine_size``).
    edge_rule: "bounded" (default) or "published", the rule of every Nagata surface built
    (`cadbridge.nagata.edge`).

    progress: optional stage reporter (see `cadbridge.common.progress.NoProgress`).
    """
    from cadbridge.iges import read_iges
    from cadbridge.io.plots import plot_error_histogram, plot_normal_sources, plot_section_error
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.mesh.io import write_mesh
    from cadbridge.mesh.mesh import CellBlock, Mesh
    from cadbridge.normals.cad import cad_normals
    from cadbridge.tool.build import CadProjector, NoProgress, build_tool
    from cadbridge.tool.outputs import staged_output, tool_data, write_tool_outputs

    p = params or UShapeParams()
    progress = progress or NoProgress()
    from cadbridge.nagata import check_edge_rule

    check_edge_rule(edge_rule)
    t_start = time.perf_counter()
    summary = UShapeSummary()
    files: list[str] = []
    faces_by_tool = tool_faces(p)
    blank_z = p.thickness / 2

    with staged_output(output) as tmp:
        for sub in ("cad", "mesh", "blank"):
            (tmp / sub).mkdir()
        for tool, faces in faces_by_tool.items():
            progress.stage(f"{tool}: CAD -> NURBS IGES")
            cad_path = tmp / "cad" / f"{tool}.igs"
            export_iges(faces, cad_path, mode="nurbs", description=f"cadbridge ushape: NUMISHEET'93 {tool} (quarter model)")
            model = read_iges(cad_path)
            projector = CadProjector(model, progress)
            radius_faces = [i for i, f in enumerate(model.faces) if f.name and "RAD" in f.name.upper()]

            progress.stage(f"{tool}: structured quads, CAD normals")
            mesh = mesh_cad(cad_path, element="quad", structured=True, radius_divisions=3, length_divisions=1, divisions=1)
            mesh = _flat_normals_toward(mesh, blank_z)
            mesh.name = f"{tool}_quad"
            write_mesh(mesh, tmp / "mesh" / f"{tool}_quad.msh")
            cn = cad_normals(mesh, model)
            on_radius = np.isin(np.concatenate(cn.element_face), radius_faces)

            progress.stage(f"{tool}: CAD vs MWE / MWAAT / MWELR normals (Fig. 49)")
            results, sections, boundaries, poly, angles, shape = _tool_sources(tool, mesh, cn, on_radius, p, projector, grid,
                                                                               edge_rule)
            if sections:
                plot_section_error(
                    tmp / f"{tool}_section_error.png", sections, element_boundaries=boundaries, polyhedral=poly, legend_outside=True,
                    title=f"{tool}: radial error along section A-A through the radius (thesis Fig. 49)",
                )
                files.append(f"{tool}_section_error.png")
            plot_normal_sources(tmp / f"{tool}_normal_sources.png", angles,
                                title=f"{tool}: node normal estimates vs exact CAD normals")
            plot_error_histogram(tmp / f"{tool}_shape_error_by_source.png", shape,
                                 xlabel="|shape error| of the Nagata surface vs CAD [mm]",
                                 title=f"{tool}: shape error by source of the node normals")
            files += [f"{tool}_normal_sources.png", f"{tool}_shape_error_by_source.png"]

            # the tool file + report: CAD normals on the structured quad mesh
            tq = build_tool(tool, mesh, cn.normals, cn.corner_normals, "cad", model=model, grid=grid,
                            node_face=cn.face, node_distance=cn.distance, projector=projector, progress=progress,
                            edge_rule=edge_rule)
            (tmp / tool).mkdir()
            progress.stage(f"{tool}: tool file and report")
            files += [f"{tool}/{f}" for f in write_tool_outputs(tq, tmp / tool, model.units.name, f"cad/{tool}.igs",
                                                                True, projector)]
            summary.tool_files[tool] = tool_data(tq, model.units.name, f"cad/{tool}.igs")
            results["cad_quad_vs_cad"] = {
                "max_abs_surface_error_mm": tq.stats["max_abs_surface_error"],
                "max_boundary_error_mm": tq.stats["max_boundary_error"],
                "max_normal_error_deg": tq.stats["max_normal_error_deg"],
            }

            progress.stage(f"{tool}: unstructured triangles ({fine_size} mm), CAD normals")
            fine = mesh_cad(cad_path, element="tri", size=fine_size, mesher=mesher)
            fine = _flat_normals_toward(fine, blank_z)
            fine.name = f"{tool}_tri"
            write_mesh(fine, tmp / "mesh" / f"{tool}_tri.msh")
            cf = cad_normals(fine, model)
            tf = build_tool(f"{tool}_tri", fine, cf.normals, cf.corner_normals, "cad", model=model,
                            grid=max(4, grid // 4), node_face=cf.face, node_distance=cf.distance,
                            projector=projector, progress=progress, edge_rule=edge_rule)
            results["cad_fine_tri_vs_cad"] = {
                "max_abs_surface_error_mm": tf.stats["max_abs_surface_error"],
                "max_boundary_error_mm": tf.stats["max_boundary_error"],
                "max_normal_error_deg": tf.stats["max_normal_error_deg"],
                "elements": int(fine.n_elements),
            }
            (tmp / tf.name).mkdir()
            files += [f"{tf.name}/{f}" for f in write_tool_outputs(tf, tmp / tf.name, model.units.name,
                                                                     f"cad/{tool}.igs", False)]
            files += [f"cad/{tool}.igs", f"mesh/{tool}_quad.msh", f"mesh/{tool}_tri.msh"]
            summary.tools[tool] = results

        # the blank: a shell mesh of the mid-surface, and its process data
        progress.stage("blank shell mesh and summary")
        bn, bq = blank_mesh(p, element_size=1.0)
        write_mesh(Mesh(nodes=bn, cells=[CellBlock("quad", bq)], name="blank"), tmp / "blank" / "blank.msh")
        (tmp / "blank" / "process.json").write_text(json.dumps({
            "thickness_mm": p.thickness, "material": "mild steel (NUMISHEET'93)",
            "blankholder_force_kN_full": p.blankholder_force, "blankholder_force_kN_model": p.model_blankholder_force,
            "friction": p.friction, "punch_stroke_mm": p.punch_stroke,
            "symmetry": {"x": p.symmetry_x, "y": p.symmetry_y},
        }, indent=2))
        files += ["blank/blank.msh", "blank/process.json", "summary.json", "summary.md"]
        summary.run = {"output": str(output), "seconds": time.perf_counter() - t_start, "grid": grid,
                       "fine_size_mm": fine_size, "params": asdict(p), "files": files}
        (tmp / "summary.json").write_text(json.dumps(summary.as_json(), indent=2))
        (tmp / "summary.md").write_text(_markdown(summary))
    return summary


def _polyhedral_section(nodes, quads, centre, radius, y, samples: int = 101):
    """Radial error of the flat quads along the section y = ``y`` (the polyhedral model):
    (angle from the first tangent point (K,), radial error in % (K,))."""
    x = nodes[quads]  # (E, 4, 3): x00 x10 x11 x01
    # the section of a flat quad crossing y is the chord between its two straight edges at y
    along = (np.abs(x[:, 1, 1] - x[:, 0, 1]) > np.abs(x[:, 3, 1] - x[:, 0, 1]))[:, None]
    e0a, e0b = x[:, 0], np.where(along, x[:, 1], x[:, 3])  # first straight edge
    e1a, e1b = np.where(along, x[:, 3], x[:, 1]), x[:, 2]  # the opposite one

    def at_y(a, b):
        return a + ((y - a[:, 1]) / (b[:, 1] - a[:, 1]))[:, None] * (b - a)

    pa, pb = at_y(e0a, e0b), at_y(e1a, e1b)
    t = np.linspace(0.0, 1.0, samples)[None, :, None]
    seg = (pa[:, None] + t * (pb - pa)[:, None]).reshape(-1, 3)
    rel = seg[:, [0, 2]] - centre
    ang = np.arctan2(rel[:, 1], rel[:, 0])
    err = (np.linalg.norm(rel, axis=1) - radius) / radius * 100.0
    o = np.argsort(ang)
    return ang[o] - ang[o][0], err[o]


def _markdown(summary: UShapeSummary) -> str:
    findings = "".join(f"- {line}\n" for line in summary.findings("die"))
    return (
        "# NUMISHEET'93 U-shape: Nagata patches with CAD and estimated normals\n\n"
        "Radial error (thesis eq. 16, signed value of largest magnitude) and normal error (eq. 17)\n"
        "along the cross-section A-A through the tool radius, quadrilateral mesh with 3 elements\n"
        "over the radius and 1 along the length (thesis Figs. 48-49); `*_vs_cad` rows: shape\n"
        "error of the whole Nagata surface against the CAD by projection.\n\n"
        + summary.table()
        + ("\n\nDie, as in the thesis' Fig. 49:\n\n" + findings if findings else "\n")
        + f"\nRun time {summary.run['seconds']:.1f} s. Parameters: see summary.json (\"_run\").\n"
    )
