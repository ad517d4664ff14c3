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
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

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
    """What `run_ushape` measured: {tool: {source: {...}}} plus timings and file list."""

    results: dict = field(default_factory=dict)
    output: str = ""
    seconds: float = 0.0
    files: list[str] = field(default_factory=list)
    params: dict = field(default_factory=dict)

    def table(self) -> str:
        """The summary as a Markdown table (also printed by `cadbridge ushape`)."""
        lines = [
            "| tool | normals | max radial error [%] | radius elements e1 / e2 / e3 [%] | max normal error [°] |",
            "|---|---|---:|---|---:|",
        ]
        for tool, by_source in self.results.items():
            for src, r in by_source.items():
                if "radius_elements_max_radial_error_pct" in r:
                    els = " / ".join(f"{e:+.4f}" for e in r["radius_elements_max_radial_error_pct"])
                    lines.append(f"| {tool} | {src} | {r['max_radial_error_pct']:+.4f} | {els} | {r['max_normal_error_deg']:.4f} |")
                elif "max_abs_shape_error_mm" in r:
                    lines.append(
                        f"| {tool} | {src} | shape {r['max_abs_shape_error_mm']:.2e} mm | - | {r['max_normal_error_deg']:.4f} |"
                    )
                else:  # the polyhedral reference
                    lines.append(f"| {tool} | {src} | {r['max_radial_error_pct']:+.4f} | - | - |")
        return "\n".join(lines)


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


