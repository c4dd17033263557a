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
