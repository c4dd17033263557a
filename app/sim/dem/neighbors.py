"""The Verlet half list: when to rebuild it, the cell list it is built from, and the build.

The decision lives on the device: ``integrate`` raises ``nlist.counters[REBUILD]`` when a
grain has moved more than skin/2 since the last build, and every loop of the rebuild runs
over ``counters[REBUILD] * n`` items, so a substep that needs no rebuild runs empty loops
and the host never reads the flag (the substeps of a fluid step are queued without
waiting). The other counters (overflow, removed grains, builds) are read once per
``DemSolver.advance``.

Ownership of a pair (which grain's row holds it): the smaller grain, ties to the lower
index. A grain's row then holds only partners at least its own size, so the slots per
grain follow from the smallest grain alone: at most ~12 ((2 r_min + skin) / (2 r_min))^2
(the kissing number of equal spheres, scaled to the skin shell), whatever the size ratio
(``fields.slots_bound``), where the owner-by-index rule needs a big grain's worth of small ones.

Build: counting sort of grains by cell (count, block scan, scatter), then each grain
gathers its new row in registers and carries every surviving pair's history slot number
to the new slot (the springs themselves stay put); each thread writes only its own row,
so no second list buffer is needed."""
import taichi as ti

from ..fields import NO_SPRING, SCAN_BLOCK
from .grains import grain_radius

REBUILD, OVERFLOW, REMOVED, BUILDS, SPRING_OVERFLOW = 0, 1, 2, 3, 4  # nlist.counters


@ti.func
def cell_of(model: ti.template(), p):
    c = ti.Vector([0, 0, 0])
    for a in ti.static(range(3)):
        c[a] = ti.min(ti.max(ti.cast(ti.floor((p[a] - model.lo[a]) / model.cell[a]), ti.i32), 0),
                      model.cells[a] - 1)
    return c


@ti.func
def cell_index(model: ti.template(), c):
    return (c[2] * model.cells[1] + c[1]) * model.cells[0] + c[0]


@ti.func
def owns(model: ti.template(), sizes: ti.template(), i, ri, j):
    """Whether the pair (i, j) lives in i's row: the smaller grain owns it, ties to the lower index."""
    result = j > i
    if ti.static(model.polydisperse):
        rj = sizes.radius[j]
        result = rj > ri or (rj == ri and j > i)
    return result


@ti.func
def rebuild_if_flagged(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
                       nlist: ti.template()):
    """The whole rebuild as top-level loops of the calling kernel; each runs empty unless flagged."""
    # one array of n_cells + 1 ints: counts, then inclusive ends (the scan), then starts (each scattered
    # grain takes its slot from the end of its cell downwards)
    nb = (model.n_cells + SCAN_BLOCK - 1) // SCAN_BLOCK
    for c in range(nlist.counters[REBUILD] * model.n_cells):
        nlist.cell_start[c] = 0
    for i in range(nlist.counters[REBUILD] * model.n):
        if state.alive[i]:
            ti.atomic_add(nlist.cell_start[cell_index(model, cell_of(model, state.x[i]))], 1)
    for b in range(nlist.counters[REBUILD] * nb):
        total = 0
        for t in range(SCAN_BLOCK):
            c = b * SCAN_BLOCK + t
            if c < model.n_cells:
                total += nlist.cell_start[c]
        nlist.block_sum[b] = total
    ti.loop_config(serialize=True)
    for _ in range(nlist.counters[REBUILD]):
        run = 0
        for k in range(nb):
            v = nlist.block_sum[k]
            nlist.block_sum[k] = run
            run += v
        nlist.cell_start[model.n_cells] = run
    for b in range(nlist.counters[REBUILD] * nb):
        run = nlist.block_sum[b]
        for t in range(SCAN_BLOCK):
            c = b * SCAN_BLOCK + t
            if c < model.n_cells:
                run += nlist.cell_start[c]
                nlist.cell_start[c] = run  # the end of cell c
    for i in range(nlist.counters[REBUILD] * model.n):
        if state.alive[i]:
            slot = ti.atomic_sub(nlist.cell_start[cell_index(model, cell_of(model, state.x[i]))], 1) - 1
            nlist.sorted[slot] = i
    for i in range(nlist.counters[REBUILD] * model.n):
        build_row(model, sizes, state, history, nlist, i)
    ti.loop_config(serialize=True)
    for _ in range(nlist.counters[REBUILD]):
        nlist.counters[BUILDS] += 1
        nlist.counters[REBUILD] = 0


@ti.func
def build_row(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
              nlist: ti.template(), i):
    """Grain i's new row, gathered in registers; the springs of surviving pairs move with them."""
    cnt = 0
    new = ti.Vector([-1] * model.slots, ti.i32)
    if state.alive[i]:
        xi = state.x[i]
        ri = grain_radius(model, sizes, i)
        c = cell_of(model, xi)
        for dz, dy, dx in ti.ndrange((-1, 2), (-1, 2), (-1, 2)):
            q = c + ti.Vector([dx, dy, dz])
            if 0 <= q[0] < model.cells[0] and 0 <= q[1] < model.cells[1] and 0 <= q[2] < model.cells[2]:
                ci = cell_index(model, q)
                for p in range(nlist.cell_start[ci], nlist.cell_start[ci + 1]):
                    j = nlist.sorted[p]
                    if owns(model, sizes, i, ri, j):
                        cut = ri + grain_radius(model, sizes, j) + model.skin
                        d = state.x[j] - xi
                        if d.dot(d) < cut * cut:
                            if cnt < model.slots:
                                new[cnt] = j
                                cnt += 1
                            else:
                                ti.atomic_max(nlist.counters[OVERFLOW], cnt + 1)
        nlist.x_ref[i] = xi
    if ti.static(model.has_history):
        # the springs stay where they are: each surviving pair's history slot number moves with it
        # (a touching pair is always within the cut-off, so no contact is dropped here)
        n_old = nlist.count[i]
        keep = ti.Vector([NO_SPRING] * model.slots, ti.i32)
        used = ti.u32(0)
        for k in range(cnt):
            for q in range(n_old):
                if nlist.partner[q, i] == new[k]:
                    h = ti.cast(nlist.spring_slot[q, i], ti.i32)
                    keep[k] = h
                    if h != NO_SPRING:
                        used |= ti.u32(1) << ti.cast(h, ti.u32)
        for k in range(model.slots):
            nlist.spring_slot[k, i] = ti.cast(keep[k], ti.u8)
        nlist.springs_used[i] = used
    for k in range(cnt):
        nlist.partner[k, i] = new[k]
    nlist.count[i] = cnt
