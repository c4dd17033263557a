"""The pressure projection: the variable-coefficient Poisson system, the correction, the cell outputs.

Incremental: u = u* - kappa grad phi, p^(n+1) = p^n + phi, kappa = eps^m / (rho eps/dt + beta) on
faces. Cell continuity theta d(eps)/dt + (1/h) sum_faces (+-) a eps_f u_f = 0 gives
sum T_f (phi_c - phi_nb) = -div(eps u*) - theta d(eps)/dt, T_f = a eps_f kappa_f / h^2, solved by
:class:`app.sim.gas.linsolve.MGPCG`. The kernels write the system into the linear solver's bundles
(:data:`~app.sim.gas.multigrid.Multigrid`, :data:`~app.sim.gas.pcg.Krylov`) and read its solution
there: the solver's bundles are its interface, not private state.
"""
import taichi as ti

from ..launch import kernel, narrowed
from . import multigrid as mgm
from .boundary import face_grad, grad_across, has_grad, periodic_twin
from .config import OUTLET
from .layout import (P_H, P_RHO, P_TRACE, SC_CORR, SC_DMAX, SC_NSW, SC_SMAX, SC_SPRED, SC_SREF, SC_UMAX, SC_UOLD,
                     SC_VACT, Cells, Grid, Inputs, State, cell_max, cell_max2, cell_max2_into, cidx, each_cell_of,
                     each_face, face_max_into, fidx, is_boundary, solved)
from .multigrid import Multigrid
from .pcg import Krylov, solve_record
from ..tasks import one_task


@ti.func
def kappa(g: ti.template(), st: ti.template(), a, I, dt):
    """Face coefficient of the pressure correction, eps^m / (rho eps/dt + beta) [m^3 s/kg], and eps_f."""
    e = st.eps_f[fidx(g, a, I)]
    be = st.beta_f[fidx(g, a, I)]
    em = 1.0
    if g.form == 1:
        em = e
    return em / (g.par[P_RHO] * e / dt + be), e


@ti.func
def cell_balance(g: ti.template(), inp: ti.template(), st: ti.template(), vb: ti.template(), I):
    """(net outflow rate, gross flow rate) of cell I per unit volume [1/s] of the face velocity vb,
    incl. theta*deps."""
    h = g.par[P_H]
    th = g.open_vol[I]
    de = inp.gas_deps_dt[I]
    net = th * de
    gross = th * ti.abs(de)
    n = g.dims
    for a in ti.static(range(3)):
        for side in ti.static(range(2)):
            J = I
            J[a] += side
            if g.wrap[a] == 1 and J[a] == n[a]:
                J[a] = 0  # the periodic duplicate face may be stale before the final copy
            f = fidx(g, a, J)
            q = g.aperture[f] * st.eps_f[f] * vb[f] / h
            net += q if side == 1 else -q
            gross += ti.abs(q)
    return net, gross


#: the members each kernel of the projection reads (Taichi 1.7.4 sets every member of a pack at every launch,
#: ~3 us each on the host: the full bundles would set 43 arrays a launch here)
BuildState = narrowed(State, "vel", "eps_f", "beta_f", "gsc")
CorrectState = narrowed(State, "vel", "vel_adv", "accel", "dpred", "eps_f", "beta_f", "gsc")
RecordState = narrowed(State, "gsc")
RateInputs = narrowed(Inputs, "gas_deps_dt")
PresCells = narrowed(Cells, "pres")
BuildMultigrid = narrowed(Multigrid, "lev", "trans", "ctrl")
CtrlMultigrid = narrowed(Multigrid, "ctrl")
BuildKrylov = narrowed(Krylov, "sol", "rhs")
SolKrylov = narrowed(Krylov, "sol")


