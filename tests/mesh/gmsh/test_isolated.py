"""gmsh in a forked child, watched (`cadbridge.mesh.gmsh.isolated`): a hang or a crash of gmsh
on one surface fails that surface, which cadbridge then meshes in its (u, v), not the run.

Class: gmsh stops making progress on a surface (Frontal-Delaunay on trj6_b1's 1 mm^2 surface
85 ran for more than 10 minutes) or crashes in its C++ (algorithm 8 on a refold of
bug24283's spheres, a segfault at size 0.2674). Neither can be caught in the process that
calls gmsh. Here the watcher is checked on jobs that behave so on purpose (a gmsh Info line,
then a sleep or a SIGSEGV), and the whole route on a generated box whose gmsh "crashes" on one
face: the box is meshed whole, that face in its (u, v).

References: the job's own result (round trip through the child), the analytic box (area,
planes), and the parent's parallel kernel for the child's serial one.
"""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from cadbridge.mesh.gmsh.isolated import GmshHalted, gmsh_call, in_child, run_isolated
from cadbridge.mesh.mesh import MeshError

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork: gmsh runs unwatched")

LINE = b"Info    : [ 40%] Meshing surface 7 (BSpline surface, Frontal-Delaunay)\n"


class _Odd(Exception):
    def __init__(self, a, b):  # pickles as Exception(args) but does not rebuild from one
        super().__init__(f"{a}{b}")


def test_the_result_and_the_exception_come_back():
    out = run_isolated(lambda: (np.arange(5.0), in_child()))
    assert out[0].tolist() == [0.0, 1.0, 2.0, 3.0, 4.0] and out[1] is True
    assert in_child() is False

    def fails():
        raise MeshError("part.igs: no surfaces found")

    with pytest.raises(MeshError, match="no surfaces found"):
        run_isolated(fails)

    def odd():
        raise _Odd("a", "b")

    with pytest.raises(RuntimeError, match="_Odd"):
        run_isolated(odd)


def test_a_stall_inside_a_watched_call_names_the_surface_gmsh_was_meshing():
    def hangs():
        with gmsh_call():
            os.write(1, LINE)
            time.sleep(60)

    t0 = time.monotonic()
    with pytest.raises(GmshHalted) as err:
        run_isolated(hangs, stall_seconds=0.5)
    assert err.value.surface == 7 and "no progress" in str(err.value)
    assert time.monotonic() - t0 < 30  # killed, not waited for


def test_a_crash_names_the_surface_and_a_stall_outside_gmsh_names_none():
    def crashes():
        with gmsh_call():
            os.write(1, LINE)
            os.kill(os.getpid(), signal.SIGSEGV)

    with pytest.raises(GmshHalted) as err:
        run_isolated(crashes)
    assert err.value.surface == 7 and "SIGSEGV" in str(err.value)

    def other_model():  # a "Meshing surface" line of gmsh's own model of something else
        with gmsh_call(surfaces=False):
            os.write(1, LINE)
            os.kill(os.getpid(), signal.SIGSEGV)

    with pytest.raises(GmshHalted) as err:
        run_isolated(other_model)
    assert err.value.surface is None


def test_slow_python_between_gmsh_calls_is_no_stall():
    def slow():
        with gmsh_call():
            os.write(1, LINE)
        time.sleep(1.5)
        return "done"

    assert run_isolated(slow, stall_seconds=0.5) == "done"


def test_the_child_evaluates_many_points_after_the_parent_ran_a_parallel_kernel():
    """GNU OpenMP terminates a forked child that starts a parallel region after its parent did:
    the child then uses the serial kernels (`cadbridge.common.jit.serial_kernels_only`).
    Reference: the parent's parallel evaluation."""
    from cadbridge.nurbs.surface import _PARALLEL_MIN, NurbsSurface

    rng = np.random.default_rng(3)
    s = NurbsSurface(knots_u=[0, 0, 0, 1, 1, 1], knots_v=[0, 0, 0, 0.5, 1, 1, 1], degree_u=2, degree_v=2,
                     control_points=rng.normal(size=(3, 4, 3)), weights=rng.uniform(0.5, 2.0, size=(3, 4)))
    u, v = rng.uniform(size=(2, 2 * _PARALLEL_MIN))
    here = s.derivatives(u, v, order=1)
    there = run_isolated(lambda: s.derivatives(u, v, order=1))
    np.testing.assert_allclose(there, here, rtol=0, atol=1e-12)


