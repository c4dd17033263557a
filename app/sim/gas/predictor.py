"""The momentum predictor: face coefficients and the implicit drag/viscous update by red-black sweeps.

Per face, backward Euler with the incremental pressure::

    (rho eps/dt + beta) u* - div(eps mu grad u*) = rho eps/dt u~ - eps^m grad p^n + rho eps g + f + beta u_s

solved in place by red-black Gauss-Seidel sweeps (the viscous stencil couples a face only to faces of
the other parity), from the last step's predictor increment as initial iterate; beta and every wall
term sit on the diagonal. The diagonal and the right-hand side without the fluid neighbours are fixed
during the sweeps: computed once per step (:func:`_visc_setup`), a sweep only sums the neighbours.
Cut-cell walls enter as ghost values u_G = -u_P (1 - t)/t (see :mod:`app.sim.gas`).
"""
import taichi as ti

from ..launch import kernel, narrowed
from .boundary import face_grad, ghost_coef
from .layout import (P_G, P_H, P_MU, P_RHO, P_THMIN, SC_DV, SC_NSW, SC_UOLD, SC_VACT, SC_VTHR, Cells, Grid, Inputs,
                     State, each_face, eps_at, face_cells, face_colour_max_into, face_eps,
                     face_mean_comp, fidx, solved, wrap)
from ..tasks import each_chunk, one_task

VISCOUS_CHUNK = 4  # red-black sweeps per launch of the viscous predictor (each stops itself on the device;
# each is a copy of the sweep in the compiled kernel; with the fixed parts computed once per step the
# solver's whole compile took as long with 4 as with 2: 122 s, 8x8x16, no offline cache, loaded CPU)
VISCOUS_CHUNK_MORE = 4  # sweeps per later launch (k_visc_more). A step takes ~3 sweeps, so the later launches are
# usually empty; they take 8 arrays instead of k_visc's 16 (host time: ~3 us an array on a GPU's host). Larger
# chunks would mean fewer launches but not fewer (empty) tasks, and cost compile time in the parallel form, where
# each sweep is unrolled: 12 sweeps a launch took the gas's cold first step from 18.8 to 32.3 s (CPU, 2 threads)


@ti.func
def face_beta(g: ti.template(), inp: ti.template(), a, I):
    """Face drag coefficient [kg m^-3 s^-1]: eps_f^(m+1) * mean(beta/eps^(m+1)) of the two cells, so
    that the drag resistance of the face is the series resistance of its two half-cells and the
    pressure drop of a 1-D flow through any eps/beta layering is exact (eps_f: mean of the cells)."""
    L, R, hL, hR = face_cells(g, a, I)
    m1 = g.form + 1
    r = 0.0
    cnt = 0.0
    if hL:
        r += inp.drag_beta[L] / eps_at(inp, L) ** m1
        cnt += 1.0
    if hR:
        r += inp.drag_beta[R] / eps_at(inp, R) ** m1
        cnt += 1.0
    e = face_eps(g, inp, a, I)
    return e ** m1 * r / ti.max(cnt, 1.0)


#: the members k_face_coef reads and writes
FaceInputs = narrowed(Inputs, "gas_eps", "drag_beta")
FaceState = narrowed(State, "eps_f", "beta_f")


@kernel
def k_face_coef(g: Grid, inp: FaceInputs, st: FaceState, serial: ti.template()):
    """Face gas fraction (mean of the two cells) and face drag coefficient, once per step."""
    one_task(serial, _face_coef, (g, inp, st, serial))


@ti.func
def _face_coef_at(c: ti.template(), f, a, I):
    c[1].eps_f[f] = face_eps(c[0], c[2], a, I)
    c[1].beta_f[f] = face_beta(c[0], c[2], a, I)


@ti.func
def _face_coef(g: ti.template(), inp: ti.template(), st: ti.template(), serial: ti.template()):
    each_face(g, g.nfaces, _face_coef_at, (g, st, inp), serial)


@ti.func
def _neighbour(g: ti.template(), a, I, b, side):
    """Face J next to a-face I along axis b (side 0: -, 1: +), wrapped on periodic axes, and whether it
    lies beyond a non-periodic domain face (ghost)."""
    n = g.dims
    J = I
    J[b] += 2 * side - 1
    ghost = False
    if b == a:
        if g.wrap[a] == 1:
            J[a] = wrap(J[a], n[a])
    elif J[b] < 0 or J[b] >= n[b]:
        if g.wrap[b] == 1:
            J[b] = wrap(J[b], n[b])
        else:
            ghost = True
    return J, ghost


