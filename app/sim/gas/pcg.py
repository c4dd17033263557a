"""Multigrid-preconditioned conjugate gradients for the variable-coefficient pressure equation.

Owns: :class:`MGPCG`, a solver for the symmetric cell-centred system

    (A x)_c = sum over the six faces f of c of  T_f (x_c - x_nb(f))  =  b_c

on a uniform (nx, ny, nz) grid, where ``T_f >= 0`` is a face *transmissibility* given by
the caller (for the gas pressure: aperture * eps_f * kappa_f / h^2). A face on the domain
boundary with ``T_f > 0`` is a Dirichlet face whose outside value ``x_nb`` is the
Dirichlet value of that domain face; ``T_f = 0`` there means no flux (Neumann). Along a
periodic axis the first and last faces are the same face (the caller gives both the same
``T``) and join the last and first cells. Cells whose faces all have ``T = 0`` are
inactive: they keep ``x = 0`` and are left out of every norm.

Method
------
* Outer iteration: flexible (Polak-Ribiere) preconditioned CG, which tolerates the slightly
  non-linear preconditioner below. Stops when ``max|r| <= tol * scale`` for the true
  residual r = b - A x (recomputed when the recursive one gets there: in float32 they drift
  apart); when the true residual stops halving between such checks the solve returns
  unconverged (precision floor: a caller can solve again for the remaining residual) (``scale`` defaults
  to ``max|b|``; the gas solver passes the gross face-flux scale so that ``tol`` bounds the
  divergence relative to the through-flow). With no Dirichlet face the matrix is singular:
  the right-hand side and every preconditioned residual are projected onto zero mean
  (over active cells) and the solution is returned with zero mean.
* Preconditioner (:mod:`.multigrid`): one geometric-multigrid V-cycle. Coarsening halves every
  axis whose length is even and whose spacing is not already coarser than 1.5x the finest coupled
  axis (semi-coarsening keeps coarse cells near-cubic, e.g. 32x32x116 -> 16x16x58 ->
  8x8x29 -> 4x4x29); when no axis qualifies but the grid is still larger than
  ``min_coarse_cells``, any even axis is halved (-> 2x2x29 -> 1x1x29). Coarse
  transmissibility = (sum of the fine faces a coarse face covers) / (coarsening ratio
  normal to it), i.e. the arithmetic mean of the fine coefficients rediscretised at the
  coarse spacing. Transfer is piecewise constant (restriction sums the children,
  prolongation injects). Smoother: red-black Gauss-Seidel, two sweeps red->black going down
  and two black->red coming up (a symmetric cycle); levels with an odd periodic length,
  where red-black colouring is inconsistent, use damped Jacobi (weight 0.8).
* Coarsest level: when it is one line of cells along a non-periodic axis (the usual end of
  semi-coarsening, e.g. 1x1x29) and the system is not singular, a tridiagonal (Thomas) sweep
  solves it exactly in 2n cell visits; otherwise Jacobi-preconditioned CG, a fixed number of
  iterations (the number of cells when that is small, so tiny coarse grids are solved exactly).
  Either runs on one thread inside one kernel (the coarsest grid has tens of cells; on a GPU
  that thread's chain of memory reads is the cost, n^2 for the CG against 2n for the sweep).
  When the dimensions do not halve far enough (coarsest grid > 512 cells, e.g. 33^3) it gets 4
  parallel symmetric red-black double sweeps instead: still a valid preconditioner, but the outer
  iteration count then grows with the grid; choose dimensions with factors of 2.

Implementation: the state is two bundles of ndarrays, :data:`app.sim.gas.multigrid.Multigrid`
(the hierarchy and the solve's control) and :data:`Krylov` (the level-0 vectors), so every
kernel compiles once per process whatever the grid. Every loop over cells is the outermost loop
of its kernel, so it runs in parallel on CPU and CUDA (in the serial form, one CPU thread, all of a kernel's
loops are nested in one serial loop: one task a launch). The iteration's control (convergence, the
true-residual check, stagnation, max_iter) runs on the device: the host launches a batch of
iterations without waiting, each of which does nothing once the solve has stopped, and reads
one record per batch (:meth:`MGPCG.solve`; the gas solver reads it with its own step record).
"""
import dataclasses

import taichi as ti

