"""The DEM substep: neighbour list upkeep, contact forces, walls and integration.

Owns: the kernels that advance grains by one DEM step, and ``DemSolver``, which holds
the field bundles of one scene and calls the kernels in order. It never prints or
writes files; diagnostics are computed only when asked for.

One substep = [rebuild the Verlet half list if some grain moved more than skin/2]
-> contact forces (grain pairs from the half list, then each wall, in one kernel)
-> symplectic Euler integration (v += a dt; x += v dt; omega += T/I dt), which also
zeroes the accumulators, removes grains that left the domain and measures the
largest displacement since the last rebuild.

Contact laws (all sign conventions: n points from grain i to its partner):
- normal: linear  F = k_n d + 2 zeta sqrt(m* k_n) dd/dt, or
          Hertz   F = 4/3 E* sqrt(R*) d^1.5 + alpha sqrt(m* k_n) d^0.25 dd/dt,
  clamped at F >= 0 (no attraction); zeta / alpha are solved from the restitution in
  ``app.config.derived``.
- tangential (with friction only): an incremental spring on the accumulated slip xi,
  k_t = 8 G* sqrt(R* d) (Mindlin) or the linear k_t, with damping of the same
  dimensionless strength as the normal one, capped by Coulomb |F_t| <= mu F_n (the
  spring is reset to the capped force, so sliding dissipates).
- rolling (optional): constant torque mu_r R* F_n against the relative rolling
  velocity, or an elastic-plastic spring-dashpot (k_r = 2.25 mu_r^2 R*^2 dF_n/dd,
  capped at mu_r R* F_n), following Ai et al. (2011) Powder Technol. 206:269.
"""

import math

import numpy as np
import taichi as ti

from .fields import (ROLL_CONSTANT, ROLL_EPSD, SCAN_BLOCK, ContactHistory, DemModel, GrainModel, GrainState,
                     NeighborList, WallData)
from .geometry import wall_clearance_normal

vec3 = ti.types.vector(3, float)


# ---------------------------------------------------------------------------- per-grain constants

@ti.func
def grain_radius(m: ti.template(), g: ti.template(), i):
    r = ti.cast(m.radius, float)
    if ti.static(m.polydisperse):
        r = g.radius[i]
    return r


@ti.func
def grain_mass(m: ti.template(), g: ti.template(), i):
    mass = ti.cast(m.mass, float)
    if ti.static(m.polydisperse):
        mass = g.mass[i]
    return mass


@ti.func
def scatter_add(m: ti.template(), f: ti.template(), j, value):
    """f[j] += value from inside the grain loop: atomic when threads run it, a plain
    read-modify-write when the loop is serial (float atomics are compare-and-swap loops on a CPU)."""
    if ti.static(m.serial):
        f[j] = f[j] + value
    else:
        ti.atomic_add(f[j], value)


@ti.func
def cell_of(m: ti.template(), p):
    c = ti.Vector([0, 0, 0])
    for a in ti.static(range(3)):
        c[a] = ti.min(ti.max(ti.cast(ti.floor((p[a] - m.lo[a]) / m.cell[a]), ti.i32), 0), m.cells[a] - 1)
    return c


@ti.func
def cell_index(m: ti.template(), c):
    return (c[2] * m.cells[1] + c[1]) * m.cells[0] + c[0]


# ---------------------------------------------------------------------------- contact law

@ti.func
def normal_force(m: ti.template(), wall: ti.template(), delta, ddelta, r_eff, m_eff):
    """Normal force magnitude (>= 0) and the local normal stiffness dF/dd."""
    e_star = ti.static(m.w_e_star if wall else m.e_star)
    damping = ti.static(m.w_damping if wall else m.damping)
    fn = 0.0
    stiff = 0.0
    if ti.static(m.hertz):
        kn = 4.0 / 3.0 * e_star * ti.sqrt(r_eff)
        sd = ti.sqrt(delta)
        fn = kn * delta * sd + damping * ti.sqrt(m_eff * kn) * ti.sqrt(sd) * ddelta
        stiff = 1.5 * kn * sd
    else:
        fn = m.kn * delta + 2.0 * damping * ti.sqrt(m_eff * m.kn) * ddelta
        stiff = ti.cast(m.kn, float)
    return ti.max(fn, 0.0), stiff


