"""Where long work is, on stderr: a line rewritten in place on a terminal, plain lines in a log.

The library's long functions take a ``progress`` object with ``stage(text)``,
``update(done, total)`` and ``close()`` (`Progress`, or `NoProgress` for silence); the CLI
passes a `Progress`, so the library itself never prints.
"""

from __future__ import annotations

import sys
import time

__all__ = ["PROGRESS_LINE", "NoProgress", "Progress", "say"]


PROGRESS_LINE = r"^cadbridge \w+( \[\s*\d+\] |: done in )"  # how `Progress` lines begin (for filters)


class Progress:
    """Stage-level progress on stderr. On a terminal, one line rewritten in place::

        cadbridge convert [ 4] die: errors vs CAD (8484 patch points)  [######........]  43%  3.1 s

    Elsewhere (a log file, a pipe, CI), plain lines: one per stage, one every
    ``log_every`` seconds within a long stage, and the closing ``done in`` line, so a log
    says where long work is as a terminal does. ``cadbridge --quiet`` (``Progress.quiet``)
    silences both. `stage(text)` starts a new stage, `update(done, total)` moves the bar
    within it (chunked projection), `close()` ends the output. ``enabled`` forces the
    terminal form (True) or silence (False). The pipeline calls it duck-typed (see
    `cadbridge.common.progress.NoProgress`).
    """

    width = 20
    log_every = 10.0  # seconds between the lines of one stage off a terminal
    quiet = False  # set by `cadbridge --quiet`

    def __init__(self, label: str, enabled: bool | None = None, stream=None) -> None:
        self.label = label
        self.stream = stream or sys.stderr
        tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.mode = ("off" if self.quiet else "tty" if tty else "lines") if enabled is None else \
            ("tty" if enabled else "off")
        self.enabled = self.mode != "off"
        self.t0 = time.perf_counter()
        self.stages = 0
        self.text = ""
        self._last = 0.0
        self._logged = 0.0

    def _line(self, frac: float | None) -> str:
        bar = "" if frac is None else f"  [{'#' * int(self.width * frac):.<{self.width}}] {100 * frac:3.0f}%"
        text = self.text[:60] if self.mode == "tty" else self.text  # a log line keeps it whole
        return f"{self.label} [{self.stages:>2}] {text}{bar}  {time.perf_counter() - self.t0:.1f} s"

    def _draw(self, frac: float | None) -> None:
        if self.mode == "tty":
            self.stream.write("\r" + self._line(frac).ljust(110)[:110])
        elif self.mode == "lines":
            self._logged = time.perf_counter()
            self.stream.write(self._line(frac) + "\n")
        else:
            return
        self.stream.flush()

    def stage(self, text: str) -> None:
        self.stages += 1
        self.text = text
        self._draw(None)

    def update(self, done: int, total: int) -> None:
        now = time.perf_counter()
        if self.mode == "lines":
            if now - self._logged >= self.log_every:
                self._draw(min(done / max(total, 1), 1.0))
        elif now - self._last > 0.1 or done >= total:  # at most ten redraws a second
            self._last = now
            self._draw(min(done / max(total, 1), 1.0))

    def close(self) -> None:
        if self.enabled:
            done = f"{self.label}: done in {time.perf_counter() - self.t0:.1f} s"
            self.stream.write(("\r" + done.ljust(110) if self.mode == "tty" else done) + "\n")
            self.stream.flush()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        if self.mode == "tty" and exc[0] is not None:
            self.stream.write("\n")  # keep the error message on its own line
            self.stream.flush()
        elif exc[0] is None:
            self.close()


class NoProgress:
    """The silent progress object (the default of library calls)."""

    def stage(self, text: str) -> None:
        pass

    def update(self, done: int, total: int) -> None:
        pass

    def close(self) -> None:
        pass


def say(msg: str) -> None:
    """One line of a command's result on stdout (flushed, so it interleaves with stderr)."""
    print(msg, flush=True)