def run_ushape(output: str, *, params: UShapeParams | None = None, grid: int = 20, fine_size: float = 4.0,
               verbose: bool = True) -> UShapeSummary:
    """Run the benchmark into ``output`` (created; files are moved in only on success)."""
    from cadbridge.iges import read_iges
    from cadbridge.io.plots import plot_normal_sources, plot_section_error
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.mesh.io import write_mesh
    from cadbridge.mesh.mesh import CellBlock, Mesh
    from cadbridge.nagata import NagataMesh
    from cadbridge.normals.cad import cad_normals
    from cadbridge.normals.estimators import estimate_normals
    from cadbridge.pipeline import _Staging, _write_tool_outputs, build_tool

    p = params or UShapeParams()
    t_start = time.perf_counter()
    summary = UShapeSummary(output=str(output), params=asdict(p))
    log = print if verbose else (lambda *a, **k: None)
    faces_by_tool = tool_faces(p)
    blank_z = p.thickness / 2
    y_mid = 0.5 * (p.y_range[0] + p.y_range[1])

    with _Staging(output) as tmp:
        (tmp / "cad").mkdir()
        (tmp / "mesh").mkdir()
        (tmp / "blank").mkdir()
        for tool, faces in faces_by_tool.items():
            log(f"[ushape] {tool}: CAD -> IGES (NURBS)")
            cad_path = tmp / "cad" / f"{tool}.igs"
            export_iges(faces, cad_path, mode="nurbs", description=f"cadbridge ushape: NUMISHEET'93 {tool} (quarter model)")
            model = read_iges(cad_path)
            radius_faces = [i for i, f in enumerate(model.faces) if f.name and "RAD" in f.name.upper()]

            log(f"[ushape] {tool}: structured quad mesh (3 over the radius, 1 along the length)")
            mesh = mesh_cad(cad_path, element="quad", structured=True, radius_divisions=3, length_divisions=1, divisions=1)
            mesh = _flat_normals_toward(mesh, blank_z)
            mesh.name = f"{tool}_quad"
            write_mesh(mesh, tmp / "mesh" / f"{tool}_quad.msh")
            quads = mesh.quads
            cn = cad_normals(mesh, model)
            elem_face = np.concatenate(cn.element_face)
            on_radius = np.isin(elem_face, radius_faces)

            tool_res: dict = {}
            sections: dict[str, tuple[np.ndarray, np.ndarray]] = {}
            node_angles: dict[str, np.ndarray] = {}
            boundaries = None
            for key, method, planes in SOURCES:
                if not radius_faces:
                    break
                if method == "cad":
                    nodes, q, nrm = mesh.nodes, quads, cn.normals
                else:
                    if planes:
                        nodes, q = mesh.nodes, quads
                    else:  # the radius elements alone, renumbered
                        used = np.unique(quads[on_radius])
                        remap = np.full(len(mesh.nodes), -1)
                        remap[used] = np.arange(len(used))
                        nodes, q = mesh.nodes[used], remap[quads[on_radius]]
                    nrm = estimate_normals(nodes, [q], method=method)
                    # the angle of each estimated node normal to the exact CAD normal
                    ref = cn.normals if planes else cn.normals[used]
                    node_angles[key] = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", nrm, ref), -1, 1)))
                nm = NagataMesh(nodes, q, nrm)
                rad_el = np.flatnonzero(on_radius) if planes or method == "cad" else np.arange(int(on_radius.sum()))
                centre, radius = _radius_axis(tool, p)
                sec = section_errors(nm, rad_el, centre, radius, y_mid)
                tool_res[key] = sec.as_dict()
                sections[key] = (sec.s, sec.radial_error)
                n_el = int(sec.element.max()) + 1
                boundaries = [float(sec.s[sec.element == k].max()) for k in range(n_el - 1)]
            # the polyhedral (flat quad) reference along the same section
            if radius_faces:
                centre, radius = _radius_axis(tool, p)
                poly = _polyhedral_section(mesh.nodes, quads[on_radius], centre, radius, y_mid)
                tool_res["polyhedral"] = {"max_radial_error_pct": float(poly[1][np.argmax(np.abs(poly[1]))])}
                plot_section_error(
                    tmp / f"{tool}_section_error.png",
                    {k.replace("_", " "): v for k, v in sections.items()},
                    element_boundaries=boundaries,
                    title=f"{tool}: radial error along section A-A through the radius (thesis Fig. 49)",
                    polyhedral=poly,
                )
                plot_normal_sources(tmp / f"{tool}_normal_sources.png", node_angles,
                                    title=f"{tool}: node normal estimates vs exact CAD normals")
                summary.files += [f"{tool}_section_error.png", f"{tool}_normal_sources.png"]

            # the tool file + report: CAD normals on the structured quad mesh
            tq = build_tool(tool, mesh, cn.normals, cn.corner_normals, "cad", model=model, grid=grid,
                            node_face=cn.face, node_distance=cn.distance)
            (tmp / tool).mkdir()
            summary.files += [f"{tool}/{f}" for f in _write_tool_outputs(tq, tmp / tool, model.units.name, f"cad/{tool}.igs", True, model)]
            tool_res["cad_quad_vs_cad"] = {
                "max_abs_shape_error_mm": tq.stats["max_abs_shape_error"],
                "max_normal_error_deg": tq.stats["max_normal_error_deg"],
            }

            log(f"[ushape] {tool}: unstructured triangles (size {fine_size} mm), CAD normals")
            fine = mesh_cad(cad_path, element="tri", size=fine_size)
            fine = _flat_normals_toward(fine, blank_z)
            fine.name = f"{tool}_tri"
            write_mesh(fine, tmp / "mesh" / f"{tool}_tri.msh")
            cf = cad_normals(fine, model)
            tf = build_tool(f"{tool}_tri", fine, cf.normals, cf.corner_normals, "cad", model=model, grid=max(4, grid // 4),
                            node_face=cf.face, node_distance=cf.distance)
            tool_res["cad_fine_tri_vs_cad"] = {
                "max_abs_shape_error_mm": tf.stats["max_abs_shape_error"],
                "max_normal_error_deg": tf.stats["max_normal_error_deg"],
                "elements": int(fine.n_elements),
            }
            write_name = f"{tool}_tri"
            (tmp / write_name).mkdir()
            summary.files += [f"{write_name}/{f}" for f in _write_tool_outputs(tf, tmp / write_name, model.units.name, f"cad/{tool}.igs", False, model)]
            summary.results[tool] = tool_res

        # the blank: a shell mesh of the mid-surface, and its process data
        bn, bq = blank_mesh(p, element_size=1.0)
        write_mesh(Mesh(nodes=bn, cells=[CellBlock("quad", bq)], name="blank"), tmp / "blank" / "blank.msh")
        (tmp / "blank" / "process.json").write_text(json.dumps({
            "thickness_mm": p.thickness, "material": "mild steel (NUMISHEET'93)",
            "blankholder_force_kN_full": p.blankholder_force, "blankholder_force_kN_model": p.model_blankholder_force,
            "friction": p.friction, "punch_stroke_mm": p.punch_stroke,
            "symmetry": {"x": p.symmetry_x, "y": p.symmetry_y},
        }, indent=2))
        summary.files += ["blank/blank.msh", "blank/process.json"] + [f"cad/{t}.igs" for t in faces_by_tool] + \
            [f"mesh/{t}_{k}.msh" for t in faces_by_tool for k in ("quad", "tri")]
        summary.seconds = time.perf_counter() - t_start
        (tmp / "summary.json").write_text(json.dumps({"results": summary.results, "seconds": summary.seconds,
                                                      "params": summary.params}, indent=2))
        (tmp / "summary.md").write_text(_markdown(summary))
        summary.files += ["summary.json", "summary.md"]
    return summary


def _polyhedral_section(nodes, quads, centre, radius, y, samples: int = 101):
    """Radial error of the flat quads along the section (the polyhedral model's error)."""
    x = nodes[quads]
    # the section of a flat quad crossing y is the chord between its two straight edges at y
    eta_along_y = np.abs(x[:, 1, 1] - x[:, 0, 1]) > np.abs(x[:, 3, 1] - x[:, 0, 1])
    t = np.linspace(0.0, 1.0, samples)
    out_s, out_e = [], []
    for q, along in zip(x, eta_along_y):
        if along:  # straight edges x00-x10 and x01-x11
            e0, e1 = (q[0], q[1]), (q[3], q[2])
        else:
            e0, e1 = (q[0], q[3]), (q[1], q[2])
        pa = e0[0] + (y - e0[0][1]) / (e0[1][1] - e0[0][1]) * (e0[1] - e0[0])
        pb = e1[0] + (y - e1[0][1]) / (e1[1][1] - e1[0][1]) * (e1[1] - e1[0])
        seg = pa + t[:, None] * (pb - pa)
        rel = seg[:, [0, 2]] - centre
        out_s.append(np.arctan2(rel[:, 1], rel[:, 0]))
        out_e.append((np.linalg.norm(rel, axis=1) - radius) / radius * 100.0)
    ang = np.concatenate(out_s)
    err = np.concatenate(out_e)
    o = np.argsort(ang)
    return np.abs(ang[o] - ang[o][0]), err[o]


def _markdown(summary: UShapeSummary) -> str:
    return (
        "# NUMISHEET'93 U-shape: Nagata patches with CAD and estimated normals\n\n"
        "Radial error (thesis eq. 16, signed value of largest magnitude) and normal error (eq. 17)\n"
        "along the cross-section A-A through the tool radius, quadrilateral mesh with 3 elements\n"
        "over the radius and 1 along the length (thesis Figs. 48-49); `*_vs_cad` rows: shape\n"
        "error of the whole Nagata surface against the CAD by projection.\n\n"
        + summary.table()
        + f"\n\nRun time {summary.seconds:.1f} s. Parameters: see summary.json.\n"
    )