@kernel
def k_build(g: Grid, inp: RateInputs, cl: PresCells, st: BuildState, mg: BuildMultigrid, ks: BuildKrylov,
            dt: float, again: ti.i32, serial: ti.template()):
    """Outlet faces get their predicted velocity (not ``again``: a refinement round projects the
    corrected field once more); the pressure system's T and b into the linear solver's bundles; the
    residual scale of the solve (the gross-flux scale of the predicted field, or the reference scale
    in a refinement round) into its control scalars. While the viscous sweeps still go on (the host launched
    fewer than they took: ``FlowSolver`` then launches the rest and projects again) a void round: no face
    written, b = 0 and x = 0, so the solve stops at once, and :func:`k_correct` does nothing."""
    one_task(serial, _build, (g, inp, cl, st, mg, ks, dt, again, serial))


@ti.func
def _build(g: ti.template(), inp: ti.template(), cl: ti.template(), st: ti.template(), mg: ti.template(),
           ks: ti.template(), dt, again, serial: ti.template()):
    # the face count in one assignment (one set in a branch is read by a task of its own before the second loop). The
    # cell loop stays an ndrange: as a loop over the cell index (no task before it) it gave the f64 parallel form
    # other round-off (the same arithmetic, compiled differently)
    live = ti.cast(st.gsc[SC_VACT] == 0.0, ti.i32)  # 0: the predictor is not done (a void round)
    nfo = g.nfaces * live * ti.cast(again == 0, ti.i32)
    each_face(g, nfo, _outlet_at, (g, cl, st, dt), serial)
    each_face(g, nfo, _trans_at, (g, st, mg, dt), serial)  # a refinement round's are the first round's
    st.gsc[SC_SMAX] = cell_max(g, 1, _rhs_at, (g, inp, st, ks, live), serial)
    if not again:
        st.gsc[SC_SPRED] = st.gsc[SC_SMAX]
        st.gsc[SC_SREF] = st.gsc[SC_SMAX]
    mg.ctrl[mgm.S_SCALE] = st.gsc[SC_SREF]
    st.gsc[SC_CORR] = 0.0


@ti.func
def _outlet_at(c: ti.template(), f, a, I):
    """Outlet face f gets its predicted velocity."""
    _outlet_at_in(c[0], c[1], c[2], c[3], f, a, I)


@ti.func
def _outlet_at_in(g: ti.template(), cl: ti.template(), st: ti.template(), dt: ti.template(), f, a, I):
    n = g.dims
    if is_boundary(g, a, I) and g.aperture[f] > 0.0:
            side = 0 if I[a] == 0 else 1
            if g.bc_kind[2 * a + side] == OUTLET:
                # zero-gradient velocity: the interior neighbour's prediction with its own pressure
                # push swapped for this face's (so a steady state extrapolates p linearly to p_out)
                J = I
                J[a] = 1 if side == 0 else n[a] - 1
                J[a] = ti.min(ti.max(J[a], 0), n[a])
                u = st.vel[fidx(g, a, J)]
                gJ, okJ = face_grad(g, cl, a, J)
                if okJ:
                    kJ, _ = kappa(g, st, a, J, dt)
                    u += kJ * gJ
                gb, okb = face_grad(g, cl, a, I)
                kb, eb = kappa(g, st, a, I, dt)
                st.vel[f] = u - kb * gb


@ti.func
def _trans_at(c: ti.template(), f, a, I):
    """The pressure system's transmissibility of face f."""
    _trans_at_in(c[0], c[1], c[2], c[3], f, a, I)


@ti.func
def _trans_at_in(g: ti.template(), st: ti.template(), mg: ti.template(), dt: ti.template(), f, a, I):
    h = g.par[P_H]
    t = 0.0
    apf = g.aperture[f]
    if has_grad(g, a, I):
        kap, e = kappa(g, st, a, I, dt)
        t = apf * e * kap / (h * h)
        if is_boundary(g, a, I):
            t *= 2.0  # outlet: the pressure is fixed half a cell away
    mg.trans[mgm.face(mg, 0, a, I)] = t


@ti.func
def _rhs_at(c: ti.template(), I):
    """The pressure system's right-hand side at cell I (minus its net outflow rate); returns the gross-flux scale."""
    return _rhs_at_in(c[0], c[1], c[2], c[3], c[4], I)


