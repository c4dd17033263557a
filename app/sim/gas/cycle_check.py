"""The one-launch coarse cycle checked on the device before a pressure solver takes it.

On CUDA, :mod:`.coarse_cycle` runs the small levels of the V-cycle and of the multigrid set-up as one block of
threads meeting at barriers (``ti.simt.block.sync``), a path no CPU runs. So once per process, before the gas solver's
:class:`~app.sim.gas.linsolve.MGPCG` takes it (:func:`coarse_block`), :func:`works` solves one pressure system both ways (the cycle, and a
launch down and up per level) and compares them: the same outer iterations, the same solution and the same hierarchy
(every level's transmissibilities and diagonal), to the round-off the two kernels may differ by on CUDA. A device that
fails gets a launch per level (the same results, more launches) and a warning, as the DEM's block scan does
(:func:`app.sim.dem.scan.block_scan_works`). ``benchmarks/coarse_cycle_check.py`` runs :func:`compare` on larger
systems, with timings.
"""
import statistics
import time
import warnings

import numpy as np

from .. import runtime
from . import coarse_cycle
from .linsolve import MGPCG

#: the start-up check's system: a 16 x 16 x 20 box with a Dirichlet top (the cycle from its 8 x 8 x 10 level down,
#: the set-up's one launch from level 0), random transmissibilities
CHECK_SYSTEM = ((16, 16, 20), (False, False, False), False)

_works: dict = {}


def system(shape, periodic, singular, seed: int = 7):
    """Random face transmissibilities (0.1-1.1) of a cell Laplacian on ``shape``, and a right-hand side: walls
    (T = 0) on every face, except a Dirichlet top (z+) unless ``singular``, and wrapped faces along ``periodic``."""
    rng = np.random.default_rng(seed)
    ts = []
    for a in range(3):
        fs = list(shape)
        fs[a] += 1
        t = 0.1 + rng.random(fs)
        sl0, sl1 = [slice(None)] * 3, [slice(None)] * 3
        sl0[a], sl1[a] = 0, -1
        if periodic[a]:
            t[tuple(sl1)] = t[tuple(sl0)]
        elif singular or a != 2:
            t[tuple(sl0)] = 0.0
            t[tuple(sl1)] = 0.0
        else:
            t[tuple(sl0)] = 0.0  # a Dirichlet top only
        ts.append(t)
    b = rng.standard_normal(shape)
    if singular:
        b -= b.mean()
    return ts, b


def tolerances(cuda: bool, precision: str) -> tuple[float, int]:
    """(largest relative difference of the solutions and hierarchies, of the iteration counts) allowed between the
    two ways. The per-cell arithmetic is the same: 0 on the CPU; on CUDA the two kernels may contract a multiply-add
    differently, round-off that can move a stopping test by an iteration. float64 at 1e-6 leaves 1e10 round-offs of
    room, float32 at 1e-3 about 1e4; a cell updated wrongly or missed by a barrier shows as far more, and in the
    iterations."""
    if not cuda:
        return 0.0, 0
    return (1e-6 if precision == "float64" else 1e-3), 1


def compare(shape, periodic, singular, tol: float, repeats: int = 0, mode=None) -> dict:
    """Solve ``system(shape, periodic, singular)`` to ``tol`` with a launch per level and with the one-launch cycle
    (``mode``: its (threads, emulate, barrier), default the device's). Returns the block's first levels
    (``block_from``, ``coarsen_from``; None where the shape has no level the cycle takes), the iterations both ways,
    whether the cycle's solve converged, the largest differences of the solutions (``x_diff``) and hierarchies
    (``h_diff``) relative to the largest value, the cycle's solution ``x``, and with ``repeats`` the median seconds
    per solve both ways (after one warm-up solve)."""
    ts, b = system(shape, periodic, singular)
    out = {}
    for block in (False, True):
        mg = MGPCG(shape, periodic, coarse_block=block)
        if block and mode is not None:
            mg.block_mode = tuple(mode)
        times, info = [], None
        for r in range(repeats + 1):
            mg.set_system(*ts, b=b, x0=0.0)
            runtime.sync()
            t0 = time.perf_counter()
            info = mg.solve(tol, 200, singular=singular)
            runtime.sync()
            if r:
                times.append(time.perf_counter() - t0)
        hier = np.concatenate([mg.mg.trans.to_numpy(), mg.mg.diag.to_numpy()])
        out[block] = (mg, info, mg.solution(), hier, statistics.median(times) if times else None)
    (_, i0, x0, h0, t0), (mg, i1, x1, h1, t1) = out[False], out[True]
    return {"block_from": mg.block_from, "coarsen_from": mg.coarsen_from,
            "iterations": (i0.iterations, i1.iterations), "converged": i1.converged,
            "x_diff": float(np.max(np.abs(x1 - x0)) / max(float(np.max(np.abs(x0))), 1e-300)),
            "h_diff": float(np.max(np.abs(h1 - h0)) / max(float(np.max(np.abs(h0))), 1e-300)),
            "x": x1, "seconds": (t0, t1)}


def passes(result: dict, cuda: bool, precision: str) -> bool:
    """Whether a :func:`compare` result shows the cycle right: it took levels, its solve converged, and its
    iterations, solution and hierarchy are those of a launch per level within :func:`tolerances`."""
    d_x, d_it = tolerances(cuda, precision)
    it0, it1 = result["iterations"]
    return (result["block_from"] is not None and result["coarsen_from"] is not None and result["converged"]
            and abs(it0 - it1) <= d_it and result["x_diff"] <= d_x and result["h_diff"] <= d_x)


def works(mode=None) -> bool:
    """Once per process (and Taichi start): :func:`compare` on :data:`CHECK_SYSTEM`, on the device's cycle (``mode``:
    another (threads, emulate, barrier), for the CPU's tests). False, with a warning, where it fails: the caller then
    launches a level at a time."""
    cur = runtime.current()
    key = (cur, None if mode is None else tuple(mode))
    if key not in _works:
        precision = cur[1] if cur else "float32"
        tol = 1e-8 if precision == "float64" else 1e-5
        ok = passes(compare(*CHECK_SYSTEM, tol, mode=mode), runtime.on_cuda(), precision)
        if not ok:
            warnings.warn("the pressure solver's one-launch coarse cycle failed its start-up check on this device: "
                          "a launch down and up per level is used (the same results, more launches; "
                          "FBED_COARSE_CELLS=0 says so without the check)", RuntimeWarning)
        _works[key] = ok
    return _works[key]


def coarse_block(serial: bool) -> bool | None:
    """The ``coarse_block`` argument of a solver's :class:`~app.sim.gas.linsolve.MGPCG`: False (a launch per level)
    on CUDA where the parallel form would take the cycle and :func:`works` fails; else None (the solver's default:
    the cycle in the parallel form). Elsewhere nothing to check: without CUDA the cycle is one thread."""
    if serial or not runtime.on_cuda() or coarse_cycle.max_cells() == 0:
        return None
    return None if works() else False
