"""The gas's arrays shared with the coupling code (:class:`GasFields`) and their reductions.

The coupling writes the inputs (gas fraction, its rate, drag coefficient, solid velocity, explicit
source) through the :data:`~app.sim.gas.layout.Inputs` bundle and reads the outputs (pressure, cell
velocity, pressure gradient) through :data:`~app.sim.gas.layout.Outputs`; the solver's kernels read and
write the same arrays (one copy of each: nothing is copied in or out per step).
"""
import numpy as np
import taichi as ti

from ..launch import kernel
from .grid import CutCells, MacGrid
from .layout import CellGeometry, Inputs, Outputs


@kernel
def _k_gas_extremes(u: ti.types.ndarray(), p: ti.types.ndarray(), out: ti.types.ndarray()):
    """out = [largest |u|^2 over the cells, number of cells with a non-finite velocity or pressure]: the
    per-step diagnostics reduced on the device (copying u and p to the host every step cost more). Both reduce
    into kernel-scope variables, stored once (an atomic per cell into ``out`` is one atomic per cell on one
    address: layout.face_max_into)."""
    vmax = 0.0
    nbad = 0.0
    for I in ti.grouped(p):
        v = u[I]
        ti.atomic_max(vmax, v.dot(v))
        bad = 0.0
        for a in ti.static(range(3)):
            if not ti.abs(v[a]) < 1e30:  # also catches NaN
                bad = 1.0
        if not ti.abs(p[I]) < 1e30:
            bad = 1.0
        nbad += bad
    out[0] = vmax
    out[1] = nbad


@kernel
def _k_end_layer_pressures(p: ti.types.ndarray(), vf: ti.types.ndarray(), out: ti.types.ndarray()):
    """out = [sums over the first, second, second-to-last and last cell layers of p x open fraction of the
    end layer (first for the bottom two, last for the top two), the first layer's and the last's open sum]."""
    nz = p.shape[2]
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    s4 = 0.0
    s5 = 0.0
    for i, j in ti.ndrange(p.shape[0], p.shape[1]):
        wb = vf[i, j, 0]
        wt = vf[i, j, nz - 1]
        s0 += p[i, j, 0] * wb
        s1 += p[i, j, 1] * wb
        s2 += p[i, j, nz - 2] * wt
        s3 += p[i, j, nz - 1] * wt
        s4 += wb
        s5 += wt
    out[0] = s0
    out[1] = s1
    out[2] = s2
    out[3] = s3
    out[4] = s4
    out[5] = s5


def _cells(sh, vec: bool = False, dtype=float):
    a = ti.Vector.ndarray(3, dtype, shape=sh) if vec else ti.ndarray(dtype, shape=sh)
    a.fill(0)
    return a


@ti.data_oriented
class GasFields:
    """Arrays of the gas (Taichi ndarrays), shared with the coupling code (all cell-centred, (nx, ny, nz)).

    Inputs (the solver reads them in every step; write them in kernels through :attr:`inputs` or
    through the FlowSolver setters):
      ``eps``      gas volume fraction [-], in (0, 1] (read clamped to [1e-3, 1]) (default 1)
      ``deps_dt``  d(eps)/dt [1/s]                                          (default 0)
      ``beta``     implicit drag coefficient [kg m^-3 s^-1], >= 0: the gas feels
                   beta (us - u) per unit volume                           (default 0)
      ``us``       solid velocity (vec3) [m/s] that beta pulls the gas toward
      ``f_exp``    explicit momentum source on the gas (vec3) [N/m^3]
    Outputs (written by every step; read them in kernels through :attr:`outputs`):
      ``p``        pressure [Pa] (gauge; outlet pressure as given; zero mean without outlet)
      ``u_gas``    interstitial gas velocity at cell centres (vec3) [m/s] (mean of the two faces)
      ``grad_p``   pressure gradient at cell centres (vec3) [Pa/m] (mean of the open faces;
                   Model A grains feel -V_p grad_p)
    Geometry (constant; :attr:`geometry`): ``vol_frac`` open volume fraction [-]; ``active`` (i32) 1 for
    gas cells. Python attributes: ``shape``, ``h`` [m], ``origin`` [m], ``periodic`` (1 or 0 per axis: 1 where
    the last cell's neighbour is the first) (compile-time constants of a kernel that takes this object as
    ``ti.template()`` for :meth:`cell_of`).
    """

    def __init__(self, grid: MacGrid, cut: CutCells, periodic=(False, False, False)):
        self.shape = tuple(grid.shape)
        self.periodic = tuple(int(bool(p)) for p in periodic)
        self.h = float(grid.h)
        self.origin = tuple(grid.origin)
        sh = self.shape
        self.eps = _cells(sh)
        self.deps_dt = _cells(sh)
        self.beta = _cells(sh)
        self.us = _cells(sh, True)
        self.f_exp = _cells(sh, True)
        self.p = _cells(sh)
        self.u_gas = _cells(sh, True)
        self.grad_p = _cells(sh, True)
        self.vol_frac = _cells(sh)
        self.active = _cells(sh, dtype=ti.i32)
        self.eps.fill(1.0)
        _load(self.vol_frac, cut.volume)
        self.active.from_numpy(cut.active.astype(np.int32))
        self.inputs = Inputs(gas_eps=self.eps, gas_deps_dt=self.deps_dt, drag_beta=self.beta, solid_vel=self.us,
                             ext_force=self.f_exp)
        self.outputs = Outputs(gas_p=self.p, gas_u=self.u_gas, gas_gradp=self.grad_p)
        self.geometry = CellGeometry(open_frac=self.vol_frac, active_cell=self.active)

    @ti.func
    def cell_of(self, x):
        """Cell index (i32 vec3, clamped into the grid) containing point x [m]."""
        q = (x - ti.Vector(self.origin)) / self.h
        c = ti.cast(ti.floor(q), ti.i32)
        for a in ti.static(range(3)):
            c[a] = ti.min(ti.max(c[a], 0), self.shape[a] - 1)
        return c

    @ti.func
    def velocity_at(self, gout: ti.template(), x):
        """Gas velocity [m/s] at point x [m]: trilinear interpolation of the cell velocity of the outputs
        bundle ``gout`` (:attr:`outputs`, a kernel argument) (clamped at the box)."""
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
            U += w * gout.gas_u[c]
        return U


def _load(field, values) -> None:
    """field.from_numpy in the array's own float type (no implicit f64 -> f32 narrowing in Taichi)."""
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
