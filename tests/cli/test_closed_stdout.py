"""A reader that closes stdout early (``cadbridge inspect F | head``): the command ends quietly
with exit 0, whatever the subcommand, as other Unix tools do (was: "error: BrokenPipeError").

Reference: a pipe whose read end is closed before the command starts, so that its first
write to stdout fails (EPIPE) deterministically.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = str(ROOT / "iges_samples" / "trimmed_hole.igs")


def _run_with_closed_stdout(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    r, w = os.pipe()
    os.close(r)  # nobody will read: every write to stdout fails
    try:
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        return subprocess.run([sys.executable, "-m", "cadbridge", *args], stdout=w, stderr=subprocess.PIPE,
                              text=True, cwd=cwd, env=env, timeout=600)
    finally:
        os.close(w)


@pytest.mark.parametrize("args", [
    ["--help"],
    ["inspect", SAMPLE],
    ["-q", "convert", SAMPLE, "-o", "OUT"],
    ["-q", "mesh", SAMPLE, "-o", "OUT.msh"],
], ids=["help", "inspect", "convert", "mesh"])
def test_closed_stdout_ends_quietly(args, tmp_path):
    args = [a.replace("OUT", str(tmp_path / "out")) for a in args]
    res = _run_with_closed_stdout(args, tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stderr == "", res.stderr


def test_warnings_are_one_line(tmp_path):
    """A library warning during a command is one line on stderr ("cadbridge CMD: warning:
    ..."), not Python's message plus the source line that warned; the error stays the last line."""
    code = ("import sys, warnings\nimport cadbridge.cli.inspect as i\n"
            "def cmd(args):\n    warnings.warn('first line\\nsecond line')\n    raise FileNotFoundError('no such file')\n"
            "i.cmd_inspect = cmd\nfrom cadbridge.cli import main\nsys.exit(main(['inspect', 'x.igs']))\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env,
                         timeout=600)
    assert res.returncode == 2
    assert res.stderr.splitlines() == ["cadbridge inspect: warning: first line", "cadbridge inspect: error: no such file"]
