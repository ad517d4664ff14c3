"""Timing shared by the benchmark scripts (not a test helper: no test times anything)."""

from __future__ import annotations

import math
import time
from typing import Callable


def best_of(fn: Callable[[], object], repeat: int) -> tuple[float, float, object]:
    """Best of ``repeat`` calls by wall time: (wall s, CPU s of this process, fn's result then)."""
    best: tuple[float, float, object] = (math.inf, math.inf, None)
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        w, c = time.perf_counter() - w, time.process_time() - c
        if w < best[0]:
            best = (w, c, out)
    return best
