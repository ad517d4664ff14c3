"""The cold-start notice: one stderr line when numba has to compile cadbridge's kernels.

References: an empty NUMBA_CACHE_DIR is a cold cache by construction (numba then compiles
every kernel it runs), and the same directory on the next run is a warm one (numba loads
the kernels it saved and raises no compile event).
"""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MESSAGE = "compiling numerical kernels (first run only, about"


def _inspect(cache: Path) -> subprocess.CompletedProcess:
    sample = min((ROOT / "iges_samples").glob("*.igs"), key=lambda p: p.stat().st_size)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    return subprocess.run([sys.executable, "-m", "cadbridge", "inspect", str(sample)], env=env,
                          capture_output=True, text=True, timeout=600)


@contextlib.contextmanager
def _unannounced():
    """The process's compile listener (if any) as if it had said nothing yet, restored after:
    said, with no stream and not quiet."""
    from cadbridge.common import jit as _jit

    saved = _jit._listener
    try:
        if saved is not None:
            saved.said = False
        yield
    finally:
        if saved is not None:
            saved.said = True
            saved.stream = None
            saved.quiet = False


def test_cli_says_once_when_the_cache_is_cold_and_nothing_when_warm(tmp_path):
    """`cadbridge inspect` (it runs the compiled IGES scanner) with an empty cache directory
    prints the notice exactly once on stderr, nothing on stdout; the second run on the now
    filled cache prints no notice."""
    cold = _inspect(tmp_path)
    assert cold.returncode == 0, cold.stderr
    assert cold.stderr.count(MESSAGE) == 1, cold.stderr
    assert MESSAGE not in cold.stdout
    assert any(tmp_path.rglob("*.nbi"))  # numba did save the compiled kernels there
    warm = _inspect(tmp_path)
    assert warm.returncode == 0, warm.stderr
    assert MESSAGE not in warm.stderr
    assert warm.stdout == cold.stdout


def test_notice_only_for_cadbridge_functions_and_only_once():
    """In-process: a freshly compiled function of a module named ``cadbridge.*`` triggers the
    line once, a second one does not, and a compile outside cadbridge never does (the
    listener is looked up from numba's own compile event, a cache miss by definition for a
    function defined here)."""
    numba = pytest.importorskip("numba")
    from cadbridge.common import jit as _jit

    stream = io.StringIO()
    with _unannounced():
        _jit.announce_compilation(stream, seconds=7)

        def make(module: str):
            ns = {"__name__": module}
            exec("def f(x):\n    return x + 1\n", ns)  # noqa: S102 - a fresh function in that module
            return numba.njit(ns["f"])

        make("not_cadbridge_probe")(1)
        assert stream.getvalue() == ""
        make("cadbridge._probe")(1)
        make("cadbridge._probe2")(1.0)
        assert stream.getvalue() == "cadbridge: compiling numerical kernels (first run only, about 7 s)\n"


def test_notice_to_a_closed_stream_never_breaks_a_compile():
    """The CLI's stream may be closed by the time a kernel compiles (pytest's captured
    stderr of an earlier test; a fresh clone's cold cache showed it as an IgesError "I/O
    operation on closed file" from the P-section scan): the compile must still succeed.
    Reference: the function's result."""
    numba = pytest.importorskip("numba")
    from cadbridge.common import jit as _jit

    stream = io.StringIO()
    stream.close()
    with _unannounced():
        _jit.announce_compilation(stream, seconds=7)
        ns = {"__name__": "cadbridge._probe_closed"}
        exec("def f(x):\n    return x * 3\n", ns)  # noqa: S102 - a fresh function in that module
        assert numba.njit(ns["f"])(2) == 6


def test_quiet_notice_says_nothing():
    """`cadbridge --quiet` (announce_compilation(quiet=True)): a compile writes nothing; a later
    call without quiet announces again (the notice was not used up). Reference: the stream."""
    numba = pytest.importorskip("numba")
    from cadbridge.common import jit as _jit

    stream = io.StringIO()
    with _unannounced():
        _jit.announce_compilation(stream, seconds=7, quiet=True)
        ns = {"__name__": "cadbridge._probe_quiet"}
        exec("def f(x):\n    return x - 1\n", ns)  # noqa: S102 - a fresh function in that module
        assert numba.njit(ns["f"])(2) == 1 and stream.getvalue() == ""
        _jit.announce_compilation(stream, seconds=7)
        ns = {"__name__": "cadbridge._probe_loud"}
        exec("def f(x):\n    return x - 2\n", ns)  # noqa: S102 - a fresh function in that module
        assert numba.njit(ns["f"])(2) == 0
        assert stream.getvalue() == "cadbridge: compiling numerical kernels (first run only, about 7 s)\n"
