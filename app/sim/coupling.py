"""Online CFD-DEM coupling: void fraction, interpolation and drag exchange, every fluid step.

Owns: the deposit of grain volume onto the gas grid (cloud-in-cell, wall-aware, optionally
smoothed, clipped at eps_min), the interpolation of gas quantities to the grains with the
same weights, and the momentum exchange (the drag law's coefficient on the gas diagonal
and the implicit drag on the grains). It reads the DEM's and the gas's bundles (the gas's as
argpacks of its own arrays: ``GasFields.inputs``, ``.outputs``, ``.geometry``) and
writes their coupling inputs; it never prints or writes files.

Weights. A grain at x spreads over the 8 cells around it with trilinear weights w_c
(cell centres as nodes), each multiplied by the cell's open volume fraction (0 inside the
wall) and renormalised to sum 1; across a periodic face the corner cells are those at the
other end of the grid (and the smoothing's neighbours too). The same w_c interpolate eps, u_gas and grad p to the
grain, and carry the grain's drag reaction back to the gas; so the deposited volume
equals the grains' volume and the drag on the grains equals minus the drag on the gas,
both to rounding.

Exchange (per grain p, with eps_p, u_p interpolated and slip w = |u_p - v_p|):
    K_p = beta(eps_p, w) V_p / phi_p          Model A (pressure_form = "shared")
    K_p = beta(eps_p, w) V_p / (phi_p eps_p)  Model B (pressure_form = "gas")
The grain feels K_p (u_p - v_p) (implicit in the DEM update) plus -V_p grad p (Model A)
or the buoyancy -rho_g V_p g (Model B; its reaction goes to the gas's explicit source, so
the gas column weighs rho_g g in a bed too and both forms give the same pressure drop). The gas feels, per cell, beta_c (us_c - u) with
beta_c = sum_p w_c K_p / V_c and us_c = sum_p w_c K_p v_p / sum_p w_c K_p, implicit in the
gas predictor. With smoothing, the sums of w K and w K v are diffused like the grains'
volume (same passes), so the gas's drag sits where eps says the grains are; the total
exchanged coefficient is conserved, and the momentum balance is exact for a uniform gas
velocity (otherwise to O(width^2 grad^2 u)).
"""
import dataclasses

import numpy as np
import taichi as ti

from .launch import kernel
from ..config.derived import SMOOTH_ALPHA, grain_volume
from . import drag
from .dem import grain_radius
from .gas.layout import CellGeometry, Inputs, Outputs


@dataclasses.dataclass(frozen=True)
class CouplingModel:
    """Compile-time description of the coupling."""

    law: drag.Law
    model_b: bool           # pressure carried by the gas (Model B)
    eps_min: float          # lower clip of the gas fraction
    gas_density: float      # [kg/m^3]
    gas_viscosity: float    # [Pa s]
    gravity: tuple          # [m/s^2]
    smoothing_passes: int   # conservative diffusion passes of the solid volume (0: none)
    serial: bool = False    # one CPU thread: each half of the coupling one serial task (``coupling_serial``)


grain_volume_func = ti.func(grain_volume)  # a grain's volume inside a kernel: the config's one formula


@ti.data_oriented
class CouplingFields:
    def __init__(self, shape):
        vec = ti.types.vector(3, float)
        self.solid = ti.field(float, shape)        # deposited grain volume per cell [m^3]
        self.solid_tmp = ti.field(float, shape)    # scratch of the smoothing passes (scalars)
        self.vec_tmp = vec.field(shape=shape)      # scratch of the smoothing passes (vectors)
        self.k_sum = ti.field(float, shape)        # sum w K [kg/s]
        self.k_v = vec.field(shape=shape)          # sum w K v [N]
        self.eps_prev = ti.field(float, shape)
        self.clipped = ti.field(ti.i32, ())


