"""gmsh in a forked child, watched: a hang or a crash of gmsh on one surface fails that surface,
not the run.

gmsh has no time limit of its own, and a crash in its C++ ends the Python process that called
it. On the OCC corpus both happen at sizes other than the default: gmsh's Frontal-Delaunay ran
for more than 10 minutes on a 1 mm^2 face of trj6_b1 (edges of 8e-5 to 3e-3 mm, at a size that
follows the part), and its quad algorithm 8 segfaulted on a refold of bug24283's spheres at
size 0.2674. `run_isolated(job)` forks; the child runs ``job``
(one meshing attempt, with its own gmsh session) and sends its result back pickled (a `Mesh`:
numpy arrays, milliseconds). The parent reads gmsh's Info lines from the child's file
descriptor 1, one per curve and surface meshed, and the child's own marks around each gmsh
call that meshes the model's surfaces (`gmsh_call`):

- no line for `STALL_SECONDS` inside such a call: the child is killed, and `GmshHalted` names
  the surface gmsh was meshing (a backstop: one face can legitimately take minutes);
- the child ends by a signal (a segfault): `GmshHalted` names the surface gmsh was meshing, or
  none where it crashed outside a watched call.

The caller (`cadbridge.mesh.generate.mesh_cad`) then runs the attempt again with that surface
hidden from gmsh, as a surface gmsh failed on: cadbridge meshes it in its (u, v)
(`cadbridge.mesh.gmsh.empty_faces`). gmsh's surface tags are the same in the new attempt: the
same file, read with the same options.

The child uses the parent's memory as it is (copy-on-write: nothing is pickled on the way in),
and numba's serial kernels only: GNU OpenMP, numba's threading layer here, terminates a forked
child that starts a parallel region after its parent did (`cadbridge.common.jit`). The fork
waits for any kernel another thread is compiling (`_no_compile_under_way`). Where fork
is missing (Windows) or `WATCH` is False, ``job`` runs here, unwatched.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import re
import select
import shutil
import signal
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator
from typing import TypeVar

__all__ = ["GmshHalted", "STALL_SECONDS", "gmsh_call", "in_child", "run_isolated"]

T = TypeVar("T")

STALL_SECONDS = 300.0
"""A gmsh call that prints no line for this long has stopped. gmsh prints one line per curve
and surface, and nothing while it meshes one surface: on a 100 x 100 square at size 0.25 (one
face), Frontal-Delaunay ran 14 s silent (371 k triangles) and Delaunay + Blossom for quads 142 s
(205 k quads); the longest gap in the production die's quad mesh at the default size is 1.0 s
(its binder). A crash is seen at once; a stall costs this long before the face is left to the
(u, v) fill."""

_MARK = "\x1fcadbridge-gmsh "  # the child's marks on its fd 1, among gmsh's lines
_SURFACE = re.compile(r"Meshing surface (\d+)")
_GMSH_LINE = re.compile(r"^(Info|Warning|Error|Debug|Progress)\s*:")

_child = False

WATCH = True
"""False: `run_isolated` runs its job here, unwatched (a debugger, or a test that records what
happens inside the meshing, sees it)."""


class GmshHalted(Exception):
    """gmsh stopped making progress or crashed in the forked child (module docs). ``surface``:
    the gmsh surface it was meshing (None where unknown); ``reason``: what happened, a phrase."""

    def __init__(self, surface: int | None, reason: str) -> None:
        super().__init__(reason if surface is None else f"{reason} on surface {surface}")
        self.surface = surface
        self.reason = reason


def in_child() -> bool:
    """Whether this process is the watched child of `run_isolated` (gmsh's Info lines then go
    to the parent: `cadbridge.mesh.gmsh.session.GmshSession` turns them on)."""
    return _child


@contextlib.contextmanager
def gmsh_call(surfaces: bool = True) -> Iterator[None]:
    """Mark a gmsh call the parent watches for a stall (module docs). ``surfaces``: the call
    meshes the model's surfaces, so a "Meshing surface N" line inside it names a surface of
    the model (False: gmsh's own model of something else, e.g. a face's (u, v) loops)."""
    if not _child:
        yield
        return
    _say("begin surfaces" if surfaces else "begin other")
    try:
        yield
    finally:
        _say("end")


def _say(text: str) -> None:
    try:
        sys.stdout.flush()
        os.write(1, f"{_MARK}{text}\n".encode())
    except OSError:
        pass


def _can_fork() -> bool:
    return WATCH and hasattr(os, "fork") and not _child


def run_isolated(job: Callable[[], T], *, stall_seconds: float = STALL_SECONDS, echo_gmsh: bool = False) -> T:
    """``job()`` run in a forked child, watched (module docs): its result, or what it raised
    (the same exception, unpickled; a `RuntimeError` with its traceback where that cannot be
    pickled). Raises `GmshHalted` where gmsh stalled or the child crashed. gmsh's own lines
    (its Info, warnings and errors) are passed on to stdout only with ``echo_gmsh``; the
    child's other output to its fd 1 and 2 goes to stderr. Temporary files the
    child made (``tempfile``) are removed whatever happened to it."""
    if not _can_fork():
        return job()
    tmp = tempfile.mkdtemp(prefix="cadbridge-gmsh-")
    result = os.path.join(tmp, "result.pickle")
    r, w = os.pipe()
    sys.stdout.flush()
    sys.stderr.flush()
    with _no_compile_under_way():
        pid = os.fork()
    if pid == 0:  # pragma: no cover - the child (its coverage is not collected)
        _run_child(job, r, w, tmp, result)
    os.close(w)
    try:
        status = _watch(pid, r, stall_seconds, echo_gmsh)
        if status is not None:
            raise status
        with open(result, "rb") as f:
            kind, value = pickle.load(f)
    except BaseException:  # a stall, an interrupt, an unreadable result: the child ends here (if it has not)
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
        with contextlib.suppress(ChildProcessError):
            os.waitpid(pid, 0)
        raise
    finally:
        os.close(r)
        shutil.rmtree(tmp, ignore_errors=True)
    if kind == "raise":
        raise value
    return value


@contextlib.contextmanager
def _no_compile_under_way() -> Iterator[None]:
    """Hold numba's compiler lock across the fork. Another thread may be loading or compiling
    kernels (`cadbridge.tool.pipeline` builds the search index on a second thread while gmsh
    meshes): a child forked while that thread held the lock would wait for it forever at its
    first kernel call (seen on the test suite: a child asleep in ``rlock_acquire``). Taken here,
    the lock is free in both processes after the fork, and no kernel is half compiled."""
    try:
        from numba.core.compiler_lock import global_compiler_lock
    except ImportError:  # pragma: no cover - numba is a dependency
        yield
        return
    with global_compiler_lock:
        yield


def _run_child(job: Callable[[], object], r: int, w: int, tmp: str, result: str) -> None:  # pragma: no cover
    global _child
    code = 0
    try:
        _child = True
        with contextlib.suppress(Exception):  # the parent reports a crash, in one line
            import faulthandler

            faulthandler.disable()
        os.close(r)
        # fd 1 and 2 (gmsh's Info lines, its warnings and errors) to the parent; Python's own
        # stderr (warnings, notices) stays where it was: a terminal stays a terminal
        err = os.dup(2)
        os.dup2(w, 1)
        os.dup2(w, 2)
        os.close(w)
        sys.stderr = open(err, "w", buffering=1, encoding=getattr(sys.stderr, "encoding", None) or "utf-8",
                          errors="backslashreplace")
        tempfile.tempdir = tmp  # removed by the parent, whatever happens here
        from cadbridge.common.jit import serial_kernels_only

        serial_kernels_only()
        try:
            out: tuple[str, object] = ("ok", job())
        except BaseException as exc:
            out = ("raise", exc)
        try:
            blob = pickle.dumps(out, protocol=pickle.HIGHEST_PROTOCOL)
            if out[0] == "raise":
                pickle.loads(blob)  # an exception whose arguments do not rebuild it
        except BaseException:
            exc = out[1] if out[0] == "raise" else None
            text = "".join(traceback.format_exception(exc)) if isinstance(exc, BaseException) else traceback.format_exc()
            blob = pickle.dumps(("raise", RuntimeError(f"in the gmsh child process: {text[-4000:]}")))
        with open(result, "wb") as f:
            f.write(blob)
    except BaseException:
        code = 1
    finally:
        with contextlib.suppress(BaseException):
            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(code)


def _watch(pid: int, r: int, stall_seconds: float, echo_gmsh: bool) -> GmshHalted | None:
    """Read the child's fd 1 until it closes and wait for the child, or stop reading on a stall
    (module docs; `run_isolated` then kills and waits for it). None where it exited normally,
    else the `GmshHalted` to raise."""
    regions: list[bool] = []  # the watched calls the child is in: True where they mesh the model's surfaces
    surface: int | None = None
    last = time.monotonic()
    pending = b""
    while True:
        wait = max(0.05, last + stall_seconds - time.monotonic()) if regions else None
        ready, _, _ = select.select([r], [], [], wait)
        if not ready:
            if regions and time.monotonic() - last >= stall_seconds:  # the caller kills the child
                return GmshHalted(surface if regions[-1] else None,
                                  f"made no progress for {stall_seconds:g} s")
            continue
        chunk = os.read(r, 65536)
        if not chunk:
            break
        last = time.monotonic()
        pending += chunk
        *lines, pending = pending.split(b"\n")
        for raw in lines:
            line = raw.decode(errors="replace")
            if line.startswith(_MARK):
                what = line[len(_MARK):]
                if what.startswith("begin"):
                    regions.append(what == "begin surfaces")
                    surface = None
                elif regions:
                    regions.pop()
                continue
            if _GMSH_LINE.match(line):
                m = _SURFACE.search(line)
                if m and regions and regions[-1]:
                    surface = int(m.group(1))
                if echo_gmsh:
                    sys.stdout.write(line + "\n")
                continue
            sys.stderr.write(line + "\n")  # what the child wrote to its old stderr object
    sys.stdout.flush()
    sys.stderr.flush()
    _, status = os.waitpid(pid, 0)
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        try:
            name = signal.Signals(sig).name
        except ValueError:
            name = f"signal {sig}"
        return GmshHalted(surface if regions and regions[-1] else None, f"crashed ({name})")
    if os.WEXITSTATUS(status) != 0:
        return GmshHalted(None, f"its process ended with exit code {os.WEXITSTATUS(status)}")
    return None
