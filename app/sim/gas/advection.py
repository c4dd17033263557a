"""Convection of the gas velocity: semi-Lagrangian back-tracing with the MacCormack correction.

RK2 midpoint trajectories, trilinear interpolation of each MAC component (ghost values across domain
faces, :func:`app.sim.gas.boundary.comp_value`), optionally the MacCormack correction clamped to the
values of the interpolation stencil (Selle et al. 2008); dt/2 of the last step's weighted
non-advective acceleration is added at the departure point and taken off at the arrival face (the
trapezoidal rule for the forces along the path; see :mod:`app.sim.gas`).

That acceleration is smoothed before it is traced (:func:`_smooth_at`). It holds the projection's answer to the
divergence of the advected field, MacCormack's grid-scale corrections included; traced from a departure point more
than a cell away (CFL > 1), whose value is unrelated to the arrival face's, that two-cell noise came back as a
velocity increment of its own size every step, and MacCormack's anti-diffusion tipped the loop over: the gust case of
``benchmarks/gust_stability.py`` (the Verma freeboard's blow-up, gas only) blew up (150 m/s) in 3 of 6 runs,
after 243-767 steps, where the smoothed trace peaks at 1.0-2.3x the speed the runs without the trace reach. The
smoothing weighs a face 6 and each solved neighbour of its axis 1, which removes the two-cell mode and changes a smooth
field by (h^2/12) lap a: the Taylor-Green decay rate at CFL 0.5, 1, 2 and 4 moved by at most 0.3% of itself
(tests/test_flow.py checks CFL 0.5 and 2). A trajectory that
starts outside the domain (it entered through an inlet or outlet) has no interior acceleration at its start and takes
no trace (first order there).
"""
import taichi as ti

from ..launch import kernel, narrowed
from .boundary import comp_value
from .layout import P_H, P_TRACE, SC_UOLD, EpsInputs, Grid, State, each_face, face_pos, fdims, fidx, solved, wrap
from ..tasks import one_task


@ti.func
def interp(g: ti.template(), inp: ti.template(), arr: ti.template(), a, X, rate):
    """Trilinear value of component a of the face array arr at grid point X (cell units from the
    origin), with the min and max of the 8 stencil values. Interior stencils take a direct path;
    stencils that touch the domain boundary go through :func:`comp_value` (wrapping, ghost values; ``rate`` = 1
    where arr is the acceleration, whose ghosts have no boundary value)."""
    n = g.dims
    Y = X
    for b in ti.static(range(3)):
        if g.wrap[b] == 0:
            Y[b] = ti.min(ti.max(Y[b], 0.0), ti.cast(n[b], float))
    s = Y - 0.5
    s[a] += 0.5
    i0 = ti.cast(ti.floor(s), ti.i32)
    fr = s - ti.cast(i0, float)
    d = fdims(g, a)
    stride = ti.Vector([d[1] * d[2], d[2], 1])
    inside = True
    for b in ti.static(range(3)):
        if b != a and g.wrap[b] == 1 and n[b] == 1:
            i0[b] = 0
            stride[b] = 0
        else:
            # largest index read directly: the last face/cell; along a periodic a the duplicate
            # last face may be stale, so it goes through the wrapping path
            lim = d[b] - 1
            if b == a and g.wrap[b] == 1:
                lim -= 1
            if i0[b] < 0 or i0[b] + 1 > lim:
                inside = False
    val = 0.0
    lo = 1e30
    hi = -1e30
    if inside:
        b0 = g.face_off[a] + i0[0] * stride[0] + i0[1] * stride[1] + i0[2] * stride[2]
        for c in ti.static(range(8)):
            o0 = ti.static(c & 1)
            o1 = ti.static((c >> 1) & 1)
            o2 = ti.static((c >> 2) & 1)
            w = (fr[0] if o0 else 1.0 - fr[0]) * (fr[1] if o1 else 1.0 - fr[1]) * (fr[2] if o2 else 1.0 - fr[2])
            v = arr[b0 + o0 * stride[0] + o1 * stride[1] + o2 * stride[2]]
            val += w * v
            lo = ti.min(lo, v)
            hi = ti.max(hi, v)
    else:
        for c in range(8):
            o = ti.Vector([c & 1, (c >> 1) & 1, (c >> 2) & 1])
            w = 1.0
            for q in ti.static(range(3)):
                w *= fr[q] if o[q] == 1 else 1.0 - fr[q]
            v = comp_value(g, inp, arr, a, i0 + o, rate)
            val += w * v
            lo = ti.min(lo, v)
            hi = ti.max(hi, v)
    return val, lo, hi


