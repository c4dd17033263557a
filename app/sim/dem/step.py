"""The DEM substep, one kernel launch (``DemSolver`` in ``solver.py`` holds a scene's bundles and runs it).

One substep (``substep``, a single kernel whose top-level loops run in order):
[rebuild the Verlet half list, when the device flag says a grain moved more than skin/2]
-> contact forces: grain pairs from the half list, then each wall, with the one contact
   law of ``contact.py``
-> symplectic Euler integration (v += a dt; x += v dt; omega += T/I dt, the gas drag
   taken implicitly), which also zeroes the accumulators, removes grains that left the
   domain (a grain that crosses a periodic face re-enters by the other) and raises the rebuild flag.
On one CPU thread (``model.serial``) a substep is one serial task, and ``advance`` runs all its
substeps in one launch (``dem_substeps``): a task's start-up (~13 us on the CPU) and a launch's host
cost are paid once per ``advance``, not per loop and substep; the steps run in the same order, to the
same bits. The host only launches: nothing is read back inside ``advance``'s loop; the counters
(overflow, removals, builds) are read once at its end, and decide whether the next ``advance``
first re-orders the grains by cell (``sort.sort_by_cell``, every ``model.sort_interval``
builds). Outside the DEM, grains are seen in id order only (``read``, ``state_arrays``). Diagnostics are computed only
when asked for. No I/O, no printing.
"""
import taichi as ti

from ..launch import kernel
from ..fields import NO_SPRING, ROLL_EPSD
from ..geometry import wall_clearance_normal
from .contact import contact
from .grains import grain_mass, grain_radius, min_image, scatter_add, wrap_position
from .neighbors import REBUILD, REMOVED, SPRING_OVERFLOW, THROUGH_WALL, clear_bins, clear_bins_of, rebuild_if_flagged
from .scan import exclusive_scan
from ..tasks import block_pass, one_block, one_task


@ti.func
def take_spring_slot(model: ti.template(), nlist: ti.template(), i):
    """The lowest free history slot of grain i, marked used; NO_SPRING (and the overflow counter) if all
    ``model.history_slots`` hold contacts."""
    used = nlist.springs_used[i]
    h = NO_SPRING
    for b in range(model.history_slots):
        if h == NO_SPRING and (used >> ti.cast(b, ti.u32)) & ti.u32(1) == ti.u32(0):
            h = b
    if h == NO_SPRING:
        ti.atomic_max(nlist.counters[SPRING_OVERFLOW], 1)
    else:
        nlist.springs_used[i] = used | (ti.u32(1) << ti.cast(h, ti.u32))
    return h


@ti.func
def springs_of(model: ti.template(), history: ti.template(), nlist: ti.template(), i, k):
    """The history slot of grain i's contact in neighbour slot k and its springs (a new contact takes a
    free slot, its springs start at zero)."""
    zero = ti.Vector([0.0, 0.0, 0.0])
    spring, roll_spring = zero, zero
    h = ti.cast(nlist.spring_slot[k, i], ti.i32)
    if h == NO_SPRING:
        h = take_spring_slot(model, nlist, i)
        nlist.spring_slot[k, i] = ti.cast(h, ti.u8)
    else:
        if ti.static(model.friction):
            spring = history.tangential[h, i]
        if ti.static(model.rolling == ROLL_EPSD):
            roll_spring = history.rolling[h, i]
    return h, spring, roll_spring


@ti.func
def release_springs(nlist: ti.template(), i, k):
    """Grain i's contact in neighbour slot k ended: free its history slot."""
    h = ti.cast(nlist.spring_slot[k, i], ti.i32)
    if h != NO_SPRING:
        nlist.spring_slot[k, i] = ti.cast(NO_SPRING, ti.u8)
        nlist.springs_used[i] &= ~(ti.u32(1) << ti.cast(h, ti.u32))


