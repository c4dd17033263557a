"""Gas solver of fbed: volume-averaged incompressible gas on a uniform staggered grid.

Owns: the gas flow set-up (:class:`FlowConfig`, boundary conditions :class:`BC`), the solver
(:class:`FlowSolver`: one fractional step per call of :meth:`FlowSolver.step`), the Taichi
field bundle shared with the coupling code (:class:`GasFields`). (The lid-driven cavity, a
verification scene, is set up with the accuracy cases, :mod:`app.accuracy.gas_cases`.) It knows nothing about particles: the coupling code
writes the gas fraction, its rate of change and the drag coefficients into the bundle.

Equations (u = interstitial gas velocity, eps = gas volume fraction, m = 1 for the
"shared" pressure form, Model A, and m = 0 for the "gas" form, Model B)::

    d(eps)/dt + div(eps u) = 0
    rho eps (du/dt + u.grad u) = -eps^m grad p + div(eps mu grad u) + rho eps g
                                 + beta (u_s - u) + f

This is the non-conservative (advective) form: it equals the conservative form
d(rho eps u)/dt + div(rho eps u u) minus u times continuity, so it needs no time
derivative of eps and keeps the momentum predictor a plain per-face update, whatever eps
does. Simplification (documented as agreed): the viscous stress is the eps-weighted
Laplacian div(eps mu grad u); the transpose and dilatational parts of the volume-averaged
stress, which vanish for uniform eps, are dropped. p is the full (gauge) pressure, gas
weight included. With "shared" the grains must also feel -V_p grad p (``GasFields.grad_p``);
with "gas" they must not.

Discretisation
--------------
* MAC grid (:mod:`app.sim.gasgrid`): u, v, w on faces, p and eps on cells; z vertical.
  Face values of eps, u_s and f are the means of the two cells; the face drag coefficient is
  beta_f = eps_f^(m+1) * mean(beta/eps^(m+1)), the series resistance of the two half-cells, so
  the pressure drop of a 1-D flow through any eps/beta layering is exact.
* Convection: semi-Lagrangian back-tracing (RK2 midpoint trajectory, trilinear
  interpolation of each MAC component, ghost values across domain faces), optionally with
  the MacCormack correction clamped to the values of the interpolation stencil (Selle et
  al. 2008): unconditionally stable (a 50 m/s jet on 6 mm cells at dt = 1e-3 s, CFL ~ 8,
  is fine), second order in smooth flow, first order where clamped. Selectable:
  "maccormack" (default), "semi_lagrangian", "none" (Stokes flow).
  Second-order splitting: dt/2 a is added at the departure point and taken off at the
  arrival face (the plain semi-Lagrangian trace of a, outside the MacCormack correction:
  corrected together with u it fed back on itself and blew up), where a is the last step's non-advective acceleration
  (u^n - u~^(n-1))/dt weighted by the inertial share rho eps/(rho eps + beta dt) of the
  face. This is the trapezoidal rule for the forces along the path; without it the
  pressure impulse integrated along a curved trajectory is not a gradient and the
  projection leaves an O(dt) error (Taylor-Green energy decayed 10% too fast at CFL 0.4).
  The weight switches it off where drag balances the pressure gradient (bed surfaces).
* Predictor (per face, backward Euler, incremental pressure)::

      (rho eps/dt + beta) u* - div(eps mu grad u*) = rho eps/dt u~ - eps^m grad p^n
                                                     + rho eps g + f + beta u_s

  solved in place by red-black Gauss-Seidel sweeps (the viscous stencil couples a face
  only to faces of the other parity) from the last step's predictor increment as initial
  iterate (exact in a steady state), until the change is below 1e-6 of the velocity scale
  (at most ``max_viscous_sweeps``). beta and every wall term sit on the diagonal, so huge
  beta (packed beds) is stable and drives u* to u_s.
* Projection (incremental): u = u* - kappa grad phi, p^(n+1) = p^n + phi, with
  kappa = eps^m / (rho eps/dt + beta) on faces. Cell continuity
  theta d(eps)/dt + (1/h) sum_faces (+-) a eps_f u_f = 0 (a = face aperture, theta = open
  volume fraction) gives the variable-coefficient Poisson equation
  sum T_f (phi_c - phi_nb) = -div(eps u*) - theta d(eps)/dt, T_f = a eps_f kappa_f / h^2,
  solved by :class:`app.sim.linsolve.MGPCG` (multigrid-preconditioned CG) to ``tol``.
  The incremental form keeps a fluid at rest in hydrostatic balance (no splitting error at
  no-slip walls) and makes steady states independent of dt. The very first step is taken
  twice: once from p = 0 to find a consistent pressure (its velocity is discarded), then
  for real (skip with :meth:`FlowSolver.set_pressure`). At a pressure outlet the predicted
  velocity is the first interior face's with its pressure push swapped for the outlet
  face's own, so a steady state extrapolates p linearly to the outlet value.
* Divergence after projection: max_c |theta eps_t + (1/h) sum a eps_f u_f| <= tol * S,
  where S is the largest gross face-flux rate of a cell, (1/h) sum a eps_f |u_f| +
  theta |eps_t|, over the predicted or the corrected field (whichever is larger).
  :meth:`FlowSolver.divergence_residual` returns that ratio.

Boundary conditions (per domain face: x-, x+, y-, y+, z-, z+; aliases bottom = z-,
top = z+; a face not given is a no-slip wall)
------------------------------------------------------------------------------
* ``wall``: zero normal velocity; tangential ghost value -u (zero at the face).
* ``moving_wall(U)``: as wall, tangential ghost 2U - u (for the lid-driven cavity).
* ``free_slip``: zero normal velocity, tangential ghost u (zero shear).
* ``velocity_inlet(U)``: U is a superficial velocity vector (flux per unit open area);
  the face carries U_n/eps. A per-cell profile (n1, n2) or (n1, n2, 3) can replace it at
  any step (:meth:`FlowSolver.set_inlet_profile`): that is how a jet is injected.
  Tangential ghost 2 U_t/eps - u.
* ``pressure_outlet(p)``: p fixed half a cell outside the last cell centre (Dirichlet in
  the pressure equation), zero-gradient velocity (the predicted normal velocity is
  copied from the first interior face, then corrected by the pressure gradient; backflow
  is allowed), tangential ghost u.
* ``periodic``: must pair x-/x+ (etc.); the first and last faces are one face.

Vessel walls (cut cells)
------------------------
Apertures, open volume fractions and active cells come from the vessel SDF
(:func:`app.sim.gasgrid.cut_cells`). Closed faces carry zero velocity; cells with no open
volume are not solved. In the viscous stencil a neighbour face that lies in the wall
(clearance < 0 at its centre, or closed) is replaced by the ghost value
u_G = -u_P (1 - t)/t, where t = c_P/(c_P - c_Q) is where the wall crosses the segment
between the two face centres (clearances c; t clamped to [0.05, 1]): linear extrapolation
to u = 0 on the true wall, put on the diagonal. Where a vessel wall cuts the cell next to a
domain face and lies closer than that face, it takes precedence over the domain ghost (its
clearance is extrapolated linearly across the boundary). Accuracy: the no-slip velocity is second
order away from the wall (first-order local truncation at the ghost, as usual for
ghost-cell immersed boundaries); the pressure flux through a cut face uses the full cell
distance and the aperture, first order near the wall; mass conservation is exact
(to ``tol``) on the cut geometry. Back-traced convection near an immersed wall sees the
closed faces as zero velocity (first order there).

Units are SI throughout. The solver never prints or writes files.

Implementation note: all solver state lives in flat Taichi ndarrays and the kernels are
module-level, so they compile once per process for any grid; only the small copy kernels
between the :class:`GasFields` bundle and that state are compiled per solver. A step does not
wait on the device: the viscous sweeps and the pressure iterations are launched in fixed
batches whose stopping tests run on the device (a launch past convergence does nothing), and
the host reads one record per step (:func:`_k_record`), a second only when the pressure solve
outran its batch or a float32 refinement round is due.
"""
import dataclasses
from typing import Mapping, Sequence

import numpy as np
import taichi as ti

from ..config.schema import GasConfig
from . import linsolve as ls
from .gasgrid import CutCells, MacGrid, cut_cells

FACES = ("x-", "x+", "y-", "y+", "z-", "z+")
ALIASES = {"bottom": "z-", "top": "z+"}
WALL, MOVING, SLIP, INLET, OUTLET, PERIODIC = range(6)
KINDS = {"wall": WALL, "moving_wall": MOVING, "free_slip": SLIP, "velocity_inlet": INLET,
         "pressure_outlet": OUTLET, "periodic": PERIODIC}
KIND_ALIASES = {"no_slip": "wall", "inlet": "velocity_inlet", "outlet": "pressure_outlet", "slip": "free_slip",
                "moving": "moving_wall"}
CONVECTION = {"none": 0, "semi_lagrangian": 1, "maccormack": 2}
PRESSURE_FORMS = {"gas": 0, "shared": 1}
THETA_MIN = 0.05  # smallest wall fraction used by the no-slip ghost values
EPS_MIN = 1e-3  # the solver reads eps clamped to [EPS_MIN, 1] (it divides by eps)
VISCOUS_REDUCTION = 1e-6  # viscous sweeps stop at this estimated error relative to the velocity scale


# ============================================================================ set-up
@dataclasses.dataclass(frozen=True)
class BC:
    """Boundary condition of one domain face. ``kind``: wall | moving_wall | free_slip |
    velocity_inlet | pressure_outlet | periodic. ``velocity`` [m/s]: wall velocity (moving
    wall, tangential) or superficial inlet velocity vector; ``pressure`` [Pa]: outlet pressure."""

    kind: str = "wall"
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    pressure: float = 0.0


def wall() -> BC:
    return BC("wall")


def moving_wall(velocity: Sequence[float]) -> BC:
    return BC("moving_wall", tuple(float(v) for v in velocity))


def free_slip() -> BC:
    return BC("free_slip")


def velocity_inlet(velocity: Sequence[float]) -> BC:
    return BC("velocity_inlet", tuple(float(v) for v in velocity))


def pressure_outlet(pressure: float = 0.0) -> BC:
    return BC("pressure_outlet", pressure=float(pressure))


def periodic() -> BC:
    return BC("periodic")


def _finite(x) -> bool:
    return bool(np.all(np.isfinite(np.asarray(x, float))))