@ti.func
def _stencil(gf: ti.template(), x):
    """Lower corner, trilinear fractions of point x among cell centres."""
    q = (x - ti.Vector(gf.origin)) / gf.h - 0.5
    i0 = ti.cast(ti.floor(q), ti.i32)
    return i0, q - ti.cast(i0, float)


@ti.func
def _weights(gf: ti.template(), geo: ti.template(), x):
    """The 8 cells (clamped indices) and their wall-aware, renormalised weights."""
    i0, fr = _stencil(gf, x)
    w = ti.Vector([0.0] * 8)
    cells = ti.Matrix([[0, 0, 0]] * 8, ti.i32)
    total = 0.0
    for k in range(8):  # run-time loops over the corners: one compiled copy, not eight (compile time)
        d = ti.Vector([k & 1, (k >> 1) & 1, (k >> 2) & 1])
        c = i0 + d
        wk = 1.0
        inside = True
        for a in ti.static(range(3)):
            wk *= fr[a] if d[a] == 1 else 1.0 - fr[a]
            if ti.static(gf.periodic[a]):  # the corner beyond a periodic face is the first/last cell
                c[a] = (c[a] + gf.shape[a]) % gf.shape[a]
            else:
                if c[a] < 0 or c[a] >= gf.shape[a]:
                    inside = False
                c[a] = ti.min(ti.max(c[a], 0), gf.shape[a] - 1)
        if inside:
            wk *= geo.open_frac[c]
        else:
            wk = 0.0
        w[k] = wk
        total += wk
        for a in ti.static(range(3)):
            cells[k, a] = c[a]
    if total > 0:
        w /= total
    else:  # no open cell around (a grain deep in a wall corner): its own cell takes it
        c = gf.cell_of(x)
        for k in range(8):
            for a in ti.static(range(3)):
                cells[k, a] = c[a]
        w[0] = 1.0
    return cells, w


# Each part of the coupling is a cell's or a grain's body (a ti.func) and the kernels loop over them:
# as top-level loops (each a parallel task: a struct-for over the cells, a range-for over the grains), or,
# on one CPU thread (``cm.serial``), all nested in one serial loop (``coupling_serial``): one task for a
# half of the coupling instead of one per loop (~70 us each on one thread), the same bodies in the same
# order.

@ti.func
def _deposit_grain(m: ti.template(), g: ti.template(), s: ti.template(), gf: ti.template(), geo: ti.template(),
                   cf: ti.template(), i):
    if s.alive[i]:
        r = grain_radius(m, g, i)
        vol = grain_volume_func(r)
        cells, w = _weights(gf, geo, s.x[i])
        for k in range(8):
            c = ti.Vector([cells[k, 0], cells[k, 1], cells[k, 2]])
            ti.atomic_add(cf.solid[c], w[k] * vol)


@kernel
def deposit(m: ti.template(), g: ti.template(), s: ti.template(), gf: ti.template(), geo: CellGeometry,
            cf: ti.template()):
    for I in ti.grouped(cf.solid):
        cf.solid[I] = 0.0
    for i in range(m.n):
        _deposit_grain(m, g, s, gf, geo, cf, i)


@ti.func
def _smooth_cell(gf: ti.template(), geo: ti.template(), f: ti.template(), tmp: ti.template(), I):
    acc = f[I]
    if geo.active_cell[I]:
        pI = ti.max(geo.open_frac[I], 1e-12)
        cI = f[I] / pI
        shape = ti.Vector(gf.shape)
        periodic = ti.Vector(gf.periodic)
        for a in range(3):  # a run-time loop: the stencil compiled once, not per axis (compile time)
            for sgn in ti.static((-1, 1)):
                J = I
                J[a] += sgn
                if periodic[a] == 1:  # across a periodic face: the cell at the other end
                    J[a] = (J[a] + shape[a]) % shape[a]
                if 0 <= J[a] < shape[a]:
                    if geo.active_cell[J]:
                        pJ = ti.max(geo.open_frac[J], 1e-12)
                        acc += SMOOTH_ALPHA * ti.min(pI, pJ) * (f[J] / pJ - cI)
    tmp[I] = acc


