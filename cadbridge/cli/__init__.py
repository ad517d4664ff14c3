"""The `cadbridge` command: CAD in, exact normals, Nagata tool files and reports out.

Each subcommand is a thin layer over the library: parse arguments, call, print, and turn
the library's errors into one clear line and an exit code:

    0  success          1  checks failed (verify deviations, nodes off the CAD, a tool worse
                           than its flat mesh or straddling a crease)
    2  bad input (unreadable IGES/mesh, wrong arguments, or input the library could not
       handle: one line naming the error and where; CADBRIDGE_DEBUG=1 shows the traceback)
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings
from pathlib import Path

from cadbridge._version import __version__
from cadbridge.common.errors import EXIT_BAD_INPUT, EXIT_CHECK_FAILED, EXIT_OK, CheckFailed, UsageError
from cadbridge.common.progress import PROGRESS_LINE, Progress, say


__all__ = ["COMMANDS", "EXIT_BAD_INPUT", "EXIT_CHECK_FAILED", "EXIT_OK", "PROGRESS_LINE", "CheckFailed", "Progress",
           "UsageError", "build_parser", "main", "say"]

# One module per subcommand, in the order `cadbridge --help` lists them. Each defines
# ``register(sub, fmt) -> None`` that adds its parser with ``set_defaults(func=...)``; its
# command functions raise `UsageError` (exit 2) or `CheckFailed` (exit 1) with one line.
COMMANDS: tuple[str, ...] = ("inspect", "verify", "mesh", "normals", "nagata", "convert", "ushape", "map", "fit",
                             "quality", "warmup")


def build_parser() -> argparse.ArgumentParser:
    fmt = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(
        prog="cadbridge",
        formatter_class=fmt,
        description="Turn die and punch CAD (IGES/NURBS) into Nagata-patch tool files.",
        epilog="example:\n  cadbridge ushape -o out/            # the NUMISHEET'93 U-shape benchmark\n"
        "  cadbridge convert die.igs -o die/   # mesh + normals + Nagata + report",
    )
    parser.add_argument("--version", action="version", version=f"cadbridge {__version__}")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress lines (errors and the summary are still printed)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    for name in COMMANDS:
        importlib.import_module(f"cadbridge.cli.{name}").register(sub, fmt)
    return parser


def _known_errors() -> tuple[type[BaseException], ...]:
    errs: list[type[BaseException]] = [UsageError, CheckFailed, FileNotFoundError, IsADirectoryError, PermissionError,
                                       NotADirectoryError]
    for mod, name in (
        ("cadbridge.iges", "IgesError"),
        ("cadbridge.step", "StepError"),
        ("cadbridge.cad.model", "EmptyModelError"),
        ("cadbridge.mesh.mesh", "MeshError"),
        ("cadbridge.normals.cad", "ProjectionError"),
        ("cadbridge.io.toolfile", "ToolFileError"),
        ("cadbridge.verify.reference", "OccReadError"),
        ("cadbridge.tool.build", "ToolQualityError"),
        ("cadbridge.tool.outputs", "OutputFolderError"),
    ):
        try:
            module = __import__(mod, fromlist=[name])
            errs.append(getattr(module, name))
        except (ImportError, AttributeError):
            pass
    return tuple(errs)


def main(argv: list[str] | None = None) -> int:
    """Run one command; its exit code. A reader that closes stdout early (``cadbridge inspect
    F | head``) ends the command quietly with exit 0, as other Unix tools do."""
    try:
        return _main(argv)
    except BrokenPipeError:
        _stdout_to_devnull()
        return EXIT_OK


def _stdout_to_devnull() -> None:
    """Point the closed stdout at /dev/null, so that the interpreter's final flush of what is
    still buffered does not fail again at exit."""
    import os

    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, sys.stdout.fileno())
        os.close(fd)
    except (OSError, ValueError, AttributeError):  # no real stdout (embedded, replaced): nothing to flush
        pass


def _error_text(exc: BaseException) -> str:
    """The error line's text: a file system error as "PATH: what" (not Python's "[Errno 2]
    No such file or directory: 'PATH'"), others as they say it."""
    if isinstance(exc, OSError) and exc.filename and exc.strerror:
        return f"{exc.filename}: {exc.strerror.lower()}"
    return str(exc)


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    Progress.quiet = bool(getattr(args, "quiet", False))
    from cadbridge.common.jit import announce_compilation

    # one line on the then-current stderr if numba has to compile (cold cache), not with --quiet
    announce_compilation(quiet=Progress.quiet)
    plain = warnings.formatwarning
    # a library warning is one line too ("cadbridge CMD: warning: ..."), not Python's two
    # (the message, then the source line that warned)
    warnings.formatwarning = lambda message, category, *_a, **_k: (
        f"cadbridge {args.command}: warning: {(str(message).splitlines() or [category.__name__])[0]}\n")
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("cadbridge: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        raise  # stdout closed by its reader: `main` ends quietly
    except _known_errors() as exc:
        from cadbridge.normals.cad import ProjectionError
        from cadbridge.tool.build import ToolQualityError

        print(f"cadbridge {args.command}: error: {_error_text(exc)}", file=sys.stderr)
        return EXIT_CHECK_FAILED if isinstance(exc, (ProjectionError, ToolQualityError, CheckFailed)) else EXIT_BAD_INPUT
    except (ValueError, ArithmeticError, MemoryError, OSError, RuntimeError, LookupError, TypeError) as exc:
        # anything the library did not anticipate: still one line (the input it could not
        # handle); CADBRIDGE_DEBUG=1 shows the traceback for a bug report
        import os
        import traceback

        if os.environ.get("CADBRIDGE_DEBUG"):
            traceback.print_exc()
        where = traceback.extract_tb(exc.__traceback__)[-1]
        print(f"cadbridge {args.command}: error: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''} "
              f"(at {Path(where.filename).name}:{where.lineno}; CADBRIDGE_DEBUG=1 shows the traceback)",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    finally:
        warnings.formatwarning = plain


if __name__ == "__main__":
    sys.exit(main())
