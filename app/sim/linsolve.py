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
* Preconditioner: one geometric-multigrid V-cycle. Coarsening halves every axis whose
  length is even and whose spacing is not already coarser than 1.5x the finest coupled
  axis (semi-coarsening keeps coarse cells near-cubic, e.g. 32x32x116 -> 16x16x58 ->
  8x8x29 -> 4x4x29); when no axis qualifies but the grid is still larger than
  ``min_coarse_cells``, any even axis is halved (-> 2x2x29 -> 1x1x29). Coarse
  transmissibility = (sum of the fine faces a coarse face covers) / (coarsening ratio
  normal to it), i.e. the arithmetic mean of the fine coefficients rediscretised at the
  coarse spacing. Transfer is piecewise constant (restriction sums the children,
  prolongation injects). Smoother: red-black Gauss-Seidel, two sweeps red->black going down
  and two black->red coming up (a symmetric cycle); levels with an odd periodic length,
  where red-black colouring is inconsistent, use damped Jacobi (weight 0.8).
* Coarsest level: Jacobi-preconditioned CG, a fixed number of iterations (the number of
  cells when that is small, so tiny coarse grids are solved exactly), run by one thread
  inside one kernel (the coarsest grid has tens of cells). When the dimensions do not halve
  far enough (coarsest grid > 512 cells, e.g. 33^3) it gets 4 parallel symmetric red-black
  double sweeps instead: still a valid preconditioner, but the outer iteration count then
  grows with the grid; choose dimensions with factors of 2.