# FlowConfig field -> the preset's [gas] key: the defaults, units and ranges are the schema's
# (app/config/schema.py, GasConfig), so a scene built here and one built from a preset agree
GAS_KEYS = {"rho": "density", "mu": "viscosity", "pressure_form": "pressure_form", "convection": "convection",
            "tol": "tolerance", "max_iter": "max_iterations", "aperture_samples": "aperture_samples",
            "min_open_fraction": "min_open_fraction", "max_viscous_sweeps": "max_viscous_sweeps",
            "trace_forces": "trace_forces"}


def _gas_default(field: str):
    return GasConfig.__dataclass_fields__[GAS_KEYS[field]].default


def _gas_check(field: str, value) -> None:
    """ValueError unless ``value`` fits the schema's range or choices of the [gas] key behind ``field``."""
    key = GAS_KEYS[field]
    meta = GasConfig.__dataclass_fields__[key].metadata
    choices = meta.get("choices")
    if choices:
        if value not in choices:
            raise ValueError(f"flow: {field} (gas.{key}) must be one of {list(choices)}, got {value!r}")
        return
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        if GasConfig.__dataclass_fields__[key].type in (bool, "bool"):
            return
        raise ValueError(f"flow: {field} (gas.{key}) must be a number, got {value!r}")
    lo, hi, unit = meta.get("lo"), meta.get("hi"), meta.get("unit", "-")
    u = "" if unit == "-" else f" {unit}"
    bad = not np.isfinite(value)
    if lo is not None and (value < lo or (meta.get("lo_open") and value <= lo)):
        bad = True
    if hi is not None and value > hi:
        bad = True
    if bad:
        rng = f"{'>' if meta.get('lo_open') else '>='} {lo:g}" if lo is not None else ""
        if hi is not None:
            rng += (" and " if rng else "") + f"<= {hi:g}"
        raise ValueError(f"flow: {field} (gas.{key}) must be {rng}{u}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class FlowConfig:
    """Everything the gas solver needs to be built (validated on construction).

    shape (nx, ny, nz) cells of size h [m] from origin [m]; rho [kg/m3]; mu [Pa s];
    gravity [m/s2]; bcs: face name -> :class:`BC` (missing faces are no-slip walls);
    walls: vessel walls (:mod:`app.sim.geometry`) for cut cells; pressure_form "gas" (Model
    B) or "shared" (Model A); convection "maccormack" | "semi_lagrangian" | "none"; tol:
    pressure-solve tolerance (relative divergence, see module doc); max_iter: outer PCG
    iterations; aperture_samples: sub-samples per face edge for cut cells; min_open_fraction:
    cut cells with at most this open volume fraction are closed (small-cell removal);
    max_viscous_sweeps: cap on red-black Gauss-Seidel sweeps of the implicit viscous predictor.
    These gas fields are the preset's [gas] keys (:data:`GAS_KEYS`): their defaults, units and
    ranges are read from the schema (app/config/schema.py), so none can drift from it.
    """

    shape: tuple[int, int, int]
    h: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rho: float = _gas_default("rho")
    mu: float = _gas_default("mu")
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    bcs: Mapping[str, BC] = dataclasses.field(default_factory=dict)
    walls: tuple = ()
    pressure_form: str = _gas_default("pressure_form")
    convection: str = _gas_default("convection")
    tol: float = _gas_default("tol")
    max_iter: int = _gas_default("max_iter")
    aperture_samples: int = _gas_default("aperture_samples")
    min_open_fraction: float = _gas_default("min_open_fraction")
    max_viscous_sweeps: int = _gas_default("max_viscous_sweeps")
    trace_forces: bool = _gas_default("trace_forces")

    def __post_init__(self):
        bad = ValueError
        try:
            shape = tuple(int(n) for n in self.shape)
        except (TypeError, ValueError):
            raise bad(f"flow: shape must be three positive integers, got {self.shape!r}") from None
        if len(shape) != 3 or min(shape) < 1 or any(int(n) != n for n in self.shape):
            raise bad(f"flow: shape must be three positive integers, got {self.shape!r}")
        object.__setattr__(self, "shape", shape)
        if not (np.isfinite(self.h) and self.h > 0):
            raise bad(f"flow: cell size h must be a positive number of metres, got {self.h!r}")
        for name in ("origin", "gravity"):
            v = getattr(self, name)
            if len(tuple(v)) != 3 or not _finite(v):
                raise bad(f"flow: {name} must be three finite numbers, got {v!r}")
            object.__setattr__(self, name, tuple(float(x) for x in v))
        for name in GAS_KEYS:  # the schema's ranges and choices of the [gas] keys
            _gas_check(name, getattr(self, name))
        norm = {}
        for face, bc in dict(self.bcs).items():
            f = ALIASES.get(face, face)
            if f not in FACES:
                raise bad(f"flow: unknown boundary face {face!r}; use one of {list(FACES) + list(ALIASES)}")
            if f in norm:
                raise bad(f"flow: boundary face {f!r} given twice (through an alias)")
            if isinstance(bc, str):
                bc = BC(bc)
            if not isinstance(bc, BC):
                raise bad(f"flow: boundary condition of {face!r} must be a BC, got {bc!r}")
            kind = KIND_ALIASES.get(bc.kind, bc.kind)
            if kind not in KINDS:
                raise bad(f"flow: unknown boundary kind {bc.kind!r} on {face!r}; use one of {sorted(KINDS)}")
            vel = tuple(float(x) for x in bc.velocity)
            if len(vel) != 3 or not _finite(vel) or not np.isfinite(bc.pressure):
                raise bad(f"flow: boundary {face!r} needs a finite 3-vector velocity and finite pressure")
            axis = "xyz".index(f[0])
            if kind == "moving_wall" and vel[axis] != 0.0:
                raise bad(f"flow: moving wall {f!r} velocity must be tangential (its {f[0]} component must be 0)")
            norm[f] = BC(kind, vel, float(bc.pressure))
        for a, ax in enumerate("xyz"):
            lo = norm.get(ax + "-", BC()).kind == "periodic"
            hi = norm.get(ax + "+", BC()).kind == "periodic"
            if lo != hi:
                raise bad(f"flow: periodic boundaries must pair {ax}- with {ax}+")
        object.__setattr__(self, "bcs", norm)
        object.__setattr__(self, "walls", tuple(self.walls))
        for w in self.walls:
            if not hasattr(w, "clearance"):
                raise bad(f"flow: walls must be geometry walls with a clearance(), got {w!r}")

    def bc(self, face: str) -> BC:
        """Boundary condition of ``face`` (aliases allowed); no-slip wall when not given."""
        return self.bcs.get(ALIASES.get(face, face), BC())

    @property
    def grid(self) -> MacGrid:
        return MacGrid(self.shape, float(self.h), self.origin)

    @property
    def periodic(self) -> tuple[bool, bool, bool]:
        return tuple(self.bc(ax + "-").kind == "periodic" for ax in "xyz")


@dataclasses.dataclass(frozen=True)
class StepInfo:
    """What one fluid step did: CFL = max|u| dt/h (old or new velocity, whichever is larger),
    diffusion number mu dt/(rho h^2), red-black Gauss-Seidel sweeps of the viscous predictor,
    pressure iterations (all refinement rounds), pressure_residual = divergence = the relative
    continuity residual of the final field (see module doc), converged = divergence <= tol."""

    dt: float
    cfl: float
    diffusion_number: float
    viscous_sweeps: int
    pressure_iterations: int
    pressure_residual: float
    converged: bool
    divergence: float


# ============================================================================ flat layout
# int slots of M
M_NX, M_NY, M_NZ = 0, 1, 2
M_BC = 3          # .. 8: kind per face
M_PER = 9         # .. 11
M_SCHEME, M_FORM, M_WALLS = 12, 13, 14
M_FO = 16         # .. 18 face offsets of u, v, w inside a face region
M_NF, M_NC = 19, 20
M_BCV = 21        # .. 26 offsets of the six boundary-value blocks
R_VEL, R_VOLD, R_VADV, R_VTMP, R_VLO, R_VHI, R_AP, R_CL = range(32, 40)
R_EPS, R_DEPS, R_BETA, R_US, R_FX, R_THETA, R_UC, R_GP, R_DIV, R_PAR, R_SC, R_ACC, R_DPRED, R_P, R_EF, R_BF = range(40, 56)
NM = 64
# parameter slots (F[M[R_PAR] + ...])
P_RHO, P_MU, P_H, P_G, P_POUT, P_THMIN, P_TRACE = 0, 1, 2, 3, 6, 12, 13
NPAR = 16
# scalar slots (F[M[R_SC] + ...])
SC_DMAX, SC_SMAX, SC_UMAX, SC_UOLD, SC_DV = range(5)
# the step's control, on the device (the host reads them once, in the step record):
# viscous sweeps done, 1 while sweeping, their threshold; the predicted field's flux scale, the
# reference scale of the divergence, 1 once the projection is applied
SC_NSW, SC_VACT, SC_VTHR, SC_SPRED, SC_SREF, SC_CORR = range(5, 11)
NSC = 16
R_VSAVE = 56  # the initial velocity, kept while the first step finds a consistent pressure
VISCOUS_CHUNK = 2  # red-black sweeps per launch of the viscous predictor (each stops itself on the device;
# each is a copy of the sweep in the compiled kernel: 4 cost 50% more compile time in all than before)

ND = ti.types.ndarray()


# ============================================================================ Taichi functions
@ti.func
def _n(M: ti.template()):
    return ti.Vector([M[M_NX], M[M_NY], M[M_NZ]])


@ti.func
def _fdims(M: ti.template(), a):
    d = _n(M)
    d[a] += 1
    return d


@ti.func
def _fidx(M: ti.template(), a, I):
    d = _fdims(M, a)
    return M[M_FO + a] + (I[0] * d[1] + I[1]) * d[2] + I[2]


@ti.func
def _fdecode(M: ti.template(), f):
    a = 0
    if f >= M[M_FO + 2]:
        a = 2
    elif f >= M[M_FO + 1]:
        a = 1
    d = _fdims(M, a)
    loc = f - M[M_FO + a]
    I = ti.Vector([loc // (d[1] * d[2]), (loc // d[2]) % d[1], loc % d[2]])
    return a, I


@ti.func
def _cidx(M: ti.template(), I):
    return (I[0] * M[M_NY] + I[1]) * M[M_NZ] + I[2]


@ti.func
def _wrap(i, n):
    return ((i % n) + n) % n


@ti.func
def _par(F: ti.template(), M: ti.template(), q):
    return F[M[R_PAR] + q]


@ti.func
def _face_cells(M: ti.template(), a, I):
    """The two cells of face (a, I), wrapped on periodic axes, and whether each exists."""
    n = _n(M)
    L = I
    L[a] -= 1
    R = I
    hasL = True
    hasR = True
    if L[a] < 0:
        if M[M_PER + a] == 1:
            L[a] += n[a]
        else:
            hasL = False
    if R[a] >= n[a]:
        if M[M_PER + a] == 1:
            R[a] -= n[a]
        else:
            hasR = False
    return L, R, hasL, hasR


@ti.func
def _face_avg(F: ti.template(), M: ti.template(), base, a, I):
    """Mean over the two cells of face (a, I) of the cell array at F[base + cell]."""
    L, R, hL, hR = _face_cells(M, a, I)
    v = 0.0
    if hL and hR:
        v = 0.5 * (F[base + _cidx(M, L)] + F[base + _cidx(M, R)])
    elif hL:
        v = F[base + _cidx(M, L)]
    elif hR:
        v = F[base + _cidx(M, R)]
    return v


@ti.func
def _face_beta(F: ti.template(), M: ti.template(), a, I):
    """Face drag coefficient [kg m^-3 s^-1]: eps_f^(m+1) * mean(beta/eps^(m+1)) of the two cells, so
    that the drag resistance of the face is the series resistance of its two half-cells and the
    pressure drop of a 1-D flow through any eps/beta layering is exact (eps_f: mean of the cells)."""
    L, R, hL, hR = _face_cells(M, a, I)
    m1 = M[M_FORM] + 1
    r = 0.0
    cnt = 0.0
    if hL:
        c = _cidx(M, L)
        r += F[M[R_BETA] + c] / F[M[R_EPS] + c] ** m1
        cnt += 1.0
    if hR:
        c = _cidx(M, R)
        r += F[M[R_BETA] + c] / F[M[R_EPS] + c] ** m1
        cnt += 1.0
    e = _face_avg(F, M, M[R_EPS], a, I)
    return e ** m1 * r / ti.max(cnt, 1.0)


@ti.func
def _is_boundary(M: ti.template(), a, I):
    n = _n(M)
    return M[M_PER + a] == 0 and (I[a] == 0 or I[a] == n[a])


@ti.func
def _tangential(a):
    """The two axes other than a, in x, y, z order."""
    t1 = 0
    t2 = 2
    if a == 0:
        t1 = 1
    if a == 2:
        t2 = 1
    return t1, t2


@ti.func
def _solved(F: ti.template(), M: ti.template(), f, a, I):
    """Face velocity is an unknown of the momentum equation."""
    n = _n(M)
    ok = F[M[R_AP] + f] > 0.0
    if M[M_PER + a] == 1:
        ok = ok and I[a] < n[a]
    else:
        ok = ok and I[a] > 0 and I[a] < n[a]
    return ok


@ti.func
def _bc_value(F: ti.template(), M: ti.template(), b, side, a, J):
    """Component a of the boundary vector of domain face (b, side) at the place of a-face J
    (J in range along the tangential axes). Inlet values are converted to interstitial."""
    n = _n(M)
    t1, t2 = _tangential(b)
    blk = M[M_BCV + 2 * b + side]
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
        v += 0.5 * F[blk + (a * n[t1] + i1) * n[t2] + i2]
    if M[M_BC + 2 * b + side] == INLET:
        C = J
        for q in ti.static(range(3)):
            C[q] = ti.min(ti.max(C[q], 0), n[q] - 1)
        C[b] = 0 if side == 0 else n[b] - 1
        v /= F[M[R_EPS] + _cidx(M, C)]
    return v


@ti.func
def _ghost_coef(F: ti.template(), M: ti.template(), b, side, a, J):
    """Ghost value beyond domain face (b, side) of the tangential component a: alpha*u_in + gamma."""
    kind = M[M_BC + 2 * b + side]
    alpha = 1.0
    gamma = 0.0
    if kind == WALL:
        alpha = -1.0
    elif kind == MOVING or kind == INLET:
        alpha = -1.0
        gamma = 2.0 * _bc_value(F, M, b, side, a, J)
    return alpha, gamma


@ti.func
def _comp_value(F: ti.template(), M: ti.template(), base, a, I):
    """Value of component a at face index I (may be outside by one): periodic wrap, clamping
    along a, boundary ghost values across the tangential domain faces."""
    n = _n(M)
    J = I
    if M[M_PER + a] == 1:
        J[a] = _wrap(J[a], n[a])
    else:
        J[a] = ti.min(ti.max(J[a], 0), n[a])
    g = ti.Vector([0, 0, 0])
    for b in ti.static(range(3)):
        if b != a and (J[b] < 0 or J[b] >= n[b]):
            if M[M_PER + b] == 1:
                J[b] = _wrap(J[b], n[b])
            else:
                g[b] = -1 if J[b] < 0 else 1
                J[b] = ti.min(ti.max(J[b], 0), n[b] - 1)
    v = F[base + _fidx(M, a, J)]
    for b in ti.static(range(3)):
        if g[b] != 0:
            al, ga = _ghost_coef(F, M, b, (g[b] + 1) // 2, a, J)
            v = al * v + ga
    return v


@ti.func
def _interp(F: ti.template(), M: ti.template(), base, a, X):
    """Trilinear value of component a at grid point X (cell units from the origin), with the
    min and max of the 8 stencil values. Interior stencils take a direct path; stencils that
    touch the domain boundary go through :func:`_comp_value` (wrapping, ghost values)."""
    n = _n(M)
    Y = X
    for b in ti.static(range(3)):
        if M[M_PER + b] == 0:
            Y[b] = ti.min(ti.max(Y[b], 0.0), ti.cast(n[b], float))
    s = Y - 0.5
    s[a] += 0.5
    i0 = ti.cast(ti.floor(s), ti.i32)
    fr = s - ti.cast(i0, float)
    d = _fdims(M, a)
    st = ti.Vector([d[1] * d[2], d[2], 1])
    inside = True
    for b in ti.static(range(3)):
        if b != a and M[M_PER + b] == 1 and n[b] == 1:
            i0[b] = 0
            st[b] = 0
        else:
            # largest index read directly: the last face/cell; along a periodic a the duplicate
            # last face may be stale, so it goes through the wrapping path
            lim = d[b] - 1
            if b == a and M[M_PER + b] == 1:
                lim -= 1
            if i0[b] < 0 or i0[b] + 1 > lim:
                inside = False
    val = 0.0
    lo = 1e30
    hi = -1e30
    if inside:
        b0 = base + M[M_FO + a] + i0[0] * st[0] + i0[1] * st[1] + i0[2] * st[2]
        for c in ti.static(range(8)):
            o0 = ti.static(c & 1)
            o1 = ti.static((c >> 1) & 1)
            o2 = ti.static((c >> 2) & 1)
            w = (fr[0] if o0 else 1.0 - fr[0]) * (fr[1] if o1 else 1.0 - fr[1]) * (fr[2] if o2 else 1.0 - fr[2])
            v = F[b0 + o0 * st[0] + o1 * st[1] + o2 * st[2]]
            val += w * v
            lo = ti.min(lo, v)
            hi = ti.max(hi, v)
    else:
        for c in range(8):
            o = ti.Vector([c & 1, (c >> 1) & 1, (c >> 2) & 1])
            w = 1.0
            for q in ti.static(range(3)):
                w *= fr[q] if o[q] == 1 else 1.0 - fr[q]
            v = _comp_value(F, M, base, a, i0 + o)
            val += w * v
            lo = ti.min(lo, v)
            hi = ti.max(hi, v)
    return val, lo, hi


@ti.func
def _vel_at(F: ti.template(), M: ti.template(), base, X):
    U = ti.Vector([0.0, 0.0, 0.0])
    for a in range(3):
        v, _, _ = _interp(F, M, base, a, X)
        U[a] = v
    return U


@ti.func
def _face_pos(a, I):
    X = ti.cast(I, float) + 0.5
    X[a] -= 0.5
    return X


@ti.func
def _kappa(F: ti.template(), M: ti.template(), a, I, dt):
    """Face coefficient of the pressure correction, eps^m / (rho eps/dt + beta) [m^3 s/kg], and eps_f."""
    e = F[M[R_EF] + _fidx(M, a, I)]
    be = F[M[R_BF] + _fidx(M, a, I)]
    em = 1.0
    if M[M_FORM] == 1:
        em = e
    return em / (_par(F, M, P_RHO) * e / dt + be), e


@ti.func
def _cell_balance(F: ti.template(), M: ti.template(), vb, I):
    """(net outflow rate, gross flow rate) of cell I per unit volume [1/s], incl. theta*deps."""
    h = _par(F, M, P_H)
    c = _cidx(M, I)
    th = F[M[R_THETA] + c]
    de = F[M[R_DEPS] + c]
    net = th * de
    gross = th * ti.abs(de)
    n = _n(M)
    for a in ti.static(range(3)):
        for side in ti.static(range(2)):
            J = I
            J[a] += side
            if M[M_PER + a] == 1 and J[a] == n[a]:
                J[a] = 0  # the periodic duplicate face may be stale before the final copy
            f = _fidx(M, a, J)
            q = F[M[R_AP] + f] * F[M[R_EF] + f] * F[vb + f] / h
            net += q if side == 1 else -q
            gross += ti.abs(q)
    return net, gross


# ============================================================================ kernels
@ti.kernel
def _k_write(F: ND, off: ti.i32, src: ND):
    for i in range(src.shape[0]):
        F[off + i] = src[i]


@ti.kernel
def _k_add_face_flux(F: ND, M: ND, acc: ND, w: float):
    """acc[f] += w * aperture * face gas fraction (the step's) * velocity, on every face (the rCFD probe's sums)."""
    for f in range(M[M_NF]):
        acc[f] += w * F[M[R_AP] + f] * F[M[R_EF] + f] * F[M[R_VEL] + f]


@ti.kernel
def _k_read(F: ND, off: ti.i32, dst: ND):
    for i in range(dst.shape[0]):
        dst[i] = F[off + i]


@ti.kernel
def _k_advect(F: ND, M: ND, dt: float):
    """old = vel; adv = back-traced vel (MacCormack-corrected when asked) + dt/2 (a at the departure
    point - a here), a being the last step's weighted acceleration; max|old| into SC_UOLD.

    The acceleration's share is carried by the plain semi-Lagrangian trace, outside the
    MacCormack correction: corrected together with the velocity (u + dt/2 a traced as one field),
    the pair fed back on itself through the next step's a and grew without bound (a gas-only
    cylinder with gusty inflow reached 200 m/s in 380 steps; either piece alone stays bounded)."""
    nf = M[M_NF]
    h = _par(F, M, P_H)
    cdt = dt / h
    vold = M[R_VOLD]
    vadv = M[R_VADV]
    vinc = M[R_VTMP]  # dt/2 (a_departure - a_arrival) per face
    vmc = M[R_VLO]    # the MacCormack result overwrites the face's own lower clamp once used
    acc = M[R_ACC]
    F[M[R_SC] + SC_UOLD] = 0.0
    for f in range(nf):
        u = F[M[R_VEL] + f]
        F[vold + f] = u
        ti.atomic_max(F[M[R_SC] + SC_UOLD], ti.abs(u))
    for f in range(nf):
        v = F[vold + f]
        inc = 0.0
        a, I = _fdecode(M, f)
        if _solved(F, M, f, a, I):
            if M[M_SCHEME] > 0:
                X = _face_pos(a, I)
                U1 = _vel_at(F, M, vold, X)
                U2 = _vel_at(F, M, vold, X - 0.5 * cdt * U1)
                val, lo, hi = _interp(F, M, vold, a, X - cdt * U2)
                v = val
                if _par(F, M, P_TRACE) > 0.0:  # a is all zero with gas.trace_forces off: skip its trace
                    adep, _, _ = _interp(F, M, acc, a, X - cdt * U2)
                    inc = 0.5 * dt * (adep - F[acc + f])
                if M[M_SCHEME] == 2:
                    F[M[R_VLO] + f] = lo
                    F[M[R_VHI] + f] = hi
        F[vadv + f] = v
        F[vinc + f] = inc
    n2 = 0
    if M[M_SCHEME] == 2:
        n2 = nf
    for f in range(n2):
        a, I = _fdecode(M, f)
        if _solved(F, M, f, a, I):
            X = _face_pos(a, I)
            U1 = _vel_at(F, M, vold, X)
            U2 = _vel_at(F, M, vold, X + 0.5 * cdt * U1)
            back, _, _ = _interp(F, M, vadv, a, X + cdt * U2)
            v = F[vadv + f] + 0.5 * (F[vold + f] - back)
            F[vmc + f] = ti.min(ti.max(v, F[M[R_VLO] + f]), F[M[R_VHI] + f])
    for f in range(nf):
        a, I = _fdecode(M, f)
        if _solved(F, M, f, a, I):
            v = F[vadv + f]
            if M[M_SCHEME] == 2:
                v = F[vmc + f]
            F[vadv + f] = v + F[vinc + f]


@ti.kernel
def _k_bc_prep(F: ND, M: ND, dt: float):
    """Boundary and closed faces of the advected field; the viscous iterates start from it."""
    n = _n(M)
    for f in range(M[M_NF]):
        a, I = _fdecode(M, f)
        v = F[M[R_VADV] + f]
        if F[M[R_AP] + f] <= 0.0:
            v = 0.0
        elif _is_boundary(M, a, I):
            side = 0 if I[a] == 0 else 1
            kind = M[M_BC + 2 * a + side]
            if kind == INLET:
                t1, t2 = _tangential(a)
                C = I
                C[a] = 0 if side == 0 else n[a] - 1
                v = F[M[M_BCV + 2 * a + side] + (a * n[t1] + I[t1]) * n[t2] + I[t2]] / F[M[R_EPS] + _cidx(M, C)]
            elif kind != OUTLET:
                v = 0.0
        F[M[R_VADV] + f] = v
        if _solved(F, M, f, a, I):
            v += F[M[R_DPRED] + f]  # initial iterate: last step's predictor increment (exact when steady)
        F[M[R_VTMP] + f] = v
        F[M[R_VEL] + f] = v


@ti.func
def _visc_colour(F: ti.template(), M: ti.template(), dt, colour, nf):
    """Gauss-Seidel update, in place on the velocity, of the faces of one colour (parity of
    i+j+k) among the first nf faces (all, or none once the sweeps have stopped): the viscous
    stencil couples a face only to faces of the other colour."""
    n = _n(M)
    src = M[R_VEL]
    rho = _par(F, M, P_RHO)
    mu = _par(F, M, P_MU)
    h = _par(F, M, P_H)
    thmin = _par(F, M, P_THMIN)
    nc = M[M_NC]
    for f in range(nf):
        a, I = _fdecode(M, f)
        if (I[0] + I[1] + I[2]) % 2 == colour and _solved(F, M, f, a, I):
            eP = F[M[R_EF] + f]
            bP = F[M[R_BF] + f]
            D = rho * eP / dt + bP
            R = rho * eP / dt * F[M[R_VADV] + f] + rho * eP * _par(F, M, P_G + a) \
                + _face_avg(F, M, M[R_FX] + a * nc, a, I) + bP * _face_avg(F, M, M[R_US] + a * nc, a, I)
            gp, okp = _face_grad(F, M, a, I)
            if okp:
                em = 1.0
                if M[M_FORM] == 1:
                    em = eP
                R -= em * gp  # incremental projection: the predictor feels the last pressure
            cw = mu * eP / (h * h)
            clP = 1e30
            if M[M_WALLS] == 1:
                clP = ti.max(F[M[R_CL] + f], 0.0)
            for b in range(3):
                if not (M[M_PER + b] == 1 and n[b] == 1) and mu > 0.0:
                    for side in range(2):
                        J = I
                        J[b] += 2 * side - 1
                        ghost = False
                        if b == a:
                            if M[M_PER + a] == 1:
                                J[a] = _wrap(J[a], n[a])
                        elif J[b] < 0 or J[b] >= n[b]:
                            if M[M_PER + b] == 1:
                                J[b] = _wrap(J[b], n[b])
                            else:
                                ghost = True
                        if ghost:
                            # a vessel wall closer than the domain face (clearance extrapolated
                            # linearly across the boundary) takes precedence over the domain ghost
                            th = 1.0
                            if M[M_WALLS] == 1 and clP > 0.0:
                                Jo = I
                                Jo[b] -= 2 * side - 1
                                if Jo[b] >= 0 and Jo[b] < n[b]:
                                    clQ = 2.0 * clP - F[M[R_CL] + _fidx(M, a, Jo)]
                                    if clQ < 0.0:
                                        th = clP / (clP - clQ)
                            if th < 0.5:
                                D += cw / ti.max(th, thmin)
                            else:
                                al, ga = _ghost_coef(F, M, b, side, a, J)
                                D += cw * (1.0 - al)
                                R += cw * ga
                        else:
                            q = _fidx(M, a, J)
                            solid = False
                            clQ = 1.0
                            if M[M_WALLS] == 1:
                                clQ = F[M[R_CL] + q]
                                solid = F[M[R_AP] + q] <= 0.0 or clQ < 0.0
                            if solid:
                                th = 1.0
                                if clQ < 0.0:
                                    th = clP / (clP - clQ)
                                th = ti.min(ti.max(th, thmin), 1.0)
                                D += cw / th
                            else:
                                eQ = F[M[R_EF] + q]
                                cq = mu * 0.5 * (eP + eQ) / (h * h)
                                D += cq
                                R += cq * F[src + q]
            unew = R / D
            ti.atomic_max(F[M[R_SC] + SC_DV], ti.abs(unew - F[src + f]))
            F[src + f] = unew


@ti.kernel
def _k_visc(F: ND, M: ND, dt: float, first: ti.i32, factor: float, bc_speed: float, max_sweeps: ti.i32):
    """VISCOUS_CHUNK red-black Gauss-Seidel sweeps of the implicit predictor (see module doc), each
    only while the sweeps go on: they stop (on the device) when the largest change of a face
    velocity is at most factor * max(max|u_old|, bc_speed) or after max_sweeps. ``first`` starts
    the count."""
    sc = M[R_SC]
    if first:
        F[sc + SC_NSW] = 0.0
        F[sc + SC_VACT] = 1.0
        F[sc + SC_VTHR] = factor * ti.max(ti.max(F[sc + SC_UOLD], bc_speed), 1e-30)
    for _s in ti.static(range(VISCOUS_CHUNK)):
        nf = M[M_NF] * ti.cast(F[sc + SC_VACT] > 0.0, ti.i32)
        F[sc + SC_DV] = 0.0
        _visc_colour(F, M, dt, 0, nf)
        _visc_colour(F, M, dt, 1, nf)
        if nf > 0:
            F[sc + SC_NSW] += 1.0
            if F[sc + SC_DV] <= F[sc + SC_VTHR] or F[sc + SC_NSW] >= ti.cast(max_sweeps, float):
                F[sc + SC_VACT] = 0.0


@ti.kernel
def _k_build(F: ND, M: ND, G: ND, MM: ND, dt: float, again: ti.i32):
    """Outlet faces get their predicted velocity (not ``again``: a refinement round projects the
    corrected field once more); pressure-system T and b into G; the residual scale of the solve
    (the gross-flux scale of the predicted field, or the reference scale in a refinement round)
    into the linear solver's scalars."""
    n = _n(M)
    h = _par(F, M, P_H)
    vel = M[R_VEL]
    nfo = M[M_NF]
    if again:
        nfo = 0
    for f in range(nfo):
        a, I = _fdecode(M, f)
        if _is_boundary(M, a, I) and F[M[R_AP] + f] > 0.0:
            side = 0 if I[a] == 0 else 1
            if M[M_BC + 2 * a + side] == OUTLET:
                # zero-gradient velocity: the interior neighbour's prediction with its own pressure
                # push swapped for this face's (so a steady state extrapolates p linearly to p_out)
                J = I
                J[a] = 1 if side == 0 else n[a] - 1
                J[a] = ti.min(ti.max(J[a], 0), n[a])
                u = F[vel + _fidx(M, a, J)]
                gJ, okJ = _face_grad(F, M, a, J)
                if okJ:
                    kJ, _ = _kappa(F, M, a, J, dt)
                    u += kJ * gJ
                gb, okb = _face_grad(F, M, a, I)
                kb, eb = _kappa(F, M, a, I, dt)
                F[vel + f] = u - kb * gb
    for f in range(M[M_NF]):
        a, I = _fdecode(M, f)
        t = 0.0
        ap = F[M[R_AP] + f]
        if _has_grad(F, M, a, I):
            kap, e = _kappa(F, M, a, I, dt)
            t = ap * e * kap / (h * h)
            if _is_boundary(M, a, I):
                t *= 2.0  # outlet: the pressure is fixed half a cell away
        G[ls._face(MM, 0, a, I)] = t
    F[M[R_SC] + SC_SMAX] = 0.0
    for i, j, k in ti.ndrange(n[0], n[1], n[2]):
        I = ti.Vector([i, j, k])
        c = _cidx(M, I)
        b = 0.0
        if F[M[R_THETA] + c] > 0.0:
            net, gross = _cell_balance(F, M, vel, I)
            b = -net
            ti.atomic_max(F[M[R_SC] + SC_SMAX], gross)
        G[MM[ls.O_B0] + c] = b
        G[MM[ls.O_X] + c] = 0.0  # the solve is for the pressure increment
    sc = M[R_SC]
    if not again:
        F[sc + SC_SPRED] = F[sc + SC_SMAX]
        F[sc + SC_SREF] = F[sc + SC_SMAX]
    G[MM[ls.O_SC] + ls.S_SCALE] = F[sc + SC_SREF]
    F[sc + SC_CORR] = 0.0


@ti.func
def _has_grad(F: ti.template(), M: ti.template(), a, I):
    """Face (a, I) carries a pressure gradient: open, and interior (not a periodic axis of
    length 1) or on a pressure outlet."""
    n = _n(M)
    ok = F[M[R_AP] + _fidx(M, a, I)] > 0.0
    if ok:
        if _is_boundary(M, a, I):
            side = 0 if I[a] == 0 else 1
            ok = M[M_BC + 2 * a + side] == OUTLET
        elif M[M_PER + a] == 1 and n[a] == 1:
            ok = False
    return ok


@ti.func
def _face_grad(F: ti.template(), M: ti.template(), a, I):
    """Gradient of the full pressure (F[R_P], outlet pressures outside) across face (a, I) [Pa/m]."""
    h = _par(F, M, P_H)
    g = 0.0
    ok = _has_grad(F, M, a, I)
    if ok:
        L, R, hL, hR = _face_cells(M, a, I)
        xb = M[R_P]
        if hL and hR:
            g = (F[xb + _cidx(M, R)] - F[xb + _cidx(M, L)]) / h
        elif hR:
            g = (F[xb + _cidx(M, R)] - _par(F, M, P_POUT + 2 * a)) / (0.5 * h)
        else:
            g = (_par(F, M, P_POUT + 2 * a + 1) - F[xb + _cidx(M, L)]) / (0.5 * h)
    return g, ok


@ti.func
def _face_grad_inc(F: ti.template(), M: ti.template(), G: ti.template(), MM: ti.template(), a, I):
    """Gradient of the pressure increment (the MG solution, 0 outside outlets) across face (a, I)."""
    h = _par(F, M, P_H)
    g = 0.0
    ok = _has_grad(F, M, a, I)
    if ok:
        L, R, hL, hR = _face_cells(M, a, I)
        xb = MM[ls.O_X]
        if hL and hR:
            g = (G[xb + _cidx(M, R)] - G[xb + _cidx(M, L)]) / h
        elif hR:
            g = G[xb + _cidx(M, R)] / (0.5 * h)
        else:
            g = -G[xb + _cidx(M, L)] / (0.5 * h)
    return g, ok


@ti.func
def _cell_outputs(F: ti.template(), M: ti.template(), G: ti.template(), MM: ti.template(), on):
    """Cell-centred gas velocity and pressure gradient, divergence and its scale (reductions);
    nothing unless ``on``."""
    n = _n(M)
    nc = M[M_NC]
    if on:
        F[M[R_SC] + SC_DMAX] = 0.0
        F[M[R_SC] + SC_SMAX] = 0.0
    for i, j, k in ti.ndrange(n[0] * on, n[1], n[2]):
        I = ti.Vector([i, j, k])
        c = _cidx(M, I)
        active = F[M[R_THETA] + c] > 0.0
        net = 0.0
        if active:
            net, gross = _cell_balance(F, M, M[R_VEL], I)
            ti.atomic_max(F[M[R_SC] + SC_DMAX], ti.abs(net))
            ti.atomic_max(F[M[R_SC] + SC_SMAX], gross)
        F[M[R_DIV] + c] = net
        for a in ti.static(range(3)):
            J = I
            J[a] += 1
            uc = 0.0
            gp = 0.0
            if active:
                uc = 0.5 * (F[M[R_VEL] + _fidx(M, a, I)] + F[M[R_VEL] + _fidx(M, a, J)])
                g0, ok0 = _face_grad(F, M, a, I)
                g1, ok1 = _face_grad(F, M, a, J)
                cnt = 0.0
                if ok0:
                    gp += g0
                    cnt += 1.0
                if ok1:
                    gp += g1
                    cnt += 1.0
                if cnt > 0.0:
                    gp /= cnt
            F[M[R_UC] + a * nc + c] = uc
            F[M[R_GP] + a * nc + c] = gp


@ti.kernel
def _k_correct(F: ND, M: ND, G: ND, MM: ND, dt: float, again: ti.i32):
    """u = u* - kappa grad phi, p += phi; periodic copies; cell outputs; (max|div|, scale, max|u|)
    into the scalars. The predictor increment is recorded in the first round only. Runs once the
    pressure solve has finished, once per round (the host launches it without waiting)."""
    n = _n(M)
    vel = M[R_VEL]
    sc = M[R_SC]
    on = 0
    if G[MM[ls.O_SC] + ls.S_DONE] > 0.0 and F[sc + SC_CORR] == 0.0:
        on = 1
    nf = M[M_NF] * on
    for f in range(nf):
        a, I = _fdecode(M, f)
        if not again:
            dp = 0.0
            if _solved(F, M, f, a, I):
                dp = F[vel + f] - F[M[R_VADV] + f]
            F[M[R_DPRED] + f] = dp
        g, ok = _face_grad_inc(F, M, G, MM, a, I)
        if ok:
            kap, _ = _kappa(F, M, a, I, dt)
            F[vel + f] -= kap * g
    for c in range(M[M_NC] * on):
        if F[M[R_THETA] + c] > 0.0:
            F[M[R_P] + c] += G[MM[ls.O_X] + c]
    for f in range(nf):
        a, I = _fdecode(M, f)
        if M[M_PER + a] == 1 and I[a] == n[a]:
            J = I
            J[a] = 0
            F[vel + f] = F[vel + _fidx(M, a, J)]
    if on:
        F[M[R_SC] + SC_UMAX] = 0.0
    rho = _par(F, M, P_RHO)
    for f in range(nf):
        ti.atomic_max(F[M[R_SC] + SC_UMAX], ti.abs(F[vel + f]))
        a, I = _fdecode(M, f)
        acc = 0.0
        if _solved(F, M, f, a, I):
            # net non-advective acceleration of this step, weighted by the inertial share of the
            # face (-> 0 where drag dominates, so a jump of a drag-balanced pressure gradient is
            # not carried along trajectories); used by the next step's second-order advection
            e = F[M[R_EF] + f]
            be = F[M[R_BF] + f]
            wt = rho * e / (rho * e + be * dt)
            acc = _par(F, M, P_TRACE) * wt * (F[vel + f] - F[M[R_VADV] + f]) / dt
        F[M[R_ACC] + f] = acc
    _cell_outputs(F, M, G, MM, on)
    if on:
        F[sc + SC_SREF] = ti.max(F[sc + SC_SREF], F[sc + SC_SMAX])
        F[sc + SC_CORR] = 1.0


@ti.kernel
def _k_record(F: ND, M: ND, G: ND, MM: ND) -> ti.types.vector(12, ti.f64):  # f64: the type is fixed at import, maybe before ti.init
    """The step record, read once per step: max|u_old|, max|u_new|, viscous sweeps, max|div|, the
    corrected field's flux scale, the reference scale, 1 once corrected, then the pressure solve's
    (iterations, max|r|, converged, scale, initial max|r|)."""
    sc = M[R_SC]
    r = ls.solve_record(G, MM)
    return ti.Vector([F[sc + SC_UOLD], F[sc + SC_UMAX], F[sc + SC_NSW], F[sc + SC_DMAX], F[sc + SC_SMAX],
                      F[sc + SC_SREF], F[sc + SC_CORR], r[0], r[1], r[2], r[3], r[4]])


@ti.kernel
def _k_outputs(F: ND, M: ND, G: ND, MM: ND) -> ti.types.vector(2, ti.f64):
    _cell_outputs(F, M, G, MM, 1)
    return ti.Vector([F[M[R_SC] + SC_DMAX], F[M[R_SC] + SC_SMAX]])


@ti.kernel
def _k_copy(F: ND, src: ti.i32, dst: ti.i32, n: ti.i32, zero: ti.i32):
    """F[dst:dst+n] = F[src:src+n] (or 0 when ``zero``)."""
    for i in range(n):
        v = 0.0
        if not zero:
            v = F[src + i]
        F[dst + i] = v


@ti.kernel
def _k_periodic_copy(F: ND, M: ND):
    n = _n(M)
    for f in range(M[M_NF]):
        a, I = _fdecode(M, f)
        if M[M_PER + a] == 1 and I[a] == n[a]:
            J = I
            J[a] = 0
            F[M[R_VEL] + f] = F[M[R_VEL] + _fidx(M, a, J)]
        if F[M[R_AP] + f] <= 0.0:
            F[M[R_VEL] + f] = 0.0


@ti.kernel
def _k_face_coef(F: ND, M: ND):
    """Face gas fraction (mean of the two cells) and face drag coefficient, once per step."""
    for f in range(M[M_NF]):
        a, I = _fdecode(M, f)
        F[M[R_EF] + f] = _face_avg(F, M, M[R_EPS], a, I)
        F[M[R_BF] + f] = _face_beta(F, M, a, I)


# ---- bundle <-> state (instantiated per solver: these take the bundle's fields)
@ti.kernel
def _k_pull(F: ND, M: ND, eps: ti.template(), deps: ti.template(), beta: ti.template(), us: ti.template(),
            fx: ti.template()):
    nc = M[M_NC]
    for i, j, k in eps:
        c = _cidx(M, ti.Vector([i, j, k]))
        F[M[R_EPS] + c] = ti.min(ti.max(eps[i, j, k], EPS_MIN), 1.0)  # guard kernels writing eps <= 0
        F[M[R_DEPS] + c] = deps[i, j, k]
        F[M[R_BETA] + c] = beta[i, j, k]
        for a in ti.static(range(3)):
            F[M[R_US] + a * nc + c] = us[i, j, k][a]
            F[M[R_FX] + a * nc + c] = fx[i, j, k][a]


@ti.kernel
def _k_push(F: ND, M: ND, G: ND, MM: ND, p: ti.template(), uc: ti.template(), gp: ti.template()):
    nc = M[M_NC]
    for i, j, k in p:
        c = _cidx(M, ti.Vector([i, j, k]))
        p[i, j, k] = F[M[R_P] + c]
        for a in ti.static(range(3)):
            uc[i, j, k][a] = F[M[R_UC] + a * nc + c]
            gp[i, j, k][a] = F[M[R_GP] + a * nc + c]


# ============================================================================ host classes
@ti.kernel
def _k_gas_extremes(u: ti.template(), p: ti.template(), out: ti.template()):
    """out = [largest |u|^2 over the cells, number of cells with a non-finite velocity or pressure]: the
    per-step diagnostics reduced on the device (copying u and p to the host every step cost more)."""
    out[0] = 0.0
    out[1] = 0.0
    for I in ti.grouped(p):
        v = u[I]
        ti.atomic_max(out[0], v.dot(v))
        bad = 0.0
        for a in ti.static(range(3)):
            if not ti.abs(v[a]) < 1e30:  # also catches NaN
                bad = 1.0
        if not ti.abs(p[I]) < 1e30:
            bad = 1.0
        ti.atomic_add(out[1], bad)


@ti.kernel
def _k_end_layer_pressures(p: ti.template(), vf: ti.template(), out: ti.template()):
    """out = [sums over the first, second, second-to-last and last cell layers of p x open fraction of the
    end layer (first for the bottom two, last for the top two), the first layer's and the last's open sum]."""
    for k in range(6):
        out[k] = 0.0
    nz = p.shape[2]
    for i, j in ti.ndrange(p.shape[0], p.shape[1]):
        wb = vf[i, j, 0]
        wt = vf[i, j, nz - 1]
        ti.atomic_add(out[0], p[i, j, 0] * wb)
        ti.atomic_add(out[1], p[i, j, 1] * wb)
        ti.atomic_add(out[2], p[i, j, nz - 2] * wt)
        ti.atomic_add(out[3], p[i, j, nz - 1] * wt)
        ti.atomic_add(out[4], wb)
        ti.atomic_add(out[5], wt)


@ti.data_oriented
class GasFields:
    """Taichi fields of the gas, shared with the coupling code (all cell-centred, shape (nx, ny, nz)).

    Inputs (the solver reads them at the start of every step; write them in kernels or
    through the FlowSolver setters):
      ``eps``      gas volume fraction [-], in (0, 1] (read clamped to [1e-3, 1]) (default 1)
      ``deps_dt``  d(eps)/dt [1/s]                                          (default 0)
      ``beta``     implicit drag coefficient [kg m^-3 s^-1], >= 0: the gas feels
                   beta (us - u) per unit volume                           (default 0)
      ``us``       solid velocity (vec3) [m/s] that beta pulls the gas toward
      ``f_exp``    explicit momentum source on the gas (vec3) [N/m^3]
    Outputs (written at the end of every step):
      ``p``        pressure [Pa] (gauge; outlet pressure as given; zero mean without outlet)
      ``u_gas``    interstitial gas velocity at cell centres (vec3) [m/s] (mean of the two faces)
      ``grad_p``   pressure gradient at cell centres (vec3) [Pa/m] (mean of the open faces;
                   Model A grains feel -V_p grad_p)
    Geometry (constant): ``vol_frac`` open volume fraction [-]; ``active`` (i32) 1 for gas cells.
    Python attributes: ``shape``, ``h`` [m], ``origin`` [m].
    """

    def __init__(self, grid: MacGrid, cut: CutCells):
        self.shape = tuple(grid.shape)
        self.h = float(grid.h)
        self.origin = tuple(grid.origin)
        sh = self.shape
        self.eps = ti.field(float, shape=sh)
        self.deps_dt = ti.field(float, shape=sh)
        self.beta = ti.field(float, shape=sh)
        self.us = ti.Vector.field(3, float, shape=sh)
        self.f_exp = ti.Vector.field(3, float, shape=sh)
        self.p = ti.field(float, shape=sh)
        self.u_gas = ti.Vector.field(3, float, shape=sh)
        self.grad_p = ti.Vector.field(3, float, shape=sh)
        self.vol_frac = ti.field(float, shape=sh)
        self.active = ti.field(ti.i32, shape=sh)
        self.eps.fill(1.0)
        _load(self.vol_frac, cut.volume)
        self.active.from_numpy(cut.active.astype(np.int32))

    @ti.func
    def cell_of(self, x):
        """Cell index (i32 vec3, clamped into the grid) containing point x [m]."""
        q = (x - ti.Vector(self.origin)) / self.h
        c = ti.cast(ti.floor(q), ti.i32)
        for a in ti.static(range(3)):
            c[a] = ti.min(ti.max(c[a], 0), self.shape[a] - 1)
        return c

    @ti.func
    def velocity_at(self, x):
        """Gas velocity [m/s] at point x [m]: trilinear interpolation of ``u_gas`` (clamped at the box)."""
        q = (x - ti.Vector(self.origin)) / self.h - 0.5
        U = ti.Vector([0.0, 0.0, 0.0])
        i0 = ti.cast(ti.floor(q), ti.i32)
        fr = q - ti.cast(i0, float)
        for d in ti.static(ti.ndrange(2, 2, 2)):
            w = 1.0
            c = ti.Vector([0, 0, 0])
            for a in ti.static(range(3)):
                w *= fr[a] if d[a] == 1 else 1.0 - fr[a]
                c[a] = ti.min(ti.max(i0[a] + d[a], 0), self.shape[a] - 1)
            U += w * self.u_gas[c]
        return U


def _load(field, values) -> None:
    """field.from_numpy in the field's own float type (no implicit f64 -> f32 narrowing in Taichi)."""
    field.from_numpy(np.ascontiguousarray(values, dtype=np.float32 if field.dtype == ti.f32 else np.float64))


def _as_cell_array(values, shape, name, vector=False):
    tgt = tuple(shape) + ((3,) if vector else ())
    a = np.asarray(values, np.float64)
    try:
        a = np.broadcast_to(a, tgt)
    except ValueError:
        raise ValueError(f"flow: {name} must be a scalar{' or 3-vector' if vector else ''} or an array of shape "
                         f"{tgt}, got shape {a.shape}") from None
    if not np.all(np.isfinite(a)):
        raise ValueError(f"flow: {name} must be finite")
    return np.ascontiguousarray(a)


class FlowSolver:
    """Fractional-step gas solver on a MAC grid (see the module doc for the equations).

    ``FlowSolver(config)``; then set the coupling inputs (or write them in ``fields``) and
    call :meth:`step` (dt) repeatedly. Reads return numpy copies.
    """

    def __init__(self, config: FlowConfig):
        if not isinstance(config, FlowConfig):
            raise ValueError(f"flow: FlowSolver needs a FlowConfig, got {type(config).__name__}")
        self.config = cfg = config
        self.grid = grid = cfg.grid
        nx, ny, nz = self.shape = cfg.shape
        self.h = float(cfg.h)
        per = cfg.periodic
        self.cut = cut = cut_cells(grid, cfg.walls, int(cfg.aperture_samples), per, float(cfg.min_open_fraction))
        self.fields = GasFields(grid, cut)
        self._reduced = ti.field(float, 6)  # device-side reductions (diagnostics, end-layer pressures)
        self.mg = ls.MGPCG(cfg.shape, per)
        kinds = [KINDS[cfg.bc(f).kind] for f in FACES]
        self._kinds = kinds
        self._singular = OUTLET not in kinds
        # ---- flat layout
        self._fshapes = [grid.face_shape(a) for a in range(3)]
        fsz = [int(np.prod(s)) for s in self._fshapes]
        nf = sum(fsz)
        nc = nx * ny * nz
        self._nf, self._nc = nf, nc
        self._flux_sum = None  # the face-flux sum of add_face_flux, allocated on first use
        M = np.zeros(NM, np.int32)
        M[M_NX:M_NZ + 1] = cfg.shape
        M[M_BC:M_BC + 6] = kinds
        M[M_PER:M_PER + 3] = per
        M[M_SCHEME] = CONVECTION[cfg.convection]
        M[M_FORM] = PRESSURE_FORMS[cfg.pressure_form]
        has_walls = len(cfg.walls) > 0
        M[M_WALLS] = int(has_walls)
        M[M_FO:M_FO + 3] = [0, fsz[0], fsz[0] + fsz[1]]
        M[M_NF], M[M_NC] = nf, nc
        off = 0

        def alloc(n):
            nonlocal off
            o = off
            off += n
            return o

        for slot in (R_VEL, R_VOLD, R_VADV, R_VTMP, R_AP, R_ACC, R_DPRED, R_EF, R_BF, R_VSAVE):
            M[slot] = alloc(nf)
        if cfg.convection == "maccormack":
            M[R_VLO] = alloc(nf)
            M[R_VHI] = alloc(nf)
        else:
            M[R_VLO] = M[R_VHI] = M[R_VTMP]
        M[R_CL] = alloc(nf) if has_walls else M[R_AP]
        for slot, k in ((R_EPS, 1), (R_DEPS, 1), (R_BETA, 1), (R_US, 3), (R_FX, 3), (R_THETA, 1), (R_UC, 3), (R_P, 1),
                        (R_GP, 3), (R_DIV, 1)):
            M[slot] = alloc(k * nc)
        self._bcv_dims = []
        for fi, face in enumerate(FACES):
            b = fi // 2
            t = [a for a in range(3) if a != b]
            dims = (cfg.shape[t[0]], cfg.shape[t[1]])
            self._bcv_dims.append(dims)
            M[M_BCV + fi] = alloc(3 * dims[0] * dims[1])
        M[R_PAR] = alloc(NPAR)
        M[R_SC] = alloc(NSC)
        self._M_np = M
        self.M = ti.ndarray(ti.i32, shape=NM)
        self.M.from_numpy(M)
        self.F = ti.ndarray(float, shape=(off,))
        self.F.fill(0.0)
        # ---- constant data
        par = np.zeros(NPAR)
        par[P_RHO], par[P_MU], par[P_H] = cfg.rho, cfg.mu, cfg.h
        par[P_G:P_G + 3] = cfg.gravity
        pout = [cfg.bc(f).pressure if kinds[i] == OUTLET else 0.0 for i, f in enumerate(FACES)]
        par[P_POUT:P_POUT + 6] = pout
        par[P_THMIN] = THETA_MIN
        par[P_TRACE] = 1.0 if cfg.trace_forces else 0.0
        self._write(R_PAR, par)
        self._write(R_AP, np.concatenate([ap.ravel() for ap in cut.apertures]))
        if has_walls:
            cl = np.concatenate([np.minimum(c, 1e30).ravel() for c in cut.clearance])
            self._write(R_CL, cl)
        self._write(R_THETA, cut.volume.ravel())
        for fi, face in enumerate(FACES):
            if kinds[fi] in (INLET, MOVING):
                self._set_bcv(fi, np.broadcast_to(np.asarray(cfg.bc(face).velocity, float),
                                                  self._bcv_dims[fi] + (3,)))
        self.mg.set_dirichlet(np.zeros(6))  # the solve is for the increment
        self._bc_speeds = [float(np.linalg.norm(cfg.bc(f).velocity)) if kinds[i] in (INLET, MOVING) else 0.0
                           for i, f in enumerate(FACES)]
        # ---- bookkeeping
        self._ncoupled = sum(1 for a in range(3) if not (per[a] and cfg.shape[a] == 1))
        self.time = 0.0
        self.steps = 0
        self.last: StepInfo | None = None
        self._s_pred = 0.0
        self._div = (0.0, 0.0)
        self._p_init_pending = True
        self._pull()

    def _pull(self) -> None:
        fl = self.fields
        _k_pull(self.F, self.M, fl.eps, fl.deps_dt, fl.beta, fl.us, fl.f_exp)
        _k_face_coef(self.F, self.M)

    # ------------------------------------------------------------------ flat-array helpers
    def _write(self, slot: int, values: np.ndarray, extra: int = 0) -> None:
        _k_write(self.F, int(self._M_np[slot]) + extra, np.ascontiguousarray(np.asarray(values, np.float64).ravel()))

    def _read(self, slot: int, n: int, extra: int = 0) -> np.ndarray:
        out = np.zeros(n)
        _k_read(self.F, int(self._M_np[slot]) + extra, out)
        return out

    def _set_bcv(self, fi: int, vec: np.ndarray) -> None:
        # stored component-major: [comp][t1][t2]
        _k_write(self.F, int(self._M_np[M_BCV + fi]),
                 np.ascontiguousarray(np.moveaxis(np.asarray(vec, np.float64), -1, 0)).ravel())

    # ------------------------------------------------------------------ inputs
    def set_eps(self, eps) -> None:
        """Gas volume fraction (scalar or (nx, ny, nz)), each in (0, 1]."""
        a = _as_cell_array(eps, self.shape, "eps")
        if np.any(a <= 0.0) or np.any(a > 1.0):
            raise ValueError("flow: eps must lie in (0, 1]")
        _load(self.fields.eps, a)

    def set_deps_dt(self, deps) -> None:
        """d(eps)/dt [1/s] (scalar or (nx, ny, nz))."""
        _load(self.fields.deps_dt, _as_cell_array(deps, self.shape, "deps_dt"))

    def set_beta(self, beta) -> None:
        """Implicit drag coefficient [kg m^-3 s^-1] (scalar or (nx, ny, nz)), >= 0."""
        a = _as_cell_array(beta, self.shape, "beta")
        if np.any(a < 0.0):
            raise ValueError("flow: beta must be >= 0")
        _load(self.fields.beta, a)

    def set_solid_velocity(self, us) -> None:
        """Solid velocity [m/s] (3-vector or (nx, ny, nz, 3)) that beta pulls the gas toward."""
        _load(self.fields.us, _as_cell_array(us, self.shape, "solid velocity", vector=True))

    def set_explicit_source(self, f) -> None:
        """Explicit momentum source on the gas [N/m^3] (3-vector or (nx, ny, nz, 3))."""
        _load(self.fields.f_exp, _as_cell_array(f, self.shape, "explicit source", vector=True))

    def set_inlet_profile(self, face: str, profile) -> None:
        """Superficial inlet velocity of a velocity-inlet ``face`` per boundary cell.

        ``profile``: (n1, n2) normal component (into the domain for a positive value on the
        '-' faces, so use the sign of the global axis) or (n1, n2, 3) full vectors, where
        (n1, n2) are the cell counts along the face's two other axes in x, y, z order.
        Takes effect from the next step; may change every step.
        """
        f = ALIASES.get(face, face)
        if f not in FACES:
            raise ValueError(f"flow: unknown face {face!r}")
        fi = FACES.index(f)
        if self._kinds[fi] != INLET:
            raise ValueError(f"flow: face {f!r} is not a velocity inlet")
        dims = self._bcv_dims[fi]
        a = np.asarray(profile, np.float64)
        if a.shape == dims:
            vec = np.zeros(dims + (3,))
            vec[..., fi // 2] = a
        elif a.shape == dims + (3,):
            vec = a
        else:
            raise ValueError(f"flow: inlet profile of {f!r} must have shape {dims} or {dims + (3,)}, got {a.shape}")
        if not np.all(np.isfinite(vec)):
            raise ValueError("flow: inlet profile must be finite")
        self._set_bcv(fi, vec)
        self._bc_speeds[fi] = float(np.max(np.linalg.norm(vec, axis=-1))) if vec.size else 0.0

    @property
    def _bc_speed(self) -> float:
        return max(self._bc_speeds)

    def set_face_velocity(self, u=None, v=None, w=None) -> None:
        """Set face velocities [m/s] (arrays of the face shapes; None keeps a component).
        Closed faces are zeroed and periodic duplicates made consistent."""
        for a, arr in enumerate((u, v, w)):
            if arr is None:
                continue
            arr = np.asarray(arr, np.float64)
            if arr.shape != self._fshapes[a]:
                raise ValueError(f"flow: face velocity {'uvw'[a]} must have shape {self._fshapes[a]}, got {arr.shape}")
            self._write(R_VEL, arr, extra=int(self._M_np[M_FO + a]))
        _k_periodic_copy(self.F, self.M)

    # ------------------------------------------------------------------ outputs
    def face_velocity(self, axis: int) -> np.ndarray:
        """Face velocities [m/s] of component ``axis`` (0, 1, 2), shape face_shape(axis)."""
        a = int(axis)
        n = int(np.prod(self._fshapes[a]))
        return self._read(R_VEL, n, extra=int(self._M_np[M_FO + a])).reshape(self._fshapes[a])

    def face_velocities(self):
        """(u, v, w) face velocities [m/s] (interstitial), each of shape face_shape(axis)."""
        return tuple(self.face_velocity(a) for a in range(3))

    def add_face_flux(self, dt: float) -> None:
        """Add dt x every face's gas volume flux [m^3] (aperture x face gas fraction x velocity x h^2, with the
        face gas fraction the step used) to a sum kept on the device; nothing is read back (face_flux_sum is)."""
        if self._flux_sum is None:
            self._flux_sum = ti.ndarray(ti.f64, shape=(self._nf,))
            self._flux_sum.fill(0.0)
        _k_add_face_flux(self.F, self.M, self._flux_sum, float(dt) * self.h ** 2)

    def face_flux_sum(self) -> tuple:
        """The sums of add_face_flux since the last call [m^3], one array per axis (face_shape(axis)), then clears
        them (zeros when nothing was added)."""
        if self._flux_sum is None:
            return tuple(np.zeros(s) for s in self._fshapes)
        flat = self._flux_sum.to_numpy()
        self._flux_sum.fill(0.0)
        off = [int(self._M_np[M_FO + a]) for a in range(3)]
        return tuple(flat[off[a]:off[a] + int(np.prod(self._fshapes[a]))].reshape(self._fshapes[a]) for a in range(3))

    def void_fraction(self) -> np.ndarray:
        """Gas volume fraction eps [-] on the cells (nx, ny, nz), as the coupling last wrote it (the
        solver reads it clamped to [1e-3, 1]). With :meth:`face_velocities`, the volume flux through a
        face is aperture * eps_face * u * h^2 (eps_face the mean of its two cells)."""
        return self.fields.eps.to_numpy()

    def cell_velocity(self) -> np.ndarray:
        """Interstitial gas velocity at cell centres (nx, ny, nz, 3) [m/s] (0 in inactive cells)."""
        return self.fields.u_gas.to_numpy()

    def pressure(self) -> np.ndarray:
        """Pressure [Pa] at cell centres (nx, ny, nz)."""
        return self.fields.p.to_numpy()

    def pressure_gradient(self) -> np.ndarray:
        return self.fields.grad_p.to_numpy()

    def gas_extremes(self) -> tuple[float, int]:
        """(largest gas speed at cell centres [m/s], number of cells with a non-finite velocity or pressure),
        reduced on the device."""
        _k_gas_extremes(self.fields.u_gas, self.fields.p, self._reduced)
        r = self._reduced.to_numpy()
        return float(np.sqrt(max(r[0], 0.0))), int(r[1])

    def end_layer_pressures(self) -> tuple[float, float, float, float]:
        """Open-area means of the pressure [Pa] in the first, second, second-to-last and last cell layers
        (weighted by the open fraction of the bottom layer for the first two, of the top layer for the others)."""
        if self.shape[2] < 2:
            raise ValueError("flow: end-layer pressures need at least two cell layers")
        _k_end_layer_pressures(self.fields.p, self.fields.vol_frac, self._reduced)
        r = self._reduced.to_numpy()
        wb, wt = max(r[4], 1e-300), max(r[5], 1e-300)
        return float(r[0] / wb), float(r[1] / wb), float(r[2] / wt), float(r[3] / wt)

    @property
    def cfl(self) -> float:
        return self.last.cfl if self.last else 0.0

    @property
    def pressure_iterations(self) -> int:
        return self.last.pressure_iterations if self.last else 0

    def divergence(self) -> np.ndarray:
        """Per-cell continuity residual theta*deps/dt + div(eps u) [1/s] of the current velocity,
        with the eps and d(eps)/dt the last step used (those at construction before any step)."""
        self._div = tuple(float(x) for x in _k_outputs(self.F, self.M, self.mg.G, self.mg.M))
        _k_push(self.F, self.M, self.mg.G, self.mg.M, self.fields.p, self.fields.u_gas, self.fields.grad_p)
        return self._read(R_DIV, self._nc).reshape(self.shape)

    def divergence_residual(self) -> float:
        """max|continuity residual| / S of the current velocity, S = the larger gross face-flux
        rate of a cell of the current field and of the last predicted field (module doc).
        After every step this is <= tol when the pressure solve converged."""
        self.divergence()
        dmax, smax = self._div
        s = max(smax, self._s_pred)
        return dmax / s if s > 0 else 0.0

    def boundary_flux(self, face: str) -> float:
        """Volumetric gas flow out of the domain through ``face`` [m^3/s] (sum a eps u h^2; negative = in)."""
        f = ALIASES.get(face, face)
        fi = FACES.index(f)
        a, side = fi // 2, fi % 2
        vel = self.face_velocity(a)
        ap = self.cut.apertures[a]
        eps = self.fields.eps.to_numpy()
        idx = 0 if side == 0 else self.shape[a]
        cell = 0 if side == 0 else self.shape[a] - 1
        q = np.take(ap * vel, idx, axis=a) * np.take(eps, cell, axis=a)
        sign = -1.0 if side == 0 else 1.0
        return sign * float(q.sum()) * self.h ** 2

    # ------------------------------------------------------------------ checkpoints
    def state_arrays(self) -> dict:
        """Every array needed to continue the run bit-for-bit (numpy copies): face velocities
        ``u``, ``v``, ``w`` [m/s]; ``pressure`` [Pa]; the coupling inputs ``eps``, ``deps_dt``,
        ``beta``, ``solid_velocity``, ``explicit_source``; the last step's ``acceleration`` and
        ``predictor_increment`` (flat face arrays, used by the second-order advection and the
        viscous initial iterate); ``inlet_<face>`` profiles (n1, n2, 3); ``time``, ``steps`` and
        ``pressure_initialised`` as 0-d arrays."""
        fl = self.fields
        out = {"u": self.face_velocity(0), "v": self.face_velocity(1), "w": self.face_velocity(2),
               "pressure": self._read(R_P, self._nc).reshape(self.shape),
               "eps": fl.eps.to_numpy(), "deps_dt": fl.deps_dt.to_numpy(), "beta": fl.beta.to_numpy(),
               "solid_velocity": fl.us.to_numpy(), "explicit_source": fl.f_exp.to_numpy(),
               "acceleration": self._read(R_ACC, self._nf), "predictor_increment": self._read(R_DPRED, self._nf),
               "time": np.asarray(self.time, np.float64), "steps": np.asarray(self.steps, np.int64),
               "pressure_initialised": np.asarray(not self._p_init_pending)}
        for fi, face in enumerate(FACES):
            if self._kinds[fi] in (INLET, MOVING):
                dims = self._bcv_dims[fi]
                blk = self._read(M_BCV + fi, 3 * dims[0] * dims[1]).reshape((3,) + dims)
                out["inlet_" + face] = np.moveaxis(blk, 0, -1).copy()
        return out

    def load_state_arrays(self, arrays: dict) -> None:
        """Restore a state written by :meth:`state_arrays` (same set-up); ValueError if it does not fit."""
        def get(name, shape):
            if name not in arrays:
                raise ValueError(f"flow: gas state lacks {name!r}")
            a = np.asarray(arrays[name], np.float64)
            if a.shape != tuple(shape):
                raise ValueError(f"flow: gas state {name!r} has shape {a.shape}, this set-up needs {tuple(shape)}")
            return a

        sh, sh3 = self.shape, self.shape + (3,)
        self.set_eps(get("eps", sh))
        self.set_deps_dt(get("deps_dt", sh))
        self.set_beta(get("beta", sh))
        self.set_solid_velocity(get("solid_velocity", sh3))
        self.set_explicit_source(get("explicit_source", sh3))
        self.set_face_velocity(*(get(n, self._fshapes[a]) for a, n in enumerate("uvw")))
        self._write(R_P, get("pressure", sh).ravel())
        self._write(R_ACC, get("acceleration", (self._nf,)))
        self._write(R_DPRED, get("predictor_increment", (self._nf,)))
        for fi, face in enumerate(FACES):
            if self._kinds[fi] in (INLET, MOVING):
                vec = get("inlet_" + face, self._bcv_dims[fi] + (3,))
                self._set_bcv(fi, vec)
                self._bc_speeds[fi] = float(np.max(np.linalg.norm(vec, axis=-1)))
        self.time = float(get("time", ()))
        self.steps = int(get("steps", ()))
        self._p_init_pending = not bool(get("pressure_initialised", ()))
        # refresh the cell outputs (u_gas, grad_p, p) from the restored state
        self._pull()
        self.divergence()

    # ------------------------------------------------------------------ the step
    def _jacobi_factor(self, dt: float) -> float:
        """Upper bound of the Jacobi contraction factor of the viscous predictor (eps = 1, beta = 0)."""
        cfg = self.config
        d = cfg.mu * dt / (cfg.rho * self.h ** 2)
        k = 2 * max(self._ncoupled, 1)
        return k * d / (1.0 + k * d)

    def set_pressure(self, p) -> None:
        """Set the pressure [Pa] (scalar or (nx, ny, nz)); it is the starting point of the
        incremental projection. Without it, the first :meth:`step` first computes a consistent
        pressure by a throw-away step from the initial velocity."""
        a = _as_cell_array(p, self.shape, "pressure")
        self._write(R_P, a.ravel())
        self._p_init_pending = False

    def step(self, dt: float) -> StepInfo:
        """Advance the gas by dt [s]: convection, implicit-drag/viscous predictor, projection."""
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"flow: dt must be a positive number of seconds, got {dt!r}")
        if self._p_init_pending:
            # the incremental projection needs a pressure that balances the forces; a step from
            # p = 0 would leave an O(dt) splitting error at no-slip walls. Take one step, keep its
            # pressure, and restart from the initial velocity.
            self._p_init_pending = False
            mp, nf = self._M_np, self._nf
            _k_copy(self.F, int(mp[R_VEL]), int(mp[R_VSAVE]), nf, 0)
            t, n = self.time, self.steps
            self._step(dt)
            self.time, self.steps = t, n
            _k_copy(self.F, int(mp[R_VSAVE]), int(mp[R_VEL]), nf, 0)
            _k_copy(self.F, 0, int(mp[R_ACC]), nf, 1)
            _k_copy(self.F, 0, int(mp[R_DPRED]), nf, 1)
        return self._step(dt)

    def _step(self, dt: float) -> StepInfo:
        """One fractional step. Every kernel is launched without waiting on the device: the viscous
        sweeps and the pressure iterations stop themselves there (a fixed number of launches, each
        doing nothing once done), and the host reads one record at the end. It reads again only
        when the pressure solve needed more iterations than the last step's count and a half
        (:meth:`MGPCG.budget`), or a refinement round is due (float32 at its precision floor)."""
        cfg = self.config
        F, M, G, MM = self.F, self.M, self.mg.G, self.mg.M
        fl = self.fields
        _k_pull(F, M, fl.eps, fl.deps_dt, fl.beta, fl.us, fl.f_exp)
        _k_face_coef(F, M)
        _k_advect(F, M, dt)
        _k_bc_prep(F, M, dt)
        # red-black Gauss-Seidel sweeps until the estimated error, change * r/(1-r) with r the
        # contraction factor at this diffusion number, and the change itself (a first sweep from a
        # poor initial iterate leaves red and black faces with different errors: a checkerboard)
        # are below VISCOUS_REDUCTION of the velocity scale (decided on the device)
        r = self._jacobi_factor(dt) ** 2
        factor = VISCOUS_REDUCTION * min(1.0, (1.0 - r) / max(r, 1e-30))
        nmax = int(cfg.max_viscous_sweeps)
        for c in range(-(-nmax // VISCOUS_CHUNK)):
            _k_visc(F, M, dt, int(c == 0), factor, self._bc_speed, nmax)
        max_iter = int(cfg.max_iter)
        rec = self._project(dt, 0, max_iter)
        first = self.mg.info_from(rec[7:])
        iters = first.iterations
        for _ in range(2):
            # refinement: where the solve stopped at its precision floor (float32 with a large
            # pressure increment), project the remaining, much smaller divergence once more
            dmax, s_ref = float(rec[3]), float(rec[5])
            if dmax <= cfg.tol * s_ref or iters >= max_iter:
                break
            rec = self._project(dt, 1, max_iter - iters)
            iters += self.mg.info_from(rec[7:]).iterations
        self.mg.last = first  # the next step's iteration budget follows the main solve
        uold, umax, nsw, dmax, smax, s_ref = (float(x) for x in rec[:6])
        self._s_pred = s_ref
        self._div = (dmax, smax)
        _k_push(F, M, G, MM, fl.p, fl.u_gas, fl.grad_p)
        div = dmax / s_ref if s_ref > 0 else 0.0
        self.time += dt
        self.steps += 1
        self.last = StepInfo(dt=dt, cfl=max(uold, umax) * dt / self.h,
                             diffusion_number=cfg.mu * dt / (cfg.rho * self.h ** 2), viscous_sweeps=int(round(nsw)),
                             pressure_iterations=iters, pressure_residual=div,
                             converged=div <= cfg.tol, divergence=div)
        return self.last

    def _project(self, dt: float, again: int, max_iter: int):
        """Pressure system, solve and correction (round ``again``); returns the step record (one read,
        more only when the solve outran its budget)."""
        F, M, G, MM = self.F, self.M, self.mg.G, self.mg.M
        _k_build(F, M, G, MM, dt, again)
        mg = self.mg
        mg.begin(self.config.tol, max_iter, singular=self._singular, device_scale=True)
        n = mg.budget()
        while True:
            mg.launch(n)
            _k_correct(F, M, G, MM, dt, again)
            rec = _k_record(F, M, G, MM)
            if rec[6] > 0.5 or mg.exhausted:
                return rec
            n = max(4, n // 2)
