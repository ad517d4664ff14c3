"""`cadbridge.common.fork_jobs.run_jobs`: every job runs exactly once, whichever process takes
it, and a failure in either process reaches the caller.

Reference: the files the jobs leave (one per job, holding its index and the id of the process
that ran it), counted here; the order of a run without fork (``fork=False``).
"""

from __future__ import annotations

import os

import pytest

from cadbridge.common.fork_jobs import JobError, run_jobs


def _writer(folder, i):
    def job():
        path = folder / f"{i}.txt"
        with open(path, "a") as fh:  # appended: a job run twice leaves two lines
            fh.write(f"{i} {os.getpid()}\n")
    return job


@pytest.mark.parametrize("fork", [None, True, False])
def test_every_job_runs_once(tmp_path, fork):
    first_done = []
    jobs = [_writer(tmp_path, i) for i in range(40)]
    run_jobs(jobs, first=lambda: first_done.append(os.getpid()), fork=fork)
    assert first_done == [os.getpid()]  # ``first`` runs once, in the caller's process
    lines = [(tmp_path / f"{i}.txt").read_text().splitlines() for i in range(40)]
    assert all(len(ln) == 1 for ln in lines)
    assert [int(ln[0].split()[0]) for ln in lines] == list(range(40))
    if fork is False:
        assert {int(ln[0].split()[1]) for ln in lines} == {os.getpid()}


def test_no_fork_runs_in_order():
    seen = []
    run_jobs([lambda i=i: seen.append(i) for i in range(5)], first=lambda: seen.append("first"), fork=False)
    assert seen == ["first", 0, 1, 2, 3, 4]


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this OS")
def test_a_failure_in_the_forked_process_is_raised(tmp_path):
    """Every job fails: whichever process takes the first one, the caller gets an error (the
    job's own in this process, `JobError` with the traceback from the forked one)."""
    def bad():
        raise ValueError("job failed on purpose")

    with pytest.raises((ValueError, JobError)) as info:
        run_jobs([bad, bad, bad], first=lambda: None, fork=True)
    assert "job failed on purpose" in str(info.value)


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this OS")
def test_a_failure_in_the_forked_process_alone(tmp_path):
    """The forked process fails its job while this one succeeds: `JobError`, after the forked
    process ended (its traceback names the job's exception)."""
    parent = os.getpid()

    def fails_off_parent():
        if os.getpid() != parent:
            raise RuntimeError("only in the forked process")

    import time

    # ``first`` sleeps, so the forked process takes the first jobs
    with pytest.raises(JobError, match="only in the forked process"):
        run_jobs([fails_off_parent] * 3, first=lambda: time.sleep(0.5), fork=True)
