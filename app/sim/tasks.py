"""One task a launch on one CPU thread: :func:`one_task`, the whole body of a kernel that takes a compile-time
``serial`` flag (:func:`app.sim.runtime.serial` says when to set it: Taichi makes each top-level loop of a kernel a
task of its own, ~70 us each on one thread)."""
import taichi as ti


@ti.func
def one_task(serial: ti.template(), body: ti.template(), args: ti.template()):
    """``body(*args)`` as the whole of a kernel: with ``serial`` nested in one serialized loop, so the launch is
    one task; otherwise inline, its loops the kernel's top-level (parallel) loops. A body that takes the flag
    itself gets it among ``args``."""
    if ti.static(serial):
        ti.loop_config(serialize=True)
        for _ in range(1):
            body(*args)
    else:
        body(*args)


@ti.func
def each_chunk(serial: ti.template(), chunks: ti.template(), body: ti.template(), args: ti.template()):
    """``body(c, *args)`` for c in 0..chunks-1, in order. In parallel unrolled at compile time, so each chunk's
    loops stay top-level (parallel) loops; on one thread (``serial``) a run-time loop, the body compiled once
    instead of once per chunk (the DEM sort of a frictional bed with rolling has ~80 chunks)."""
    if ti.static(serial):
        for c in range(chunks):
            body(c, *args)
    else:
        for c in ti.static(range(chunks)):
            body(c, *args)