def test_a_face_gmsh_crashes_on_is_meshed_in_its_uv_and_the_box_stays_whole(tmp_path, monkeypatch):
    cq = pytest.importorskip("cadquery")
    import gmsh

    from cadbridge.mesh.generate import mesh_cad

    path = tmp_path / "box.step"
    cq.exporters.export(cq.Workplane("XY").box(30, 20, 10), str(path))
    victim = 3
    real = gmsh.model.mesh.generate

    def generate(dim=3):
        if gmsh.model.getCurrent() != "cadbridge-mesh":  # the fill's own model of the face's (u, v)
            return real(dim)
        hidden = gmsh.option.getNumber("Mesh.MeshOnlyVisible") and not gmsh.model.getVisibility(2, victim)
        if dim == 2 and in_child() and not hidden and not len(gmsh.model.mesh.getElements(2, victim)[1]):
            os.write(1, f"Info    : [ 50%] Meshing surface {victim} (Plane, Frontal-Delaunay)\n".encode())
            os.kill(os.getpid(), signal.SIGSEGV)
        return real(dim)

    monkeypatch.setattr(gmsh.model.mesh, "generate", staticmethod(generate))
    mesh = mesh_cad(path, element="tri", size=4.0)
    assert any(f"gmsh failed (crashed (SIGSEGV))" in n and f"surface {victim}" in n for n in mesh.notes), mesh.notes
    x, t = mesh.nodes, mesh.triangles
    area = 0.5 * np.linalg.norm(np.cross(x[t[:, 1]] - x[t[:, 0]], x[t[:, 2]] - x[t[:, 0]]), axis=1)
    assert abs(area.sum() - 2 * (30 * 20 + 30 * 10 + 20 * 10)) < 1e-9 * 2200
    ent = np.asarray(mesh.cell_data["element_entity"])[:len(t)]
    assert np.count_nonzero(ent == victim) > 0
    # every node on the box's planes (analytic)
    half = np.array([15.0, 10.0, 5.0])
    assert np.all(np.min(np.abs(np.abs(x) - half), axis=1) < 1e-9)


def test_a_kernel_another_thread_is_compiling_at_the_fork_does_not_block_the_child():
    """`cadbridge.tool.pipeline` builds the search index on a second thread while gmsh meshes:
    a child forked while that thread held numba's compiler lock waited for it forever at its
    first kernel call. Here a thread holds the lock across the fork, and the child compiles a
    kernel of its own (inside a watched call: a blocked child is stopped, not waited for)."""
    import threading

    import numba
    from numba.core.compiler_lock import global_compiler_lock

    @numba.njit(cache=False)
    def twice(x):
        return 2.0 * x

    held, done = threading.Event(), threading.Event()

    def compiling():
        with global_compiler_lock:
            held.set()
            done.wait(1.0)

    t = threading.Thread(target=compiling)
    t.start()
    held.wait()

    def job():
        with gmsh_call():
            return twice(21.0)

    try:
        assert run_isolated(job, stall_seconds=10.0) == 42.0
    finally:
        done.set()
        t.join()


def test_gmsh_warnings_stay_quiet_and_the_childs_own_messages_pass(capfd):
    """gmsh prints its warnings to fd 2 in the child (its terminal output is on there, for the
    Info lines the watcher reads): they are dropped unless asked, as a session in this process
    keeps them quiet; what cadbridge itself writes reaches stderr."""
    import sys

    def job():
        os.write(2, b"Warning : Cannot apply Blossom: odd number of triangles (5) in surface 8\n")
        os.write(2, b"a line of the child's C code\n")
        print("a notice of the child's Python", file=sys.stderr)
        return 1

    assert run_isolated(job) == 1
    out, err = capfd.readouterr()
    assert "Blossom" not in out + err
    assert "a line of the child's C code" in err and "a notice of the child's Python" in err