@ti.func
def _rhs_at_in(g: ti.template(), inp: ti.template(), st: ti.template(), ks: ti.template(), live: ti.template(), I):
    ci = cidx(g, I)
    b = 0.0
    gross = 0.0
    if g.open_vol[I] > 0.0 and live == 1:
        net, gr = cell_balance(g, inp, st, st.vel, I)
        b = -net
        gross = gr
    ks.rhs[ci] = b
    ks.sol[ci] = 0.0  # the solve is for the pressure increment
    return gross


@ti.func
def _project_at(c: ti.template(), f, a, I):
    """u = u* - kappa grad phi at face f (the predictor increment recorded in the first round)."""
    _project_at_in(c[0], c[1], c[2], c[3], c[4], f, a, I)


@ti.func
def _project_at_in(g: ti.template(), ks: ti.template(), st: ti.template(), dt: ti.template(),
                   again: ti.template(), f, a, I):
    if not again:
        dp = 0.0
        if solved(g, f, a, I):
            dp = st.vel[f] - st.vel_adv[f]
        st.dpred[f] = dp
    gr, ok = grad_across(g, ks.sol, True, 0.0, 0.0, a, I)  # the increment: 0 beyond outlets
    if ok:
        kap, _ = kappa(g, st, a, I, dt)
        st.vel[f] -= kap * gr


@ti.func
def _pressure_at(c: ti.template(), I):
    _pressure_at_in(c[0], c[1], c[2], I)


@ti.func
def _pressure_at_in(g: ti.template(), ks: ti.template(), cl: ti.template(), I):
    if g.open_vol[I] > 0.0:
        cl.pres[I] += ks.sol[cidx(g, I)]


@ti.func
def _accel_at(c: ti.template(), f, a, I):
    """The step's weighted non-advective acceleration at face f; returns |u| there."""
    return _accel_at_in(c[0], c[1], c[2], f, a, I)


@ti.func
def _accel_at_in(g: ti.template(), st: ti.template(), dt: ti.template(), f, a, I):
    acc = 0.0
    if solved(g, f, a, I):
        # net non-advective acceleration of this step, weighted by the inertial share of the
        # face (-> 0 where drag dominates, so a jump of a drag-balanced pressure gradient is
        # not carried along trajectories); used by the next step's second-order advection
        rho = g.par[P_RHO]
        e = st.eps_f[f]
        be = st.beta_f[f]
        wt = rho * e / (rho * e + be * dt)
        acc = g.par[P_TRACE] * wt * (st.vel[f] - st.vel_adv[f]) / dt
    st.accel[f] = acc
    return ti.abs(st.vel[f])


@ti.func
def cell_outputs(g: ti.template(), inp: ti.template(), st: ti.template(), cl: ti.template(), on,
                 serial: ti.template()):
    """Cell-centred gas velocity and pressure gradient, divergence and its scale (reductions);
    nothing unless ``on``."""
    dmax, smax = cell_max2(g, on, _outputs_at, (g, inp, st, cl), serial)
    if on:
        st.gsc[SC_DMAX] = dmax
        st.gsc[SC_SMAX] = smax


@ti.func
def _outputs_at(c: ti.template(), I):
    return _outputs_at_in(c[0], c[1], c[2], c[3], I)


@ti.func
def _outputs_at_in(g: ti.template(), inp: ti.template(), st: ti.template(), cl: ti.template(), I):
    active = g.open_vol[I] > 0.0
    net = 0.0
    gross = 0.0
    if active:
        net, gr = cell_balance(g, inp, st, st.vel, I)
        gross = gr
    cl.div_cell[I] = net
    # a run-time loop over the two faces of an axis: unrolled, the pressure gradient (with its outlet and
    # cut-cell cases) was inlined six times. k_correct's cold compile 4.6 -> 3.0 s; the axes stay unrolled
    # (run-time axes gave 1.7 s, but 16.5 against 15.9 ms a one-thread step; 2026-12-04, RESULTS.md)
    for a in ti.static(range(3)):
        J = I
        J[a] += 1
        uc = 0.0
        gp = 0.0
        if active:
            uc = 0.5 * (st.vel[fidx(g, a, I)] + st.vel[fidx(g, a, J)])
            cnt = 0.0
            for side in range(2):
                K = I
                K[a] += side
                gk, ok = face_grad(g, cl, a, K)
                if ok:
                    gp += gk
                    cnt += 1.0
            if cnt > 0.0:
                gp /= cnt
        cl.u_cell[I][a] = uc
        cl.gradp_cell[I][a] = gp
    return ti.abs(net), gross