@kernel
def smooth_pass(gf: ti.template(), geo: CellGeometry, f: ti.template(), tmp: ti.template()):
    """One conservative diffusion pass of an extensive cell quantity f (grain volume, drag
    coefficient sums): the flux between open neighbours I, J is alpha min(phi_I, phi_J) (c_J - c_I),
    with c = f / phi the amount per full cell volume and phi the open volume fraction. So a
    sliver cut cell at the wall exchanges in proportion to its open volume, and a uniform bed
    stays uniform up to the wall (a flux of alpha (f_J - f_I) would fill slivers as if they
    were whole cells, clip their eps and leave their drag empty). Stable: the weights of c_I
    sum to at most 6 alpha < 1."""
    for I in ti.grouped(f):
        _smooth_cell(gf, geo, f, tmp, I)
    for I in ti.grouped(f):
        f[I] = tmp[I]


@ti.func
def _void_cell(cm: ti.template(), gf: ti.template(), geo: ti.template(), cf: ti.template(), dt, first,
               gin: ti.template(), I):
    vcell = gf.h * gf.h * gf.h
    e = 1.0
    if geo.active_cell[I]:
        e = 1.0 - cf.solid[I] / (vcell * ti.max(geo.open_frac[I], 1e-12))
        if e < cm.eps_min:
            e = ti.cast(cm.eps_min, float)
            cf.clipped[None] += 1
    prev = cf.eps_prev[I]
    if first:
        prev = e
    gin.gas_deps_dt[I] = (e - prev) / dt
    gin.gas_eps[I] = e
    cf.eps_prev[I] = e


@kernel
def void_fraction(cm: ti.template(), gf: ti.template(), geo: CellGeometry, cf: ti.template(), dt: float,
                  first: ti.i32, gin: Inputs):
    """eps = 1 - solid / open cell volume, clipped at eps_min; d(eps)/dt against the previous step: the
    gas's inputs (``gin``, its own arrays)."""
    cf.clipped[None] = 0
    for I in ti.grouped(cf.solid):
        _void_cell(cm, gf, geo, cf, dt, first, gin, I)


@ti.func
def _clear_exchange_cell(cm: ti.template(), cf: ti.template(), gin: ti.template(), I):
    cf.k_sum[I] = 0.0
    cf.k_v[I] = ti.Vector([0.0, 0.0, 0.0])
    if ti.static(cm.model_b):
        gin.ext_force[I] = ti.Vector([0.0, 0.0, 0.0])


@ti.func
def _exchange_grain(cm: ti.template(), m: ti.template(), g: ti.template(), s: ti.template(), gf: ti.template(),
                    geo: ti.template(), gout: ti.template(), cf: ti.template(), gin: ti.template(), i):
    if s.alive[i]:
        r = grain_radius(m, g, i)
        vol = grain_volume_func(r)
        cells, w = _weights(gf, geo, s.x[i])
        eps = 0.0
        ug = ti.Vector([0.0, 0.0, 0.0])
        gp = ti.Vector([0.0, 0.0, 0.0])
        for k in range(8):
            c = ti.Vector([cells[k, 0], cells[k, 1], cells[k, 2]])
            eps += w[k] * gin.gas_eps[c]
            ug += w[k] * gout.gas_u[c]
            gp += w[k] * gout.gas_gradp[c]
        v = s.v[i]
        slip = (ug - v).norm()
        phi = ti.max(1.0 - eps, 0.0)
        # beta / phi directly: in float32 a grain alone in a large cell has eps == 1 (phi == 0)
        kp = drag.per_grain_volume_func(cm.law, eps, phi, slip, 2.0 * r, cm.gas_density, cm.gas_viscosity) * vol
        if ti.static(cm.model_b):
            kp /= eps
            buoyancy = -cm.gas_density * vol * ti.Vector(cm.gravity)
            s.external_force[i] = buoyancy
            # its reaction on the gas, so momentum is conserved and the gas column weighs rho_g g
            # everywhere (as in Model A): both forms then give the same pressure drop
            for k in range(8):
                c = ti.Vector([cells[k, 0], cells[k, 1], cells[k, 2]])
                vc = gf.h * gf.h * gf.h * ti.max(geo.open_frac[c], 1e-12)
                ti.atomic_add(gin.ext_force[c], -w[k] * buoyancy / vc)
        else:
            s.external_force[i] = -vol * gp
        s.drag_coeff[i] = kp
        s.gas_velocity[i] = ug
        for k in range(8):
            c = ti.Vector([cells[k, 0], cells[k, 1], cells[k, 2]])
            ti.atomic_add(cf.k_sum[c], w[k] * kp)
            ti.atomic_add(cf.k_v[c], w[k] * kp * v)