@ti.func
def tangential_force(m: ti.template(), wall: ti.template(), xi, n, vt, fn, delta, r_eff, m_eff):
    """Tangential force on grain i and the updated spring ``xi`` (slip history)."""
    g_star = ti.static(m.w_g_star if wall else m.g_star)
    damping = ti.static(m.w_damping if wall else m.damping)
    mu = ti.static(m.w_mu if wall else m.mu)
    # keep the spring in the current tangent plane, at its length
    mag = xi.norm()
    xi -= xi.dot(n) * n
    mag2 = xi.norm()
    if mag2 > 1e-30:
        xi *= mag / mag2
    xi += vt * m.dt
    kt = 0.0
    gamma = 0.0
    if ti.static(m.hertz):
        kt = 8.0 * g_star * ti.sqrt(r_eff * delta)
        # same dimensionless damping as the normal law: alpha sqrt(m* k_n) d^(1/4) = alpha sqrt(2/3 m* S_n)
        gamma = damping * ti.sqrt(2.0 / 3.0 * m_eff * kt)
    else:
        kt = ti.cast(m.kt, float)
        gamma = 2.0 * damping * ti.sqrt(m_eff * kt)
    ft = -kt * xi - gamma * vt
    ftn = ft.norm()
    limit = mu * fn
    if ftn > limit:
        if ftn > 1e-30:
            ft *= limit / ftn
        if kt > 0:
            xi = -(ft + gamma * vt) / kt
    return ft, xi


@ti.func
def rolling_torque(m: ti.template(), wall: ti.template(), mr, w_rel, fn, stiff, r_eff):
    """Rolling-resistance torque on grain i; ``mr`` is the elastic-plastic spring torque."""
    mu_r = ti.static(m.w_mu_roll if wall else m.mu_roll)
    tr = ti.Vector([0.0, 0.0, 0.0])
    limit = mu_r * r_eff * fn
    if ti.static(m.rolling == ROLL_CONSTANT):
        wn = w_rel.norm()
        if wn > 1e-12:
            tr = -limit * w_rel / wn
    elif ti.static(m.rolling == ROLL_EPSD):
        kr = 2.25 * mu_r * mu_r * r_eff * r_eff * stiff
        mr -= kr * w_rel * m.dt
        mn = mr.norm()
        if mn > limit and mn > 1e-30:
            mr *= limit / mn
        tr = mr
    return tr, mr


# ---------------------------------------------------------------------------- forces

