"""Independent fits on the machine's cores, in threads.

The compiled model releases the GIL (``nogil``), so fits that are mostly single model runs in
sequence (the deterministic method's one-knob searches, a local fit's steps) run side by side:
on 2 cores two such fits take the time of one. Python's own ``concurrent.futures`` does the work;
results come back in the order of the inputs whatever the threads' timing, so the outcome does
not depend on the machine's load.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, TypeVar

T = TypeVar("T")
R = TypeVar("R")


def workers() -> int:
    """Threads for independent fits: ``EHA_HEALTH_THREADS`` if set (1: none), else the cores this
    process may use."""
    env = os.environ.get("EHA_HEALTH_THREADS", "").strip()
    if env:
        try:
            n = int(env)
        except ValueError:
            raise ValueError(f"EHA_HEALTH_THREADS must be a whole number of threads, got {env!r}") from None
        if n < 1:
            raise ValueError(f"EHA_HEALTH_THREADS must be >= 1, got {n}")
        return n
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:          # not on Linux
        return max(1, os.cpu_count() or 1)


def concurrently(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(item) for item in items]``, the calls spread over :func:`workers` threads."""
    items = list(items)
    n = min(workers(), len(items))
    if n <= 1:
        return [fn(item) for item in items]
    with ThreadPoolExecutor(max_workers=n) as pool:
        return list(pool.map(fn, items))