@ti.func
def pair_contact(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
                 nlist: ti.template(), i, k, j, xi, vi, wi, ri, mi, rj, dx, d2):
    """The touching pair (i, j) of neighbour slot k: its force and torque on i (returned) and on j
    (scattered), its springs updated."""
    zero = ti.Vector([0.0, 0.0, 0.0])
    rs = ri + rj
    dist = ti.sqrt(d2)
    n = dx * (1.0 / ti.max(dist, 1e-30))
    delta = rs - dist
    mj = grain_mass(model, sizes, j)
    # lever arms to the contact point, the middle of the overlap: they sum to the centre
    # distance, so the pair's torques conserve angular momentum exactly
    arm_i = ri - 0.5 * delta
    arm_j = rj - 0.5 * delta
    vrel = vi - state.v[j]
    w_rel = zero
    spring, roll_spring = zero, zero
    h = NO_SPRING
    if ti.static(model.has_history):
        h, spring, roll_spring = springs_of(model, history, nlist, i, k)
    if ti.static(model.friction):
        wj = state.omega[j]
        vrel += (wi * arm_i + wj * arm_j).cross(n)
        w_rel = wi - wj
    # sqrt(I_r / m*) of the epsd rolling mode, I_r = 1.4 m_i r_i^2 m_j r_j^2 / (m_i r_i^2 + m_j r_j^2)
    # (each grain about the contact point, Ai et al. 2011): sqrt(1.4) r for equal grains
    gyration = 0.0
    if ti.static(model.rolling == ROLL_EPSD):
        if ti.static(model.polydisperse):
            gyration = ti.sqrt(1.4 * ri * ri * rj * rj * (mi + mj) / (mi * ri * ri + mj * rj * rj))
        else:
            gyration = ti.static(1.4 ** 0.5 * model.radius)
    f, ft, tr, spring, roll_spring = contact(model, False, n, delta, vrel, w_rel, ri * rj / rs,
                                             mi * mj / (mi + mj), gyration, spring, roll_spring)
    if ti.static(model.has_history):
        if h != NO_SPRING:
            if ti.static(model.friction):
                history.tangential[h, i] = spring
            if ti.static(model.rolling == ROLL_EPSD):
                history.rolling[h, i] = roll_spring
    torque_i = zero
    if ti.static(model.friction):
        tq = n.cross(ft)  # torque per unit lever arm: arm_i n x F on i, arm_j n x F on j
        torque_i = arm_i * tq + tr
        scatter_add(model, state.torque, j, arm_j * tq - tr)
    scatter_add(model, state.force, j, -f)
    return f, torque_i


@ti.func
def wall_contact(model: ti.template(), history: ti.template(), w: ti.template(), i, vi, wi, ri, mi, nrm, delta):
    """Grain i touching wall w (overlap ``delta`` > 0, the wall's normal ``nrm`` into the open side): the force
    on i, its tangential part, the rolling torque, the updated springs (not stored), the normal towards the wall
    and the lever arm."""
    zero = ti.Vector([0.0, 0.0, 0.0])
    n = -nrm  # from the grain towards the wall
    arm = ri - 0.5 * delta
    vrel = vi
    spring, roll_spring = zero, zero
    if ti.static(model.friction):
        vrel += (wi * arm).cross(n)
        spring = history.wall_tangential[w, i]
    if ti.static(model.rolling == ROLL_EPSD):
        roll_spring = history.wall_rolling[w, i]
    f, ft, tr, spring, roll_spring = contact(model, True, n, delta, vrel, wi, ri, mi, 1.4 ** 0.5 * ri,
                                             spring, roll_spring)  # sqrt(I_r / m*), I_r = 1.4 m r^2
    return f, ft, tr, spring, roll_spring, n, arm


@ti.func
def wall_contacts(model: ti.template(), history: ti.template(), walls: ti.template(), i, xi, vi, wi, ri, mi, fi,
                  torque_i):
    """Grain i's force and torque ``fi``, ``torque_i`` with every wall's added (unrolled at compile time,
    each wall with its own springs)."""
    zero = ti.Vector([0.0, 0.0, 0.0])
    for w in ti.static(range(len(model.walls))):
        clearance, nrm = wall_clearance_normal(model.walls[w], walls.sampled[w], xi)
        delta = ri - clearance
        if delta > 0:
            f, ft, tr, spring, roll_spring, n, arm = wall_contact(model, history, w, i, vi, wi, ri, mi, nrm, delta)
            if ti.static(model.friction):
                history.wall_tangential[w, i] = spring
                torque_i += arm * n.cross(ft) + tr
            if ti.static(model.rolling == ROLL_EPSD):
                history.wall_rolling[w, i] = roll_spring
            fi += f
        else:
            if ti.static(model.friction):
                history.wall_tangential[w, i] = zero
            if ti.static(model.rolling == ROLL_EPSD):
                history.wall_rolling[w, i] = zero
    return fi, torque_i