@ti.kernel
def compute_forces(m: ti.template(), g: ti.template(), s: ti.template(), h: ti.template(),
                   nl: ti.template(), wd: ti.template()):
    # one CPU thread: a serial loop lets Taichi demote the partner atomics to plain adds
    ti.loop_config(serialize=m.serial)
    for i in range(m.n):
        if s.alive[i]:
            xi = s.x[i]
            vi = s.v[i]
            ri = grain_radius(m, g, i)
            mi = grain_mass(m, g, i)
            wi = ti.Vector([0.0, 0.0, 0.0])
            if ti.static(m.friction):
                wi = s.omega[i]
            fi = ti.Vector([0.0, 0.0, 0.0])
            ti_ = ti.Vector([0.0, 0.0, 0.0])
            for k in range(nl.count[i]):
                j = nl.partner[k, i]
                dx = s.x[j] - xi
                rj = grain_radius(m, g, j)
                d2 = dx.dot(dx)
                rs = ri + rj
                if d2 < rs * rs and s.alive[j]:
                    dist = ti.sqrt(d2)
                    n = dx / ti.max(dist, 1e-30)
                    delta = rs - dist
                    mj = grain_mass(m, g, j)
                    r_eff = ri * rj / rs
                    m_eff = mi * mj / (mi + mj)
                    # lever arms to the contact point, the middle of the overlap: they sum to the centre
                    # distance, so the pair's torques conserve angular momentum exactly
                    arm_i = ri - 0.5 * delta
                    arm_j = rj - 0.5 * delta
                    vrel = vi - s.v[j]
                    if ti.static(m.friction):
                        vrel += (wi * arm_i + s.omega[j] * arm_j).cross(n)
                    vn = vrel.dot(n)
                    fn, stiff = normal_force(m, False, delta, vn, r_eff, m_eff)
                    f = -fn * n
                    if ti.static(m.friction):
                        ft, xi_new = tangential_force(m, False, h.tangential[k, i], n, vrel - vn * n, fn, delta, r_eff, m_eff)
                        h.tangential[k, i] = xi_new
                        f += ft
                        tq = n.cross(ft)  # torque per unit lever arm: arm_i n x F on i, arm_j n x F on j
                        t_i = arm_i * tq
                        t_j = arm_j * tq
                        if ti.static(m.rolling != 0):
                            mr = ti.Vector([0.0, 0.0, 0.0])
                            if ti.static(m.rolling == ROLL_EPSD):
                                mr = h.rolling[k, i]
                            tr, mr = rolling_torque(m, False, mr, wi - s.omega[j], fn, stiff, r_eff)
                            if ti.static(m.rolling == ROLL_EPSD):
                                h.rolling[k, i] = mr
                            t_i += tr
                            t_j -= tr
                        ti_ += t_i
                        scatter_add(m, s.torque, j, t_j)
                    fi += f
                    scatter_add(m, s.force, j, -f)
                else:
                    if ti.static(m.friction):
                        h.tangential[k, i] = ti.Vector([0.0, 0.0, 0.0])
                    if ti.static(m.rolling == ROLL_EPSD):
                        h.rolling[k, i] = ti.Vector([0.0, 0.0, 0.0])
            # walls: unrolled at compile time, each with its own history slot
            for w in ti.static(range(len(m.walls))):
                clearance, nrm = wall_clearance_normal(m.walls[w], wd.sampled[w], xi)
                delta = ri - clearance
                if delta > 0:
                    n = -nrm  # from the grain towards the wall
                    arm = ri - 0.5 * delta
                    vrel = vi
                    if ti.static(m.friction):
                        vrel += (wi * arm).cross(n)
                    vn = vrel.dot(n)
                    fn, stiff = normal_force(m, True, delta, vn, ri, mi)
                    f = -fn * n
                    if ti.static(m.friction):
                        ft, xi_new = tangential_force(m, True, h.wall_tangential[w, i], n, vrel - vn * n, fn, delta, ri, mi)
                        h.wall_tangential[w, i] = xi_new
                        f += ft
                        ti_ += arm * n.cross(ft)
                        if ti.static(m.rolling != 0):
                            mr = ti.Vector([0.0, 0.0, 0.0])
                            if ti.static(m.rolling == ROLL_EPSD):
                                mr = h.wall_rolling[w, i]
                            tr, mr = rolling_torque(m, True, mr, wi, fn, stiff, ri)
                            if ti.static(m.rolling == ROLL_EPSD):
                                h.wall_rolling[w, i] = mr
                            ti_ += tr
                    fi += f
                else:
                    if ti.static(m.friction):
                        h.wall_tangential[w, i] = ti.Vector([0.0, 0.0, 0.0])
                    if ti.static(m.rolling == ROLL_EPSD):
                        h.wall_rolling[w, i] = ti.Vector([0.0, 0.0, 0.0])
            scatter_add(m, s.force, i, fi)
            if ti.static(m.friction):
                scatter_add(m, s.torque, i, ti_)