@kernel
def exchange(cm: ti.template(), m: ti.template(), g: ti.template(), s: ti.template(), gf: ti.template(),
             geo: CellGeometry, gout: Outputs, cf: ti.template(), gin: Inputs):
    """Per-grain drag coefficient, gas velocity and explicit force from the gas's outputs (``gout``) and
    gas fraction; the reaction onto the gas cells (the sums in ``cf``; Model B's explicit source in ``gin``)."""
    for I in ti.grouped(cf.k_sum):
        _clear_exchange_cell(cm, cf, gin, I)
    for i in range(m.n):
        _exchange_grain(cm, m, g, s, gf, geo, gout, cf, gin, i)


@ti.func
def _drag_cell(gf: ti.template(), geo: ti.template(), cf: ti.template(), gin: ti.template(), I):
    k = cf.k_sum[I]
    vc = gf.h * gf.h * gf.h * ti.max(geo.open_frac[I], 1e-12)
    gin.drag_beta[I] = k / vc
    us = ti.Vector([0.0, 0.0, 0.0])
    if k > 0:
        us = cf.k_v[I] / k
    gin.solid_vel[I] = us


@kernel
def drag_on_gas(gf: ti.template(), geo: CellGeometry, cf: ti.template(), gin: Inputs):
    """beta and us per cell (the gas's inputs ``gin``) from the (smoothed) sums of w K and w K v."""
    for I in ti.grouped(cf.k_sum):
        _drag_cell(gf, geo, cf, gin, I)


@ti.func
def _smooth_nested(gf: ti.template(), geo: ti.template(), f: ti.template(), tmp: ti.template()):
    """``smooth_pass`` inside a loop (a struct-for cannot be nested: the cells as an ndrange)."""
    for I in ti.grouped(ti.ndrange(*gf.shape)):
        _smooth_cell(gf, geo, f, tmp, I)
    for I in ti.grouped(ti.ndrange(*gf.shape)):
        f[I] = tmp[I]