@ti.func
def pair_forces(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
                nlist: ti.template(), walls: ti.template(), built: ti.template()):
    """Contact forces and torques: each grain's row of the half list (the partner's share scattered),
    then the walls. ``built``: the list was built this substep, whose bins item i helps zero
    (``neighbors.clear_bins_of``: the rows that read them are done)."""
    # one CPU thread: a serial loop lets Taichi demote the partner atomics to plain adds
    ti.loop_config(serialize=model.serial)
    for i in range(model.n):
        if ti.static(model.bins_zeroed_after):
            if built:
                clear_bins_of(model, nlist, i)
        if state.alive[i]:
            xi = state.x[i]
            vi = state.v[i]
            ri = grain_radius(model, sizes, i)
            mi = grain_mass(model, sizes, i)
            wi = ti.Vector([0.0, 0.0, 0.0])
            if ti.static(model.friction):
                wi = state.omega[i]
            fi = ti.Vector([0.0, 0.0, 0.0])
            torque_i = ti.Vector([0.0, 0.0, 0.0])
            for k in range(nlist.count[i]):
                j = nlist.partner[k, i]
                dx = state.x[j] - xi
                if ti.static(model.wraps):  # nothing compiled without periodic faces
                    dx = min_image(model, dx)
                rj = grain_radius(model, sizes, j)
                d2 = dx.dot(dx)
                rs = ri + rj
                if d2 < rs * rs and state.alive[j]:
                    f, t = pair_contact(model, sizes, state, history, nlist, i, k, j, xi, vi, wi, ri, mi, rj, dx, d2)
                    fi += f
                    torque_i += t
                else:
                    if ti.static(model.has_history):
                        release_springs(nlist, i, k)
            fi, torque_i = wall_contacts(model, history, walls, i, xi, vi, wi, ri, mi, fi, torque_i)
            scatter_add(model, state.force, i, fi)
            if ti.static(model.friction):
                scatter_add(model, state.torque, i, torque_i)


@ti.func
def left_through_wall(model: ti.template(), x0, x):
    """A grain inside the domain at ``x0`` that is now at ``x``, outside, has crossed a face the walls seal
    (``model.sealed``): it passed through a wall (one inside the domain at the start, ``x0``, is merely removed)."""
    was_inside = True
    crossed = False
    for a in ti.static(range(3)):
        if ti.static(not model.periodic[a]):
            if not (model.lo[a] <= x0[a] <= model.hi[a]):
                was_inside = False
            if ti.static(model.sealed[2 * a]):
                if x[a] < model.lo[a]:
                    crossed = True
            if ti.static(model.sealed[2 * a + 1]):
                if x[a] > model.hi[a]:
                    crossed = True
    return was_inside and crossed


