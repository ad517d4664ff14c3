"""`cadbridge warmup`: the kernels of the main job compiled ahead, so that its first run is warm.

References: numba itself (a listed kernel is a numba dispatcher of that name whose
signature takes as many arguments as the function; numba's repr of the types reads back to
the same types), and numba's compile event, raised on every cache miss and nothing else
(`cadbridge.common.jit` turns it into the "compiling numerical kernels" notice): after a
warm-up into an empty NUMBA_CACHE_DIR, `cadbridge ushape` in that directory must not raise it.
"""

from __future__ import annotations

import inspect
import os
import re
import subprocess
import sys

import pytest

from cadbridge.cli import warmup
from cadbridge.cli.warmup_kernels import KERNELS

NOTICE = "compiling numerical kernels"


def test_listed_kernels_exist_and_their_types_read_back():
    """Every entry names a numba dispatcher; its argument types parse (numba's repr read back
    gives the same repr) and are as many as the function's parameters; each kernel once."""
    from numba.core.registry import CPUDispatcher

    assert KERNELS
    names = [(m, n) for m, n, _, _ in KERNELS]
    assert len(set(names)) == len(names)  # one specialisation per kernel
    for module, name, sig, seconds in KERNELS:
        disp = getattr(__import__(module, fromlist=[name]), name)
        assert isinstance(disp, CPUDispatcher), (module, name)
        args = warmup.parse_signature(sig)
        assert repr(args) == sig
        assert len(args) == len(inspect.signature(disp.py_func).parameters), (module, name)
        assert seconds >= 0


def _small(n: int) -> list:
    """The n listed kernels of shortest recorded compile time, shortest last."""
    return sorted(KERNELS, key=lambda e: e[3])[:n][::-1]


@pytest.mark.parametrize("jobs", [1, 2])
def test_compile_kernels_reports_a_stale_entry_and_compiles_the_others(jobs):
    """A kernel that is gone comes back with its error, the others compile (or load) with
    their listed types: afterwards numba has exactly those signatures."""
    entries = _small(2) + [("cadbridge.mesh.topology", "no_such_kernel", "(int64,)", 99.0)]
    results = warmup.compile_kernels(entries, jobs=jobs)
    # slowest (as recorded) first: the stale entry (99 s) leads
    assert [r[0] for r in results] == [f"{m}.{n}" for m, n, _, _ in [entries[2], entries[0], entries[1]]]
    assert results[0][3].startswith("AttributeError")
    assert all(r[3] is None for r in results[1:])
    if jobs == 1:  # compiled in this process: the dispatcher holds the listed signature
        for module, name, sig, _ in entries[:2]:
            disp = getattr(__import__(module, fromlist=[name]), name)
            assert warmup.parse_signature(sig) in [tuple(s) for s in disp.signatures]


def test_warmup_never_fails_on_a_stale_entry_and_fails_when_nothing_compiles(monkeypatch, capsys):
    """Exit 0 with a warning naming the stale kernel, whether others compile or not (a stale
    list: the job compiles on first use); exit 1 only if numba cannot compile at all (here:
    its compile made to fail)."""
    from cadbridge.cli import main
    from cadbridge.cli import warmup_kernels

    stale = ("cadbridge.mesh.topology", "no_such_kernel", "(int64,)", 1.0)
    monkeypatch.setattr(warmup_kernels, "KERNELS", (stale, *_small(1)))
    assert main(["warmup", "--jobs", "1"]) == 0
    out, err = capsys.readouterr()
    assert "warning: cadbridge.mesh.topology.no_such_kernel not compiled (AttributeError" in err
    assert "1 failed" in out
    monkeypatch.setattr(warmup_kernels, "KERNELS", (stale,))
    assert main(["warmup", "--jobs", "1"]) == 0
    import numba

    def broken(*a, **k):
        raise RuntimeError("no compiler")

    monkeypatch.setattr(numba, "njit", broken)
    assert main(["warmup", "--jobs", "1"]) == 1
    assert "numba cannot compile here" in capsys.readouterr().err
    assert main(["warmup", "--jobs", "0"]) == 2


@pytest.mark.slow
def test_ushape_after_warmup_compiles_nothing(tmp_path):
    """The acceptance of the README's install: `cadbridge warmup` into an empty cache, then
    `cadbridge ushape` there raises no compile event (no notice on stderr). Fails when the
    list no longer covers the job (re-record: `cadbridge warmup --record`)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    w = subprocess.run([sys.executable, "-m", "cadbridge", "warmup"], env=env, capture_output=True, text=True,
                       timeout=900)
    assert w.returncode == 0, w.stderr
    # an empty cache: every listed kernel compiled here, by one of the two processes (a kernel that
    # another listed one calls may be in the cache already when its own turn comes)
    m = re.search(r"compiled (\d+) kernels \((\d+) already in the cache, 0 failed\)", w.stdout)
    assert m and int(m.group(1)) + int(m.group(2)) == len(KERNELS) and int(m.group(1)) > len(KERNELS) // 2, w.stdout
    u = subprocess.run([sys.executable, "-m", "cadbridge", "ushape", "-o", str(tmp_path / "out")], env=env,
                       capture_output=True, text=True, timeout=900)
    assert u.returncode == 0, u.stderr
    assert NOTICE not in u.stderr