@ti.func
def _solid(g: ti.template(), q):
    """Neighbour face q is closed (aperture 0) or inside the vessel wall (clearance < 0), and its clearance."""
    solid = False
    clQ = 1.0
    if g.has_walls == 1:
        clQ = g.clear[q]
        solid = g.aperture[q] <= 0.0 or clQ < 0.0
    return solid, clQ


@ti.func
def _coupled(g: ti.template(), b):
    return not (g.wrap[b] == 1 and g.dims[b] == 1) and g.par[P_MU] > 0.0


@ti.func
def _visc_const(g: ti.template(), inp: ti.template(), cl: ti.template(), st: ti.template(), dt, f, a, I):
    """Diagonal D and the right-hand side R of face f without its fluid neighbours' terms: both fixed
    during the sweeps (inertia, drag, gravity, sources, the last pressure, walls and ghosts)."""
    n = g.dims
    rho = g.par[P_RHO]
    h = g.par[P_H]
    thmin = g.par[P_THMIN]
    eP = st.eps_f[f]
    bP = st.beta_f[f]
    D = rho * eP / dt + bP
    R = rho * eP / dt * st.vel_adv[f] + rho * eP * g.par[P_G + a] \
        + face_mean_comp(g, inp.ext_force, a, a, I) + bP * face_mean_comp(g, inp.solid_vel, a, a, I)
    gp, okp = face_grad(g, cl, a, I)
    if okp:
        em = 1.0
        if g.form == 1:
            em = eP
        R -= em * gp  # incremental projection: the predictor feels the last pressure
    cw = g.par[P_MU] * eP / (h * h)
    clP = 1e30
    if g.has_walls == 1:
        clP = ti.max(g.clear[f], 0.0)
    for b in range(3):
        if _coupled(g, b):
            for side in range(2):
                J, ghost = _neighbour(g, a, I, b, side)
                if ghost:
                    # a vessel wall closer than the domain face (clearance extrapolated
                    # linearly across the boundary) takes precedence over the domain ghost
                    th = 1.0
                    if g.has_walls == 1 and clP > 0.0:
                        Jo = I
                        Jo[b] -= 2 * side - 1
                        if Jo[b] >= 0 and Jo[b] < n[b]:
                            clQ = 2.0 * clP - g.clear[fidx(g, a, Jo)]
                            if clQ < 0.0:
                                th = clP / (clP - clQ)
                    if th < 0.5:
                        D += cw / ti.max(th, thmin)
                    else:
                        al, ga = ghost_coef(g, inp, b, side, a, J)
                        D += cw * (1.0 - al)
                        R += cw * ga
                else:
                    q = fidx(g, a, J)
                    solid, clQ = _solid(g, q)
                    if solid:
                        th = 1.0
                        if clQ < 0.0:
                            th = clP / (clP - clQ)
                        th = ti.min(ti.max(th, thmin), 1.0)
                        D += cw / th
                    else:
                        D += g.par[P_MU] * 0.5 * (eP + st.eps_f[q]) / (h * h)
    return D, R


@ti.func
def _visc_setup_at(c: ti.template(), f, a, I):
    _visc_setup_in(c[0], c[1], c[2], c[3], c[4], f, a, I)


@ti.func
def _visc_setup_in(g: ti.template(), inp: ti.template(), cl: ti.template(), st: ti.template(), dt, f, a, I):
    if solved(g, f, a, I):
        D, R = _visc_const(g, inp, cl, st, dt, f, a, I)
        st.vel_tmp[f] = D
        st.vel_lo[f] = R


@ti.func
def _visc_setup(g: ti.template(), inp: ti.template(), cl: ti.template(), st: ti.template(), dt, nf,
                serial: ti.template()):
    """The fixed parts of the sweeps, once per step: D into vel_tmp, R into vel_lo (advection's scratch)."""
    each_face(g, nf, _visc_setup_at, (g, inp, cl, st, dt), serial)


@ti.func
def _visc_colour(dv: ti.template(), g: ti.template(), st: ti.template(), colour: ti.template(), nf: ti.template(),
                 serial: ti.template()):
    """Gauss-Seidel update, in place on the velocity, of the faces of one colour (parity of
    i+j+k) among the first nf faces (all, or none once the sweeps have stopped): the viscous
    stencil couples a face only to faces of the other colour. u = (R + sum of the fluid neighbours'
    c_q u_q) / D with D and R from :func:`_visc_setup`. The largest change of a face velocity goes into the
    caller's ``dv`` (by reference: the two colours' loops run back to back in the parallel form)."""
    face_colour_max_into(dv, g, nf, colour, _visc_face, (g, st), serial)