from ..launch import kernel, narrowed
from . import multigrid as mgm
from .multigrid import (S_ACTIVE, S_BNORM, S_CNT, S_CONV, S_DONE, S_FIRST, S_IT, S_LAST, S_PAP, S_R0, S_RINF,
                        S_RZ, S_RZN, S_RZO, S_SCALE, S_SUM, S_THR, S_TRUE, Multigrid, decode, on, plan_levels, stencil)
from ..tasks import one_task

__all__ = ["SolveInfo", "Krylov", "plan_levels", "solve_record"]  # the solver object: app.sim.gas.linsolve.MGPCG

ND1 = mgm.ND1
#: level-0 vectors of the outer CG: sol the solution (and initial guess), res the residual, prec /
#: prec_old the preconditioned residual and its last value, dirn the search direction, a_dirn = A dirn,
#: rhs the right-hand side
Krylov = ti.types.argpack(sol=ND1, res=ND1, prec=ND1, prec_old=ND1, dirn=ND1, a_dirn=ND1, rhs=ND1)


@dataclasses.dataclass(frozen=True)
class SolveInfo:
    """Outcome of one solve: outer iterations, final ``max|r| / scale``, whether it reached tol."""

    iterations: int
    residual: float
    converged: bool
    scale: float
    initial_residual: float


# ============================================================================ kernels
# Every reduction below (max|r|, the dot products, the active sums) accumulates in a kernel-scope variable that
# is stored once: Taichi 1.7.4 reduces such a variable per thread (then per warp on CUDA), where an atomic into
# an element of ``ctrl`` is one atomic per cell on one address (see app/sim/gas/layout.py, face_max_into).
@ti.func
def _true_residual_cell(mg: ti.template(), ks: ti.template(), n, fo, I, c):
    """r = b - A x at cell c into res and bs; returns |r| (0 at an inactive cell, whose x is zeroed)."""
    r = 0.0
    if mg.diag[c] > 0.0:
        _, _, ax = stencil(mg, n, fo, ks.sol, 0, I, c, True)
        r = ks.rhs[c] - ax
    else:
        ks.sol[c] = 0.0
    ks.res[c] = r
    mg.bs[c] = r
    return ti.abs(r)


@ti.func
def _true_residual(mg: ti.template(), ks: ti.template(), nc, serial: ti.template()):
    """r = b - A x (affine, with the Dirichlet values) over the first nc cells (nc = 0: nothing, else all of
    level 0); max|r| into S_TRUE. It also feeds the next V-cycle (bs). ``serial``: nested loops over i, j, k."""
    n = mgm.dims(mg, 0)
    fo = mgm.face_offsets(mg, 0)
    rmax = 0.0
    _true_residual_into(rmax, mg, ks, nc, n, fo, serial)
    mg.ctrl[S_TRUE] = rmax


@ti.func
def _true_residual_into(rmax: ti.template(), mg: ti.template(), ks: ti.template(), nc: ti.template(), n: ti.template(),
                        fo: ti.template(), serial: ti.template()):
    """:func:`_true_residual`'s loop, its level-0 dims n and face offsets fo and its maximum ``rmax`` (by reference)
    the caller's: set at a kernel's head, they leave no statement between this loop and the one before."""
    if ti.static(serial):
        for i in range(n[0] * ti.cast(nc > 0, ti.i32)):
            for j in range(n[1]):
                cij = (i * n[1] + j) * n[2]
                for k in range(n[2]):
                    ti.atomic_max(rmax, _true_residual_cell(mg, ks, n, fo, ti.Vector([i, j, k]), cij + k))
    else:
        for c in range(nc):
            ti.atomic_max(rmax, _true_residual_cell(mg, ks, n, fo, decode(n, c), c))


@ti.func
def _active_sum_into(total: ti.template(), cnt: ti.template(), mg: ti.template(), values: ti.template(),
                     nc: ti.template()):
    """Sum of values over the active cells (diag > 0) among the first nc cells into ``total``, their count into
    ``cnt`` (the caller's accumulators, by reference; nc = 0: both stay zero): the mean a singular system's
    solution and right-hand side lose."""
    for c in range(nc):
        if mg.diag[c] > 0.0:
            total += values[c]
            cnt += 1.0


