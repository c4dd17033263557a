"""The gas solver's bundles (Taichi argpacks of ndarrays) and the index functions over them.

Every kernel of the gas takes named bundles, so its signature says what it reads and writes, and
compiles once per process for any grid (an argpack of ndarrays is specialised on the arrays' types,
not their sizes). Face arrays hold the u, v and w faces back to back (``face_off``), each in C order of
its face shape; the linear solver's cell vectors hold the cells in C order, c = (i*ny + j)*nz + k,
and the cell arrays shared with the coupling are (nx, ny, nz) arrays (vec3 for vectors).

Taichi 1.7.4 flattens an argpack's members into kernel arguments by name: member names differ across
every bundle a kernel takes (and from the local variables of the kernels), and one kernel never takes
two bundles of the same type.
"""
import taichi as ti

from ..launch import kernel, narrowed
from .config import EPS_MIN

ND1 = ti.types.ndarray(ndim=1)
ND3 = ti.types.ndarray(ndim=3)
VEC3I = ti.types.vector(3, ti.i32)
VEC6I = ti.types.vector(6, ti.i32)

#: the constant set-up: dims (nx, ny, nz); wrap: periodic axes; bc_kind: kind of each domain face
#: (x-, x+, y-, y+, z-, z+; config.WALL ...); bcv: the boundary-value blocks of the faces (component-major
#: [comp][t1][t2], offsets bcv_off; moving-wall and inlet velocities, superficial); face_off: offsets of
#: the u, v, w faces; scheme: convection (config.CONVECTION); form: 1 "shared" pressure, 0 "gas";
#: has_walls: vessel walls (cut cells) present; nfaces, ncells; aperture and clear(ance) [m] per face;
#: open_vol: open volume fraction per cell (the ``GasFields.vol_frac`` array); par: the float parameters (P_*)
Grid = ti.types.argpack(dims=VEC3I, wrap=VEC3I, bc_kind=VEC6I, bcv_off=VEC6I, face_off=VEC3I, scheme=ti.i32,
                        form=ti.i32, has_walls=ti.i32, nfaces=ti.i32, ncells=ti.i32, aperture=ND1, clear=ND1,
                        open_vol=ND3, par=ND1, bcv=ND1)
#: the gas's inputs, written by the coupling (cells, (nx, ny, nz)): gas_eps the gas fraction (read
#: clamped to [EPS_MIN, 1]), gas_deps_dt its rate [1/s], drag_beta the drag coefficient [kg m^-3 s^-1],
#: solid_vel the solid velocity [m/s] and ext_force the explicit source [N/m^3] (vec3 arrays)
Inputs = ti.types.argpack(gas_eps=ND3, gas_deps_dt=ND3, drag_beta=ND3, solid_vel=ND3, ext_force=ND3)
#: the gas's outputs as the coupling reads them (cells): gas_p pressure [Pa], gas_u interstitial
#: velocity [m/s] and gas_gradp pressure gradient [Pa/m] at cell centres (the arrays of :data:`Cells`)
Outputs = ti.types.argpack(gas_p=ND3, gas_u=ND3, gas_gradp=ND3)
#: the gas fraction alone, for the kernels that read no other input (Inputs' other arrays are not set at their launches)
EpsInputs = narrowed(Inputs, "gas_eps")
#: the cut-cell geometry as the coupling reads it: open_frac (the open volume fraction), active_cell (i32)
CellGeometry = ti.types.argpack(open_frac=ND3, active_cell=ND3)
#: face state of a step: vel (the velocity), vel_old (at the step's start), vel_adv (advected), vel_tmp,
#: vel_lo, vel_hi (scratch of the advection; the clamps of MacCormack; then vel_tmp and vel_lo hold the
#: viscous predictor's diagonal and fixed right-hand side), accel (last step's weighted
#: acceleration), dpred (last predictor increment), eps_f, beta_f (face gas fraction and drag
#: coefficient), vel_save (the initial velocity while the first step finds a pressure); gsc: the step's
#: scalars (SC_*), read by the host once per step in the record
State = ti.types.argpack(vel=ND1, vel_old=ND1, vel_adv=ND1, vel_tmp=ND1, vel_lo=ND1, vel_hi=ND1, accel=ND1,
                         dpred=ND1, eps_f=ND1, beta_f=ND1, vel_save=ND1, gsc=ND1)
