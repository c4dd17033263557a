"""One cell of each pass of a red-black multigrid level, and a level's constants: the parallel form's loops
(:mod:`.vcycle`) and the coarse levels' one-launch cycle (:mod:`.coarse_cycle`) run the same arithmetic through
these; the serial form's nested loops call :func:`red_cell` and :func:`gs_cell`."""
import taichi as ti

from .multigrid import L_CO, L_NCELL, _ratio, decode, dims, face_offsets, local, stencil, stencil_lifted


@ti.func
def red_cell(mg: ti.template(), co, c, red):
    x = 0.0
    dg = mg.diag[co + c]
    if red and dg > 0.0:
        x = mg.bs[co + c] / dg
    mg.xs[co + c] = x


@ti.func
def gs_cell(mg: ti.template(), n, fo, co, I, c):
    if mg.diag[co + c] > 0.0:
        d, s, _ = stencil(mg, n, fo, mg.xs, co, I, c, False)
        mg.xs[co + c] = (mg.bs[co + c] + s) / d


@ti.func
def level(mg: ti.template(), l, act):
    """(dims, face offsets, cell offset, cells x act) of level l."""
    return dims(mg, l), face_offsets(mg, l), mg.lev[l, L_CO], mg.lev[l, L_NCELL] * act


@ti.func
def sweep_range(n, act):
    """(h2, nq) of a colour sweep on a level of dims n: half a column's cells rounded up, and the loop's count
    (x act) over (column, every other k)."""
    h2 = (n[2] + 1) // 2
    return h2, n[0] * n[1] * h2 * act


@ti.func
def level_pair(mg: ti.template(), l, act):
    """Every constant a red-black level's launch down or up (``vcycle._down``, ``vcycle._up``) uses: level l's
    (dims, face offsets, cell offset, cells x act, :func:`sweep_range`), its coarsening ratio, and level l+1's
    (dims, cell offset, cells x act)."""
    n, fo, co, nc = level(mg, l, act)
    h2, nq = sweep_range(n, act)
    N, _, cb, NC = level(mg, l + 1, act)
    return n, fo, co, nc, h2, nq, _ratio(mg, l), N, cb, NC


# One cell (or coarse cell, or colour-sweep index) of each pass
@ti.func
def first_red_at(c, mg: ti.template(), n: ti.template(), co: ti.template()):
    """Cell c of the level (dims n, cell offset co): x = 0, then x = b / diag if red (``vcycle._first_red``)."""
    I = decode(n, c)
    red_cell(mg, co, c, (I[0] + I[1] + I[2]) % 2 == 0)


@ti.func
def _colour_cell(n, h2, colour, q):
    """Cell I of index q of a sweep of one colour: column q // h2, the (q % h2)-th cell of that colour up it
    (I[2] >= n[2]: none, at the top of a column of odd height)."""
    ij = q // h2
    I = ti.Vector([ij // n[1], ij % n[1], 0])
    I[2] = 2 * (q % h2) + (I[0] + I[1] + colour) % 2
    return I


@ti.func
def colour_at(q, mg: ti.template(), n: ti.template(), fo: ti.template(), co: ti.template(), h2: ti.template(),
              colour: ti.template()):
    """Index q of a Gauss-Seidel sweep of one colour."""
    I = _colour_cell(n, h2, colour, q)
    if I[2] < n[2]:
        gs_cell(mg, n, fo, co, I, local(n, I))


@ti.func
def prolong_black_at(q, mg: ti.template(), n: ti.template(), fo: ti.template(), co: ti.template(),
                     h2: ti.template(), r: ti.template(), N: ti.template(), cb: ti.template()):
    """Index q of the first sweep up (black) with the prolongation in it: a black cell's update reads only its
    red neighbours, each as the prolongation would have left it (x + x of its coarse cell,
    ``multigrid.stencil_lifted``), and overwrites its own x, so the prolongation pass (every cell) and this sweep
    are one pass; the red cells, not written, are overwritten by the red sweep that follows. The same sums as the
    two passes, so the same values."""
    I = _colour_cell(n, h2, 1, q)
    if I[2] < n[2]:
        c = local(n, I)
        if mg.diag[co + c] > 0.0:
            d, s, _ = stencil_lifted(mg, n, fo, mg.xs, co, I, c, False, (r, N, cb))
            mg.xs[co + c] = (mg.bs[co + c] + s) / d


@ti.func
def restrict_at(C, mg: ti.template(), n: ti.template(), fo: ti.template(), co: ti.template(), r: ti.template(),
                N: ti.template(), cb: ti.template()):
    """Coarse cell C (level dims N, offset cb): b = the sum of its fine cells' residuals b - A x."""
    K = decode(N, C)
    s = 0.0
    for d in range(8):
        o = ti.Vector([d & 1, (d >> 1) & 1, (d >> 2) & 1])
        if o[0] < r[0] and o[1] < r[1] and o[2] < r[2]:
            I = K * r + o
            c = local(n, I)
            if mg.diag[co + c] > 0.0:
                _, _, ax = stencil(mg, n, fo, mg.xs, co, I, c, False)
                s += mg.bs[co + c] - ax
    mg.bs[cb + C] = s


@ti.func
def prolong_at(c, mg: ti.template(), n: ti.template(), co: ti.template(), r: ti.template(), N: ti.template(),
               cb: ti.template()):
    """Fine cell c: x += x of the coarse cell it lies in."""
    if mg.diag[co + c] > 0.0:
        K = decode(n, c) // r
        mg.xs[co + c] += mg.xs[cb + local(N, K)]
