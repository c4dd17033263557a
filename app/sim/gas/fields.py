"""The gas's field bundle shared with the coupling code (:class:`GasFields`) and its reductions.

The coupling writes the inputs (gas fraction, its rate, drag coefficient, solid velocity, explicit
source) and reads the outputs (pressure, cell velocity, pressure gradient); the solver reads the inputs
into its :data:`~app.sim.gas.layout.Inputs` bundle at the start of a step and writes the outputs from
its :data:`~app.sim.gas.layout.Cells` bundle at the end (:func:`k_pull`, :func:`k_push`: compiled per
set of fields, the only gas kernels that are).
"""
import numpy as np
import taichi as ti

from .config import EPS_MIN
from .grid import CutCells, MacGrid


@ti.kernel
def k_pull(eps: ti.template(), deps: ti.template(), beta: ti.template(), us: ti.template(), fx: ti.template(),
           eps_c: ti.types.ndarray(), deps_c: ti.types.ndarray(), beta_c: ti.types.ndarray(),
           us_c: ti.types.ndarray(), fx_c: ti.types.ndarray()):
    """The coupling's inputs into the solver's cell arrays (eps clamped to [EPS_MIN, 1]: guards kernels
    writing eps <= 0)."""
    ny, nz = eps.shape[1], eps.shape[2]
    nc = eps.shape[0] * ny * nz
    for i, j, k in eps:
        c = (i * ny + j) * nz + k
        eps_c[c] = ti.min(ti.max(eps[i, j, k], EPS_MIN), 1.0)
        deps_c[c] = deps[i, j, k]
        beta_c[c] = beta[i, j, k]
        for a in ti.static(range(3)):
            us_c[a * nc + c] = us[i, j, k][a]
            fx_c[a * nc + c] = fx[i, j, k][a]


@ti.kernel
def k_push(pres: ti.types.ndarray(), u_cell: ti.types.ndarray(), gradp_cell: ti.types.ndarray(), p: ti.template(),
           uc: ti.template(), gp: ti.template()):
    ny, nz = p.shape[1], p.shape[2]
    nc = p.shape[0] * ny * nz
    for i, j, k in p:
        c = (i * ny + j) * nz + k
        p[i, j, k] = pres[c]
        for a in ti.static(range(3)):
            uc[i, j, k][a] = u_cell[a * nc + c]
            gp[i, j, k][a] = gradp_cell[a * nc + c]


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