#: the members the solve's first and last kernels read and write
BeginMultigrid = narrowed(Multigrid, "lev", "trans", "diag", "bs", "dirichlet", "ctrl", "periodic", "ncell0")
BeginKrylov = narrowed(Krylov, "sol", "res", "rhs")
FinishMultigrid = narrowed(Multigrid, "diag", "ctrl", "ncell0")
FinishKrylov = narrowed(Krylov, "sol")


@kernel
def k_pcg_begin(mg: BeginMultigrid, ks: BeginKrylov, singular: ti.i32, tol: float, scale_mode: ti.i32, scale: float,
                serial: ti.template()):
    """Project b (singular case), measure max|b|, r = b - A x; the stopping threshold tol * scale with
    scale = max|b| (scale_mode 0), the argument (1) or mg.ctrl[S_SCALE] as a caller's kernel left it (2);
    the solve is active unless r already meets it."""
    one_task(serial, _pcg_begin, (mg, ks, singular, tol, scale_mode, scale, serial))


@ti.func
def _pcg_begin(mg: ti.template(), ks: ti.template(), singular, tol, scale_mode, scale, serial: ti.template()):
    # the counts and accumulators first, the three loops back to back (each reads the sums where they were reduced),
    # then the scalars: in the parallel form 5 tasks, not 7
    nc = mg.ncell0
    nsing = nc * singular
    n = mgm.dims(mg, 0)
    fo = mgm.face_offsets(mg, 0)
    total = 0.0
    cnt = 0.0
    bmax = 0.0
    rmax = 0.0
    _active_sum_into(total, cnt, mg, ks.rhs, nsing)
    for c in range(nc):
        if mg.diag[c] > 0.0:
            if singular and cnt > 0.0:
                ks.rhs[c] -= total / cnt
            ti.atomic_max(bmax, ti.abs(ks.rhs[c]))
    _true_residual_into(rmax, mg, ks, nc, n, fo, serial)
    mg.ctrl[S_SUM] = total
    mg.ctrl[S_CNT] = cnt
    mg.ctrl[S_BNORM] = bmax
    mg.ctrl[S_TRUE] = rmax
    if scale_mode == 0:
        mg.ctrl[S_SCALE] = mg.ctrl[S_BNORM]
    elif scale_mode == 1:
        mg.ctrl[S_SCALE] = scale
    mg.ctrl[S_THR] = tol * mg.ctrl[S_SCALE]
    mg.ctrl[S_R0] = mg.ctrl[S_TRUE]
    mg.ctrl[S_RINF] = mg.ctrl[S_TRUE]
    mg.ctrl[S_IT] = 0.0
    mg.ctrl[S_LAST] = -1.0
    mg.ctrl[S_FIRST] = 1.0
    mg.ctrl[S_DONE] = 0.0
    conv = mg.ctrl[S_TRUE] <= mg.ctrl[S_THR]
    mg.ctrl[S_CONV] = ti.select(conv, 1.0, 0.0)
    mg.ctrl[S_ACTIVE] = ti.select(conv, 0.0, 1.0)


@kernel
def k_pcg_from(mg: Multigrid, ks: Krylov, singular: ti.i32, serial: ti.template()):
    one_task(serial, pcg_from, (mg, ks, singular))


@ti.func
def pcg_from(mg: ti.template(), ks: ti.template(), singular):
    """z = V-cycle output (zero mean if singular); new search direction (flexible CG; a restart
    when S_FIRST is set). Nothing once the solve has stopped. Also the tail of
    :func:`app.sim.gas.vcycle.k_up_from`."""
    nc, nsing, total, cnt, rzn, rzo = pcg_from_head(mg, singular)
    pcg_from_loops(mg, ks, singular, nc, nsing, total, cnt, rzn, rzo)


@ti.func
def pcg_from_head(mg: ti.template(), singular):
    """:func:`pcg_from_loops`' counts, nc cells (0 once the solve has stopped) and nsing for the singular mean, and
    its four accumulators, zero."""
    nc = mg.ncell0 * on(mg)
    return nc, nc * singular, 0.0, 0.0, 0.0, 0.0


