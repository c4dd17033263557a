"""The sort: memory order follows space. Every per-grain array is gathered into cell order
(``neighbors.bin_by_cell``), two loops per array (gather into a scratch, copy back), every
``DemModel.sort_interval`` builds (``DemSolver``), so that the grains near one another in space sit near one
another in memory (a mixed bed on an H100: 1.30x faster substeps, benchmarks/RESULTS.md). The scratch is the force
accumulator (3 numbers per grain, integers held exactly: n < 2^24 in float32), which is zero between substeps
(``integrate`` clears it) and is left zero. Partner indices are mapped to the partners' new slots; pairs stay in
their rows (ownership ties go by grain id), their springs move with their grains, x_ref with its grain: the list
stays valid and no build is needed. Outside the DEM nothing sees the order: outputs, probes and checkpoints go by
grain id."""
import taichi as ti

from ..fields import NO_SPRING, ROLL_EPSD
from ..launch import kernel
from ..tasks import each_chunk, one_task
from .neighbors import bin_by_cell, clear_bins



@ti.func
def move_scalars(model: ti.template(), nlist: ti.template(), scratch: ti.template(), fields: ti.template()):
    """Up to three 1-D scalar fields into cell order."""
    for p in range(model.n):
        o = nlist.sorted[p]
        for c in ti.static(range(len(fields))):
            scratch[p][c] = ti.cast(fields[c][o], float)
    for p in range(model.n):
        for c in ti.static(range(len(fields))):
            fields[c][p] = ti.cast(scratch[p][c], fields[c].dtype)


@ti.func
def move_rows(c, model: ti.template(), nlist: ti.template(), scratch: ti.template(), field: ti.template(),
              rows: ti.template()):
    """Rows 3c..3c+2 (those below ``rows``) of a 2-D scalar field into cell order."""
    for p in range(model.n):
        o = nlist.sorted[p]
        for t in ti.static(range(3)):
            if 3 * c + t < rows:
                scratch[p][t] = ti.cast(field[3 * c + t, o], float)
    for p in range(model.n):
        for t in ti.static(range(3)):
            if 3 * c + t < rows:
                field[3 * c + t, p] = ti.cast(scratch[p][t], field.dtype)


@ti.func
def move_vector(model: ti.template(), nlist: ti.template(), scratch: ti.template(), field: ti.template()):
    """One 1-D 3-vector field into cell order."""
    for p in range(model.n):
        scratch[p] = field[nlist.sorted[p]]
    for p in range(model.n):
        field[p] = scratch[p]


@ti.func
def move_vector_row(h, model: ti.template(), nlist: ti.template(), scratch: ti.template(), field: ti.template()):
    """Row h of a 2-D 3-vector field into cell order."""
    for p in range(model.n):
        scratch[p] = field[h, nlist.sorted[p]]
    for p in range(model.n):
        field[h, p] = scratch[p]


@ti.func
def move_partners(c, model: ti.template(), nlist: ti.template(), scratch: ti.template()):
    """Neighbour slots 2c, 2c+1 (those below ``model.slots``) into cell order, each partner renamed by its new
    slot, which the scratch's third component holds; the slots past a row's count become -1."""
    for p in range(model.n):
        o = nlist.sorted[p]
        for t in ti.static(range(2)):
            k = 2 * c + t
            if k < model.slots:
                moved = -1.0
                if k < nlist.count[o]:
                    moved = scratch[nlist.partner[k, o]][2]
                scratch[p][t] = moved
    for p in range(model.n):
        for t in ti.static(range(2)):
            if 2 * c + t < model.slots:
                nlist.partner[2 * c + t, p] = ti.cast(scratch[p][t], ti.i32)


@kernel
def sort_by_cell(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
                 nlist: ti.template()):
    """Re-order every per-grain array by cell (dead grains last); the list stays valid. On one CPU thread
    (``model.serial``) one serial task (its ~50 loops nested in one loop, in the same order)."""
    one_task(model.serial, sort_parts, (model, sizes, state, history, nlist))


@ti.func
def sort_parts(model: ti.template(), sizes: ti.template(), state: ti.template(), history: ti.template(),
               nlist: ti.template()):
    bin_by_cell(model, state, nlist, False)
    clear_bins(model, nlist, 1)  # the sort's bins back to zero where builds count from zeros (sorted[] is its use)
    for p in range(model.n):  # the new slot of the grain now in slot o
        state.force[nlist.sorted[p]][2] = p
    each_chunk(model.serial, (model.slots + 1) // 2, move_partners, (model, nlist, state.force))
    move_scalars(model, nlist, state.force, (nlist.count, state.alive, sizes.grain_id))
    if ti.static(model.has_history):
        each_chunk(model.serial, (model.slots + 2) // 3, move_rows, (model, nlist, state.force, nlist.spring_slot,
                                                                     model.slots))
        for p in range(model.n):  # the history slots in use are those a neighbour slot names
            used = ti.u32(0)
            for k in range(nlist.count[p]):
                h = ti.cast(nlist.spring_slot[k, p], ti.u32)
                if h != ti.u32(NO_SPRING):
                    used |= ti.u32(1) << h
            nlist.springs_used[p] = used
    if ti.static(model.polydisperse):
        move_scalars(model, nlist, state.force, (sizes.radius, sizes.mass))
    for field in ti.static((state.x, state.v, nlist.x_ref)):
        move_vector(model, nlist, state.force, field)
    if ti.static(model.friction):
        move_vector(model, nlist, state.force, state.omega)
        move_vector(model, nlist, state.force, state.torque)
        each_chunk(model.serial, model.history_slots, move_vector_row, (model, nlist, state.force, history.tangential))
        if ti.static(len(model.walls)):
            each_chunk(model.serial, ti.static(len(model.walls)), move_vector_row,
                       (model, nlist, state.force, history.wall_tangential))
    if ti.static(model.rolling == ROLL_EPSD):
        each_chunk(model.serial, model.history_slots, move_vector_row, (model, nlist, state.force, history.rolling))
        if ti.static(len(model.walls)):
            each_chunk(model.serial, ti.static(len(model.walls)), move_vector_row,
                       (model, nlist, state.force, history.wall_rolling))
    if ti.static(model.coupled):
        move_scalars(model, nlist, state.force, (state.drag_coeff,))
        move_vector(model, nlist, state.force, state.gas_velocity)
        move_vector(model, nlist, state.force, state.external_force)
    for p in range(model.n):
        state.force[p] = ti.Vector([0.0, 0.0, 0.0])
