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
gathers its new row in registers, nearest partner first, and carries every surviving pair's history slot number
to the new slot (the springs themselves stay put); each thread writes only its own row,
so no second list buffer is needed."""
import taichi as ti

from ..fields import NO_SPRING
from .grains import grain_id, grain_radius, min_image
from .scan import block_scan

REBUILD, OVERFLOW, REMOVED, BUILDS, SPRING_OVERFLOW, DEAD, THROUGH_WALL = 0, 1, 2, 3, 4, 5, 6  # nlist.counters


@ti.func
def cell_of(model: ti.template(), p):
    """The cell holding point p: clamped to the grid, wrapped along a periodic axis (whose cells tile the
    period exactly)."""
    c = ti.Vector([0, 0, 0])
    for a in ti.static(range(3)):
        if ti.static(model.periodic[a]):  # Taichi's % on integers is Python's: never negative here
            c[a] = ti.cast(ti.floor((p[a] - model.lo[a]) / model.cell[a]), ti.i32) % model.cells[a]
        else:
            c[a] = ti.min(ti.max(ti.cast(ti.floor((p[a] - model.lo[a]) / model.cell[a]), ti.i32), 0),
                          model.cells[a] - 1)
    return c


@ti.func
def wrap_cell(model: ti.template(), q):
    """Cell index q (at most one cell outside the grid) wrapped along the periodic axes. With at least 3 cells
    there, the 27 cells around a cell are distinct."""
    for a in ti.static(range(3)):
        if ti.static(model.periodic[a]):
            q[a] = (q[a] + model.cells[a]) % model.cells[a]
    return q


@ti.func
def cell_index(model: ti.template(), c):
    return (c[2] * model.cells[1] + c[1]) * model.cells[0] + c[0]


@ti.func
def owns(model: ti.template(), sizes: ti.template(), i, ri, j):
    """Whether the pair (i, j) lives in i's row: the smaller grain owns it, ties to the lower grain id (not
    the memory slot, so re-ordering the grains never moves a pair to the other row)."""
    result = grain_id(model, sizes, j) > grain_id(model, sizes, i)
    if ti.static(model.polydisperse):
        rj = sizes.radius[j]
        result = rj > ri or (rj == ri and result)
    return result


@ti.func
def gate(nlist: ti.template(), gated: ti.template()):
    """1 or 0: a rebuild's loops run over gate * n items (the device flag); a sort's always run."""
    g = 1
    if ti.static(gated):
        g = nlist.counters[REBUILD]
    return g


@ti.func
def bin_by_cell(model: ti.template(), state: ti.template(), nlist: ti.template(), gated: ti.template()):
    """Counting sort of the alive grains by cell into ``nlist.sorted`` (``cell_start``: each cell's first
    entry, then the count); ungated (a sort), the dead grains follow the alive ones, so every slot is named."""
    # one array of n_cells + 1 ints: counts, then inclusive ends (the scan), then starts (each scattered
    # grain takes its slot from the end of its cell downwards). The flag is read once, ahead of the loops: in the
    # parallel form a statement between two loops is a one-thread task of its own (a kernel launch on CUDA), and
    # nothing here writes the flag
    nb = ti.static(model.scan_blocks)
    g = gate(nlist, gated)
    n_cells = g * model.n_cells
    n_grains = g * model.n
    n_blocks = g * nb
    if ti.static(not gated or not model.bins_zeroed_after):  # (else a build counts from the zeros it left)
        for c in range(n_cells):
            clear_bins_at(model, nlist, c)
    for i in range(n_grains):  # each cell's count, and each block's (integers: the same sums in any order)
        if state.alive[i]:
            ci = cell_index(model, cell_of(model, state.x[i]))
            ti.atomic_add(nlist.cell_start[ci], 1)
            ti.atomic_add(nlist.block_sum[ci // model.scan_block], 1)
    scan_block_sums(model, nlist, g)
    for b in range(n_blocks):
        run = nlist.block_sum[b]
        for t in range(model.scan_block):
            c = b * model.scan_block + t
            if c < model.n_cells:
                run += nlist.cell_start[c]
                nlist.cell_start[c] = run  # the end of cell c
    ti.loop_config(serialize=model.serial)  # one thread: the order within a cell is the same run to run
    for i in range(n_grains):
        if state.alive[i]:
            slot = ti.atomic_sub(nlist.cell_start[cell_index(model, cell_of(model, state.x[i]))], 1) - 1
            nlist.sorted[slot] = i
        elif ti.static(not gated):
            nlist.sorted[nlist.cell_start[model.n_cells] + ti.atomic_add(nlist.counters[DEAD], 1)] = i


@ti.func
def scan_block_sums(model: ti.template(), nlist: ti.template(), g):
    """The blocks' counts replaced by their exclusive running sums (each block's first entry), the total into
    ``cell_start[n_cells]``, the dead-grain counter zeroed; nothing unless ``g``. One thread (``model.scan_threads``
    0), else one block of that many threads (CUDA; ``model.scan_emulate``: one CPU thread taking their shares)."""
    nb = ti.static(model.scan_blocks)
    if ti.static(model.scan_threads == 0):
        ti.loop_config(serialize=True)
        for _ in range(g):
            run = 0
            for k in range(nb):
                v = nlist.block_sum[k]
                nlist.block_sum[k] = run
                run += v
            _scanned(run, model, nlist)
    else:
        block_scan(nlist.block_sum, nb, nlist.scan_tmp, model.scan_threads, model.scan_emulate, g, _scanned,
                   (model, nlist))


@ti.func
def _scanned(total, model: ti.template(), nlist: ti.template()):
    """After the blocks' scan (one thread): the total (the alive grains) ends the cell list; no dead grain placed."""
    nlist.cell_start[model.n_cells] = total
    nlist.counters[DEAD] = 0


