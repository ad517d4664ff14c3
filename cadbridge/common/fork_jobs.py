"""Independent jobs shared between this process and one forked copy of it.

The report pictures of a tool (matplotlib, Python-bound: about 12 s of CPU on the production
die) need nothing but arrays the process already holds. `run_jobs` forks once; the parent
first does its own work (``first``: the tool files and VTUs), then both processes take the
remaining jobs one at a time from a shared counter until none is left, so the two cores of a
small machine share them whatever their sizes. A forked child needs no pickling: it sees the
parent's arrays as they are. Where fork is missing (Windows) or one core is all there is,
everything runs here, in order. Each job writes its own file (atomically), so the outputs are
the same either way.
"""

from __future__ import annotations

import os
import traceback
from collections.abc import Callable, Sequence

__all__ = ["JobError", "run_jobs"]


class JobError(RuntimeError):
    """A job failed in the forked process: the message holds its traceback."""


def _available_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def run_jobs(jobs: Sequence[Callable[[], object]], *, first: Callable[[], object] | None = None,
             fork: bool | None = None) -> None:
    """Run ``first`` (if given) and every one of ``jobs`` once each, the jobs shared with one
    forked process (module docs). Put the longest jobs first: each process takes the next
    one when it is free. ``fork``: None forks where the OS can and more than one CPU is
    available; False runs everything here. Raises what ``first`` or a job here raises, or
    `JobError` with the traceback of a job that failed in the forked process (after it
    ended: it never writes after this returns)."""
    jobs = list(jobs)
    if fork is None:
        fork = hasattr(os, "fork") and _available_cpus() > 1 and len(jobs) > 1
    if not fork or not jobs:
        if first is not None:
            first()
        for job in jobs:
            job()
        return
    import multiprocessing

    counter = multiprocessing.get_context("fork").Value("q", 0)  # the next job's index, in shared memory

    def take() -> int:
        with counter.get_lock():
            i = counter.value
            counter.value = i + 1
        return i

    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the forked copy: jobs only, then out without running the parent's exit handlers
        os.close(r)
        code = 0
        try:
            while (i := take()) < len(jobs):
                jobs[i]()
        except BaseException:
            code = 1
            try:
                os.write(w, traceback.format_exc()[-8000:].encode(errors="replace"))  # below a pipe's buffer
            except BaseException:
                pass
        finally:
            os._exit(code)
    os.close(w)
    try:
        if first is not None:
            first()
        while (i := take()) < len(jobs):
            jobs[i]()
    except BaseException:
        with counter.get_lock():
            counter.value = len(jobs)  # the child stops after the job it is on
        raise
    finally:
        _, status = os.waitpid(pid, 0)
        with os.fdopen(r, "rb") as fh:
            message = fh.read().decode(errors="replace")
    if status != 0:
        raise JobError(f"a job failed in the forked process (status {status}):\n{message}")
