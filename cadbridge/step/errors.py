"""`StepError`: a STEP file cadbridge cannot read, or that holds nothing to convert."""

from __future__ import annotations

__all__ = ["StepError"]


class StepError(ValueError):
    """A STEP file OCC cannot read, or whose transfer gives no B-rep face (exit 2 in the CLI).
    The message names the file and the reason."""
