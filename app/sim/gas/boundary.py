"""Boundary conditions and inlets of the gas: ghost values, inlet velocities, pressure faces.

Domain faces (x-, x+, y-, y+, z-, z+) carry a kind (:mod:`.config`); moving-wall and inlet faces a
boundary-value block per boundary cell (``Grid.bcv``, superficial for inlets, converted to interstitial
with the boundary cell's eps where read). Tangential ghost values beyond a face are alpha u + gamma:
wall -u, moving wall and inlet 2U - u, free slip, outlet and periodic u. A pressure outlet fixes p half
a cell outside the last cell centre.
"""
import taichi as ti

from ..launch import kernel, narrowed
from .config import INLET, MOVING, OUTLET, WALL
from .layout import (P_H, P_POUT, EpsInputs, Grid, State, cidx, each_face, eps_at, face_cells, fdecode, fidx,
                     is_boundary, solved, tangential, wrap)
from ..tasks import one_task


@ti.func
def bc_value(g: ti.template(), inp: ti.template(), b, side, a, J):
    """Component a of the boundary vector of domain face (b, side) at the place of a-face J
    (J in range along the tangential axes). Inlet values are converted to interstitial."""
    n = g.dims
    t1, t2 = tangential(b)
    blk = g.bcv_off[2 * b + side]
    v = 0.0
    for q in range(2):
        i1 = J[t1]
        i2 = J[t2]
        if t1 == a:
            i1 = J[a] - 1 + q
        if t2 == a:
            i2 = J[a] - 1 + q
        i1 = ti.min(ti.max(i1, 0), n[t1] - 1)
        i2 = ti.min(ti.max(i2, 0), n[t2] - 1)
        v += 0.5 * g.bcv[blk + (a * n[t1] + i1) * n[t2] + i2]
    if g.bc_kind[2 * b + side] == INLET:
        C = J
        for q in ti.static(range(3)):
            C[q] = ti.min(ti.max(C[q], 0), n[q] - 1)
        C[b] = 0 if side == 0 else n[b] - 1
        v /= eps_at(inp, C)
    return v


@ti.func
def ghost_coef(g: ti.template(), inp: ti.template(), b, side, a, J):
    """Ghost value beyond domain face (b, side) of the tangential component a: alpha*u_in + gamma."""
    kind = g.bc_kind[2 * b + side]
    alpha = 1.0
    gamma = 0.0
    if kind == WALL:
        alpha = -1.0
    elif kind == MOVING or kind == INLET:
        alpha = -1.0
        gamma = 2.0 * bc_value(g, inp, b, side, a, J)
    return alpha, gamma


