"""STEP input: `read_step` (file -> `Model`, through OpenCASCADE) and `StepError`."""

from cadbridge.step.errors import StepError
from cadbridge.step.reader import is_step, read_step

__all__ = ["StepError", "is_step", "read_step"]
