"""Taichi start-up: one place decides the backend and the float precision.

Owns: ``ti.init`` and the record of how Taichi was started, so that building a second
scene with the same settings reuses the compiled kernels instead of resetting Taichi.
"""
from __future__ import annotations

import contextlib
import gc
import os
import time

import taichi as ti

from ..config.errors import ConfigError

_current: tuple | None = None
#: Taichi wrappers (ndarrays, argpacks) still referenced when Taichi restarted, by id: kept alive for good (see
#: :func:`_keep_survivors`)
_survivors: dict = {}


def gpu_available() -> bool:
    """True when Taichi can start on CUDA here (probed in a way that does not keep CUDA)."""
    try:
        import ctypes

        ctypes.CDLL("libcuda.so.1")
    except OSError:
        return False
    return True


#: the share of the GPU's memory Taichi takes as its pool at start-up (every field and ndarray lives in it)
CUDA_MEMORY_FRACTION = 0.9


def cuda_memory() -> int | None:
    """Total memory of CUDA device 0 [bytes], asked of the driver (libcuda); None where there is no driver or it
    cannot say."""
    try:
        import ctypes

        cu = ctypes.CDLL("libcuda.so.1")
        dev, total = ctypes.c_int(), ctypes.c_size_t()
        if cu.cuInit(0) or cu.cuDeviceGet(ctypes.byref(dev), 0) or cu.cuDeviceTotalMem_v2(ctypes.byref(total), dev):
            return None
        return int(total.value)
    except (OSError, AttributeError):
        return None


def ndarray_bytes() -> int:
    """Bytes of the Taichi ndarrays alive in the running program (those of programs before a restart excluded):
    what the gas solver holds, which :data:`app.scene.GAS_DEVICE_BYTES_PER_CELL` is measured from."""
    from taichi.lang._ndarray import Ndarray

    gc.collect()
    live = {id(o): o for o in gc.get_objects() if isinstance(o, Ndarray) and id(o) not in _survivors}
    return sum(o._get_nelement() * o._get_element_size() for o in live.values())