@ti.func
def _face_centre(g: ti.template(), arr: ti.template(), b, a, I):
    """(inside, value): :func:`interp`'s value of component b (!= a) at the centre of a-face I, read directly where
    its stencil is interior. There b's trilinear weights are 1/4 on the four b-faces J[b] in {I[b], I[b]+1},
    J[a] in {I[a]-1, I[a]}, J[c] = I[c] (fraction 0 along the third axis c) and 0 elsewhere: those four are summed
    in :func:`interp`'s corner order (the same float sum). Not inside: the caller interpolates."""
    n = g.dims
    d = fdims(g, b)
    J0 = I
    J0[a] -= 1
    stride = ti.Vector([d[1] * d[2], d[2], 1])
    inside = True
    for q in ti.static(range(3)):
        lim = d[q] - 1
        if q == b and g.wrap[q] == 1:
            lim -= 1
        if (g.wrap[q] == 1 and n[q] == 1) or J0[q] < 0 or J0[q] + 1 > lim:
            inside = False
    val = 0.0
    if inside:
        p = ti.min(a, b)
        r = ti.max(a, b)
        b0 = g.face_off[b] + J0[0] * stride[0] + J0[1] * stride[1] + J0[2] * stride[2]
        sp = stride[p]
        sr = stride[r]
        val = 0.25 * (((arr[b0] + arr[b0 + sp]) + arr[b0 + sr]) + arr[b0 + sp + sr])
    return inside, val


@ti.func
def rk2_path(g: ti.template(), inp: ti.template(), arr: ti.template(), f, a, I, X, c, to_end: ti.template()):
    """The RK2 midpoint trajectory from face f (axis a, index I, at X) over c = -dt/h (back) or +dt/h (forward)
    in the velocity arr: U1 = u(X), U2 = u(X + c/2 U1), and the end point X + c U2; when ``to_end``, also
    component a of arr there with its stencil's clamps (lo, hi). At X, component a is the face's own value and
    the other two are :func:`_face_centre`'s (interp's weights there are 1 and 0, or 1/4: the same values).
    The evaluations run as a run-time loop over one inlined :func:`interp`: each interpolation inlined once per
    kernel is what its cold compile pays for (see :func:`k_advect`)."""
    P = X
    val, lo, hi = 0.0, 0.0, 0.0
    for s in range(ti.static(3 if to_end else 2)):  # at X, at the midpoint, [at the end]
        V = ti.Vector([0.0, 0.0, 0.0])
        for b in range(3):
            if s < 2 or b == a:
                v = 0.0
                direct = False
                if s == 0:
                    if b == a:
                        direct = True
                        v = arr[f]
                    else:
                        direct, v = _face_centre(g, arr, b, a, I)
                if not direct:
                    v, lo, hi = interp(g, inp, arr, b, P, 0)
                V[b] = v
        if s == 0:  # V = U1
            P = X + 0.5 * c * V
        elif s == 1:  # V = U2
            P = X + c * V
        else:
            val = V[a]
    return P, val, lo, hi


#: the members of State the back trace (:func:`k_advect`) reads and writes
AdvectState = narrowed(State, "vel", "vel_old", "vel_adv", "vel_tmp", "vel_lo", "vel_hi", "accel", "gsc")
#: those the MacCormack correction (:func:`k_advect_finish`) reads and writes
CorrectionState = narrowed(State, "vel_old", "vel_adv", "vel_tmp", "vel_lo", "vel_hi")


@kernel
def k_advect(g: Grid, inp: EpsInputs, st: AdvectState, dt: float, serial: ti.template()):
    """vel_old = vel; vel_adv = back-traced vel + dt/2 (a at the departure point - a here), a being the last
    step's weighted acceleration, with the interpolation stencil's clamps; max|vel_old| into SC_UOLD. Then
    :func:`k_advect_finish` applies the MacCormack correction when asked.

    The acceleration's share is carried by the plain semi-Lagrangian trace, outside the
    MacCormack correction: corrected together with the velocity (u + dt/2 a traced as one field),
    the pair fed back on itself through the next step's a and grew without bound (a gas-only
    cylinder with gusty inflow reached 200 m/s in 380 steps; either piece alone stays bounded).
    Scratch: vel_tmp holds dt/2 (a_departure - a_arrival) per face. ``serial``: every loop nested in one
    serial loop.

    Two kernels, not one, for the cold compile: the back trace (4 interpolations inlined) and the correction
    (3) as one kernel took 37.0 s on one EPYC core, as two 9.2 s and 6.0 s; with :func:`rk2_path`'s run-time
    loop (2 interpolations inlined in each) 3.8 s and 3.4 s (2026-12-04, benchmarks/RESULTS.md)."""
    one_task(serial, _advect, (g, inp, st, dt, serial))


@kernel
def k_advect_finish(g: Grid, inp: EpsInputs, st: CorrectionState, dt: float, serial: ti.template()):
    """After :func:`k_advect`: the MacCormack pass (forward trace of the result, half the error back, clamped;
    its result overwrites the face's own lower clamp vel_lo once used), then vel_adv += vel_tmp."""
    one_task(serial, _advect_finish, (g, inp, st, dt, serial))


@ti.func
def _trace(c: ti.template(), f, a, I):
    """First pass at face f: the back-traced value, its clamps and dt/2 of the acceleration's change."""
    _trace_at(c[0], c[1], c[2], c[3], c[4], f, a, I)


