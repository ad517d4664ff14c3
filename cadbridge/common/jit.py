"""Tell the user, once, when numba compiles cadbridge's kernels (a cold cache: the first run
after an install or an upgrade).

The kernels are ``@numba.njit(cache=True)``: compiled on first use, then loaded from the
cache (``__pycache__`` next to the sources, or ``NUMBA_CACHE_DIR``). A compile happens only
on a cache miss, which numba announces with its ``numba:compile`` event; the listener here
writes one line on the first such event for a function of cadbridge and stays silent after
(and on every warm run, where no compile event is raised at all).
"""

from __future__ import annotations

import sys
from typing import TextIO

__all__ = ["COMPILE_SECONDS", "announce_compilation", "parallel_kernels", "serial_kernels_only"]

# cold minus warm `cadbridge ushape -o DIR` (empty NUMBA_CACHE_DIR, then the same again):
# 17.9 s - 11.2 s wall, 16.3 s - 7.0 s CPU on a shared 2-core machine; rounded up, as a
# command running the parallel kernels (many points) compiles those too. The batched
# projection kernels (nurbs.project_many, trims) made reading the bearing and projecting
# 20 000 points onto it 46.7 s cold against 5.0 s warm (was 25.5 s against 5.8 s)
COMPILE_SECONDS = 40

_listener = None
_parallel = True


def serial_kernels_only() -> None:
    """From now on, surface evaluation and Newton projection call their serial kernels only
    (the batched projection of `cadbridge.nurbs.project_many` and the fitting kernels have no
    serial twin, and a meshing child does not call them). For a forked child
    (`cadbridge.mesh.gmsh.isolated`): GNU OpenMP, numba's threading layer on Linux, terminates a
    child that starts a parallel region after its parent did ("fork() called from a process
    already using GNU OpenMP, this is unsafe")."""
    global _parallel
    _parallel = False


def parallel_kernels() -> bool:
    """Whether this process may call numba's parallel (prange) kernels (`serial_kernels_only`)."""
    return _parallel


def announce_compilation(stream: TextIO | None = None, seconds: float = COMPILE_SECONDS, quiet: bool = False) -> None:
    """Write "compiling numerical kernels (first run only, about N s)" to ``stream`` (stderr
    by default) when numba starts compiling a cadbridge function, at most once per process;
    nothing while ``quiet`` (`cadbridge --quiet`: no progress lines; a later call without it
    still announces). Safe to call more than once (one listener; the last call's stream,
    seconds and quiet count) and without numba (a no-op)."""
    global _listener
    if _listener is not None:
        _listener.stream, _listener.seconds, _listener.quiet = stream, seconds, quiet
        return
    try:
        from numba.core import event
    except ImportError:  # pragma: no cover - numba is a dependency
        return

    class _Once(event.Listener):
        def __init__(self) -> None:
            self.stream = stream
            self.seconds = seconds
            self.quiet = quiet
            self.said = False

        def on_start(self, ev) -> None:
            if self.said or self.quiet:
                return
            disp = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
            module = getattr(getattr(disp, "py_func", None), "__module__", "") or ""
            if not module.startswith("cadbridge."):
                return  # numba's own helpers compile inside ours; the first of ours decides
            self.said = True
            out = self.stream or sys.stderr
            # on a terminal the progress line is rewritten with "\r": start a fresh line
            line = f"cadbridge: compiling numerical kernels (first run only, about {self.seconds:.0f} s)"
            try:
                if getattr(out, "isatty", lambda: False)():
                    line = "\r" + line.ljust(110)
                out.write(line + "\n")
                out.flush()
            except (ValueError, OSError):
                pass  # the stream is gone (closed by its owner): a notice must never break a compile

        def on_end(self, ev) -> None:
            pass

    _listener = _Once()
    event.register("numba:compile", _listener)