@ti.func
def integrate(model: ti.template(), sizes: ti.template(), state: ti.template(), nlist: ti.template()):
    """Symplectic Euler; zeroes the accumulators; removes grains outside the domain; flags a rebuild."""
    half_skin2 = (0.5 * model.skin) ** 2
    for i in range(model.n):
        if state.alive[i]:
            mass = grain_mass(model, sizes, i)
            f = state.force[i]
            v = state.v[i]
            if ti.static(model.coupled):
                # drag K (u_gas - v) taken implicitly: stable even when m/K is shorter than dt
                f += state.external_force[i]
                kdt = state.drag_coeff[i] * model.dt / mass
                v = (v + (f / mass + ti.Vector(model.gravity)) * model.dt + kdt * state.gas_velocity[i]) / (1.0 + kdt)
            else:
                v = v + (f / mass + ti.Vector(model.gravity)) * model.dt
            x0 = state.x[i]
            x = x0 + v * model.dt
            if ti.static(model.wraps):
                x = wrap_position(model, x)
            state.v[i] = v
            state.x[i] = x
            state.force[i] = ti.Vector([0.0, 0.0, 0.0])
            if ti.static(model.friction):
                r = grain_radius(model, sizes, i)
                state.omega[i] += state.torque[i] / (0.4 * mass * r * r) * model.dt
                state.torque[i] = ti.Vector([0.0, 0.0, 0.0])
            inside = True
            for a in ti.static(range(3)):
                if ti.static(not model.periodic[a]):
                    if not (model.lo[a] <= x[a] <= model.hi[a]):
                        inside = False
            if not inside:
                state.alive[i] = ti.cast(0, ti.u8)
                state.v[i] = ti.Vector([0.0, 0.0, 0.0])
                ti.atomic_add(nlist.counters[REMOVED], 1)
                if ti.static(model.seals):
                    if left_through_wall(model, x0, x):
                        ti.atomic_add(nlist.counters[THROUGH_WALL], 1)
            else:
                d = x - nlist.x_ref[i]
                if ti.static(model.wraps):
                    d = min_image(model, d)  # a grain that wrapped has not moved a period
                if d.dot(d) > half_skin2:
                    nlist.counters[REBUILD] = 1  # every writer stores the same value


@kernel
def dem_substep(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
                nlist: ti.template(), walls: ti.template()):
    """One DEM step in one launch: [rebuild] -> pair and wall forces -> integration. On one CPU thread
    (``model.serial``) the whole step is one serial task (the parts' loops nested in one loop of one
    pass, run in the same order: the same results, without a task's start-up per loop)."""
    one_task(model.serial, substep_parts, (model, sizes, state, history, nlist, walls))


@kernel
def dem_substeps(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
                 nlist: ti.template(), walls: ti.template(), substeps: ti.i32):
    """``substeps`` DEM steps in one launch, on one CPU thread only (``model.serial``): one serial task,
    the steps in order, each as ``dem_substep`` (the same results bit for bit, no launch per step)."""
    ti.static_assert(model.serial, "dem_substeps runs on one CPU thread only")
    ti.loop_config(serialize=True)
    for _ in range(1):
        for _s in range(substeps):
            substep_parts(model, sizes, state, history, nlist, walls)


@kernel
def dem_build(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
              nlist: ti.template()):
    """The list build that the next substep would start with, done ahead (nothing when no build is flagged)."""
    one_task(model.serial, _build_alone, (model, sizes, state, history, nlist))


@ti.func
def _build_alone(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
                 nlist: ti.template()):
    built = rebuild_if_flagged(model, sizes, state, history, nlist)
    clear_bins(model, nlist, built)


@ti.func
def substep_parts(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
                  nlist: ti.template(), walls: ti.template()):
    built = rebuild_if_flagged(model, sizes, state, history, nlist)
    pair_forces(model, sizes, state, history, nlist, walls, built)
    integrate(model, sizes, state, nlist)


# ---------------------------------------------------------------------------- diagnostics

#: what ``measure`` writes into a row of the diagnostics ring, in this order (``DemSolver.diagnostics_of`` reads it):
#: the translational and rotational kinetic energy [J], the largest overlap over a diameter, the largest speed
#: [m/s], then counts: grains alive, grains with a non-finite position or velocity, touching pairs, grains
#: removed, and the bin of the grain-height histogram holding the 95th percentile, the grains below that bin
#: and in it (the host interpolates the bed height from these, as from the histogram itself), the grains that left
#: through a face the walls seal (``DemModel.sealed``: they passed through a wall; the guard stops the run); then,
#: one column per wall (``DemSolver.diag_columns``), the vertical force the wall exerts on the grains [N]
DIAG_COLUMNS = ("kinetic_energy_translational", "kinetic_energy_rotational", "max_overlap", "max_speed",
                "grains_alive", "non_finite", "contacts", "grains_removed", "height_bin", "height_below",
                "height_in_bin", "grains_through_walls")


