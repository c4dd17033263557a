"""The multigrid hierarchy of the pressure solver (the preconditioner of :mod:`.pcg`).

Owns: the level plan (:func:`plan_levels`), the :data:`Multigrid` bundle (every level's
transmissibilities, diagonal, smoother vectors, the level table and the solve's control
scalars), the stencil, the diagonal and the coarsening; the V-cycle's kernels are in
:mod:`.vcycle`. The method is described in :mod:`app.sim.gas.pcg`.

Level layout: ``lev[l, L_*]`` gives level l's dims, its cell offset ``L_CO`` into the
per-cell arrays (``diag``, ``xs``, ``bs``, ``rs`` hold every level back to back), the offsets
``L_FOX + a`` of its faces in ``t`` and its coarsening ratio. The kernels take the bundle, so
they compile once per process whatever the grid.
"""
import numpy as np
import taichi as ti

from ..launch import kernel, narrowed
from ..tasks import one_task

NMETA = 16
# per-level slots of lev[l, ...]
L_NX, L_NY, L_NZ, L_CO, L_FOX, L_FOY, L_FOZ, L_RX, L_RY, L_RZ, L_NCELL = range(11)
# the solve's scalars (sc[...]), kept on the device so that the host launches iterations without waiting
S_RZ, S_RZN, S_RZO, S_PAP, S_RINF, S_SUM, S_CNT, S_BNORM = range(8)
# S_ACTIVE 1 while iterating; S_FIRST restart the flexible CG; S_LAST the last true residual, -1 none
# yet; S_DONE 1 once the solution is final (zero mean taken); S_SCALE the residual scale, S_THR = tol * scale
S_ACTIVE, S_IT, S_THR, S_LAST, S_FIRST, S_R0, S_SCALE, S_CONV, S_TRUE, S_DONE = range(8, 18)
NSCAL = 24

PRE_SWEEPS = 2
POST_SWEEPS = 2
COARSE_SERIAL_MAX = 512  # largest coarsest grid solved on one thread (coarse.py: a line sweep or the CG)
COARSE_SMOOTH_SWEEPS = 4  # symmetric red-black double sweeps on a larger coarsest grid
JACOBI_WEIGHT = 0.8

ND1 = ti.types.ndarray(ndim=1)
#: the hierarchy: lev (i32, [levels, NMETA]); trans: the transmissibilities of every level's faces;
#: diag, xs (smoother iterate), bs (level right-hand side), rs (level residual): cells of every level;
#: cg_p, cg_ap the coarsest CG's vectors; dirichlet the six Dirichlet values; ctrl the solve's scalars
#: (S_*); periodic axes; ncell0 cells of level 0; coarse_iters iterations of the coarsest CG; coarse_axis the
#: axis of a coarsest level that is one line of cells along a non-periodic axis (solved exactly by a tridiagonal
#: sweep, :func:`app.sim.gas.coarse.coarse_solve`), -1 otherwise.
#: (Taichi 1.7.4 flattens an argpack's members into kernel arguments by name: member names must differ
#: across the bundles of one kernel and from its local variables.)
Multigrid = ti.types.argpack(lev=ti.types.ndarray(ndim=2), trans=ND1, diag=ND1, xs=ND1, bs=ND1, rs=ND1, cg_p=ND1,
                             cg_ap=ND1, dirichlet=ND1, ctrl=ND1, periodic=ti.types.vector(3, ti.i32),
                             ncell0=ti.i32, coarse_iters=ti.i32, coarse_axis=ti.i32)
#: the members of :data:`Multigrid` a red-black level of the V-cycle reads (the same arrays): launched
#: 2L times a cycle, its launch costs less host time with fewer members (Taichi 1.7.4 sets every
#: member on every launch; CPU: 6 ndarrays and a vector 129 us, the whole Multigrid 190 us, loaded)
VCycle = narrowed(Multigrid, "lev", "trans", "diag", "xs", "bs", "ctrl", "periodic")


