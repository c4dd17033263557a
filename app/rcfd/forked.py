"""Independent pieces of an rCFD command spread over forked processes, one per core: the jumps a run's paths take
(matching.GrainMatcher.prefetch) and the paths' transport (engine.Engine.transport_paths).

A forked worker inherits the parent's arrays (a million-grain database is shared, not copied) and returns its
result by pickling. Each piece is seeded by its own key, so the results equal those computed one by one. One
process where fork is missing or Taichi is loaded (`fbed rcfd validate` runs the full runs in the same process:
Taichi's threads are not forked)."""
from __future__ import annotations

import multiprocessing
import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed

_TARGET = None  # the object a worker calls a method of (inherited through the fork)


def cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def can_fork() -> bool:
    return "taichi" not in sys.modules and "fork" in multiprocessing.get_all_start_methods()


def _call(method: str, args: tuple):
    return getattr(_TARGET, method)(*args)


def forked(target, method: str, items: list, workers: int):
    """Yield (index, target.method(*items[index])) as each finishes, in ``workers`` forked processes."""
    global _TARGET
    _TARGET = target
    try:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as pool:
            futures = {pool.submit(_call, method, tuple(item)): k for k, item in enumerate(items)}
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
    finally:
        _TARGET = None
