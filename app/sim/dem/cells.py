"""Each tracked grain's cell on a grid, on the device: the rCFD recording probe's per-frame work
(``app/rcfd_probe.py``) without copying a million positions to the host at every frame.

Grain k of a tracked list (``place[id]`` = k for a tracked grain id, -1 for one that is not) gets, from its
centre x, the half-cell indices q_a = floor((x_a - o_a) / (h / 2)) clipped to [0, 2 n_a - 1], its cell
((q_0 >> 1) n_1 + (q_1 >> 1)) n_2 + (q_2 >> 1) and its octant ((q_0 & 1) << 2) | ((q_1 & 1) << 1) | (q_2 & 1),
in float64 whatever the run's precision: ``RcfdRecorder.cells_and_octants``' floors on the host, so the same
integers (tests/test_dem_sort.py checks them after sorts, with grains on half-cell faces). ``flags[k]``: bit 1 set
if the grain is alive, bit 0 where x_axis op value (op 0 <, 1 <=, 2 >, 3 >=: the probe's tag expression,
``app.rcfd.database.parse_tag``). A million grains on one CPU thread: 27 ms a frame, against 68 ms for the positions
read back and the same floors in numpy (benchmarks/rcfd_frame_cost.py --device).
"""
import taichi as ti

from ..launch import kernel
from .grains import grain_id

#: the tag expression's comparisons, in the kernel's numbering
TAG_OPS = {"<": 0, "<=": 1, ">": 2, ">=": 3}


@kernel
def grain_cells(model: ti.template(), sizes: ti.template(), state: ti.template(),
                place: ti.types.ndarray(dtype=ti.i32, ndim=1), ox: ti.f64, oy: ti.f64, oz: ti.f64, half: ti.f64,
                nx: ti.i32, ny: ti.i32, nz: ti.i32, tag_axis: ti.i32, tag_op: ti.i32, tag_value: ti.f64,
                cells: ti.types.ndarray(dtype=ti.i32, ndim=1), octant: ti.types.ndarray(dtype=ti.u8, ndim=1),
                flags: ti.types.ndarray(dtype=ti.u8, ndim=1)):
    """``cells[k]``, ``octant[k]``, ``flags[k]`` of every tracked grain k (see the module's text); grid origin
    (ox, oy, oz) [m], half a cell ``half`` [m], nx x ny x nz cells."""
    for i in range(model.n):
        k = place[grain_id(model, sizes, i)]
        if k >= 0:
            x = ti.cast(state.x[i], ti.f64)
            o = ti.Vector([ox, oy, oz])
            top = ti.Vector([2 * nx - 1, 2 * ny - 1, 2 * nz - 1])
            q = ti.Vector([0, 0, 0])
            for a in ti.static(range(3)):  # clipped before the cast (the host clips int64s: the same for finite x)
                f = ti.min(ti.max(ti.floor((x[a] - o[a]) / half), 0.0), ti.cast(top[a], ti.f64))
                q[a] = ti.cast(f, ti.i32)
            cells[k] = ((q[0] >> 1) * ny + (q[1] >> 1)) * nz + (q[2] >> 1)
            octant[k] = ti.cast(((q[0] & 1) << 2) | ((q[1] & 1) << 1) | (q[2] & 1), ti.u8)
            v = x[0]
            if tag_axis == 1:
                v = x[1]
            elif tag_axis == 2:
                v = x[2]
            t = v < tag_value
            if tag_op == 1:
                t = v <= tag_value
            elif tag_op == 2:
                t = v > tag_value
            elif tag_op == 3:
                t = v >= tag_value
            flags[k] = ti.cast(t, ti.u8) | (ti.cast(state.alive[i] != 0, ti.u8) << 1)
