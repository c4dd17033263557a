"""The pressure solver's coarsest level, solved on one thread inside a kernel (the last launch down of a V-cycle,
:func:`app.sim.gas.vcycle.k_down_coarse`, or :func:`k_coarse`): exactly by a tridiagonal sweep when the level is
one line of cells along a non-periodic axis and the system is not singular, else by Jacobi-preconditioned CG.
(A coarsest level too large for one thread is smoothed in parallel instead: ``vcycle.k_coarse_smooth``.)"""
import taichi as ti

from ..launch import kernel
from .multigrid import L_CO, L_NCELL, Multigrid, decode, dims, face, face_offsets, on, stencil


@ti.func
def _line_solve(mg: ti.template(), l, a):
    """The coarsest level l as one line of cells along axis a (``coarse_axis``): its matrix is tridiagonal
    (-T below, the diagonal, -T above; the faces across the other axes and the ends are Dirichlet faces with
    zero outside values, or closed), so one forward and one backward sweep (Thomas) solve it exactly: 2n cell
    visits where the CG took up to n iterations of 3n, a sequence one thread runs (on a GPU the coarsest solve is
    latency, not arithmetic). Inactive cells (diagonal 0) get x = 0. cg_p holds the reduced upper coefficients,
    cg_ap the reduced right-hand side. Returns 0, or 1 where a pivot was not positive (a line with a part that
    touches no Dirichlet face: singular), for the caller to solve by CG instead."""
    nc = mg.lev[l, L_NCELL]
    co = mg.lev[l, L_CO]
    e = ti.Vector([ti.cast(a == 0, ti.i32), ti.cast(a == 1, ti.i32), ti.cast(a == 2, ti.i32)])  # the line's axis
    bad = 0
    up_prev = 0.0  # the reduced upper coefficient of the cell below
    rhs_prev = 0.0
    for c in range(nc):
        dg = mg.diag[co + c]
        below = 0.0
        if c > 0:
            below = mg.trans[face(mg, l, a, c * e)]
        above = 0.0
        if c < nc - 1:
            above = mg.trans[face(mg, l, a, (c + 1) * e)]
        up = 0.0
        r = 0.0
        if dg > 0.0:
            piv = dg + below * up_prev  # the row less (-below) x the reduced row of the cell below
            if piv > 1e-12 * dg:
                up = -above / piv
                r = (mg.bs[co + c] + below * rhs_prev) / piv
            else:
                bad = 1
        mg.cg_p[c] = up
        mg.cg_ap[c] = r
        up_prev = up
        rhs_prev = r
    x_next = 0.0
    for q in range(nc):
        c = nc - 1 - q
        x = mg.cg_ap[c] - mg.cg_p[c] * x_next
        mg.xs[co + c] = x
        x_next = x
    return bad


@ti.func
def coarse_solve(mg: ti.template(), l, singular, act):
    """The (tiny) coarsest level l, by one thread (none once the solve has stopped or with act = 0): a line of
    cells of a non-singular system exactly by :func:`_line_solve`, anything else (or a line the sweep finds
    singular) by Jacobi-PCG."""
    for _t in range(on(mg) * act):
        use_cg = 1
        if mg.coarse_axis >= 0 and not singular:
            use_cg = _line_solve(mg, l, mg.coarse_axis)
        n = dims(mg, l)
        fo = face_offsets(mg, l)
        nc = mg.lev[l, L_NCELL] * use_cg
        co = mg.lev[l, L_CO]
        mean = 0.0
        if singular:
            cnt = 0.0
            for c in range(nc):
                if mg.diag[co + c] > 0.0:
                    mean += mg.bs[co + c]
                    cnt += 1.0
            if cnt > 0.0:
                mean /= cnt
        rz = 0.0
        for c in range(nc):
            r = 0.0
            z = 0.0
            if mg.diag[co + c] > 0.0:
                r = mg.bs[co + c] - mean
                z = r / mg.diag[co + c]
            mg.rs[co + c] = r
            mg.xs[co + c] = 0.0
            mg.cg_p[c] = z
            rz += r * z
        for _it in range(mg.coarse_iters * use_cg):
            pap = 0.0
            for c in range(nc):
                ap = 0.0
                if mg.diag[co + c] > 0.0:
                    _, _, ax = stencil(mg, n, fo, mg.cg_p, 0, decode(n, c), c, False)
                    ap = ax
                mg.cg_ap[c] = ap
                pap += ap * mg.cg_p[c]
            if pap > 0.0 and rz > 0.0:
                alpha = rz / pap
                rzn = 0.0
                for c in range(nc):
                    mg.xs[co + c] += alpha * mg.cg_p[c]
                    mg.rs[co + c] -= alpha * mg.cg_ap[c]
                    if mg.diag[co + c] > 0.0:
                        rzn += mg.rs[co + c] * mg.rs[co + c] / mg.diag[co + c]
                beta = rzn / rz
                for c in range(nc):
                    z = 0.0
                    if mg.diag[co + c] > 0.0:
                        z = mg.rs[co + c] / mg.diag[co + c]
                    mg.cg_p[c] = z + beta * mg.cg_p[c]
                rz = rzn


@kernel
def k_coarse(mg: Multigrid, l: ti.i32, singular: ti.i32):
    coarse_solve(mg, l, singular, 1)