@ti.func
def pcg_from_loops(mg: ti.template(), ks: ti.template(), singular: ti.template(), nc: ti.template(),
                   nsing: ti.template(), total: ti.template(), cnt: ti.template(), rzn: ti.template(),
                   rzo: ti.template()):
    """The loops of :func:`pcg_from`, its counts (nc cells, nsing = nc or 0 for the mean) and accumulators
    (zero) set by the caller and passed by reference: a kernel whose loops come before sets them at its head,
    so that in the parallel form no serial task separates its loops from these (``passes.level_pair``)."""
    _active_sum_into(total, cnt, mg, mg.xs, nsing)  # the mean a singular system's z loses
    for c in range(nc):
        m = 0.0
        if singular and cnt > 0.0:
            m = total / cnt
        z = 0.0
        if mg.diag[c] > 0.0:
            z = mg.xs[c] - m
        zo = ks.prec[c]
        ks.prec_old[c] = zo
        ks.prec[c] = z
        r = ks.res[c]
        rzn += r * z
        rzo += r * zo
    for c in range(nc):  # the sums read where they were reduced: no one-thread task to store them between the loops
        beta = 0.0
        if mg.ctrl[S_FIRST] == 0.0 and mg.ctrl[S_RZ] != 0.0:
            beta = (rzn - rzo) / mg.ctrl[S_RZ]
        ks.dirn[c] = ks.prec[c] + beta * ks.dirn[c]
    mg.ctrl[S_SUM] = total
    mg.ctrl[S_CNT] = cnt
    mg.ctrl[S_RZN] = rzn
    mg.ctrl[S_RZO] = rzo
    if nc > 0:
        mg.ctrl[S_RZ] = rzn


@kernel
def k_pcg_iter(mg: Multigrid, ks: Krylov, max_iter: ti.i32, serial: ti.template()):
    one_task(serial, pcg_iter, (mg, ks, max_iter, serial))


@ti.func
def _ap_cell(mg: ti.template(), ks: ti.template(), n, fo, I, c):
    ap = 0.0
    if mg.diag[c] > 0.0:
        _, _, ax = stencil(mg, n, fo, ks.dirn, 0, I, c, False)
        ap = ax
    ks.a_dirn[c] = ap
    return ap * ks.dirn[c]


@ti.func
def pcg_iter(mg: ti.template(), ks: ti.template(), max_iter, serial: ti.template()):
    """One outer iteration, decided on the device: x += alpha p, r -= alpha A p; when the recursive
    residual meets the threshold, the true residual b - A x is measured: converged if it meets it
    too, stagnated (stop, the caller may refine) if it did not halve since the last such check,
    else a restart from it. Stops at max_iter. Nothing once the solve has stopped. Also the head of
    :func:`app.sim.gas.vcycle.k_iter_down`."""
    n = mgm.dims(mg, 0)
    fo = mgm.face_offsets(mg, 0)
    nc = mg.ncell0 * on(mg)
    pap = 0.0
    rmax = 0.0  # the accumulators ahead of the loops, which run back to back (parallel form: no serial task between)
    rtrue = 0.0
    if ti.static(serial):  # nested loops over i, j, k: no index decoding by division
        for i in range(n[0] * on(mg)):
            for j in range(n[1]):
                cij = (i * n[1] + j) * n[2]
                for k in range(n[2]):
                    pap += _ap_cell(mg, ks, n, fo, ti.Vector([i, j, k]), cij + k)
    else:
        for c in range(nc):
            pap += _ap_cell(mg, ks, n, fo, decode(n, c), c)
    for c in range(nc):
        alpha = 0.0
        if pap > 0.0:
            alpha = mg.ctrl[S_RZ] / pap
        ks.sol[c] += alpha * ks.dirn[c]
        r = ks.res[c] - alpha * ks.a_dirn[c]
        ks.res[c] = r
        mg.bs[c] = r
        if mg.diag[c] > 0.0:
            ti.atomic_max(rmax, ti.abs(r))
    if ti.static(not serial):
        # the recursively updated residual drifts from b - A x in float32: where it meets the threshold (each
        # thread tests it: no one-thread task between the loops), the true one is measured
        for c in range(nc):
            if rmax <= mg.ctrl[S_THR]:
                ti.atomic_max(rtrue, _true_residual_cell(mg, ks, n, fo, decode(n, c), c))
    mg.ctrl[S_PAP] = pap
    mg.ctrl[S_TRUE] = rmax
    cand = 0
    if nc > 0:
        mg.ctrl[S_IT] += 1.0
        mg.ctrl[S_RINF] = mg.ctrl[S_TRUE]
        mg.ctrl[S_FIRST] = 0.0
        if mg.ctrl[S_RINF] <= mg.ctrl[S_THR]:
            cand = 1
    if ti.static(serial):
        _true_residual(mg, ks, mg.ncell0 * cand, serial)
    else:
        mg.ctrl[S_TRUE] = rtrue  # what _true_residual stores: 0 where not measured
    if cand == 1:
        t = mg.ctrl[S_TRUE]
        mg.ctrl[S_RINF] = t
        if t <= mg.ctrl[S_THR]:
            mg.ctrl[S_CONV] = 1.0
            mg.ctrl[S_ACTIVE] = 0.0
        elif mg.ctrl[S_LAST] >= 0.0 and t > 0.5 * mg.ctrl[S_LAST]:
            mg.ctrl[S_ACTIVE] = 0.0  # stagnated at the precision floor: let the caller refine
        else:
            mg.ctrl[S_LAST] = t
            mg.ctrl[S_FIRST] = 1.0
    if nc > 0 and mg.ctrl[S_IT] >= ti.cast(max_iter, float):
        mg.ctrl[S_ACTIVE] = 0.0


