"""The cell list's scan: the block sums of the counting sort (``neighbors.bin_by_cell``) turned into each block's
first entry, by one thread or by one block of threads.

The counting sort counts grains per cell and per block of ``DemModel.scan_block`` cells, scans the blocks' sums
(this module), then each block's cells (a loop over blocks). On the CPU's parallel form one thread scans the
block sums (``scan_threads`` 0), cheap there. On CUDA a thread's loop is a chain of global-memory loads, each
~0.2-0.5 us: the Verma bed's 1.65 M cells make 1,612 blocks of 1,024, about 0.5 ms per scan on one thread, and
another ~0.3 ms for each block's 1,024 cells in turn (a prediction from the latencies, not measured). So on CUDA
(:func:`layout`) the blocks are smaller (128 cells: 12,900 of them, each scanned by its own thread in 128 loads)
and their sums are scanned by one block of ``scan_threads`` threads meeting at barriers (:func:`exclusive_scan`):
each thread sums a contiguous chunk, the chunk sums are scanned in log2(threads) Hillis-Steele steps, and each
thread writes its chunk's running sums. Integers, so the result is the same in any order and on any device.
The barrier path runs on no CPU: on CUDA it is checked once per process against numpy (:func:`block_scan_works`)
before a DEM takes it, and a device that fails gets the one-thread scan (the same lists) and a warning.
The same block scans the height histogram of the step's diagnostics record (``step.measure``).
"""
import dataclasses
import os
import warnings

import numpy as np
import taichi as ti

from ...config.errors import ConfigError
from ..tasks import block_pass, one_block

#: the CPU's layout: blocks of 1,024 cells, their sums scanned by one thread
CPU_BLOCK = 1024
#: CUDA's: blocks of 128 cells (each a thread's sequential scan), their sums scanned by a block of 512 threads (at
#: most 128 registers a thread: any such loop fits)
CUDA_BLOCK, CUDA_THREADS = 128, 512


def layout(model, cuda: bool):
    """``model`` with the scan's layout for the device. On CUDA: :data:`CUDA_BLOCK` cells a block, their sums
    scanned by :data:`CUDA_THREADS` threads, unless ``FBED_DEM_SCAN=serial`` (the CPU's one-thread scan of 1,024-cell
    blocks: for an A/B, and for a device whose check of the block scan failed, benchmarks/dem_scan_check.py).
    Elsewhere ``model`` as it is (the CPU's layout is the default; tests set the emulated block scan)."""
    mode = os.environ.get("FBED_DEM_SCAN", "").strip() or "block"
    if mode not in ("block", "serial"):
        raise ConfigError(f"'{mode}' is not a scan mode", "environment", "FBED_DEM_SCAN",
                          hint="'block' (one block of threads, CUDA's default) or 'serial' (one thread, the CPU's); "
                               "unset it for the device's default")
    if not cuda or model.serial:
        return model
    if mode == "block" and not block_scan_works(CUDA_THREADS):
        warnings.warn("the DEM's block scan failed its start-up check on this device: the one-thread scan is used "
                      "(the same lists, slower builds; FBED_DEM_SCAN=serial says so without the check)", RuntimeWarning)
        mode = "serial"
    if mode == "serial":
        return dataclasses.replace(model, scan_block=CPU_BLOCK, scan_threads=0, scan_emulate=False)
    return dataclasses.replace(model, scan_block=CUDA_BLOCK, scan_threads=CUDA_THREADS, scan_emulate=False)


_works: dict = {}


def block_scan_works(threads: int, emulate: bool = False, n: int = 40000) -> bool:
    """Once per process and thread count: :func:`exclusive_scan` as one block of ``threads`` threads at barriers
    (CUDA; ``emulate``: their shares on one thread, the CPU) on ``n`` random counts, against numpy. The barrier path
    runs on no CPU: a device where it misbehaves gets the one-thread scan instead of wrong neighbour lists."""
    key = (threads, emulate, n)
    if key not in _works:
        values, tmp, total = ti.field(ti.i32, n), ti.field(ti.i32, 2 * threads), ti.field(ti.i32, ())
        counts = np.random.default_rng(5).integers(0, 9, n).astype(np.int32)
        values.from_numpy(counts)
        _k_scan_check(values, tmp, total, n, threads, emulate)
        got = values.to_numpy()
        _works[key] = bool(np.array_equal(got[1:], np.cumsum(counts)[:-1]) and got[0] == 0
                           and total[None] == counts.sum())
    return _works[key]