@kernel
def coupling_serial(cm: ti.template(), m: ti.template(), g: ti.template(), s: ti.template(), gf: ti.template(),
                    geo: CellGeometry, gout: Outputs, cf: ti.template(), gin: Inputs, dt: float, first: ti.i32,
                    with_deposit: ti.template(), with_exchange: ti.template()):
    """On one CPU thread: the deposit (with its smoothing and the void fraction) and/or the exchange (with
    its smoothing and the drag on the gas) as one serial task, the loops of the kernels above in their order."""
    ti.static_assert(cm.serial, "coupling_serial runs on one CPU thread only")
    ti.loop_config(serialize=True)
    for _ in range(1):
        if ti.static(with_deposit):
            for I in ti.grouped(ti.ndrange(*gf.shape)):
                cf.solid[I] = 0.0
            for i in range(m.n):
                _deposit_grain(m, g, s, gf, geo, cf, i)
            for _p in range(cm.smoothing_passes):
                _smooth_nested(gf, geo, cf.solid, cf.solid_tmp)
            cf.clipped[None] = 0
            for I in ti.grouped(ti.ndrange(*gf.shape)):
                _void_cell(cm, gf, geo, cf, dt, first, gin, I)
        if ti.static(with_exchange):
            for I in ti.grouped(ti.ndrange(*gf.shape)):
                _clear_exchange_cell(cm, cf, gin, I)
            for i in range(m.n):
                _exchange_grain(cm, m, g, s, gf, geo, gout, cf, gin, i)
            for _p in range(cm.smoothing_passes):
                _smooth_nested(gf, geo, cf.k_sum, cf.solid_tmp)
                _smooth_nested(gf, geo, cf.k_v, cf.vec_tmp)
            for I in ti.grouped(ti.ndrange(*gf.shape)):
                _drag_cell(gf, geo, cf, gin, I)


class Coupler:
    """Runs the coupling between one DEM solver and one gas solver (no I/O)."""

    def __init__(self, model: CouplingModel, dem, flow):
        self.cm = model
        self.dem = dem
        self.flow = flow
        self.gf = flow.fields
        self.cf = CouplingFields(self.gf.shape)
        self._first = True

    def _serial(self, dt: float, with_deposit: bool, with_exchange: bool) -> None:
        d, gf = self.dem, self.gf
        coupling_serial(self.cm, d.m, d.fixed, d.state, gf, gf.geometry, gf.outputs, self.cf, gf.inputs, dt,
                        int(self._first), with_deposit, with_exchange)

    def deposit(self, dt: float) -> None:
        """Grains -> eps and d(eps)/dt on the gas grid."""
        d, gf = self.dem, self.gf
        if self.cm.serial:
            self._serial(dt, True, False)
        else:
            deposit(d.m, d.fixed, d.state, gf, gf.geometry, self.cf)
            for _ in range(self.cm.smoothing_passes):
                smooth_pass(gf, gf.geometry, self.cf.solid, self.cf.solid_tmp)
            void_fraction(self.cm, gf, gf.geometry, self.cf, dt, int(self._first), gf.inputs)
        self._first = False

    def exchange(self) -> None:
        """Drag coefficients onto the gas diagonal and onto the grains (uses the current gas velocity)."""
        d, gf = self.dem, self.gf
        if self.cm.serial:
            self._serial(1.0, False, True)
            return
        exchange(self.cm, d.m, d.fixed, d.state, gf, gf.geometry, gf.outputs, self.cf, gf.inputs)
        # the gas feels the drag spread like the grains' volume, so beta and eps agree cell by cell
        for _ in range(self.cm.smoothing_passes):
            smooth_pass(gf, gf.geometry, self.cf.k_sum, self.cf.solid_tmp)
            smooth_pass(gf, gf.geometry, self.cf.k_v, self.cf.vec_tmp)
        drag_on_gas(gf, gf.geometry, self.cf, gf.inputs)

    def step(self, dt: float) -> None:
        """The coupling half of a fluid step: deposit, then exchange (the gas step and DEM substeps follow);
        on one CPU thread one launch of one serial task."""
        if self.cm.serial:
            self._serial(dt, True, True)
            self._first = False
        else:
            self.deposit(dt)
            self.exchange()

    @property
    def clipped_cells(self) -> int:
        return int(self.cf.clipped[None])

    def deposited_volume(self) -> float:
        return float(self.cf.solid.to_numpy().sum())

    def state_arrays(self) -> dict:
        return {"eps_prev": self.cf.eps_prev.to_numpy(), "first": np.array(int(self._first))}

    def load_state_arrays(self, a: dict) -> None:
        self.cf.eps_prev.from_numpy(np.asarray(a["eps_prev"], self.cf.eps_prev.to_numpy().dtype))
        self._first = bool(int(a["first"]))