def available_cpus() -> int:
    """CPUs this process may run on (its affinity, which a container or `taskset` may narrow), else all."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def cpu_threads(requested: int | None) -> int:
    """Threads for the CPU backend: ``requested``, at most the CPUs available (more only switch between each
    other: on 2 cores, settle.toml for 2 steps took 15 s of wall with 1000 threads against 5 s with 4, one run
    each, and 99999 had not finished a step after a minute), or automatically one on machines with 2 cores or
    fewer (measured: one thread with plain adds matches two with float atomics there), else all."""
    cores = available_cpus()
    if requested:
        return min(int(requested), cores)
    return 1 if cores <= 2 else cores


def _keep_survivors() -> None:
    """Before a restart: every ndarray and argpack wrapper of the old program is made harmless to the new one.

    Taichi 1.7.4 frees all of a program's ndarrays and argpacks at a restart, but a Python wrapper that dies later
    calls ``delete_ndarray`` / ``delete_argpack`` on the *current* program with its old pointer; once the new program
    has put a new ndarray at that freed address (malloc reuses it: seen within a few restarts), that live array is
    freed under its owner, whose next kernel launch reads a freed shape: a segfault, or "RuntimeError: argument not
    found" (fmt failing to format the assertion "External array cannot have > {max_num_indices} indices"). So the
    wrappers nothing references die now, in their own program, and the ones still referenced are kept for good
    (a few hundred bytes each; their arrays are gone with the old program either way)."""
    from taichi.lang._ndarray import Ndarray
    from taichi.lang.argpack import ArgPack

    gc.collect()
    for o in gc.get_objects():
        if isinstance(o, (Ndarray, ArgPack)):
            _survivors[id(o)] = o


#: Taichi's offline cache of compiled kernels may hold this many bytes before it evicts the least recently used
#: quarter. Taichi's default, 100 MiB, is soon outgrown by fbed's kernels (measured 2026-12-03: six presets' smoke
#: runs left 29 MiB; the test suite 191 MiB), so past it every dump evicted kernels that the next run compiled
#: again (the suite with a warm cache took as long as from an empty one, 16 min 51 s against 17 min 13 s).
#: ``TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES`` overrides it.
OFFLINE_CACHE_BYTES = 1 << 30

#: a Taichi offline-cache lock older than this is stale (s): the lock is held only while the cache's index is read
#: or written, well under a second
STALE_LOCK_S = 120.0


def _clear_stale_cache_lock() -> None:
    """Remove a stale lock of Taichi's offline cache.

    Taichi 1.7.4 guards the cache with a lock file (``ticache.lock``, made with O_EXCL, removed on unlock, no owner
    recorded). A process killed while it holds the lock leaves the file for good, and from then on every Taichi
    program fails to take it ("Lock ... ticache.lock failed") and neither reads nor writes the cache: every process
    compiles every kernel from scratch (seen 2026-12-02: a 45 s test took 240 s, the unit tier 5 min instead of
    40 s, for hours). A lock older than :data:`STALE_LOCK_S` cannot belong to a live reader or writer."""
    from taichi.lang import impl

    path = os.environ.get("TI_OFFLINE_CACHE_FILE_PATH") or impl.default_cfg().offline_cache_file_path
    lock = os.path.join(path, "ticache.lock")
    try:
        if time.time() - os.path.getmtime(lock) > STALE_LOCK_S:
            os.remove(lock)
    except OSError:  # no lock, or another process removed it first
        pass


def init(arch: str = "auto", precision: str = "float32", threads: int | None = None, debug: bool = False,
         kernel_profiler: bool = False) -> str:
    """Start Taichi on ``arch`` ('auto', 'cpu', 'cuda') with ``precision`` ('float32'|'float64').

    Re-initialises only when the settings change (re-init drops every field and kernel).
    Returns the arch actually used ('cpu' or 'cuda'). 'cuda' where Taichi finds no usable CUDA device is a
    ConfigError (Taichi itself would fall back to the CPU); 'auto' then takes the CPU. ``kernel_profiler``: Taichi's kernel profiler on
    (benchmarks only: it records every offloaded task, :func:`profiled_tasks`).
    """
    global _current
    auto = arch == "auto"
    if auto:
        arch = "cuda" if gpu_available() else "cpu"
    key = (arch, precision, threads, debug) + ((True,) if kernel_profiler else ())
    if _current == key:
        return arch
    fp = ti.f64 if precision == "float64" else ti.f32
    kwargs = dict(default_fp=fp, default_ip=ti.i32, debug=debug, log_level=ti.WARN, kernel_profiler=kernel_profiler)
    if not os.environ.get("TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES"):  # the user's own limit wins
        kwargs["offline_cache_max_size_of_files"] = OFFLINE_CACHE_BYTES
    _keep_survivors()
    _clear_stale_cache_lock()
    if arch == "cpu":
        kwargs["cpu_max_num_threads"] = cpu_threads(threads)
        ti.init(arch=ti.cpu, **kwargs)
    elif arch == "cuda":
        ti.init(arch=ti.cuda, device_memory_fraction=CUDA_MEMORY_FRACTION, **kwargs)
        if ti.lang.impl.current_cfg().arch != ti.cuda:  # Taichi fell back to the CPU: a run would say 'cuda'
            ti.reset()
            _current = None
            if auto:  # a CUDA driver without a usable device: the CPU, set up as such (its threads)
                return init("cpu", precision, threads, debug, kernel_profiler)
            raise ConfigError("CUDA was asked for, but Taichi found no usable CUDA device here (it would have run on "
                              "the CPU while its outputs said cuda)", "--arch", "cuda",
                              hint="--arch cpu, or --arch auto (the GPU when there is one, else the CPU)")
    else:
        raise ValueError(f"unknown arch {arch!r}")
    _current = key
    return arch


def serial() -> bool:
    """True when Taichi runs on the CPU with one thread (the default on 2 cores or fewer): then a kernel's
    top-level loops are best nested in one serial loop, since each top-level loop is a task of its own
    (measured 2026-12-02, Taichi 1.7.4, one thread: ~70 us per task; ten empty loops 700 us a launch as
    tasks, 21 us nested in one serial loop). False before ``init`` and on CUDA."""
    if _current is None:
        return False
    arch, threads = _current[0], _current[2]
    return arch == "cpu" and cpu_threads(threads) == 1


def clear_profile() -> None:
    """Forget the kernel profiler's records (Taichi started with ``kernel_profiler=True``)."""
    ti.sync()
    ti.profiler.clear_kernel_profiler_info()


def profiled_tasks() -> int:
    """Offloaded tasks run since :func:`clear_profile` (each top-level loop of a kernel, or a serial block, is
    one task per launch; counted by Taichi's kernel profiler)."""
    from taichi.profiler.kernel_profiler import get_default_kernel_profiler

    ti.sync()
    prof = get_default_kernel_profiler()
    prof._update_records()
    return len(prof._traced_records)


def profiled_times() -> list[tuple[str, float]]:
    """(task name, seconds) of every offloaded task run since :func:`clear_profile`, in launch order (Taichi's
    kernel profiler: device time of each task on CUDA, measured by events around it; wall time on the CPU)."""
    from taichi.profiler.kernel_profiler import get_default_kernel_profiler

    ti.sync()
    prof = get_default_kernel_profiler()
    prof._update_records()
    return [(r.name, 1e-3 * r.kernel_time) for r in prof._traced_records]


def reset() -> None:
    """Forget the current settings so the next init() restarts Taichi (used by tests)."""
    global _current
    _current = None


def on_cuda() -> bool:
    """True when the running Taichi program is on CUDA (``init('cuda')`` falls back to the CPU without a GPU)."""
    from taichi.lang import impl

    return _current is not None and impl.current_cfg().arch == ti.cuda


def sync() -> None:
    """Wait for every launched kernel to finish (read the clock after this when timing kernels)."""
    ti.sync()


def current() -> tuple | None:
    """(arch, precision, threads, debug[, True with the kernel profiler]) Taichi was started with, or None
    before the first init()."""
    return _current


@contextlib.contextmanager
def kept():
    """Hand Taichi back as it was on exit (a bench that switches precision inside must not leave a test
    session, which runs in float64, on float32)."""
    previous = _current
    try:
        yield
    finally:
        if previous is not None:
            init(*previous)
