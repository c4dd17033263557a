"""The V-cycle of the pressure solver's multigrid (:mod:`.multigrid` holds the hierarchy): one launch down
and one up per level, the coarsest solve riding on the last launch down.

:func:`k_down` runs a red-black level's pre-smoothing, residual and restriction (:func:`k_down_coarse`, on
the last level, the coarsest level's one-thread solve as well, :mod:`.coarse`), :func:`k_up` its prolongation and
post-smoothing; these two take the :data:`~.multigrid.VCycle` bundle (the members they read, so their
launches cost less host time than with the whole hierarchy). Every loop over cells
is a top-level loop of its kernel, so each runs as its own parallel task (a grid-wide barrier between
tasks); in the serial form (one CPU thread, ``serial`` True) the kernel's loops are nested in one serial loop
and walk i, j, k as nested loops. Levels with an odd periodic length use damped Jacobi (:func:`k_down_j`, :func:`k_up_j`).
Fusing several levels into one kernel (``ti.static`` unrolled, idle levels over zero cells) was tried
and dropped: Taichi 1.7.4's compile time grows faster than the kernel (CPU, 16 x 16 x 32: 8 s for the
whole solver with one level a launch, 21-39 s with two, 198 s with six). In the parallel form the small levels
at the coarse end run instead as one launch with a run-time level loop on one block (:mod:`.coarse_cycle`),
through the per-cell functions the loops here use (:mod:`.passes`).

The arithmetic of the red-black path is the textbook one up to reorganisations that give the same
values: a red sweep from x = 0 is x = b / diag on red cells (their neighbours are black, still 0), so the
zeroing and the first red sweep are one pass; a colour sweep visits only the cells of its colour (half
the loop); the residual of a fine cell is computed where the restriction sums it (each fine cell belongs
to one coarse cell), so the level's residual is not stored.
"""
import taichi as ti

from ..launch import kernel, narrowed
from .pcg import Krylov, pcg_from, pcg_from_head, pcg_from_loops, pcg_iter
from .multigrid import (JACOBI_WEIGHT, L_CO, L_NCELL, POST_SWEEPS, PRE_SWEEPS, Multigrid, VCycle, _ncell, _ratio,
                        decode, dims, face_offsets, on, stencil)
from .passes import (colour_at, first_red_at, gs_cell, level, level_pair, prolong_at, prolong_black_at, red_cell,
                     restrict_at, sweep_range)
from ..tasks import each_chunk, one_task
from .coarse import coarse_solve


@ti.func
def _first_red(mg: ti.template(), l, act, serial: ti.template()):
    """x = 0 on the level, then one red sweep: x = b / diag on active red cells. ``serial``: nested loops over
    i, j, k (inside one serial loop: no index decoding by division), else one parallel loop over cells."""
    n = dims(mg, l)
    co = mg.lev[l, L_CO]
    if ti.static(serial):
        for i in range(n[0] * act):
            for j in range(n[1]):
                cij = (i * n[1] + j) * n[2]
                for k in range(n[2]):
                    red_cell(mg, co, cij + k, (i + j + k) % 2 == 0)
    else:
        nc = mg.lev[l, L_NCELL] * act
        _first_red_loop(mg, n, co, nc)