@kernel
def measure(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
            nlist: ti.template(), walls: ti.template(), out: ti.template(), hist: ti.template(),
            ring: ti.types.ndarray(), row: ti.i32, col: ti.i32):
    """Fill ``out`` with [KE_trans, KE_rot, max overlap/diameter, max speed, alive, bad values, touching
    pairs, then each wall's vertical force on the grains] and ``hist`` with a height histogram of alive grains,
    then write the step's record (``DemSolver.diag_columns``) into ``ring[row, col:]`` (float64): nothing is
    returned, so the host waits for nothing. The wall forces are the contact law's at this instant, with the
    springs as they stand (read, not stepped). On one CPU thread (``model.serial``) one serial task (the loops
    nested in one loop, in the same order). The record's bed-height bin: one thread's running sum where the list
    build's scan has one thread (``model.scan_threads`` 0, the CPU), else the same block of threads
    (:func:`_record_block`)."""
    one_task(model.serial, measure_parts, (model, sizes, state, history, nlist, walls, out, hist, ring, row, col))


@ti.func
def _grain_contacts(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
                    nlist: ti.template(), walls: ti.template(), out: ti.template(), i, x, v, ri, mass):
    """Grain i's largest overlap / diameter with its neighbours and walls, and its touching neighbours; each
    wall's vertical force on it added into ``out[7 + w]`` (few grains touch a wall)."""
    touching = 0
    ov = -1e30
    for k in range(nlist.count[i]):
        j = nlist.partner[k, i]
        if state.alive[j]:
            rj = grain_radius(model, sizes, j)
            sep = state.x[j] - x
            if ti.static(model.wraps):
                sep = min_image(model, sep)
            d = sep.norm()
            ov = ti.max(ov, (ri + rj - d) / (2.0 * ti.min(ri, rj)))
            if d < ri + rj:
                touching += 1
    wi = ti.Vector([0.0, 0.0, 0.0])
    if ti.static(model.friction):
        wi = state.omega[i]
    for w in ti.static(range(len(model.walls))):
        clearance, nrm = wall_clearance_normal(model.walls[w], walls.sampled[w], x)
        ov = ti.max(ov, (ri - clearance) / (2.0 * ri))
        delta = ri - clearance
        if delta > 0:
            f, _ft, _tr, _s, _r, _n, _a = wall_contact(model, history, w, i, v, wi, ri, mass, nrm, delta)
            ti.atomic_add(out[7 + w], f[2])  # the force on the grain, from the wall
    return ov, touching


@ti.func
def measure_parts(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
                  nlist: ti.template(), walls: ti.template(), out: ti.template(), hist: ti.template(),
                  ring: ti.template(), row, col):
    for k in range(7, 7 + ti.static(len(model.walls))):  # the wall forces (the rest is stored after the loop)
        out[k] = 0.0
    for b in range(hist.shape[0]):
        hist[b] = 0
    # the sums and maxima accumulate in kernel-scope variables, stored once after the loop: Taichi 1.7.4 reduces
    # those per thread (per warp on CUDA); an atomic into an element of ``out`` would be one per grain (and per
    # neighbour) on one address, a compare-and-swap loop for a float max on CUDA (benchmarks/reduction_cost.py)
    alive = 0
    ke = 0.0
    ke_rot = 0.0
    overlap = 0.0
    vmax = 0.0
    n_bad = 0
    n_touch = 0
    nb = hist.shape[0]
    for i in range(model.n):
        if state.alive[i]:
            alive += 1
            mass = grain_mass(model, sizes, i)
            ri = grain_radius(model, sizes, i)
            v = state.v[i]
            x = state.x[i]
            ke += 0.5 * mass * v.dot(v)
            if ti.static(model.friction):
                w = state.omega[i]
                ke_rot += 0.5 * 0.4 * mass * ri * ri * w.dot(w)
            ti.atomic_max(vmax, v.norm())
            bad = 0
            for a in ti.static(range(3)):
                if not (ti.abs(x[a]) < 1e30 and ti.abs(v[a]) < 1e30):  # also catches NaN
                    bad = 1
            n_bad += bad
            zb = ti.cast((x[2] - model.lo[2]) / (model.hi[2] - model.lo[2]) * nb, ti.i32)
            ti.atomic_add(hist[ti.min(ti.max(zb, 0), nb - 1)], 1)
            ov, touching = _grain_contacts(model, sizes, state, history, nlist, walls, out, i, x, v, ri, mass)
            n_touch += touching
            ti.atomic_max(overlap, ov)
    out[0] = ke
    out[1] = ke_rot
    out[2] = overlap
    out[3] = vmax
    out[4] = alive
    out[5] = n_bad
    out[6] = n_touch
    if ti.static(model.scan_threads == 0):  # one thread (the CPU): the record, and the 95% bin by a running sum
        ti.loop_config(serialize=True)
        for _ in range(1):
            _record_head(model, nlist, out, ring, row, col, alive)
            target = 0.95 * ti.cast(alive, ti.f64)
            cum = 0
            found = 0
            for b in range(nb):
                if found == 0 and ti.cast(cum + hist[b], ti.f64) >= target:
                    found = 1
                    ring[row, col + 8] = ti.cast(b, ti.f64)
                    ring[row, col + 9] = ti.cast(cum, ti.f64)
                    ring[row, col + 10] = ti.cast(hist[b], ti.f64)
                cum += hist[b]
    else:  # one block of threads (CUDA; see _record_block)
        one_block(model.scan_threads, model.scan_emulate, not model.scan_emulate, 1, _record_block,
                  (model, nlist, out, hist, ring, row, col))