@ti.func
def _store(total, out: ti.template()):
    out[None] = total


@ti.kernel
def _k_scan_check(values: ti.template(), tmp: ti.template(), total: ti.template(), n: ti.template(),
                  nt: ti.template(), emulate: ti.template()):
    block_scan(values, n, tmp, nt, emulate, 1, _store, (total,))


@ti.func
def block_scan(values: ti.template(), n: ti.template(), tmp: ti.template(), nt: ti.template(),
               emulate: ti.template(), g, done: ti.template(), done_args: ti.template()):
    """:func:`exclusive_scan` as a top-level loop of the calling kernel, nothing unless ``g``: one block of ``nt``
    threads (CUDA), or with ``emulate`` one thread taking their shares (:func:`app.sim.tasks.one_block`); then
    ``done(total, *done_args)`` once. The DEM's build (``neighbors.scan_block_sums``) and the start-up check
    (:func:`block_scan_works`) both run this."""
    one_block(nt, emulate, not emulate, g, _scan_then, (values, n, tmp, done, done_args))


@ti.func
def _scan_then(t, nt: ti.template(), emulate: ti.template(), barrier: ti.template(), values: ti.template(),
               n: ti.template(), tmp: ti.template(), done: ti.template(), done_args: ti.template()):
    total = exclusive_scan(t, values, n, tmp, nt, emulate, barrier)
    if t == 0:
        done(total, *done_args)


@ti.func
def _chunk_sum(i, values: ti.template(), tmp: ti.template(), n: ti.template(), chunk: ti.template()):
    s = 0
    for k in range(i * chunk, ti.min(i * chunk + chunk, n)):
        s += values[k]
    tmp[i] = s


@ti.func
def _step(i, tmp: ti.template(), d: ti.template(), src: ti.template(), dst: ti.template()):
    """One Hillis-Steele step: tmp[dst + i] = tmp[src + i] + tmp[src + i - d] (i >= d)."""
    v = tmp[src + i]
    if i >= d:
        v += tmp[src + i - d]
    tmp[dst + i] = v


@ti.func
def _chunk_write(i, values: ti.template(), tmp: ti.template(), n: ti.template(), chunk: ti.template(),
                 res: ti.template()):
    """Chunk i's exclusive running sums, from the inclusive sum of the chunks before it."""
    run = 0
    if i > 0:
        run = tmp[res + i - 1]
    for k in range(i * chunk, ti.min(i * chunk + chunk, n)):
        v = values[k]
        values[k] = run
        run += v


@ti.func
def exclusive_scan(t, values: ti.template(), n: ti.template(), tmp: ti.template(), nt: ti.template(),
                   emulate: ti.template(), barrier: ti.template()):
    """``values[0..n)`` replaced by their exclusive running sums; returns the total, to every thread (each reads it
    after the last Hillis-Steele step's barrier, and nothing writes it after: ``step._record_block`` relies on it).
    Thread t of ``nt`` (``tmp`` holds 2 nt integers): its chunk's sum, the chunks' sums scanned in
    log2(nt) steps (double-buffered: each step reads one half of ``tmp`` and writes the other), its chunk written.
    ``barrier``: one CUDA block; ``emulate``: one thread taking the shares in turn
    (:func:`app.sim.tasks.block_pass`)."""
    chunk = ti.static((n + nt - 1) // nt)
    block_pass(t, nt, emulate, barrier, nt, _chunk_sum, (values, tmp, n, chunk))
    steps = ti.static(max(0, (nt - 1).bit_length()))
    for s in ti.static(range(steps)):
        block_pass(t, nt, emulate, barrier, nt, _step, (tmp, 1 << s, (s % 2) * nt, ((s + 1) % 2) * nt))
    res = ti.static((steps % 2) * nt)
    total = tmp[res + nt - 1]
    block_pass(t, nt, emulate, barrier, nt, _chunk_write, (values, tmp, n, chunk, res))
    return total
