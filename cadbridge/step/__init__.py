"""STEP input: `read_step` (file -> `Model`, through OpenCASCADE) and `StepError`."""

from cadbridge.step.errors import StepError
from cadbridge.step.reader import is_step, occ_step_shape, originating_system, read_step

__all__ = ["StepError", "is_step", "occ_step_shape", "originating_system", "read_step"]