@ti.func
def _record_head(model: ti.template(), nlist: ti.template(), out: ti.template(), ring: ti.template(), row, col,
                 alive):
    """The record's columns but the height bin's: the sums, counts and wall forces of ``out``."""
    for k in ti.static(range(4)):
        ring[row, col + k] = ti.cast(out[k], ti.f64)
    ring[row, col + 4] = ti.cast(alive, ti.f64)
    ring[row, col + 5] = ti.cast(out[5], ti.f64)
    ring[row, col + 6] = ti.cast(out[6], ti.f64)
    ring[row, col + 7] = ti.cast(nlist.counters[REMOVED], ti.f64)
    ring[row, col + 11] = ti.cast(nlist.counters[THROUGH_WALL], ti.f64)
    for w in ti.static(range(len(model.walls))):
        ring[row, col + 12 + w] = ti.cast(out[7 + w], ti.f64)


@ti.func
def _record_block(t, nt: ti.template(), emulate: ti.template(), barrier: ti.template(), model: ti.template(),
                  nlist: ti.template(), out: ti.template(), hist: ti.template(), ring: ti.template(), row, col):
    """The record by one block of threads (CUDA; ``emulate``: their shares on one CPU thread), as the one-thread
    loop writes it: on CUDA that loop is a chain of 1,024 loads, ~0.2-0.3 ms a fluid step (a prediction from load
    latencies, not measured). The histogram is scanned in place (:func:`scan.exclusive_scan`, in the list build's
    buffer ``nlist.scan_tmp``; its total is the alive grains, each binned once), then each thread looks at its bins:
    the 95% bin is the first whose running sum reaches 0.95 alive, the one bin where it does and the sum before it
    does not (the histogram is zeroed by the next measure)."""
    total = exclusive_scan(t, hist, ti.static(hist.shape[0]), nlist.scan_tmp, nt, emulate, barrier)
    block_pass(t, nt, emulate, barrier, ti.static(hist.shape[0]), _bin_at_95, (hist, total, ring, row, col))
    if t == 0:
        _record_head(model, nlist, out, ring, row, col, total)


@ti.func
def _bin_at_95(b, hist: ti.template(), total, ring: ti.template(), row, col):
    """Bin b's share of the search: ``hist`` holds the counts' exclusive running sums."""
    nb = ti.static(hist.shape[0])
    below = hist[b]
    upto = total
    if b + 1 < nb:
        upto = hist[b + 1]
    target = 0.95 * ti.cast(total, ti.f64)
    if ti.cast(upto, ti.f64) >= target and (b == 0 or ti.cast(below, ti.f64) < target):
        ring[row, col + 8] = ti.cast(b, ti.f64)
        ring[row, col + 9] = ti.cast(below, ti.f64)
        ring[row, col + 10] = ti.cast(upto - below, ti.f64)