@kernel
def k_correct(g: Grid, inp: RateInputs, mg: CtrlMultigrid, ks: SolKrylov, st: CorrectState, cl: Cells,
              dt: float, again: ti.i32, serial: ti.template()):
    """u = u* - kappa grad phi, p += phi; periodic copies; cell outputs; (max|div|, scale, max|u|)
    into the scalars. The predictor increment is recorded in the first round only. Runs once the
    pressure solve has finished, once per round (the host launches it without waiting)."""
    one_task(serial, _correct, (g, inp, mg, ks, st, cl, dt, again, serial))


@ti.func
def _correct(g: ti.template(), inp: ti.template(), mg: ti.template(), ks: ti.template(), st: ti.template(),
             cl: ti.template(), dt, again, serial: ti.template()):
    # every count and accumulator first, then the five loops back to back, then the scalars: in the parallel form
    # a statement between two loops is a one-thread task of its own (7 tasks, not 11)
    on = 0
    if mg.ctrl[mgm.S_DONE] > 0.0 and st.gsc[SC_CORR] == 0.0 and st.gsc[SC_VACT] == 0.0:  # not in a void round
        on = 1
    nf = g.nfaces * on
    nc = g.ncells * on
    nper = nf * ti.max(g.wrap[0], g.wrap[1], g.wrap[2])  # one assignment: a bound set in a branch costs a task
    umax = 0.0
    dmax = 0.0
    smax = 0.0
    each_face(g, nf, _project_at, (g, ks, st, dt, again), serial)
    each_cell_of(g, nc, _pressure_at, (g, ks, cl), serial)
    each_face(g, nper, _periodic_at, (g, st), serial)  # periodic duplicates (every face of a periodic grid)
    face_max_into(umax, g, nf, _accel_at, (g, st, dt), serial)
    cell_max2_into(dmax, smax, g, nc, _outputs_at, (g, inp, st, cl), serial)
    if on:
        st.gsc[SC_UMAX] = umax
        st.gsc[SC_DMAX] = dmax
        st.gsc[SC_SMAX] = smax
        st.gsc[SC_SREF] = ti.max(st.gsc[SC_SREF], smax)
        st.gsc[SC_CORR] = 1.0


@ti.func
def _periodic_at(c: ti.template(), f, a, I):
    """each_face's body for :func:`boundary.periodic_twin` (c = (g, st))."""
    periodic_twin(c[0], c[1], f, a, I)


# the record's f64: fixed at import, maybe before ti.init
@kernel
def k_record(st: RecordState, mg: CtrlMultigrid) -> ti.types.vector(13, ti.f64):
    """The step record, read once per step: max|u_old|, max|u_new|, viscous sweeps, max|div|, the
    corrected field's flux scale, the reference scale, 1 once corrected, then the pressure solve's
    (iterations, max|r|, converged, scale, initial max|r|), then 1 if the viscous sweeps still go on (a void
    round, :func:`k_build`)."""
    r = solve_record(mg)
    return ti.Vector([st.gsc[SC_UOLD], st.gsc[SC_UMAX], st.gsc[SC_NSW], st.gsc[SC_DMAX], st.gsc[SC_SMAX],
                      st.gsc[SC_SREF], st.gsc[SC_CORR], r[0], r[1], r[2], r[3], r[4], st.gsc[SC_VACT]])


@kernel
def k_outputs(g: Grid, inp: Inputs, st: State, cl: Cells) -> ti.types.vector(2, ti.f64):
    cell_outputs(g, inp, st, cl, 1, False)
    return ti.Vector([st.gsc[SC_DMAX], st.gsc[SC_SMAX]])