@ti.func
def _colour_sweep(mg: ti.template(), l, colour, act, serial: ti.template()):
    """Gauss-Seidel update of the cells of one colour (parity of i+j+k), visiting only those (``serial``:
    nested loops over i, j and every other k, no index decoding by division)."""
    n = dims(mg, l)
    fo = face_offsets(mg, l)
    co = mg.lev[l, L_CO]
    if ti.static(serial):
        for i in range(n[0] * act):
            for j in range(n[1]):
                k0 = (i + j + colour) % 2
                cij = (i * n[1] + j) * n[2]
                for kk in range((n[2] - k0 + 1) // 2):
                    k = k0 + 2 * kk
                    gs_cell(mg, n, fo, co, ti.Vector([i, j, k]), cij + k)
    else:
        h2, nq = sweep_range(n, act)
        _colour_loop(mg, n, fo, co, h2, nq, colour)


@ti.func
def _restrict_residual(mg: ti.template(), l, act):
    """b of level l+1 = the sum of the residuals b - A x of the fine cells each coarse cell covers."""
    r = _ratio(mg, l)
    n, fo, co, _ = level(mg, l, act)
    N, _, cb, NC = level(mg, l + 1, act)
    _restrict_loop(mg, n, fo, co, r, N, cb, NC)


@ti.func
def _prolong(mg: ti.template(), l, act, serial: ti.template()):
    """x of level l += x of the coarse cell (level l+1) each fine cell lies in (``serial``: nested loops, the
    coarse index by shifts: every ratio is 1 or 2)."""
    L = l + 1
    r = _ratio(mg, l)
    n = dims(mg, l)
    N = dims(mg, L)
    co = mg.lev[l, L_CO]
    cb = mg.lev[L, L_CO]
    if ti.static(serial):
        sh = r - 1
        for i in range(n[0] * act):
            for j in range(n[1]):
                cij = (i * n[1] + j) * n[2]
                Cij = cb + ((i >> sh[0]) * N[1] + (j >> sh[1])) * N[2]
                for k in range(n[2]):
                    if mg.diag[co + cij + k] > 0.0:
                        mg.xs[co + cij + k] += mg.xs[Cij + (k >> sh[2])]
    else:
        nc = mg.lev[l, L_NCELL] * act
        _prolong_loop(mg, n, co, nc, r, N, cb)


@ti.func
def _residual(mg: ti.template(), l):
    n = dims(mg, l)
    fo = face_offsets(mg, l)
    co = mg.lev[l, L_CO]
    for c in range(_ncell(mg, l)):
        r = 0.0
        if mg.diag[co + c] > 0.0:
            I = decode(n, c)
            _, _, ax = stencil(mg, n, fo, mg.xs, co, I, c, False)
            r = mg.bs[co + c] - ax
        mg.rs[co + c] = r


@ti.func
def _jacobi_sweep(s, mg: ti.template(), l):
    """Sweep s of a damped-Jacobi series (every sweep alike), the body :func:`~..tasks.each_chunk` runs."""
    _residual(mg, l)
    co = mg.lev[l, L_CO]
    for c in range(_ncell(mg, l)):
        dg = mg.diag[co + c]
        if dg > 0.0:
            mg.xs[co + c] += JACOBI_WEIGHT * mg.rs[co + c] / dg


@ti.func
def _zero_x(mg: ti.template(), l):
    co = mg.lev[l, L_CO]
    for c in range(_ncell(mg, l)):
        mg.xs[co + c] = 0.0


@ti.func
def _black_first(s, mg: ti.template(), l, act, serial: ti.template()):
    """Sweep s of a series that starts black (colour 1) and alternates. Through :func:`~..tasks.each_chunk`:
    unrolled in parallel (each sweep its own parallel loops), a run-time loop on one thread, where the
    stencil is compiled once instead of once per sweep."""
    _colour_sweep(mg, l, (s + 1) % 2, act, serial)


# ---------------------------------------------------------------------------- the parallel form's loops
# In the parallel form every top-level loop is a task, and so is every run of statements between two loops (a
# serial task, one thread): the level's constants computed ahead of each loop (and the copies a ti.func makes of
# its value arguments) cost a serial task per loop. The red-black level kernels therefore compute the constants
# of both levels once, at their head, and run their loops back to back through these functions, whose arguments
# are templates (passed by reference: no copy, no statement between the loops). The arithmetic is the serial
# form's and the functions' above, loop for loop.
@ti.func
def _first_red_loop(mg: ti.template(), n: ti.template(), co: ti.template(), nc: ti.template()):
    for c in range(nc):
        first_red_at(c, mg, n, co)


@ti.func
def _colour_loop(mg: ti.template(), n: ti.template(), fo: ti.template(), co: ti.template(), h2: ti.template(),
                 nq: ti.template(), colour: ti.template()):
    for q in range(nq):
        colour_at(q, mg, n, fo, co, h2, colour)


@ti.func
def _restrict_loop(mg: ti.template(), n: ti.template(), fo: ti.template(), co: ti.template(), r: ti.template(),
                   N: ti.template(), cb: ti.template(), NC: ti.template()):
    for C in range(NC):
        restrict_at(C, mg, n, fo, co, r, N, cb)


@ti.func
def _prolong_loop(mg: ti.template(), n: ti.template(), co: ti.template(), nc: ti.template(), r: ti.template(),
                  N: ti.template(), cb: ti.template()):
    for c in range(nc):
        prolong_at(c, mg, n, co, r, N, cb)


@ti.func
def _prolong_black_loop(mg: ti.template(), n: ti.template(), fo: ti.template(), co: ti.template(), h2: ti.template(),
                        nq: ti.template(), r: ti.template(), N: ti.template(), cb: ti.template()):
    for q in range(nq):
        prolong_black_at(q, mg, n, fo, co, h2, r, N, cb)


# ============================================================================ kernels
@ti.func
def _down(mg: ti.template(), l, serial: ti.template()):
    act = on(mg)
    if ti.static(serial):
        _first_red(mg, l, act, serial)
        each_chunk(serial, 2 * PRE_SWEEPS - 1, _black_first, (mg, l, act, serial))  # black, red, black
        _restrict_residual(mg, l, act)
    else:  # the same loops, the constants first (see passes.level_pair)
        n, fo, co, nc, h2, nq, r, N, cb, NC = level_pair(mg, l, act)
        _first_red_loop(mg, n, co, nc)
        for s in ti.static(range(2 * PRE_SWEEPS - 1)):  # black, red, black
            _colour_loop(mg, n, fo, co, h2, nq, (s + 1) % 2)
        _restrict_loop(mg, n, fo, co, r, N, cb, NC)


@kernel
def k_down(vc: VCycle, l: ti.i32, serial: ti.template()):
    """Pre-smoothing, residual and restriction of red-black level l."""
    one_task(serial, _down, (vc, l, serial))


#: the members the outer CG's two fused kernels read (each launched once an iteration: fewer members, less host
#: time a launch; Taichi 1.7.4 sets every member of a pack at every launch)
IterMultigrid = narrowed(Multigrid, "lev", "trans", "diag", "xs", "bs", "dirichlet", "ctrl", "periodic", "ncell0")
IterDownKrylov = narrowed(Krylov, "sol", "res", "dirn", "a_dirn", "rhs")
UpFromKrylov = narrowed(Krylov, "res", "prec", "prec_old", "dirn")


@ti.func
def _iter_down(mg: ti.template(), ks: ti.template(), max_iter, serial: ti.template()):
    pcg_iter(mg, ks, max_iter, serial)
    _down(mg, 0, serial)


@kernel
def k_iter_down(mg: IterMultigrid, ks: IterDownKrylov, max_iter: ti.i32, serial: ti.template()):
    """The outer CG's iteration (:func:`.pcg.pcg_iter`, which leaves its residual in level 0's b),
    then :func:`k_down` of level 0 (red-black, not the last level)."""
    one_task(serial, _iter_down, (mg, ks, max_iter, serial))


@ti.func
def _down_coarse(mg: ti.template(), l, singular, serial: ti.template()):
    _down(mg, l, serial)
    coarse_solve(mg, l + 1, singular, 1)


@kernel
def k_down_coarse(mg: Multigrid, l: ti.i32, singular: ti.i32, serial: ti.template()):
    """:func:`k_down` of the last red-black level l, then the one-thread solve of level l+1 (the coarsest,
    :func:`.coarse.coarse_solve`)."""
    one_task(serial, _down_coarse, (mg, l, singular, serial))


@ti.func
def _up(mg: ti.template(), l, serial: ti.template()):
    act = on(mg)
    if ti.static(serial):
        _prolong(mg, l, act, serial)
        each_chunk(serial, 2 * POST_SWEEPS, _black_first, (mg, l, act, serial))  # black, red, black, red
    else:  # the same loops, the constants first (see passes.level_pair); the prolongation rides on the first sweep
        n, fo, co, nc, h2, nq, r, N, cb, _ = level_pair(mg, l, act)
        _prolong_black_loop(mg, n, fo, co, h2, nq, r, N, cb)
        for s in ti.static(range(1, 2 * POST_SWEEPS)):  # red, black, red
            _colour_loop(mg, n, fo, co, h2, nq, (s + 1) % 2)


@kernel
def k_up(vc: VCycle, l: ti.i32, serial: ti.template()):
    """Prolongation from level l+1 and post-smoothing of red-black level l."""
    one_task(serial, _up, (vc, l, serial))


@ti.func
def _up_from(mg: ti.template(), ks: ti.template(), singular, serial: ti.template()):
    if ti.static(serial):
        _up(mg, 0, serial)
        pcg_from(mg, ks, singular)
    else:  # pcg_from's counts and accumulators at the head, with _up's constants (see passes.level_pair)
        nc, nsing, total, cnt, rzn, rzo = pcg_from_head(mg, singular)
        _up(mg, 0, serial)
        pcg_from_loops(mg, ks, singular, nc, nsing, total, cnt, rzn, rzo)


@kernel
def k_up_from(mg: IterMultigrid, ks: UpFromKrylov, singular: ti.i32, serial: ti.template()):
    """:func:`k_up` of level 0 (red-black), then the outer CG's new direction (:func:`.pcg.pcg_from`)."""
    one_task(serial, _up_from, (mg, ks, singular, serial))


@ti.func
def _down_j(mg: ti.template(), l, serial: ti.template()):
    _zero_x(mg, l)
    each_chunk(serial, PRE_SWEEPS, _jacobi_sweep, (mg, l))
    _restrict_residual(mg, l, on(mg))


@kernel
def k_down_j(mg: Multigrid, l: ti.i32, serial: ti.template()):
    one_task(serial, _down_j, (mg, l, serial))


@ti.func
def _up_j(mg: ti.template(), l, serial: ti.template()):
    _prolong(mg, l, on(mg), serial)
    each_chunk(serial, POST_SWEEPS, _jacobi_sweep, (mg, l))


@kernel
def k_up_j(mg: Multigrid, l: ti.i32, serial: ti.template()):
    one_task(serial, _up_j, (mg, l, serial))



@ti.func
def _coarse_smooth(mg: ti.template(), l, first, serial: ti.template()):
    if first:
        _zero_x(mg, l)
    for s in ti.static((0, 1, 1, 0)):
        _colour_sweep(mg, l, s, on(mg), serial)


@kernel
def k_coarse_smooth(mg: Multigrid, l: ti.i32, first: ti.i32, serial: ti.template()):
    """Large coarsest level (dimensions that do not halve): symmetric red-black sweeps in parallel
    instead of the one-thread CG."""
    one_task(serial, _coarse_smooth, (mg, l, first, serial))
