"""One task a launch on one CPU thread: :func:`one_task`, the whole body of a kernel that takes a compile-time
``serial`` flag (:func:`app.sim.runtime.serial` says when to set it: Taichi makes each top-level loop of a kernel a
task of its own, ~70 us each on one thread); :func:`each_chunk`; and a kernel that a single block of threads runs,
meeting at barriers (CUDA), or one thread that takes their shares in turn: :func:`one_block` launches it,
:func:`block_pass` is one of its passes."""
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


@ti.func
def block_pass(t, nt: ti.template(), emulate: ti.template(), barrier: ti.template(), count, body: ti.template(),
               args: ti.template()):
    """One pass of a one-block kernel (:mod:`app.sim.gas.coarse_cycle`, :mod:`app.sim.dem.scan`): ``body(i, *args)``
    for i in 0..count-1, thread t of ``nt`` taking i = t, t + nt, ...; then the block's barrier (``barrier``: CUDA,
    ``ti.simt.block.sync``), so the next pass sees every write of this one. ``emulate``: one thread takes every
    thread's share in turn (the CPU, which has no barrier; what a barrier guarantees, the shares in one order)."""
    lo = t
    hi = t + 1
    if ti.static(emulate):
        lo = 0
        hi = nt
    for tt in range(lo, hi):
        for q in range((count - tt + nt - 1) // nt):
            body(tt + q * nt, *args)
    if ti.static(barrier):
        ti.simt.block.sync()


@ti.func
def one_block(nt: ti.template(), emulate: ti.template(), barrier: ti.template(), g, body: ti.template(),
              args: ti.template()):
    """``body(t, nt, emulate, barrier, *args)`` as a top-level loop of the calling kernel, nothing unless ``g``:
    with ``barrier`` (CUDA) one block of ``nt`` threads (a loop of constant length nt is one block; ``g`` is the same
    in all its threads), else one thread, t = 0 (``emulate``: it takes the nt threads' shares in turn, see
    :func:`block_pass`). The body's passes are :func:`block_pass` calls."""
    if ti.static(barrier):
        ti.loop_config(block_dim=nt)
        for t in range(nt):
            if g != 0:
                body(t, nt, False, True, *args)
    else:
        ti.loop_config(serialize=True)
        for _ in range(g):
            body(0, nt, emulate, False, *args)
