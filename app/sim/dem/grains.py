"""Per-grain constants read inside the DEM kernels, the grain id of a memory slot, the scatter that adds
to another grain, and the periodic images.

Monodisperse scenes store no radius or mass per grain: the kernels read the model's
compile-time constants instead (``ti.static`` on ``model.polydisperse``)."""
import taichi as ti


@ti.func
def grain_radius(model: ti.template(), sizes: ti.template(), i):
    r = ti.cast(model.radius, float)
    if ti.static(model.polydisperse):
        r = sizes.radius[i]
    return r


@ti.func
def grain_mass(model: ti.template(), sizes: ti.template(), i):
    mass = ti.cast(model.mass, float)
    if ti.static(model.polydisperse):
        mass = sizes.mass[i]
    return mass


@ti.func
def scatter_add(model: ti.template(), target: ti.template(), j, value):
    """target[j] += value from inside the grain loop: atomic when threads run it, a plain
    read-modify-write when the loop is serial (float atomics are compare-and-swap loops on a CPU)."""
    if ti.static(model.serial):
        target[j] = target[j] + value
    else:
        ti.atomic_add(target[j], value)


@ti.func
def grain_id(model: ti.template(), sizes: ti.template(), i):
    """The id (the index ``set_grains`` was given) of the grain in memory slot i: grains are re-ordered by
    cell when ``model.sorts``, so a kernel that keys anything on the grain (a tracer colour) reads this."""
    g = i
    if ti.static(model.sorts):
        g = sizes.grain_id[i]
    return g


@ti.func
def min_image(model: ti.template(), d):
    """The separation d = x_j - x_i [m] of two points inside the box to the nearest periodic image of x_j:
    shifted by a period along each periodic axis (``model.periodic``) where |d_a| > L_a / 2 (|d_a| < L_a for
    points inside, so one period is enough). Two selects, not ``ti.round``: with the rounding a periodic bed's
    substep cost 1.17x the walled bed's on one CPU thread, with the selects 1.05x (benchmarks/periodic_cost.py).
    Nothing is compiled for the other axes: a scene without periodic faces pays nothing."""
    for a in ti.static(range(3)):
        if ti.static(model.periodic[a]):
            period = ti.static(model.hi[a] - model.lo[a])
            d[a] = ti.select(d[a] > 0.5 * period, d[a] - period, ti.select(d[a] < -0.5 * period, d[a] + period, d[a]))
    return d


@ti.func
def wrap_position(model: ti.template(), x):
    """x [m] brought back into [lo, hi) along each periodic axis (a grain that left by one face enters by
    the other); returned unchanged along the others."""
    for a in ti.static(range(3)):
        if ti.static(model.periodic[a]):
            period = ti.static(model.hi[a] - model.lo[a])
            if x[a] < model.lo[a]:
                x[a] += period
            elif x[a] >= model.hi[a]:
                x[a] -= period
    return x