def plan_levels(shape, min_coarse_cells=8, max_levels=16):
    """Grid shapes of the multigrid hierarchy and the coarsening ratio of each level (host only)."""
    levels = [dict(shape=tuple(shape), hrel=(1, 1, 1), ratio=(1, 1, 1))]
    while len(levels) < max_levels:
        s, hr = levels[-1]["shape"], levels[-1]["hrel"]
        if int(np.prod(s)) <= min_coarse_cells:
            break
        coupled = [s[a] > 1 for a in range(3)]
        if not any(coupled):
            break
        hmin = min(hr[a] for a in range(3) if coupled[a])
        even = [coupled[a] and s[a] % 2 == 0 for a in range(3)]
        r = tuple(2 if (even[a] and hr[a] <= 1.5 * hmin) else 1 for a in range(3))
        if r == (1, 1, 1):
            r = tuple(2 if even[a] else 1 for a in range(3))
        if r == (1, 1, 1):
            break
        levels[-1]["ratio"] = r
        levels.append(dict(shape=tuple(s[a] // r[a] for a in range(3)), hrel=tuple(hr[a] * r[a] for a in range(3)),
                           ratio=(1, 1, 1)))
    return levels


def line_axis(shape, periodic) -> int:
    """The axis along which a grid of ``shape`` is one line of cells (every other length 1, that one > 1 and not
    periodic: its matrix is tridiagonal), else -1 (host)."""
    long = [a for a in range(3) if shape[a] > 1]
    if len(long) == 1 and not periodic[long[0]]:
        return long[0]
    return -1


def level_table(plan):
    """(lev table, total faces, total cells) of a plan (host)."""
    lev = np.zeros((len(plan), NMETA), np.int32)
    off = co = 0
    for l, lv in enumerate(plan):
        s = lv["shape"]
        lev[l, L_NX:L_NZ + 1] = s
        lev[l, L_RX:L_RZ + 1] = lv["ratio"]
        lev[l, L_NCELL] = int(np.prod(s))
        lev[l, L_CO] = co
        co += int(np.prod(s))
        for a in range(3):
            fs = list(s)
            fs[a] += 1
            lev[l, L_FOX + a] = off
            off += int(np.prod(fs))
    return lev, off, co


# ============================================================================ Taichi functions
@ti.func
def dims(mg: ti.template(), l):
    return ti.Vector([mg.lev[l, L_NX], mg.lev[l, L_NY], mg.lev[l, L_NZ]])


@ti.func
def _ratio(mg: ti.template(), l):
    return ti.Vector([mg.lev[l, L_RX], mg.lev[l, L_RY], mg.lev[l, L_RZ]])


@ti.func
def on(mg: ti.template()):
    """1 while the solve iterates, else 0: every loop of an iteration runs over on * cells, so
    launches after convergence (the host launches a fixed count without waiting) do nothing."""
    return ti.cast(mg.ctrl[S_ACTIVE] > 0.0, ti.i32)


@ti.func
def _ncell(mg: ti.template(), l):
    return mg.lev[l, L_NCELL] * on(mg)


@ti.func
def local(n, I):
    """Local (level-relative) cell index of I in a grid of dims n."""
    return (I[0] * n[1] + I[1]) * n[2] + I[2]


@ti.func
def decode(n, c):
    return ti.Vector([c // (n[1] * n[2]), (c // n[2]) % n[1], c % n[2]])


@ti.func
def face(mg: ti.template(), l, a, I):
    """Index into ``t`` of the face of axis a with (face) index I at level l."""
    d = dims(mg, l)
    d[a] += 1
    return mg.lev[l, L_FOX + a] + (I[0] * d[1] + I[1]) * d[2] + I[2]


@ti.func
def face_offsets(mg: ti.template(), l):
    """Offsets into ``trans`` of level l's x, y and z faces."""
    return ti.Vector([mg.lev[l, L_FOX], mg.lev[l, L_FOX + 1], mg.lev[l, L_FOX + 2]])


@ti.func
def stencil(mg: ti.template(), n, fo, v: ti.template(), vo, I, c, affine: ti.template()):
    """(diag, sum T x_nb, sum T (x_c - x_nb)) at cell I (local index c) of the level of dims n and face
    offsets fo (:func:`dims`, :func:`face_offsets`, taken once per loop by the caller) for the vector
    v[vo + local]. The face and neighbour indices are those of :func:`face` and :func:`local` written
    as offsets from c."""
    return stencil_lifted(mg, n, fo, v, vo, I, c, affine, ())


@ti.func
def stencil_lifted(mg: ti.template(), n, fo, v: ti.template(), vo, I, c, affine: ti.template(), lift: ti.template()):
    """:func:`stencil` (``lift`` = ()); with ``lift`` = (r, N, cb) each neighbour's value is first raised by the value of the coarse
    cell (level dims N, cell offset cb, coarsening ratio r) it lies in, as the prolongation would store it
    (x_nb + x_coarse, the same sum): a red-black sweep reads its neighbours prolonged without their being written."""
    xc = v[vo + c]
    stride = ti.Vector([n[1] * n[2], n[2], 1])
    # faces below cell I: x faces (F0 n1 + I1) n2 + I2 = c (+ n1 n2 above), y faces c + I0 n2 (+ n2),
    # z faces c + I0 n1 + I1 (+ 1)
    fbase = ti.Vector([fo[0] + c, fo[1] + c + I[0] * n[2], fo[2] + c + I[0] * n[1] + I[1]])
    d = 0.0
    s = 0.0
    ax = 0.0
    for a in ti.static(range(3)):
        for side in ti.static(range(2)):
            t = mg.trans[fbase[a] + side * stride[a]]
            if t != 0.0:
                J = I
                J[a] += 2 * side - 1
                xn = 0.0
                inside = 0
                if J[a] >= 0 and J[a] < n[a]:
                    xn = v[vo + c + (2 * side - 1) * stride[a]]
                    inside = 1
                elif mg.periodic[a] == 1:
                    J[a] = (J[a] + n[a]) % n[a]
                    xn = v[vo + local(n, J)]
                    inside = 1
                else:
                    if ti.static(affine):
                        xn = mg.dirichlet[2 * a + side]
                if ti.static(len(lift) == 3):
                    if inside == 1:
                        xn += v[lift[2] + local(lift[1], J // lift[0])]
                d += t
                s += t * xn
                ax += t * (xc - xn)
    return d, s, ax


@ti.func
def level_diag(mg: ti.template(), l):
    n = dims(mg, l)
    co = mg.lev[l, L_CO]
    nc = mg.lev[l, L_NCELL]
    _diag_loop(mg, l, n, co, nc)


#: the members the hierarchy's set-up kernels read (k_coarsen runs once per level each solve)
Hierarchy = narrowed(Multigrid, "lev", "trans", "diag", "periodic")


# ============================================================================ kernels
@kernel
def k_diag(mg: Hierarchy, l: ti.i32, serial: ti.template()):
    one_task(serial, level_diag, (mg, l))


@kernel
def k_coarsen(mg: Hierarchy, l: ti.i32, serial: ti.template()):
    """Transmissibilities and diagonal of level l+1 from level l; of level 0, its diagonal too (the set-up's first
    launch: no launch of :func:`k_diag` of its own)."""
    one_task(serial, _coarsen, (mg, l))


@ti.func
def coarsen_constants(mg: ti.template(), l):
    """Every constant of the coarsening of level l into l+1: (L = l+1, the ratio r, L's dims N, its x, y and z face
    grids and their counts, its cell offset and cells)."""
    L = l + 1
    r = _ratio(mg, l)
    N = dims(mg, L)
    nfx = N + ti.Vector([1, 0, 0])
    nfy = N + ti.Vector([0, 1, 0])
    nfz = N + ti.Vector([0, 0, 1])
    mx = nfx[0] * nfx[1] * nfx[2]
    my = nfy[0] * nfy[1] * nfy[2]
    mz = nfz[0] * nfz[1] * nfz[2]
    return L, r, N, nfx, nfy, nfz, mx, my, mz, mg.lev[L, L_CO], mg.lev[L, L_NCELL]


@ti.func
def _coarsen(mg: ti.template(), l):
    # every constant first, then the five loops back to back (template arguments, nothing copied between them):
    # in the parallel form a statement between two loops is a one-thread task of its own
    L, r, N, nfx, nfy, nfz, mx, my, mz, co, nc = coarsen_constants(mg, l)
    n0 = dims(mg, 0)
    co0 = mg.lev[0, L_CO]
    nc0 = mg.lev[0, L_NCELL] * ti.cast(l == 0, ti.i32)  # level 0's diagonal: in the first launch only
    _diag_loop(mg, 0, n0, co0, nc0)
    _coarsen_faces(mg, l, L, r, N, nfx, mx, 0)
    _coarsen_faces(mg, l, L, r, N, nfy, my, 1)
    _coarsen_faces(mg, l, L, r, N, nfz, mz, 2)
    _diag_loop(mg, L, N, co, nc)


@ti.func
def _coarsen_faces(mg: ti.template(), l: ti.template(), L: ti.template(), r: ti.template(), N: ti.template(),
                   nfa: ti.template(), m: ti.template(), a: ti.template()):
    """Transmissibilities of level L's m faces of axis a (shape nfa) from level l's."""
    for c in range(m):
        coarsen_face_at(c, mg, l, L, r, N, nfa, a)


@ti.func
def coarsen_face_at(c, mg: ti.template(), l: ti.template(), L: ti.template(), r: ti.template(), N: ti.template(),
                    nfa: ti.template(), a: ti.template()):
    """Face c of axis a (face grid nfa) of level L (dims N): the sum of the fine faces of level l (coarsening
    ratio r) it covers, over r[a]."""
    b1 = ti.static((a + 1) % 3)
    b2 = ti.static((a + 2) % 3)
    K = decode(nfa, c)
    s = 0.0
    for d in range(4):
        o1 = d & 1
        o2 = (d >> 1) & 1
        if o1 < r[b1] and o2 < r[b2]:
            F = K * r
            F[b1] += o1
            F[b2] += o2
            s += mg.trans[face(mg, l, a, F)]
    s /= r[a]
    if mg.periodic[a] == 1 and N[a] == 1:
        s = 0.0
    mg.trans[face(mg, L, a, K)] = s


@ti.func
def _diag_loop(mg: ti.template(), l: ti.template(), n: ti.template(), co: ti.template(), nc: ti.template()):
    """:func:`level_diag` with the level's constants given."""
    for c in range(nc):
        diag_at(c, mg, l, n, co)


@ti.func
def diag_at(c, mg: ti.template(), l: ti.template(), n: ti.template(), co: ti.template()):
    """The diagonal of cell c of level l (dims n, cell offset co): the sum of its six faces' transmissibilities."""
    I = decode(n, c)
    d = 0.0
    for a in ti.static(range(3)):
        for side in ti.static(range(2)):
            F = I
            F[a] += side
            d += mg.trans[face(mg, l, a, F)]
    mg.diag[co + c] = d