@ti.kernel
def integrate(m: ti.template(), g: ti.template(), s: ti.template(), nl: ti.template()):
    """Symplectic Euler; zeroes the accumulators; removes grains outside the domain."""
    nl.max_disp2[None] = 0.0
    for i in range(m.n):
        if s.alive[i]:
            mass = grain_mass(m, g, i)
            f = s.force[i]
            v = s.v[i]
            if ti.static(m.coupled):
                # drag K (u_gas - v) taken implicitly: stable even when m/K is shorter than dt
                f += s.external_force[i]
                kdt = s.drag_coeff[i] * m.dt / mass
                v = (v + (f / mass + ti.Vector(m.gravity)) * m.dt + kdt * s.gas_velocity[i]) / (1.0 + kdt)
            else:
                v = v + (f / mass + ti.Vector(m.gravity)) * m.dt
            x = s.x[i] + v * m.dt
            s.v[i] = v
            s.x[i] = x
            s.force[i] = ti.Vector([0.0, 0.0, 0.0])
            if ti.static(m.friction):
                r = grain_radius(m, g, i)
                s.omega[i] += s.torque[i] / (0.4 * mass * r * r) * m.dt
                s.torque[i] = ti.Vector([0.0, 0.0, 0.0])
            inside = True
            for a in ti.static(range(3)):
                if not (m.lo[a] <= x[a] <= m.hi[a]):
                    inside = False
            if not inside:
                s.alive[i] = ti.cast(0, ti.u8)
                s.v[i] = ti.Vector([0.0, 0.0, 0.0])
                ti.atomic_add(nl.removed[None], 1)
            else:
                d = x - nl.x_ref[i]
                ti.atomic_max(nl.max_disp2[None], d.dot(d))


# ---------------------------------------------------------------------------- neighbour list

@ti.kernel
def count_cells(m: ti.template(), s: ti.template(), nl: ti.template()):
    for c in range(m.n_cells):
        nl.cell_count[c] = 0
    for i in range(m.n):
        if s.alive[i]:
            ti.atomic_add(nl.cell_count[cell_index(m, cell_of(m, s.x[i]))], 1)


@ti.kernel
def scan_blocks(m: ti.template(), nl: ti.template()):
    nb = (m.n_cells + SCAN_BLOCK - 1) // SCAN_BLOCK
    for b in range(nb):
        total = 0
        for t in range(SCAN_BLOCK):
            c = b * SCAN_BLOCK + t
            if c < m.n_cells:
                total += nl.cell_count[c]
        nl.block_sum[b] = total


@ti.kernel
def scan_block_sums(m: ti.template(), nl: ti.template()):
    nb = (m.n_cells + SCAN_BLOCK - 1) // SCAN_BLOCK
    ti.loop_config(serialize=True)
    for b in range(1):
        run = 0
        for k in range(nb):
            v = nl.block_sum[k]
            nl.block_sum[k] = run
            run += v
        nl.cell_start[m.n_cells] = run


@ti.kernel
def scan_fill(m: ti.template(), nl: ti.template()):
    nb = (m.n_cells + SCAN_BLOCK - 1) // SCAN_BLOCK
    for b in range(nb):
        run = nl.block_sum[b]
        for t in range(SCAN_BLOCK):
            c = b * SCAN_BLOCK + t
            if c < m.n_cells:
                nl.cell_start[c] = run
                run += nl.cell_count[c]
                nl.cell_count[c] = nl.cell_start[c]  # becomes the scatter cursor


@ti.kernel
def scatter_cells(m: ti.template(), s: ti.template(), nl: ti.template()):
    for i in range(m.n):
        if s.alive[i]:
            slot = ti.atomic_add(nl.cell_count[cell_index(m, cell_of(m, s.x[i]))], 1)
            nl.sorted[slot] = i