@ti.func
def comp_value(g: ti.template(), inp: ti.template(), arr: ti.template(), a, I, rate):
    """Value of component a of the face array arr at face index I (may be outside by one): periodic
    wrap, clamping along a, boundary ghost values across the tangential domain faces. ``rate`` (0 or 1): arr is a
    rate of change of the velocity (the traced acceleration), whose ghost beyond a moving wall or inlet is
    -a (its boundary value is steady), not the velocity's 2U - u."""
    n = g.dims
    J = I
    if g.wrap[a] == 1:
        J[a] = wrap(J[a], n[a])
    else:
        J[a] = ti.min(ti.max(J[a], 0), n[a])
    gh = ti.Vector([0, 0, 0])
    # run-time loops over the axes: unrolled, the ghost logic was inlined 3x into each of the ~7 interpolations
    # of the advection kernel, which then took 86 s to compile (43 s with this loop alone run-time)
    for b in range(3):
        if b != a and (J[b] < 0 or J[b] >= n[b]):
            if g.wrap[b] == 1:
                J[b] = wrap(J[b], n[b])
            else:
                gh[b] = -1 if J[b] < 0 else 1
                J[b] = ti.min(ti.max(J[b], 0), n[b] - 1)
    v = arr[fidx(g, a, J)]
    for b in range(3):
        if gh[b] != 0:
            al, ga = ghost_coef(g, inp, b, (gh[b] + 1) // 2, a, J)
            v = al * v + (1 - rate) * ga
    return v


@ti.func
def has_grad(g: ti.template(), a, I):
    """Face (a, I) carries a pressure gradient: open, and interior (not a periodic axis of
    length 1) or on a pressure outlet."""
    n = g.dims
    ok = g.aperture[fidx(g, a, I)] > 0.0
    if ok:
        if is_boundary(g, a, I):
            side = 0 if I[a] == 0 else 1
            ok = g.bc_kind[2 * a + side] == OUTLET
        elif g.wrap[a] == 1 and n[a] == 1:
            ok = False
    return ok


@ti.func
def _cell(g: ti.template(), src: ti.template(), flat: ti.template(), C):
    v = 0.0
    if ti.static(flat):
        v = src[cidx(g, C)]
    else:
        v = src[C]
    return v


@ti.func
def grad_across(g: ti.template(), src: ti.template(), flat: ti.template(), out0, out1, a, I):
    """Gradient across face (a, I) [1/m times src's unit] of the cell values src ((nx, ny, nz), or a cell
    vector indexed as :func:`cidx` when ``flat``), out0 / out1 the values beyond the - / + domain face
    (half a cell away); (0, False) on a face without a pressure gradient (:func:`has_grad`)."""
    h = g.par[P_H]
    gr = 0.0
    ok = has_grad(g, a, I)
    if ok:
        L, R, hL, hR = face_cells(g, a, I)
        if hL and hR:
            gr = (_cell(g, src, flat, R) - _cell(g, src, flat, L)) / h
        elif hR:
            gr = (_cell(g, src, flat, R) - out0) / (0.5 * h)
        else:
            gr = (out1 - _cell(g, src, flat, L)) / (0.5 * h)
    return gr, ok


@ti.func
def face_grad(g: ti.template(), cl: ti.template(), a, I):
    """Gradient of the full pressure (cl.pres, outlet pressures outside) across face (a, I) [Pa/m]."""
    return grad_across(g, cl.pres, False, g.par[P_POUT + 2 * a], g.par[P_POUT + 2 * a + 1], a, I)


#: the members of State the boundary preparation reads and writes
BcState = narrowed(State, "vel", "vel_adv", "dpred")


@kernel
def k_bc_prep(g: Grid, inp: EpsInputs, st: BcState, serial: ti.template()):
    """Boundary and closed faces of the advected field; the viscous iterates start from it."""
    one_task(serial, _bc_prep, (g, inp, st, serial))


@ti.func
def _bc_prep(g: ti.template(), inp: ti.template(), st: ti.template(), serial: ti.template()):
    each_face(g, g.nfaces, _bc_prep_at, (g, inp, st), serial)


@ti.func
def _bc_prep_at(c: ti.template(), f, a, I):
    _bc_prep_in(c[0], c[1], c[2], f, a, I)


@ti.func
def _bc_prep_in(g: ti.template(), inp: ti.template(), st: ti.template(), f, a, I):
    n = g.dims
    v = st.vel_adv[f]
    if g.aperture[f] <= 0.0:
        v = 0.0
    elif is_boundary(g, a, I):
        side = 0 if I[a] == 0 else 1
        kind = g.bc_kind[2 * a + side]
        if kind == INLET:
            t1, t2 = tangential(a)
            C = I
            C[a] = 0 if side == 0 else n[a] - 1
            v = g.bcv[g.bcv_off[2 * a + side] + (a * n[t1] + I[t1]) * n[t2] + I[t2]] / eps_at(inp, C)
        elif kind != OUTLET:
            v = 0.0
    st.vel_adv[f] = v
    if solved(g, f, a, I):
        v += st.dpred[f]  # initial iterate: last step's predictor increment (exact when steady)
    st.vel[f] = v


@ti.func
def periodic_twin(g: ti.template(), st: ti.template(), f, a, I):
    """A periodic grid's duplicate face f (index n along a periodic axis a) takes its twin's (index 0) velocity."""
    if g.wrap[a] == 1 and I[a] == g.dims[a]:
        J = I
        J[a] = 0
        st.vel[f] = st.vel[fidx(g, a, J)]


@kernel
def k_periodic_copy(g: Grid, st: State):
    """Periodic duplicates of the first faces and zero on closed faces (after the host set velocities)."""
    for f in range(g.nfaces):
        a, I = fdecode(g, f)
        periodic_twin(g, st, f, a, I)
        if g.aperture[f] <= 0.0:
            st.vel[f] = 0.0