@kernel
def k_pcg_finish(mg: FinishMultigrid, ks: FinishKrylov, singular: ti.i32, serial: ti.template()):
    """Once the solve has stopped (and only once): the zero-mean solution of a singular system."""
    one_task(serial, _pcg_finish, (mg, ks, singular))


@ti.func
def _pcg_finish(mg: ti.template(), ks: ti.template(), singular):
    # as _pcg_begin: counts and sums first, the two loops back to back, the scalars last (4 tasks, not 5)
    fin = ti.cast(mg.ctrl[S_ACTIVE] == 0.0, ti.i32) * ti.cast(mg.ctrl[S_DONE] == 0.0, ti.i32)
    nc = mg.ncell0 * fin * singular
    total = 0.0
    cnt = 0.0
    _active_sum_into(total, cnt, mg, ks.sol, nc)
    for c in range(nc):
        m = 0.0
        if cnt > 0.0:
            m = total / cnt
        if mg.diag[c] > 0.0:
            ks.sol[c] -= m
    mg.ctrl[S_SUM] = total
    mg.ctrl[S_CNT] = cnt
    if fin == 1:
        mg.ctrl[S_DONE] = 1.0


@ti.func
def solve_record(mg: ti.template()):
    """(iterations, max|r|, converged, scale, initial max|r|, done) of the current solve."""
    return ti.Vector([mg.ctrl[S_IT], mg.ctrl[S_RINF], mg.ctrl[S_CONV], mg.ctrl[S_SCALE], mg.ctrl[S_R0],
                      mg.ctrl[S_DONE]])


@kernel
def k_record(mg: Multigrid) -> ti.types.vector(6, ti.f64):
    return solve_record(mg)


# ---- host <-> level-0 transfer (used by tests and by callers without their own kernels)
@kernel
def k_set_faces(mg: Multigrid, a: ti.i32, src: ti.types.ndarray()):
    # loop bounds built without a dynamic-index store (Taichi 1.7.4 gets ndrange bounds wrong
    # after ``d[a] += 1`` with a runtime a)
    n = mgm.dims(mg, 0)
    for i, j, k in ti.ndrange(n[0] + (a == 0), n[1] + (a == 1), n[2] + (a == 2)):
        mg.trans[mgm.face(mg, 0, a, ti.Vector([i, j, k]))] = ti.cast(src[i, j, k], float)  # (the run's precision)


@kernel
def k_get_faces(mg: Multigrid, a: ti.i32, dst: ti.types.ndarray()):
    n = mgm.dims(mg, 0)
    for i, j, k in ti.ndrange(n[0] + (a == 0), n[1] + (a == 1), n[2] + (a == 2)):
        dst[i, j, k] = mg.trans[mgm.face(mg, 0, a, ti.Vector([i, j, k]))]


@kernel
def k_cells_in(v: ti.types.ndarray(), src: ti.types.ndarray()):
    for i, j, k in src:
        v[(i * src.shape[1] + j) * src.shape[2] + k] = ti.cast(src[i, j, k], float)


@kernel
def k_cells_out(v: ti.types.ndarray(), dst: ti.types.ndarray()):
    for i, j, k in dst:
        dst[i, j, k] = v[(i * dst.shape[1] + j) * dst.shape[2] + k]