@ti.func
def _visc_face(c: ti.template(), f, a, I):
    return _visc_face_in(c[0], c[1], f, a, I)


@ti.func
def _visc_face_in(g: ti.template(), st: ti.template(), f, a, I):
    h = g.par[P_H]
    dv = 0.0
    if solved(g, f, a, I):
        eP = st.eps_f[f]
        s = 0.0
        for b in range(3):
            if _coupled(g, b):
                for side in range(2):
                    J, ghost = _neighbour(g, a, I, b, side)
                    if not ghost:
                        q = fidx(g, a, J)
                        solid, _ = _solid(g, q)
                        if not solid:
                            s += g.par[P_MU] * 0.5 * (eP + st.eps_f[q]) / (h * h) * st.vel[q]
        unew = (st.vel_lo[f] + s) / st.vel_tmp[f]
        dv = ti.abs(unew - st.vel[f])
        st.vel[f] = unew
    return dv


#: the members k_visc reads (launched up to ~10 times a step: fewer members, less host time a launch)
ViscState = narrowed(State, "vel", "vel_adv", "vel_tmp", "vel_lo", "eps_f", "beta_f", "gsc")
ViscInputs = narrowed(Inputs, "gas_eps", "solid_vel", "ext_force")
ViscCells = narrowed(Cells, "pres")
#: what the sweeps alone read (k_visc_more: the fixed parts are k_visc's first launch)
SweepGrid = narrowed(Grid, "dims", "wrap", "face_off", "has_walls", "nfaces", "clear", "aperture", "par")
SweepState = narrowed(State, "vel", "vel_tmp", "vel_lo", "eps_f", "gsc")


@kernel
def k_visc(g: Grid, inp: ViscInputs, cl: ViscCells, st: ViscState, dt: float, first: ti.i32, factor: float,
           bc_speed: float, max_sweeps: ti.i32, serial: ti.template()):
    """VISCOUS_CHUNK red-black Gauss-Seidel sweeps of the implicit predictor, each only while the
    sweeps go on: they stop (on the device) when the largest change of a face velocity is at most
    factor * max(max|u_old|, bc_speed) or after max_sweeps. ``first`` starts the count and computes the
    sweeps' fixed parts. ``serial``: every loop nested in one serial loop."""
    one_task(serial, _visc, (g, inp, cl, st, dt, first, factor, bc_speed, max_sweeps, serial))


@ti.func
def _visc(g: ti.template(), inp: ti.template(), cl: ti.template(), st: ti.template(), dt, first, factor, bc_speed,
          max_sweeps, serial: ti.template()):
    if first:
        st.gsc[SC_NSW] = 0.0
        st.gsc[SC_VACT] = 1.0
        st.gsc[SC_VTHR] = factor * ti.max(ti.max(st.gsc[SC_UOLD], bc_speed), 1e-30)
    _visc_setup(g, inp, cl, st, dt, g.nfaces * first, serial)
    each_chunk(serial, VISCOUS_CHUNK, _visc_sweep, (g, st, max_sweeps, serial))


@kernel
def k_visc_more(g: SweepGrid, st: SweepState, max_sweeps: ti.i32, serial: ti.template()):
    """VISCOUS_CHUNK_MORE more sweeps after :func:`k_visc`'s first launch, each only while the sweeps go on
    (the same sweeps and stopping test)."""
    one_task(serial, _visc_more, (g, st, max_sweeps, serial))


@ti.func
def _visc_more(g: ti.template(), st: ti.template(), max_sweeps, serial: ti.template()):
    each_chunk(serial, VISCOUS_CHUNK_MORE, _visc_sweep, (g, st, max_sweeps, serial))


@ti.func
def _visc_sweep(_sweep, g: ti.template(), st: ti.template(), max_sweeps, serial: ti.template()):
    """One red-black sweep (of a chunk of ``VISCOUS_CHUNK``), unless the sweeps have stopped; then the stopping
    test."""
    nf = g.nfaces * ti.cast(st.gsc[SC_VACT] > 0.0, ti.i32)
    dv0 = 0.0
    dv1 = 0.0
    _visc_colour(dv0, g, st, 0, nf, serial)
    _visc_colour(dv1, g, st, 1, nf, serial)
    st.gsc[SC_DV] = ti.max(dv0, dv1)
    if nf > 0:
        st.gsc[SC_NSW] += 1.0
        if st.gsc[SC_DV] <= st.gsc[SC_VTHR] or st.gsc[SC_NSW] >= ti.cast(max_sweeps, float):
            st.gsc[SC_VACT] = 0.0