@ti.func
def clear_bins_at(model: ti.template(), nlist: ti.template(), c):
    """Cell c's count (and block c's sum, for c below the block count) back to zero."""
    nlist.cell_start[c] = 0
    if c < model.scan_blocks:
        nlist.block_sum[c] = 0


@ti.func
def clear_bins_of(model: ti.template(), nlist: ti.template(), i):
    """Item i's share of zeroing the bins after a build (cells i, i + n, ...; at most ``model.zero_share``), run by
    the loop over grains that follows the rows (the substep's pair forces): a build's counting then starts from zeros
    without a zeroing loop of its own, a launch every substep on CUDA (empty unless flagged)."""
    for t in ti.static(range((model.n_cells + model.n - 1) // model.n)):
        c = i + t * model.n
        if c < model.n_cells:
            clear_bins_at(model, nlist, c)


@ti.func
def clear_bins(model: ti.template(), nlist: ti.template(), g: ti.template()):
    """Every bin back to zero when ``g`` (a build or a sort ran), where builds count from the zeros the last one left
    (``model.bins_zeroed_after``): for kernels with no loop over grains after it."""
    if ti.static(model.bins_zeroed_after):
        for c in range(g * model.n_cells):
            clear_bins_at(model, nlist, c)


@ti.func
def rebuild_if_flagged(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
                       nlist: ti.template()):
    """The whole rebuild as top-level loops of the calling kernel; each runs empty unless flagged. The flag is
    cleared (and the build counted) by the rows' first item: the loop's count was taken before it, nothing in the
    loop reads the flag, and only the integration after it raises the flag again (a one-thread task of its own
    after the loop cost a launch a substep on CUDA). Where ``model.bins_zeroed_after``, the bins are left counted
    and the caller zeroes them after the rows (:func:`clear_bins_of` in its next loop over grains, or
    :func:`clear_bins`), so between kernels every bin is zero. Returns the gate (1 if it built)."""
    g = gate(nlist, True)
    bin_by_cell(model, state, nlist, True)
    for i in range(nlist.counters[REBUILD] * ti.static(max(model.n, 1))):  # (one item with no grains: the flag)
        if i == 0:
            nlist.counters[BUILDS] += 1
            nlist.counters[REBUILD] = 0
        if ti.static(model.n > 0):
            build_row(model, sizes, state, history, nlist, i)
    return g


@ti.func
def gather(model: ti.template(), sizes: ti.template(), state: ti.template(), nlist: ti.template(), i, xi, ri, begin,
           end, found: ti.template(), near: ti.template(), cnt):
    """Grain i's partners among the sorted grains begin..end-1 appended to ``found`` (and each one's
    d^2 - (r_i + r_j)^2 to ``near``); returns the new count. The distance first: most candidates lie beyond the
    cut-off (about 85% of 27 cells one cut-off wide), and their ownership (a read of the partner's id) is never
    asked; the same partners in the same order as ownership first."""
    for p in range(begin, end):
        j = nlist.sorted[p]
        rs = ri + grain_radius(model, sizes, j)
        d = state.x[j] - xi
        if ti.static(model.wraps):
            d = min_image(model, d)
        dd = d.dot(d)
        if dd < (rs + model.skin) ** 2:
            if owns(model, sizes, i, ri, j):
                if cnt < model.slots:
                    found[cnt] = j
                    near[cnt] = dd - rs * rs  # < 0 where they touch, whatever the sizes
                    cnt += 1
                else:
                    ti.atomic_max(nlist.counters[OVERFLOW], cnt + 1)
    return cnt


@ti.func
def build_row(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
              nlist: ti.template(), i):
    """Grain i's new row, gathered in registers, nearest partner first; the springs of surviving pairs move
    with them.

    Nearest first: the pair loop's touching test is a branch, and in a row in cell order its outcomes follow
    no pattern (about 2.5 touching among 6.5 partners in a settled bed) that a CPU's branch predictor could
    learn. Sorted by d^2 - (r_i + r_j)^2 (by distance, for equal grains), the touching pairs lead and the
    outcome changes about once a row: a settled 125k-grain substep ran 1.11x faster in float32 and 1.05x in
    float64 (benchmarks/RESULTS.md, 2026-12-04). A sort by cell keeps each row's order.

    The candidates: the 27 cells around grain i, visited as 9 runs of the sorted grains (a row's three cells
    along x are consecutive) unless x is periodic; the same candidates in the same order as cell by cell, in half
    the time with the distance tested first (:func:`gather`; benchmarks/RESULTS.md, 2026-12-06)."""
    cnt = 0
    new = ti.Vector([-1] * model.slots, ti.i32)
    found = ti.Vector([-1] * model.slots, ti.i32)  # the partners in the order found
    near = ti.Vector([0.0] * model.slots)  # and each one's d^2 - (r_i + r_j)^2
    if state.alive[i]:
        xi = state.x[i]
        ri = grain_radius(model, sizes, i)
        c = cell_of(model, xi)
        if ti.static(model.periodic[0]):  # the 27 cells one by one (the x neighbours wrap)
            for dz, dy, dx in ti.ndrange((-1, 2), (-1, 2), (-1, 2)):
                q = wrap_cell(model, c + ti.Vector([dx, dy, dz]))
                if 0 <= q[1] < model.cells[1] and 0 <= q[2] < model.cells[2]:
                    ci = cell_index(model, q)
                    cnt = gather(model, sizes, state, nlist, i, xi, ri, nlist.cell_start[ci],
                                 nlist.cell_start[ci + 1], found, near, cnt)
        else:  # x is the fastest cell index: the cells x-1, x, x+1 of a row are one run of the sorted grains
            for dz, dy in ti.ndrange((-1, 2), (-1, 2)):
                q = c + ti.Vector([0, dy, dz])
                if ti.static(model.wraps):  # (without periodic axes the loop is compiled as it always was: a
                    q = wrap_cell(model, q)  # helper here made substeps 3% slower on one CPU thread, measured)
                if 0 <= q[1] < model.cells[1] and 0 <= q[2] < model.cells[2]:
                    row = (q[2] * model.cells[1] + q[1]) * model.cells[0]
                    cnt = gather(model, sizes, state, nlist, i, xi, ri, nlist.cell_start[row + ti.max(q[0] - 1, 0)],
                                 nlist.cell_start[row + ti.min(q[0] + 1, model.cells[0] - 1) + 1], found, near, cnt)
        # nearest first: each partner's rank is the number of those nearer (ties by the order found), counted
        # without a branch (an insertion sort's shifts stop at unpredictable places: its builds took 1.13x as
        # long as in cell order, these 1.05x)
        for k in range(cnt):
            rank = 0
            for q in range(cnt):  # integer arithmetic: Taichi's `or` / `and` compile to branches here
                rank += ti.cast(near[q] < near[k], ti.i32) + ti.cast(near[q] == near[k], ti.i32) * ti.cast(
                    q < k, ti.i32)
            new[rank] = found[k]
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