Implementation: all state lives in two flat Taichi ndarrays (floats ``G``, ints ``M``)
and the kernels are module-level, so they compile once per process whatever the grid
(a new scene or test does not recompile). Every loop over cells is the outermost loop of
its kernel, so it runs in parallel on CPU and CUDA. The iteration's control (convergence, the
true-residual check, stagnation, max_iter) runs on the device: the host launches a batch of
iterations without waiting, each of which does nothing once the solve has stopped, and reads
one record per batch (:meth:`MGPCG.solve`; the gas solver reads it with its own step record).
"""
import dataclasses
import math
from typing import Sequence

import numpy as np
import taichi as ti

# ---- global slots of M
(O_T, O_DIAG, O_XS, O_BS, O_RS, O_X, O_R, O_Z, O_ZO, O_P, O_AP, O_B0, O_CP, O_CAP, O_DVAL, O_SC,
 O_NLEV, O_PX, O_PY, O_PZ, O_NC0, O_CIT, O_TOTAL) = range(23)
LBASE = 32
NMETA = 16
# ---- per-level slots (LBASE + NMETA*l + ...)
L_NX, L_NY, L_NZ, L_CO, L_FOX, L_FOY, L_FOZ, L_RX, L_RY, L_RZ, L_NCELL = range(11)
# ---- scalars (G[M[O_SC] + ...])
S_RZ, S_RZN, S_RZO, S_PAP, S_RINF, S_SUM, S_CNT, S_BNORM = range(8)
# the solve's state, kept on the device so that the host launches iterations without waiting on them
# (S_ACTIVE 1 while iterating; S_FIRST restart the flexible CG; S_LAST the last true residual, -1 none yet;
# S_DONE 1 once the solution is final (zero mean taken); S_SCALE the residual scale, S_THR = tol * scale)
S_ACTIVE, S_IT, S_THR, S_LAST, S_FIRST, S_R0, S_SCALE, S_CONV, S_TRUE, S_DONE = range(8, 18)
NSCAL = 24

PRE_SWEEPS = 2
POST_SWEEPS = 2
COARSE_SERIAL_MAX = 512  # largest coarsest grid solved by the one-thread CG
COARSE_SMOOTH_SWEEPS = 4  # symmetric red-black double sweeps on a larger coarsest grid
JACOBI_WEIGHT = 0.8

ND = ti.types.ndarray()


@dataclasses.dataclass(frozen=True)
class SolveInfo:
    """Outcome of one solve: outer iterations, final ``max|r| / scale``, whether it reached tol."""

    iterations: int
    residual: float
    converged: bool
    scale: float
    initial_residual: float


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


# ============================================================================ Taichi functions
@ti.func
def _lm(M: ti.template(), l, q):
    return M[LBASE + NMETA * l + q]


@ti.func
def _dims(M: ti.template(), l):
    return ti.Vector([_lm(M, l, L_NX), _lm(M, l, L_NY), _lm(M, l, L_NZ)])


@ti.func
def _ratio(M: ti.template(), l):
    return ti.Vector([_lm(M, l, L_RX), _lm(M, l, L_RY), _lm(M, l, L_RZ)])


@ti.func
def _on(G: ti.template(), M: ti.template()):
    """1 while the solve iterates, else 0: every loop of an iteration runs over _on * cells, so
    launches after convergence (the host launches a fixed count without waiting) do nothing."""
    return ti.cast(G[M[O_SC] + S_ACTIVE] > 0.0, ti.i32)


@ti.func
def _ncell(G: ti.template(), M: ti.template(), l):
    return _lm(M, l, L_NCELL) * _on(G, M)


@ti.func
def _local(n, I):
    """Local (level-relative) cell index of I in a grid of dims n."""
    return (I[0] * n[1] + I[1]) * n[2] + I[2]


@ti.func
def _decode(n, c):
    return ti.Vector([c // (n[1] * n[2]), (c // n[2]) % n[1], c % n[2]])


@ti.func
def _face(M: ti.template(), l, a, I):
    """Absolute index into G of the face of axis a with (face) index I at level l."""
    d = _dims(M, l)
    d[a] += 1
    return _lm(M, l, L_FOX + a) + (I[0] * d[1] + I[1]) * d[2] + I[2]


@ti.func
def _stencil(G: ti.template(), M: ti.template(), l, vb, I, affine: ti.template()):
    """(diag, sum T x_nb, sum T (x_c - x_nb)) at cell I of level l for the vector stored at G[vb + local]."""
    n = _dims(M, l)
    xc = G[vb + _local(n, I)]
    d = 0.0
    s = 0.0
    ax = 0.0
    for a in ti.static(range(3)):
        for side in ti.static(range(2)):
            F = I
            F[a] += side
            t = G[_face(M, l, a, F)]
            if t != 0.0:
                J = I
                J[a] += 2 * side - 1
                xn = 0.0
                inside = (J[a] >= 0) and (J[a] < n[a])
                if (not inside) and M[O_PX + a] == 1:
                    J[a] = (J[a] + n[a]) % n[a]
                    inside = True
                if inside:
                    xn = G[vb + _local(n, J)]
                else:
                    if ti.static(affine):
                        xn = G[M[O_DVAL] + 2 * a + side]
                d += t
                s += t * xn
                ax += t * (xc - xn)
    return d, s, ax


@ti.func
def _level_diag(G: ti.template(), M: ti.template(), l):
    n = _dims(M, l)
    co = M[O_DIAG] + _lm(M, l, L_CO)
    for c in range(_lm(M, l, L_NCELL)):
        I = _decode(n, c)
        d = 0.0
        for a in ti.static(range(3)):
            for side in ti.static(range(2)):
                F = I
                F[a] += side
                d += G[_face(M, l, a, F)]
        G[co + c] = d


@ti.func
def _rb_sweep(G: ti.template(), M: ti.template(), l, color):
    n = _dims(M, l)
    co = _lm(M, l, L_CO)
    xb = M[O_XS] + co
    for c in range(_ncell(G, M, l)):
        I = _decode(n, c)
        if (I[0] + I[1] + I[2]) % 2 == color and G[M[O_DIAG] + co + c] > 0.0:
            d, s, _ = _stencil(G, M, l, xb, I, False)
            G[xb + c] = (G[M[O_BS] + co + c] + s) / d


@ti.func
def _residual(G: ti.template(), M: ti.template(), l):
    n = _dims(M, l)
    co = _lm(M, l, L_CO)
    xb = M[O_XS] + co
    for c in range(_ncell(G, M, l)):
        r = 0.0
        if G[M[O_DIAG] + co + c] > 0.0:
            I = _decode(n, c)
            _, _, ax = _stencil(G, M, l, xb, I, False)
            r = G[M[O_BS] + co + c] - ax
        G[M[O_RS] + co + c] = r


@ti.func
def _jacobi_sweep(G: ti.template(), M: ti.template(), l):
    _residual(G, M, l)
    co = _lm(M, l, L_CO)
    for c in range(_ncell(G, M, l)):
        dg = G[M[O_DIAG] + co + c]
        if dg > 0.0:
            G[M[O_XS] + co + c] += JACOBI_WEIGHT * G[M[O_RS] + co + c] / dg


@ti.func
def _zero_x(G: ti.template(), M: ti.template(), l):
    co = _lm(M, l, L_CO)
    for c in range(_ncell(G, M, l)):
        G[M[O_XS] + co + c] = 0.0


@ti.func
def _restrict(G: ti.template(), M: ti.template(), l):
    L = l + 1
    r = _ratio(M, l)
    n = _dims(M, l)
    N = _dims(M, L)
    rb = M[O_RS] + _lm(M, l, L_CO)
    cb = M[O_BS] + _lm(M, L, L_CO)
    for C in range(_ncell(G, M, L)):
        K = _decode(N, C)
        s = 0.0
        for d in range(8):
            o = ti.Vector([d & 1, (d >> 1) & 1, (d >> 2) & 1])
            if o[0] < r[0] and o[1] < r[1] and o[2] < r[2]:
                s += G[rb + _local(n, K * r + o)]
        G[cb + C] = s


@ti.func
def _prolong(G: ti.template(), M: ti.template(), l):
    L = l + 1
    r = _ratio(M, l)
    n = _dims(M, l)
    N = _dims(M, L)
    co = _lm(M, l, L_CO)
    xb = M[O_XS] + co
    cb = M[O_XS] + _lm(M, L, L_CO)
    for c in range(_ncell(G, M, l)):
        if G[M[O_DIAG] + co + c] > 0.0:
            K = _decode(n, c) // r
            G[xb + c] += G[cb + _local(N, K)]


# ============================================================================ kernels
@ti.kernel
def _k_diag(G: ND, M: ND, l: ti.i32):
    _level_diag(G, M, l)


@ti.kernel
def _k_coarsen(G: ND, M: ND, l: ti.i32):
    """Transmissibilities and diagonal of level l+1 from level l."""
    L = l + 1
    r = _ratio(M, l)
    N = _dims(M, L)
    for a in ti.static(range(3)):
        nfa = N
        nfa[a] += 1
        b1 = ti.static((a + 1) % 3)
        b2 = ti.static((a + 2) % 3)
        for c in range(nfa[0] * nfa[1] * nfa[2]):
            K = _decode(nfa, c)
            s = 0.0
            for d in range(4):
                o1 = d & 1
                o2 = (d >> 1) & 1
                if o1 < r[b1] and o2 < r[b2]:
                    F = K * r
                    F[b1] += o1
                    F[b2] += o2
                    s += G[_face(M, l, a, F)]
            s /= r[a]
            if M[O_PX + a] == 1 and N[a] == 1:
                s = 0.0
            G[_face(M, L, a, K)] = s
    _level_diag(G, M, L)


@ti.kernel
def _k_down(G: ND, M: ND, l: ti.i32):
    _zero_x(G, M, l)
    for _s in ti.static(range(PRE_SWEEPS)):
        _rb_sweep(G, M, l, 0)
        _rb_sweep(G, M, l, 1)
    _residual(G, M, l)
    _restrict(G, M, l)


@ti.kernel
def _k_down_j(G: ND, M: ND, l: ti.i32):
    _zero_x(G, M, l)
    for _s in ti.static(range(PRE_SWEEPS)):
        _jacobi_sweep(G, M, l)
    _residual(G, M, l)
    _restrict(G, M, l)


@ti.kernel
def _k_up(G: ND, M: ND, l: ti.i32):
    _prolong(G, M, l)
    for _s in ti.static(range(POST_SWEEPS)):
        _rb_sweep(G, M, l, 1)
        _rb_sweep(G, M, l, 0)


@ti.kernel
def _k_up_j(G: ND, M: ND, l: ti.i32):
    _prolong(G, M, l)
    for _s in ti.static(range(POST_SWEEPS)):
        _jacobi_sweep(G, M, l)


@ti.kernel
def _k_coarse(G: ND, M: ND, l: ti.i32, singular: ti.i32):
    """Jacobi-PCG on the (tiny) coarsest level, by one thread (none once the solve has stopped)."""
    for _t in range(_on(G, M)):
        n = _dims(M, l)
        nc = _lm(M, l, L_NCELL)
        co = _lm(M, l, L_CO)
        db = M[O_DIAG] + co
        xb = M[O_XS] + co
        bb = M[O_BS] + co
        rb = M[O_RS] + co
        pb = M[O_CP]
        qb = M[O_CAP]
        mean = 0.0
        if singular:
            cnt = 0.0
            for c in range(nc):
                if G[db + c] > 0.0:
                    mean += G[bb + c]
                    cnt += 1.0
            if cnt > 0.0:
                mean /= cnt
        rz = 0.0
        for c in range(nc):
            r = 0.0
            z = 0.0
            if G[db + c] > 0.0:
                r = G[bb + c] - mean
                z = r / G[db + c]
            G[rb + c] = r
            G[xb + c] = 0.0
            G[pb + c] = z
            rz += r * z
        for _it in range(M[O_CIT]):
            pap = 0.0
            for c in range(nc):
                ap = 0.0
                if G[db + c] > 0.0:
                    _, _, ax = _stencil(G, M, l, pb, _decode(n, c), False)
                    ap = ax
                G[qb + c] = ap
                pap += ap * G[pb + c]
            if pap > 0.0 and rz > 0.0:
                alpha = rz / pap
                rzn = 0.0
                for c in range(nc):
                    G[xb + c] += alpha * G[pb + c]
                    G[rb + c] -= alpha * G[qb + c]
                    if G[db + c] > 0.0:
                        rzn += G[rb + c] * G[rb + c] / G[db + c]
                beta = rzn / rz
                for c in range(nc):
                    z = 0.0
                    if G[db + c] > 0.0:
                        z = G[rb + c] / G[db + c]
                    G[pb + c] = z + beta * G[pb + c]
                rz = rzn


@ti.kernel
def _k_coarse_smooth(G: ND, M: ND, l: ti.i32, first: ti.i32):
    """Large coarsest level (dimensions that do not halve): symmetric red-black sweeps in parallel
    instead of the one-thread CG."""
    if first:
        _zero_x(G, M, l)
    _rb_sweep(G, M, l, 0)
    _rb_sweep(G, M, l, 1)
    _rb_sweep(G, M, l, 1)
    _rb_sweep(G, M, l, 0)


@ti.func
def _true_residual(G: ti.template(), M: ti.template(), nc):
    """r = b - A x (affine, with the Dirichlet values) over the first nc cells (nc = 0: nothing);
    max|r| into S_TRUE. It also feeds the next V-cycle (BS)."""
    n = _dims(M, 0)
    sc = M[O_SC]
    G[sc + S_TRUE] = 0.0
    for c in range(nc):
        r = 0.0
        if G[M[O_DIAG] + c] > 0.0:
            _, _, ax = _stencil(G, M, 0, M[O_X], _decode(n, c), True)
            r = G[M[O_B0] + c] - ax
            ti.atomic_max(G[sc + S_TRUE], ti.abs(r))
        else:
            G[M[O_X] + c] = 0.0
        G[M[O_R] + c] = r
        G[M[O_BS] + c] = r


@ti.kernel
def _k_pcg_begin(G: ND, M: ND, singular: ti.i32, tol: float, scale_mode: ti.i32, scale: float):
    """Project b (singular case), measure max|b|, r = b - A x; the stopping threshold tol * scale with
    scale = max|b| (scale_mode 0), the argument (1) or G[S_SCALE] as a caller's kernel left it (2);
    the solve is active unless r already meets it."""
    nc = M[O_NC0]
    sc = M[O_SC]
    G[sc + S_SUM] = 0.0
    G[sc + S_CNT] = 0.0
    for c in range(nc):
        if singular and G[M[O_DIAG] + c] > 0.0:
            G[sc + S_SUM] += G[M[O_B0] + c]
            G[sc + S_CNT] += 1.0
    G[sc + S_BNORM] = 0.0
    for c in range(nc):
        if G[M[O_DIAG] + c] > 0.0:
            if singular and G[sc + S_CNT] > 0.0:
                G[M[O_B0] + c] -= G[sc + S_SUM] / G[sc + S_CNT]
            ti.atomic_max(G[sc + S_BNORM], ti.abs(G[M[O_B0] + c]))
    _true_residual(G, M, nc)
    if scale_mode == 0:
        G[sc + S_SCALE] = G[sc + S_BNORM]
    elif scale_mode == 1:
        G[sc + S_SCALE] = scale
    G[sc + S_THR] = tol * G[sc + S_SCALE]
    G[sc + S_R0] = G[sc + S_TRUE]
    G[sc + S_RINF] = G[sc + S_TRUE]
    G[sc + S_IT] = 0.0
    G[sc + S_LAST] = -1.0
    G[sc + S_FIRST] = 1.0
    G[sc + S_DONE] = 0.0
    conv = G[sc + S_TRUE] <= G[sc + S_THR]
    G[sc + S_CONV] = ti.select(conv, 1.0, 0.0)
    G[sc + S_ACTIVE] = ti.select(conv, 0.0, 1.0)


@ti.kernel
def _k_pcg_from(G: ND, M: ND, singular: ti.i32):
    """z = V-cycle output (zero mean if singular); new search direction (flexible CG; a restart
    when S_FIRST is set). Nothing once the solve has stopped."""
    nc = M[O_NC0] * _on(G, M)
    sc = M[O_SC]
    G[sc + S_SUM] = 0.0
    G[sc + S_CNT] = 0.0
    for c in range(nc):
        if singular and G[M[O_DIAG] + c] > 0.0:
            G[sc + S_SUM] += G[M[O_XS] + c]
            G[sc + S_CNT] += 1.0
    G[sc + S_RZN] = 0.0
    G[sc + S_RZO] = 0.0
    for c in range(nc):
        m = 0.0
        if singular and G[sc + S_CNT] > 0.0:
            m = G[sc + S_SUM] / G[sc + S_CNT]
        z = 0.0
        if G[M[O_DIAG] + c] > 0.0:
            z = G[M[O_XS] + c] - m
        zo = G[M[O_Z] + c]
        G[M[O_ZO] + c] = zo
        G[M[O_Z] + c] = z
        r = G[M[O_R] + c]
        G[sc + S_RZN] += r * z
        G[sc + S_RZO] += r * zo
    for c in range(nc):
        beta = 0.0
        if G[sc + S_FIRST] == 0.0 and G[sc + S_RZ] != 0.0:
            beta = (G[sc + S_RZN] - G[sc + S_RZO]) / G[sc + S_RZ]
        G[M[O_P] + c] = G[M[O_Z] + c] + beta * G[M[O_P] + c]
    if nc > 0:
        G[sc + S_RZ] = G[sc + S_RZN]


@ti.kernel
def _k_pcg_iter(G: ND, M: ND, max_iter: ti.i32):
    """One outer iteration, decided on the device: x += alpha p, r -= alpha A p; when the recursive
    residual meets the threshold, the true residual b - A x is measured: converged if it meets it
    too, stagnated (stop, the caller may refine) if it did not halve since the last such check,
    else a restart from it. Stops at max_iter. Nothing once the solve has stopped."""
    n = _dims(M, 0)
    nc = M[O_NC0] * _on(G, M)
    sc = M[O_SC]
    G[sc + S_PAP] = 0.0
    for c in range(nc):
        ap = 0.0
        if G[M[O_DIAG] + c] > 0.0:
            _, _, ax = _stencil(G, M, 0, M[O_P], _decode(n, c), False)
            ap = ax
        G[M[O_AP] + c] = ap
        G[sc + S_PAP] += ap * G[M[O_P] + c]
    G[sc + S_TRUE] = 0.0
    for c in range(nc):
        alpha = 0.0
        if G[sc + S_PAP] > 0.0:
            alpha = G[sc + S_RZ] / G[sc + S_PAP]
        G[M[O_X] + c] += alpha * G[M[O_P] + c]
        r = G[M[O_R] + c] - alpha * G[M[O_AP] + c]
        G[M[O_R] + c] = r
        G[M[O_BS] + c] = r
        if G[M[O_DIAG] + c] > 0.0:
            ti.atomic_max(G[sc + S_TRUE], ti.abs(r))
    cand = 0
    if nc > 0:
        G[sc + S_IT] += 1.0
        G[sc + S_RINF] = G[sc + S_TRUE]
        G[sc + S_FIRST] = 0.0
        if G[sc + S_RINF] <= G[sc + S_THR]:
            cand = 1
    # the recursively updated residual drifts from b - A x in float32: confirm with the true one
    _true_residual(G, M, M[O_NC0] * cand)
    if cand == 1:
        t = G[sc + S_TRUE]
        G[sc + S_RINF] = t
        if t <= G[sc + S_THR]:
            G[sc + S_CONV] = 1.0
            G[sc + S_ACTIVE] = 0.0
        elif G[sc + S_LAST] >= 0.0 and t > 0.5 * G[sc + S_LAST]:
            G[sc + S_ACTIVE] = 0.0  # stagnated at the precision floor: let the caller refine
        else:
            G[sc + S_LAST] = t
            G[sc + S_FIRST] = 1.0
    if nc > 0 and G[sc + S_IT] >= ti.cast(max_iter, float):
        G[sc + S_ACTIVE] = 0.0


@ti.kernel
def _k_pcg_finish(G: ND, M: ND, singular: ti.i32):
    """Once the solve has stopped (and only once): the zero-mean solution of a singular system."""
    sc = M[O_SC]
    fin = 0
    if G[sc + S_ACTIVE] == 0.0 and G[sc + S_DONE] == 0.0:
        fin = 1
    nc = M[O_NC0] * fin * singular
    G[sc + S_SUM] = 0.0
    G[sc + S_CNT] = 0.0
    for c in range(nc):
        if G[M[O_DIAG] + c] > 0.0:
            G[sc + S_SUM] += G[M[O_X] + c]
            G[sc + S_CNT] += 1.0
    for c in range(nc):
        m = 0.0
        if G[sc + S_CNT] > 0.0:
            m = G[sc + S_SUM] / G[sc + S_CNT]
        if G[M[O_DIAG] + c] > 0.0:
            G[M[O_X] + c] -= m
    if fin == 1:
        G[sc + S_DONE] = 1.0


@ti.func
def solve_record(G: ti.template(), M: ti.template()):
    """(iterations, max|r|, converged, scale, initial max|r|, done) of the current solve."""
    sc = M[O_SC]
    return ti.Vector([G[sc + S_IT], G[sc + S_RINF], G[sc + S_CONV], G[sc + S_SCALE], G[sc + S_R0],
                      G[sc + S_DONE]])


@ti.kernel
def _k_record(G: ND, M: ND) -> ti.types.vector(6, ti.f64):
    return solve_record(G, M)


# ---- host <-> level-0 transfer (used by tests and by callers without their own kernels)
@ti.kernel
def _k_set_faces(G: ND, M: ND, a: ti.i32, src: ND):
    # loop bounds built without a dynamic-index store (Taichi 1.7.4 gets ndrange bounds wrong
    # after ``d[a] += 1`` with a runtime a)
    n = _dims(M, 0)
    for i, j, k in ti.ndrange(n[0] + (a == 0), n[1] + (a == 1), n[2] + (a == 2)):
        G[_face(M, 0, a, ti.Vector([i, j, k]))] = src[i, j, k]


@ti.kernel
def _k_set_cells(G: ND, M: ND, slot: ti.i32, src: ND):
    n = _dims(M, 0)
    for i, j, k in ti.ndrange(n[0], n[1], n[2]):
        G[M[slot] + _local(n, ti.Vector([i, j, k]))] = src[i, j, k]


@ti.kernel
def _k_get_cells(G: ND, M: ND, slot: ti.i32, dst: ND):
    n = _dims(M, 0)
    for i, j, k in ti.ndrange(n[0], n[1], n[2]):
        dst[i, j, k] = G[M[slot] + _local(n, ti.Vector([i, j, k]))]


@ti.kernel
def _k_get_faces(G: ND, M: ND, a: ti.i32, dst: ND):
    n = _dims(M, 0)
    for i, j, k in ti.ndrange(n[0] + (a == 0), n[1] + (a == 1), n[2] + (a == 2)):
        dst[i, j, k] = G[_face(M, 0, a, ti.Vector([i, j, k]))]


class MGPCG:
    """Multigrid-preconditioned CG on a (nx, ny, nz) cell grid (state in flat ndarrays ``G``/``M``).

    Level-0 layout, for callers that fill the system inside their own kernels (pass ``G`` and
    ``M`` and use the Taichi functions of this module):
      * faces of axis a, index (i, j, k) within (n_a + 1 along a):  ``_face(M, 0, a, I)``;
      * transmissibility there: ``G[_face(...)]``; cell c = (i*ny + j)*nz + k:
        right-hand side ``G[M[O_B0] + c]``, solution / initial guess ``G[M[O_X] + c]``.
    Host helpers :meth:`set_system`, :meth:`solution` do the same from numpy.
    """

    def __init__(self, shape: Sequence[int], periodic: Sequence[bool] = (False, False, False), *,
                 min_coarse_cells: int = 8, max_levels: int = 16, coarse_iterations: int | None = None):
        self.shape = tuple(int(n) for n in shape)
        if len(self.shape) != 3 or min(self.shape) < 1:
            raise ValueError(f"grid shape must be three positive ints, got {shape!r}")
        self.periodic = tuple(bool(p) for p in periodic)
        plan = plan_levels(self.shape, int(min_coarse_cells), int(max_levels))
        self.nlevels = len(plan)
        self.level_shapes = [lv["shape"] for lv in plan]
        self.level_jacobi = [any(self.periodic[a] and s[a] > 1 and s[a] % 2 == 1 for a in range(3))
                             for s in self.level_shapes]
        meta = np.zeros(LBASE + NMETA * self.nlevels, np.int32)
        # faces of every level first
        off = 0
        co = 0
        for l, lv in enumerate(plan):
            s = lv["shape"]
            base = LBASE + NMETA * l
            meta[base + L_NX:base + L_NZ + 1] = s
            meta[base + L_RX:base + L_RZ + 1] = lv["ratio"]
            meta[base + L_NCELL] = int(np.prod(s))
            meta[base + L_CO] = co
            co += int(np.prod(s))
            for a in range(3):
                fs = list(s)
                fs[a] += 1
                meta[base + L_FOX + a] = off
                off += int(np.prod(fs))
        ncells_all = co
        n0 = int(np.prod(self.shape))
        ncoarse = int(np.prod(plan[-1]["shape"]))

        def alloc(n):
            nonlocal off
            o = off
            off += n
            return o

        meta[O_T] = 0
        meta[O_DIAG] = alloc(ncells_all)
        meta[O_XS] = alloc(ncells_all)
        meta[O_BS] = alloc(ncells_all)
        meta[O_RS] = alloc(ncells_all)
        for slot in (O_X, O_R, O_Z, O_ZO, O_P, O_AP, O_B0):
            meta[slot] = alloc(n0)
        meta[O_CP] = alloc(ncoarse)
        meta[O_CAP] = alloc(ncoarse)
        meta[O_DVAL] = alloc(6)
        meta[O_SC] = alloc(NSCAL)
        meta[O_NLEV] = self.nlevels
        meta[O_PX:O_PZ + 1] = self.periodic
        meta[O_NC0] = n0
        if coarse_iterations is None:
            coarse_iterations = min(ncoarse, max(8, 3 * max(plan[-1]["shape"])), 100)
        self.coarse_iterations = int(coarse_iterations)
        # a coarsest grid too large for one thread (dimensions that do not halve, e.g. 33^3) is
        # smoothed in parallel instead; the outer CG then needs more iterations (choose grid
        # dimensions with factors of 2 for multigrid efficiency)
        self.coarse_parallel = ncoarse > COARSE_SERIAL_MAX
        meta[O_CIT] = self.coarse_iterations
        meta[O_TOTAL] = off
        self._meta_np = meta
        self.M = ti.ndarray(ti.i32, shape=meta.shape)
        self.M.from_numpy(meta)
        self.G = ti.ndarray(float, shape=(off,))
        self.G.fill(0.0)
        self.last: SolveInfo | None = None
        self._singular = False
        self._max_iter = 0
        self._launched = 0

    # ---------------------------------------------------------------- host helpers
    def offset(self, slot: int) -> int:
        return int(self._meta_np[slot])

    def set_system(self, tx=None, ty=None, tz=None, b=None, x0=None) -> None:
        """Copy level-0 transmissibilities / right-hand side / initial guess from numpy."""
        for a, t in enumerate((tx, ty, tz)):
            if t is not None:
                fs = list(self.shape)
                fs[a] += 1
                t = np.ascontiguousarray(t, dtype=np.float64)
                if t.shape != tuple(fs):
                    raise ValueError(f"transmissibility of axis {a} must have shape {tuple(fs)}, got {t.shape}")
                _k_set_faces(self.G, self.M, a, t)
        for slot, v in ((O_B0, b), (O_X, x0)):
            if v is not None:
                v = np.ascontiguousarray(np.broadcast_to(np.asarray(v, np.float64), self.shape))
                _k_set_cells(self.G, self.M, slot, v)

    def solution(self) -> np.ndarray:
        out = np.zeros(self.shape)
        _k_get_cells(self.G, self.M, O_X, out)
        return out

    def rhs(self) -> np.ndarray:
        out = np.zeros(self.shape)
        _k_get_cells(self.G, self.M, O_B0, out)
        return out

    def transmissibility(self, a: int) -> np.ndarray:
        fs = list(self.shape)
        fs[a] += 1
        out = np.zeros(fs)
        _k_get_faces(self.G, self.M, a, out)
        return out

    def set_dirichlet(self, values: Sequence[float]) -> None:
        """Outside value of each domain face (x-, x+, y-, y+, z-, z+) where its T > 0."""
        dv = np.asarray(values, np.float64)
        if dv.shape != (6,):
            raise ValueError(f"dirichlet needs 6 values (x-, x+, y-, y+, z-, z+), got shape {dv.shape}")
        o = self.offset(O_DVAL)
        for i, v in enumerate(dv):
            self.G[o + i] = float(v)

    # ---------------------------------------------------------------- solve
    def _vcycle(self) -> None:
        L = self.nlevels - 1
        for l in range(L):
            (_k_down_j if self.level_jacobi[l] else _k_down)(self.G, self.M, l)
        if self.coarse_parallel:
            for k in range(COARSE_SMOOTH_SWEEPS):
                _k_coarse_smooth(self.G, self.M, L, int(k == 0))
        else:
            _k_coarse(self.G, self.M, L, int(self._singular))
        for l in reversed(range(L)):
            (_k_up_j if self.level_jacobi[l] else _k_up)(self.G, self.M, l)

    def begin(self, tol: float, max_iter: int, *, singular: bool = False, scale: float | None = None,
              device_scale: bool = False) -> None:
        """Start a solve of A x = b (level-0 T, b, x already in ``G``) from the current x; launches only
        (nothing is read back). ``scale``: see :meth:`solve`; ``device_scale``: a caller's kernel has
        written the scale into the solver's scalars (``G[M[O_SC] + S_SCALE]``)."""
        if not (tol > 0.0):
            raise ValueError(f"tolerance must be > 0, got {tol}")
        G, M = self.G, self.M
        self._singular = bool(singular)
        self._max_iter = int(max_iter)
        self._launched = 0
        _k_diag(G, M, 0)
        for l in range(self.nlevels - 1):
            _k_coarsen(G, M, l)
        mode = 2 if device_scale else (0 if scale is None else 1)
        _k_pcg_begin(G, M, int(self._singular), float(tol), mode, float(scale or 0.0))
        self._vcycle()
        _k_pcg_from(G, M, int(self._singular))

    def launch(self, iterations: int) -> None:
        """Queue up to ``iterations`` more outer iterations (each stops itself on the device once the
        solve has converged, stagnated or reached max_iter), then the final zero-mean step (once)."""
        n = max(0, min(int(iterations), self._max_iter - self._launched))
        sg = int(self._singular)
        for _ in range(n):
            _k_pcg_iter(self.G, self.M, self._max_iter)
            self._vcycle()
            _k_pcg_from(self.G, self.M, sg)
        self._launched += n
        _k_pcg_finish(self.G, self.M, sg)

    @property
    def exhausted(self) -> bool:
        """Every iteration up to max_iter has been launched."""
        return self._launched >= self._max_iter

    def budget(self) -> int:
        """Iterations to launch before the first look: the last solve's count and half as many more
        (at least 4 more). The launches past convergence do nothing on the device; a solve that
        needs more gets further batches, each with one more read."""
        last = self.last.iterations if self.last is not None else 8
        return max(4, last + max(4, last // 2))

    def info_from(self, rec) -> SolveInfo:
        """A :class:`SolveInfo` from a record (:func:`solve_record`) read from the device."""
        it, rinf, conv, scale, r0 = (float(x) for x in rec[:5])
        if scale > 0:
            rel, rel0 = rinf / scale, r0 / scale
        else:
            rel, rel0 = (0.0 if rinf == 0 else math.inf), (0.0 if r0 == 0 else math.inf)
        info = SolveInfo(int(round(it)), rel, bool(conv > 0.5), scale, rel0)
        self.last = info
        return info

    def solve(self, tol: float = 1e-6, max_iter: int = 200, *, singular: bool = False,
              scale: float | None = None) -> SolveInfo:
        """Solve A x = b (level-0 T, b, x already in ``G``) from the current x.

        Stops when ``max|b - A x| <= tol * scale``; ``scale`` defaults to ``max|b|`` (after the
        zero-mean projection when ``singular``). ``singular``: no Dirichlet face at all (pure
        Neumann/periodic): b is projected onto zero mean and x returned with zero mean.
        The iterations are launched in batches (:meth:`budget`) and their convergence is decided on
        the device; the host reads one record per batch (one in all when the budget suffices).
        Returns a :class:`SolveInfo` (also kept as ``last``).
        """
        self.begin(tol, max_iter, singular=singular, scale=scale)
        n = self.budget()
        while True:
            self.launch(n)
            rec = _k_record(self.G, self.M)
            if rec[5] > 0.5 or self.exhausted:
                break
            n = max(4, n // 2)
        return self.info_from(rec)
