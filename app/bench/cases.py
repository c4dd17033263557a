"""The accuracy bench's case record: what a verification case declares.

Owns: the :class:`Case` record (a verification case with an exact or published answer, the knobs
that trade its cost against its error, and the acceptable error that defines the knee) and the two
exceptions a measure may raise. The families (one module each: :mod:`.dem_cases`, :mod:`.gas_cases`,
:mod:`.bed_cases`) register their cases in ``CASES``; the runner (:mod:`.accuracy`: the registry,
sweeps, CSV, Pareto plots, the recommended-settings table) collects them.

A case's ``measure(settings, size)`` builds and runs its scene with ``settings`` (every knob of the
case at its default except the one swept) at ``size`` ('small': seconds to a minute on a CPU core;
'full': the sizes quoted in benchmarks/ACCURACY.md, meant for the GPU) and returns at least
``error`` (>= 0, relative unless the case says otherwise) and ``cost`` (in the case's
``cost_label`` unit, e.g. wall seconds of the timed steps after a warm-up, or DEM steps per contact).
Taichi's precision is set by the runner before each measure (``settings['precision']``).
"""
from __future__ import annotations

import dataclasses
from typing import Callable


class Unavailable(Exception):
    """Raised by a measure whose reference data is missing here: the runner skips the case and says why."""


class Interrupted(Exception):
    """Raised by a measure whose run was stopped by a signal (Ctrl-C, or SIGTERM from a time limit): the bench
    writes what it has measured and ends; ``--resume`` continues it. Not a result: the row is not recorded."""


@dataclasses.dataclass(frozen=True)
class Case:
    name: str                   # short id, used by --cases and in file names
    title: str                  # what is measured, against what answer
    error_label: str            # e.g. "relative error of the pressure drop"
    cost_label: str             # e.g. "wall s per simulated s", "DEM steps per contact"
    knobs: dict                 # knob -> tuple of values swept (cheapest last or first, any order)
    defaults: dict              # knob -> the value fbed's presets use (the point the table judges)
    tolerance: float            # acceptable error: the knee is the cheapest value within it
    measure: Callable[[dict, str], dict]
    note: str = ""              # one line for the table: the reference's own uncertainty, caveats

