"""The two ways a run ends short of success, shared by the library and the command line.

`UsageError`: the input or the arguments cannot be used (exit code 2, with `IgesError`,
`MeshError` and the other input errors); `CheckFailed`: a check the user asked for did not
hold (exit code 1). Both carry one line for the user.
"""

from __future__ import annotations

__all__ = ["EXIT_BAD_INPUT", "EXIT_CHECK_FAILED", "EXIT_OK", "CheckFailed", "UsageError"]

EXIT_OK, EXIT_CHECK_FAILED, EXIT_BAD_INPUT = 0, 1, 2


class UsageError(Exception):
    """Wrong combination of arguments or unusable input (exit code 2, like argparse's own errors)."""


class CheckFailed(Exception):
    """A check the user asked for did not hold (exit code 1): the message says which."""