#: cell outputs as the solver writes them (the arrays of :data:`Outputs`, (nx, ny, nz)): pres the pressure
#: [Pa] (the state of the incremental projection), u_cell the cell-centred velocity [m/s] and gradp_cell
#: the pressure gradient [Pa/m] (vec3), div_cell the continuity residual [1/s]
Cells = ti.types.argpack(pres=ND3, u_cell=ND3, gradp_cell=ND3, div_cell=ND3)

# float parameters (par[...])
P_RHO, P_MU, P_H, P_G, P_POUT, P_THMIN, P_TRACE = 0, 1, 2, 3, 6, 12, 13
NPAR = 16
# the step's scalars (gsc[...]): max|div|, flux scale, max|u_new|, max|u_old|, largest viscous change;
# viscous sweeps done, 1 while sweeping, their threshold; the predicted field's flux scale, the
# reference scale of the divergence, 1 once the projection is applied
SC_DMAX, SC_SMAX, SC_UMAX, SC_UOLD, SC_DV = range(5)
SC_NSW, SC_VACT, SC_VTHR, SC_SPRED, SC_SREF, SC_CORR = range(5, 11)
NSC = 16


@ti.func
def fdims(g: ti.template(), a):
    d = g.dims
    d[a] += 1
    return d


@ti.func
def fidx(g: ti.template(), a, I):
    d = fdims(g, a)
    return g.face_off[a] + (I[0] * d[1] + I[1]) * d[2] + I[2]