@ti.kernel
def build_pairs(m: ti.template(), g: ti.template(), s: ti.template(), h: ti.template(), nl: ti.template()):
    """Rebuild each grain's half list in place, carrying every surviving pair's history to its new slot.

    A grain's new row is gathered in registers first; each thread writes only its own row, so
    no second list buffer is needed (this keeps the list at 4 bytes per slot)."""
    nl.overflow[None] = 0
    for i in range(m.n):
        cnt = 0
        new = ti.Vector([-1] * m.slots, ti.i32)
        if s.alive[i]:
            xi = s.x[i]
            ri = grain_radius(m, g, i)
            c = cell_of(m, xi)
            for dz, dy, dx in ti.ndrange((-1, 2), (-1, 2), (-1, 2)):
                q = c + ti.Vector([dx, dy, dz])
                if 0 <= q[0] < m.cells[0] and 0 <= q[1] < m.cells[1] and 0 <= q[2] < m.cells[2]:
                    ci = cell_index(m, q)
                    for p in range(nl.cell_start[ci], nl.cell_start[ci + 1]):
                        j = nl.sorted[p]
                        if j > i:
                            cut = ri + grain_radius(m, g, j) + m.skin
                            d = s.x[j] - xi
                            if d.dot(d) < cut * cut:
                                if cnt < m.slots:
                                    new[cnt] = j
                                    cnt += 1
                                else:
                                    ti.atomic_max(nl.overflow[None], cnt + 1)
            nl.x_ref[i] = xi
        if ti.static(m.friction or m.rolling == ROLL_EPSD):
            n_old = nl.count[i]
            keep_t = ti.Matrix.zero(float, m.slots, 3)
            keep_r = ti.Matrix.zero(float, m.slots, 3)
            for k in range(cnt):
                for q in range(n_old):
                    if nl.partner[q, i] == new[k]:
                        for a in ti.static(range(3)):
                            if ti.static(m.friction):
                                keep_t[k, a] = h.tangential[q, i][a]
                            if ti.static(m.rolling == ROLL_EPSD):
                                keep_r[k, a] = h.rolling[q, i][a]
            for k in range(m.slots):
                if ti.static(m.friction):
                    h.tangential[k, i] = ti.Vector([keep_t[k, 0], keep_t[k, 1], keep_t[k, 2]])
                if ti.static(m.rolling == ROLL_EPSD):
                    h.rolling[k, i] = ti.Vector([keep_r[k, 0], keep_r[k, 1], keep_r[k, 2]])
        for k in range(cnt):
            nl.partner[k, i] = new[k]
        nl.count[i] = cnt


# ---------------------------------------------------------------------------- diagnostics

@ti.kernel
def measure(m: ti.template(), g: ti.template(), s: ti.template(), nl: ti.template(), wd: ti.template(),
            out: ti.template(), hist: ti.template()) -> ti.i32:
    """Fill ``out`` with [KE_trans, KE_rot, max overlap/diameter, max speed, alive, bad values];
    ``hist`` with a height histogram of alive grains. Returns the alive count."""
    for k in range(6):
        out[k] = 0.0
    for b in range(hist.shape[0]):
        hist[b] = 0
    alive = 0
    nb = hist.shape[0]
    for i in range(m.n):
        if s.alive[i]:
            alive += 1
            mass = grain_mass(m, g, i)
            ri = grain_radius(m, g, i)
            v = s.v[i]
            x = s.x[i]
            ti.atomic_add(out[0], 0.5 * mass * v.dot(v))
            if ti.static(m.friction):
                w = s.omega[i]
                ti.atomic_add(out[1], 0.5 * 0.4 * mass * ri * ri * w.dot(w))
            ti.atomic_max(out[3], v.norm())
            bad = 0
            for a in ti.static(range(3)):
                if not (ti.abs(x[a]) < 1e30 and ti.abs(v[a]) < 1e30):  # also catches NaN
                    bad = 1
            ti.atomic_add(out[5], bad)
            zb = ti.cast((x[2] - m.lo[2]) / (m.hi[2] - m.lo[2]) * nb, ti.i32)
            ti.atomic_add(hist[ti.min(ti.max(zb, 0), nb - 1)], 1)
            for k in range(nl.count[i]):
                j = nl.partner[k, i]
                if s.alive[j]:
                    rj = grain_radius(m, g, j)
                    d = (s.x[j] - x).norm()
                    ti.atomic_max(out[2], (ri + rj - d) / (2.0 * ti.min(ri, rj)))
            for w in ti.static(range(len(m.walls))):
                clearance, nrm = wall_clearance_normal(m.walls[w], wd.sampled[w], x)
                ti.atomic_max(out[2], (ri - clearance) / (2.0 * ri))
    out[4] = alive
    return alive