@ti.func
def _trace_at(g: ti.template(), inp: ti.template(), st: ti.template(), dt, cdt, f, a, I):
    v = st.vel_old[f]
    inc = 0.0
    if solved(g, f, a, I):
        if g.scheme > 0:
            dep, val, lo, hi = rk2_path(g, inp, st.vel_old, f, a, I, face_pos(a, I), -cdt, True)
            v = val
            if g.par[P_TRACE] > 0.0 and inside_domain(g, dep):  # a is all zero with gas.trace_forces off
                # (and a path that entered through an inlet or outlet has no interior start: first order there)
                adep, _, _ = interp(g, inp, st.accel, a, dep, 1)
                inc = 0.5 * dt * (adep - st.accel[f])
            if g.scheme == 2:
                st.vel_lo[f] = lo
                st.vel_hi[f] = hi
    st.vel_adv[f] = v
    st.vel_tmp[f] = inc


@ti.func
def _correct(c: ti.template(), f, a, I):
    """MacCormack pass at face f: forward trace of the result, half the error back, clamped (into vel_lo)."""
    _correct_at(c[0], c[1], c[2], c[3], c[4], f, a, I)


@ti.func
def _correct_at(g: ti.template(), inp: ti.template(), st: ti.template(), dt, cdt, f, a, I):
    if solved(g, f, a, I):
        end, _, _, _ = rk2_path(g, inp, st.vel_old, f, a, I, face_pos(a, I), cdt, False)
        back, _, _ = interp(g, inp, st.vel_adv, a, end, 0)
        v = st.vel_adv[f] + 0.5 * (st.vel_old[f] - back)
        st.vel_lo[f] = ti.min(ti.max(v, st.vel_lo[f]), st.vel_hi[f])


@ti.func
def _finish(c: ti.template(), f, a, I):
    _finish_at(c[0], c[1], c[2], c[3], c[4], f, a, I)


@ti.func
def _finish_at(g: ti.template(), inp: ti.template(), st: ti.template(), dt, cdt, f, a, I):
    if solved(g, f, a, I):
        v = st.vel_adv[f]
        if g.scheme == 2:
            v = st.vel_lo[f]
        st.vel_adv[f] = v + st.vel_tmp[f]


@ti.func
def _advect(g: ti.template(), inp: ti.template(), st: ti.template(), dt, serial: ti.template()):
    nf = g.nfaces
    cdt = dt / g.par[P_H]
    uold = 0.0  # a kernel-scope reduction, not an atomic per face into gsc (layout.face_max_into)
    for f in range(nf):
        u = st.vel[f]
        st.vel_old[f] = u
        ti.atomic_max(uold, ti.abs(u))
    st.gsc[SC_UOLD] = uold
    nt = nf * ti.cast(g.par[P_TRACE] > 0.0, ti.i32)  # the traced acceleration smoothed first (into vel_lo, back)
    each_face(g, nt, _smooth, (g, st), serial)
    for f in range(nt):
        st.accel[f] = st.vel_lo[f]
    each_face(g, nf, _trace, (g, inp, st, dt, cdt), serial)


@ti.func
def inside_domain(g: ti.template(), X):
    """Point X (cell units) inside the grid along every axis that does not wrap."""
    ok = True
    for b in ti.static(range(3)):
        if g.wrap[b] == 0 and (X[b] < 0.0 or X[b] > ti.cast(g.dims[b], float)):
            ok = False
    return ok


@ti.func
def _smooth(c: ti.template(), f, a, I):
    _smooth_at(c[0], c[1], f, a, I)


@ti.func
def _smooth_at(g: ti.template(), st: ti.template(), f, a, I):
    """vel_lo[f] = the acceleration at face f smoothed over itself (weight 6) and its solved neighbours of the
    same axis (weight 1 each), normalised: (6 a_f + sum a_nb) / (6 + count). The two-cell mode (signs alternating
    along every axis) is removed, a smooth field changes by (h^2/12) lap a; a face that is not solved keeps a."""
    v = st.accel[f]
    if solved(g, f, a, I):
        tot = 6.0 * v
        wsum = 6.0
        n = g.dims
        d = fdims(g, a)  # the faces of axis a: index 0..d[b]-1 along each axis b
        for q in range(6):  # a run-time loop: unrolled six times, the kernel's cold compile took 4 s longer
            b = q // 2
            J = I
            J[b] += 2 * (q % 2) - 1
            ok = True
            if g.wrap[b] == 1:
                J[b] = wrap(J[b], n[b])
            else:
                ok = 0 <= J[b] < d[b]
            if ok:
                fn = fidx(g, a, J)
                if solved(g, fn, a, J):
                    tot += st.accel[fn]
                    wsum += 1.0
        v = tot / wsum
    st.vel_lo[f] = v


@ti.func
def _advect_finish(g: ti.template(), inp: ti.template(), st: ti.template(), dt, serial: ti.template()):
    nf = g.nfaces
    cdt = dt / g.par[P_H]
    n2 = 0
    if g.scheme == 2:
        n2 = nf
    each_face(g, n2, _correct, (g, inp, st, dt, cdt), serial)
    each_face(g, nf, _finish, (g, inp, st, dt, cdt), serial)