@ti.func
def fdecode(g: ti.template(), f):
    a = 0
    if f >= g.face_off[2]:
        a = 2
    elif f >= g.face_off[1]:
        a = 1
    d = fdims(g, a)
    loc = f - g.face_off[a]
    I = ti.Vector([loc // (d[1] * d[2]), (loc // d[2]) % d[1], loc % d[2]])
    return a, I


@ti.func
def cidx(g: ti.template(), I):
    return (I[0] * g.dims[1] + I[1]) * g.dims[2] + I[2]


@ti.func
def wrap(i, n):
    return ((i % n) + n) % n


@ti.func
def face_cells(g: ti.template(), a, I):
    """The two cells of face (a, I), wrapped on periodic axes, and whether each exists."""
    n = g.dims
    L = I
    L[a] -= 1
    R = I
    hasL = True
    hasR = True
    if L[a] < 0:
        if g.wrap[a] == 1:
            L[a] += n[a]
        else:
            hasL = False
    if R[a] >= n[a]:
        if g.wrap[a] == 1:
            R[a] -= n[a]
        else:
            hasR = False
    return L, R, hasL, hasR


@ti.func
def face_mean(g: ti.template(), arr: ti.template(), a, I):
    """Mean over the two cells of face (a, I) of the scalar cell array arr."""
    L, R, hL, hR = face_cells(g, a, I)
    v = 0.0
    if hL and hR:
        v = 0.5 * (arr[L] + arr[R])
    elif hL:
        v = arr[L]
    elif hR:
        v = arr[R]
    return v


@ti.func
def face_mean_comp(g: ti.template(), arr: ti.template(), q: ti.template(), a, I):
    """Mean over the two cells of face (a, I) of component q of the vec3 cell array arr."""
    L, R, hL, hR = face_cells(g, a, I)
    v = 0.0
    if hL and hR:
        v = 0.5 * (arr[L][q] + arr[R][q])
    elif hL:
        v = arr[L][q]
    elif hR:
        v = arr[R][q]
    return v


@ti.func
def eps_at(inp: ti.template(), C):
    """The gas fraction of cell C as the solver reads it: clamped to [EPS_MIN, 1] (it divides by eps;
    guards kernels writing eps <= 0)."""
    return ti.min(ti.max(inp.gas_eps[C], EPS_MIN), 1.0)


@ti.func
def face_eps(g: ti.template(), inp: ti.template(), a, I):
    """Face gas fraction: the mean of the (clamped) fractions of the two cells of face (a, I)."""
    L, R, hL, hR = face_cells(g, a, I)
    v = 0.0
    if hL and hR:
        v = 0.5 * (eps_at(inp, L) + eps_at(inp, R))
    elif hL:
        v = eps_at(inp, L)
    elif hR:
        v = eps_at(inp, R)
    return v


@ti.func
def is_boundary(g: ti.template(), a, I):
    return g.wrap[a] == 0 and (I[a] == 0 or I[a] == g.dims[a])


@ti.func
def tangential(a):
    """The two axes other than a, in x, y, z order."""
    t1 = 0
    t2 = 2
    if a == 0:
        t1 = 1
    if a == 2:
        t2 = 1
    return t1, t2


@ti.func
def solved(g: ti.template(), f, a, I):
    """Face velocity is an unknown of the momentum equation."""
    n = g.dims
    ok = g.aperture[f] > 0.0
    if g.wrap[a] == 1:
        ok = ok and I[a] < n[a]
    else:
        ok = ok and I[a] > 0 and I[a] < n[a]
    return ok


@ti.func
def face_pos(a, I):
    X = ti.cast(I, float) + 0.5
    X[a] -= 0.5
    return X


# ---- generic copies between the host and one bundle array
@kernel
def k_write(dst: ti.types.ndarray(), off: ti.i32, src: ti.types.ndarray()):
    for i in range(src.shape[0]):
        dst[off + i] = src[i]


@kernel
def k_read(src: ti.types.ndarray(), off: ti.i32, dst: ti.types.ndarray()):
    for i in range(dst.shape[0]):
        dst[i] = src[off + i]


@kernel
def k_copy(src: ti.types.ndarray(), dst: ti.types.ndarray(), zero: ti.i32):
    """dst = src (or 0 when ``zero``), whole arrays of one size."""
    for i in range(dst.shape[0]):
        v = 0.0
        if not zero:
            v = src[i]
        dst[i] = v


# ---- loops over faces and cells: nested in the serial form, one parallel loop otherwise
@ti.func
def each_face(g: ti.template(), nf: ti.template(), body: ti.template(), ctx: ti.template(), serial: ti.template()):
    """body(ctx, f, a, I) for every face, or none when nf = 0 (nf: g.nfaces or 0). ``serial`` (inside one
    serial loop): nested loops over a, i, j, k, no index decoding by division; else one loop over f, a
    top-level parallel loop of the kernel, with :func:`fdecode`. ctx: a tuple of the body's bundles and values.
    ``nf`` is a template (not copied: a caller's variable set ahead of its loops leaves no statement between them)."""
    if ti.static(serial):
        for a in range(3 * ti.cast(nf > 0, ti.i32)):
            d = fdims(g, a)
            for i in range(d[0]):
                for j in range(d[1]):
                    fij = g.face_off[a] + (i * d[1] + j) * d[2]
                    for k in range(d[2]):
                        body(ctx, fij + k, a, ti.Vector([i, j, k]))
    else:
        for f in range(nf):
            a, I = fdecode(g, f)
            body(ctx, f, a, I)


@ti.func
def each_face_colour(g: ti.template(), nf: ti.template(), colour: ti.template(), body: ti.template(),
                     ctx: ti.template(), serial: ti.template()):
    """:func:`each_face` over the faces whose i + j + k has the parity ``colour`` (serial: only those are visited).
    ``nf`` and ``colour`` are templates (not copied: no statement ahead of the loop in the parallel form)."""
    if ti.static(serial):
        for a in range(3 * ti.cast(nf > 0, ti.i32)):
            d = fdims(g, a)
            for i in range(d[0]):
                for j in range(d[1]):
                    fij = g.face_off[a] + (i * d[1] + j) * d[2]
                    k0 = (i + j + colour) % 2
                    for kk in range((d[2] - k0 + 1) // 2):
                        k = k0 + 2 * kk
                        body(ctx, fij + k, a, ti.Vector([i, j, k]))
    else:
        for f in range(nf):
            a, I = fdecode(g, f)
            if (I[0] + I[1] + I[2]) % 2 == colour:
                body(ctx, f, a, I)


# ---- the same loops reducing what the body returns. The largest value accumulates in a kernel-scope variable,
# which Taichi 1.7.4 reduces per thread (then per warp on CUDA) and writes once (make_thread_local); an atomic
# into an array element would be one atomic per face on one address, and a float max on CUDA is a
# compare-and-swap loop that retries until its write lands (benchmarks/reduction_cost.py). Values are >= 0.
# The accumulator travels to the body in its context tuple, by reference (a template).
@ti.func
def _face_max_body(c: ti.template(), f, a, I):
    """each_face's body for the reductions: c = (m, body, ctx), unpacked by name as the gas's bodies are."""
    _face_max_in(c[0], c[1], c[2], f, a, I)


@ti.func
def _face_max_in(m: ti.template(), body: ti.template(), ctx: ti.template(), f, a, I):
    ti.atomic_max(m, body(ctx, f, a, I))  # m: the caller's kernel-scope variable, by reference


@ti.func
def _cell_max_body(c: ti.template(), I):
    """each_cell's body for :func:`cell_max`: c = (m, body, ctx)."""
    _cell_max_in(c[0], c[1], c[2], I)


@ti.func
def _cell_max_in(m: ti.template(), body: ti.template(), ctx: ti.template(), I):
    ti.atomic_max(m, body(ctx, I))


@ti.func
def _cell_max2_body(c: ti.template(), I):
    """each_cell's body for :func:`cell_max2`: c = (m1, m2, body, ctx), body returning two values."""
    _cell_max2_in(c[0], c[1], c[2], c[3], I)


@ti.func
def _cell_max2_in(m1: ti.template(), m2: ti.template(), body: ti.template(), ctx: ti.template(), I):
    v1, v2 = body(ctx, I)
    ti.atomic_max(m1, v1)
    ti.atomic_max(m2, v2)


@ti.func
def face_colour_max_into(m: ti.template(), g: ti.template(), nf: ti.template(), colour: ti.template(),
                         body: ti.template(), ctx: ti.template(), serial: ti.template()):
    """The largest body(ctx, f, a, I) over the faces :func:`each_face_colour` visits, into the caller's variable
    ``m`` (by reference, as is every argument: a kernel that sets several accumulators first and then runs such
    loops back to back makes no serial task between them in the parallel form; see passes.py, ``level_pair``)."""
    each_face_colour(g, nf, colour, _face_max_body, (m, body, ctx), serial)


@ti.func
def face_max_into(m: ti.template(), g: ti.template(), nf: ti.template(), body: ti.template(), ctx: ti.template(),
                  serial: ti.template()):
    """The largest body(ctx, f, a, I) over the faces :func:`each_face` visits, into the caller's variable ``m``
    (by reference, as :func:`face_colour_max_into`)."""
    each_face(g, nf, _face_max_body, (m, body, ctx), serial)


@ti.func
def cell_max2_into(m1: ti.template(), m2: ti.template(), g: ti.template(), count: ti.template(), body: ti.template(),
                   ctx: ti.template(), serial: ti.template()):
    """:func:`cell_max2` over :func:`each_cell_of`'s cells into the caller's variables ``m1``, ``m2``."""
    each_cell_of(g, count, _cell_max2_body, (m1, m2, body, ctx), serial)


@ti.func
def each_cell_of(g: ti.template(), count: ti.template(), body: ti.template(), ctx: ti.template(),
                 serial: ti.template()):
    """:func:`each_cell` over ``count`` cells (g.ncells, or 0 for none), a template: in the parallel form one loop
    over the cell index, its bound the caller's variable, so no statement stands between it and the loop before."""
    if ti.static(serial):
        each_cell(g, ti.cast(count > 0, ti.i32), body, ctx, serial)
    else:
        for c in range(count):
            n = g.dims
            body(ctx, ti.Vector([c // (n[1] * n[2]), (c // n[2]) % n[1], c % n[2]]))


@ti.func
def cell_max(g: ti.template(), on, body: ti.template(), ctx: ti.template(), serial: ti.template()):
    """The largest body(ctx, I) over the cells :func:`each_cell` visits (0 with none)."""
    m = 0.0
    each_cell(g, on, _cell_max_body, (m, body, ctx), serial)
    return m


@ti.func
def cell_max2(g: ti.template(), on, body: ti.template(), ctx: ti.template(), serial: ti.template()):
    """The largest of each of the two values body(ctx, I) returns, over the cells :func:`each_cell` visits
    (0, 0 with none)."""
    m1 = 0.0
    m2 = 0.0
    each_cell(g, on, _cell_max2_body, (m1, m2, body, ctx), serial)
    return m1, m2


@ti.func
def each_cell(g: ti.template(), on, body: ti.template(), ctx: ti.template(), serial: ti.template()):
    """body(ctx, I) for every cell I (none unless ``on``); serial: nested loops, else a parallel ndrange."""
    n = g.dims
    if ti.static(serial):
        for i in range(n[0] * on):
            for j in range(n[1]):
                for k in range(n[2]):
                    body(ctx, ti.Vector([i, j, k]))
    else:
        for i, j, k in ti.ndrange(n[0] * on, n[1], n[2]):
            body(ctx, ti.Vector([i, j, k]))