# ---------------------------------------------------------------------------- host side

class NeighborOverflow(RuntimeError):
    pass


class DemSolver:
    """Holds one scene's DEM fields and advances them; no I/O, no printing."""

    def __init__(self, model: DemModel):
        self.m = model
        self.fixed = GrainModel(model)
        self.state = GrainState(model)
        self.history = ContactHistory(model)
        self.nlist = NeighborList(model)
        self.walls = WallData(model)
        self._diag = ti.field(float, 6)
        self._hist = ti.field(ti.i32, 1024)
        self.substeps_done = 0
        self._need_build = True

    # -- state in and out -------------------------------------------------------------
    def _f(self, a):
        """numpy array in the kernels' float type (float32 or float64)."""
        return np.ascontiguousarray(a, dtype=np.float64 if self.state.v.dtype == ti.f64 else np.float32)

    def set_grains(self, position, velocity=None, radius=None, omega=None, alive=None):
        n = self.m.n
        position = self._f(position)
        if position.shape != (n, 3):
            raise ValueError(f"positions must be ({n}, 3), got {position.shape}")
        self.state.x.from_numpy(position)
        self.state.v.from_numpy(self._f(np.zeros((n, 3)) if velocity is None else velocity))
        self.state.force.fill(0)
        self.state.alive.from_numpy(np.ones(n, np.uint8) if alive is None else np.asarray(alive, np.uint8))
        if self.m.polydisperse:
            r = np.asarray(radius, float)
            self.fixed.radius.from_numpy(self._f(r))
            self.fixed.mass.from_numpy(self._f(self.m.density * 4.0 / 3.0 * math.pi * r ** 3))
        if self.m.friction:
            self.state.omega.from_numpy(self._f(np.zeros((n, 3)) if omega is None else omega))
            self.state.torque.fill(0)
            self.history.tangential.fill(0)
            self.history.wall_tangential.fill(0)
        if self.m.rolling == ROLL_EPSD:
            self.history.rolling.fill(0)
            self.history.wall_rolling.fill(0)
        if self.m.coupled:
            self.state.external_force.fill(0)
            self.state.drag_coeff.fill(0)
            self.state.gas_velocity.fill(0)
        self.nlist.count.fill(0)
        self.nlist.removed[None] = 0
        self._need_build = True

    def radii(self) -> np.ndarray:
        if self.m.polydisperse:
            return self.fixed.radius.to_numpy()
        return np.full(self.m.n, self.m.radius)

    def masses(self) -> np.ndarray:
        if self.m.polydisperse:
            return self.fixed.mass.to_numpy()
        return np.full(self.m.n, self.m.mass)

    def state_arrays(self) -> dict:
        """Every changing field (and the neighbour list) as numpy arrays: a full checkpoint."""
        s, h, nl = self.state, self.history, self.nlist
        out = {"position": s.x.to_numpy(), "velocity": s.v.to_numpy(), "alive": s.alive.to_numpy(),
               "radius": self.radii(), "nl_partner": nl.partner.to_numpy(), "nl_count": nl.count.to_numpy(),
               "nl_x_ref": nl.x_ref.to_numpy(), "removed": np.array(nl.removed[None]),
               "substeps_done": np.array(self.substeps_done), "need_build": np.array(int(self._need_build))}
        if self.m.friction:
            out.update(omega=s.omega.to_numpy(), torque=s.torque.to_numpy(),
                       tangential=h.tangential.to_numpy(), wall_tangential=h.wall_tangential.to_numpy())
        if self.m.rolling == ROLL_EPSD:
            out.update(rolling=h.rolling.to_numpy(), wall_rolling=h.wall_rolling.to_numpy())
        out["force"] = s.force.to_numpy()
        if self.m.coupled:
            out.update(external_force=s.external_force.to_numpy(), drag_coeff=s.drag_coeff.to_numpy(),
                       gas_velocity=s.gas_velocity.to_numpy())
        return out

    def load_state_arrays(self, a: dict) -> None:
        """Restore exactly what ``state_arrays`` returned (same scene model required)."""
        s, h, nl = self.state, self.history, self.nlist
        self.set_grains(a["position"], a["velocity"], a["radius"], a.get("omega"), a["alive"])
        s.force.from_numpy(self._f(a["force"]))
        nl.partner.from_numpy(a["nl_partner"])
        nl.count.from_numpy(a["nl_count"])
        nl.x_ref.from_numpy(self._f(a["nl_x_ref"]))
        nl.removed[None] = int(a["removed"])
        self.substeps_done = int(a["substeps_done"])
        self._need_build = bool(int(a["need_build"]))
        if self.m.friction:
            s.torque.from_numpy(self._f(a["torque"]))
            h.tangential.from_numpy(self._f(a["tangential"]))
            h.wall_tangential.from_numpy(self._f(a["wall_tangential"]))
        if self.m.rolling == ROLL_EPSD:
            h.rolling.from_numpy(self._f(a["rolling"]))
            h.wall_rolling.from_numpy(self._f(a["wall_rolling"]))
        if self.m.coupled and "drag_coeff" in a:
            s.external_force.from_numpy(self._f(a["external_force"]))
            s.drag_coeff.from_numpy(self._f(a["drag_coeff"]))
            s.gas_velocity.from_numpy(self._f(a["gas_velocity"]))

    # -- stepping ---------------------------------------------------------------------
    def rebuild(self) -> None:
        m, s, nl = self.m, self.state, self.nlist
        count_cells(m, s, nl)
        scan_blocks(m, nl)
        scan_block_sums(m, nl)
        scan_fill(m, nl)
        scatter_cells(m, s, nl)
        build_pairs(m, self.fixed, s, self.history, nl)
        over = nl.overflow[None]
        if over:
            raise NeighborOverflow(f"a grain has at least {over} neighbours within the skin but the list holds "
                                   f"{m.slots}: raise dem.max_neighbors (now {m.slots}) or lower dem.skin")
        nl.builds += 1
        self._need_build = False

    def substep(self) -> None:
        m = self.m
        if self._need_build or self.nlist.max_disp2[None] > (0.5 * m.skin) ** 2:
            self.rebuild()
        compute_forces(m, self.fixed, self.state, self.history, self.nlist, self.walls)
        integrate(m, self.fixed, self.state, self.nlist)
        self.substeps_done += 1

    def advance(self, substeps: int) -> None:
        for _ in range(substeps):
            self.substep()

    def diagnostics(self) -> dict:
        """Kinetic energy [J], max overlap / diameter, max speed [m/s], grains alive and removed,
        non-finite values, and the bed height (95th percentile of grain heights) [m]."""
        alive = measure(self.m, self.fixed, self.state, self.nlist, self.walls, self._diag, self._hist)
        d = self._diag.to_numpy()
        hist = self._hist.to_numpy()
        z95 = float("nan")
        if alive > 0:
            cum = np.cumsum(hist)
            target = 0.95 * alive
            b = int(np.searchsorted(cum, target))
            below = cum[b - 1] if b > 0 else 0
            frac = (target - below) / max(hist[b], 1)
            width = (self.m.hi[2] - self.m.lo[2]) / hist.size
            z95 = self.m.lo[2] + (b + frac) * width
        return {"kinetic_energy": float(d[0] + d[1]), "kinetic_energy_rotational": float(d[1]),
                "max_overlap": float(max(d[2], 0.0)), "max_speed": float(d[3]), "grains_alive": int(alive),
                "grains_removed": int(self.nlist.removed[None]), "non_finite": int(d[5]), "bed_height": z95}
