"""The coarse end of a V-cycle in one launch: every red-black level from ``m`` down, the coarsest solve and the
way back up, as one task (:func:`k_coarse_cycle`), where :mod:`.vcycle` launches two kernels a level.

Why: on CUDA every loop of a level's launch is a kernel launch of its own, each on Taichi's full launch width
(8448 blocks on an H100) however few cells the level has, and every launch costs host time (tens of us with
its arrays). The Verma grid's levels below 16 x 16 x 58 have 1856 cells or fewer, yet took 7 launches and about
40 tasks a V-cycle, 8 V-cycles a step. Here one block of :data:`BLOCK_THREADS` threads runs them all: each pass
over a level's cells (the first red sweep, a colour sweep, the restriction, the prolongation with the first sweep
up) gives thread t the cells t, t + T, t + 2T, ..., and a barrier (``ti.simt.block.sync``) separates passes, as a
kernel boundary did.
The levels are a run-time loop, so the kernel is compiled once whatever the hierarchy (levels unrolled with
``ti.static`` compiled too slowly, :mod:`.vcycle`).

The arithmetic is the launches': the same per-cell functions (:mod:`.passes`: ``first_red_at``, ``colour_at``,
``restrict_at``, ``prolong_black_at``) in the same passes, and a colour's cells do not depend on one another, so the
result is the same to the bit whatever thread takes which cell. Without a GPU the cycle runs on one thread (the
parallel form on the CPU: one task instead of ~40); ``emulate`` walks the T threads' shares one after the other
inside each pass, which is what the barrier guarantees, so the CPU tests check the threads' division of the cells.

Used for levels m..L-1 when each is red-black and has at most :func:`max_cells` cells and the coarsest is solved on
one thread (``MGPCG.block_from``, :mod:`app.sim.gas.linsolve`).

The multigrid set-up of every solve (the transmissibilities and diagonal of each coarse level from the one above,
``multigrid.k_coarsen``: a launch of 5 tasks a level) takes the same block for the levels of at most
:func:`max_cells` cells, :func:`k_coarsen_levels` (``MGPCG.coarsen_from``), with the same per-face and per-cell
functions, so the hierarchy is the same to the bit. With level 0's diagonal in the first ``k_coarsen`` (no
``k_diag`` launch of its own), the Verma grid's set-up went from 6 launches and 27 tasks a solve to 2 and 7.
"""
import os

import taichi as ti

from ...config.errors import ConfigError
from ..launch import kernel
from ..tasks import block_pass, one_block
from .coarse import coarse_solve
from .multigrid import POST_SWEEPS, PRE_SWEEPS, Hierarchy, Multigrid, coarsen_constants, coarsen_face_at, diag_at, on
from .passes import colour_at, first_red_at, level_pair, prolong_black_at, restrict_at

#: threads of the one block on CUDA (256: any kernel's registers fit; 1024 would need at most 64 a thread)
BLOCK_THREADS = 256
#: the largest level (cells) the block cycles: 16 a thread and pass at 256 threads (Verma grid: from 8 x 8 x 29)
MAX_CELLS = 4096


def max_cells() -> int:
    """:data:`MAX_CELLS`, or the environment's ``FBED_COARSE_CELLS`` where set (0: no level qualifies, a launch down
    and up per level and a set-up launch per level, the same results; for a device whose check of this cycle
    failed, benchmarks/device_run.sh)."""
    v = os.environ.get("FBED_COARSE_CELLS", "").strip()
    if not v:
        return MAX_CELLS
    try:
        n = int(v)
    except ValueError:
        n = -1
    if n < 0:
        raise ConfigError("not a whole number of cells >= 0", "environment", "FBED_COARSE_CELLS",
                          hint=f"0 turns the pressure solver's one-launch coarse cycle and set-up off (a launch "
                               f"down and up per level, the same results); unset it for the default, {MAX_CELLS}")
    return n


@ti.func
def _cycle(t, nt: ti.template(), emulate: ti.template(), barrier: ti.template(), mg: ti.template(), m, L, singular):
    """Levels m..L-1 down (x = 0 and a red sweep, black, red, black, restriction: ``vcycle._down``), the coarsest
    level L's one-thread solve (thread 0), levels L-1..m up (prolongation with black, red, black, red:
    ``vcycle._up``). Nothing once the solve has stopped (every count is x on)."""
    act = on(mg)
    for l in range(m, L):
        n, fo, co, nc, h2, nq, r, N, cb, NC = level_pair(mg, l, act)
        block_pass(t, nt, emulate, barrier, nc, first_red_at, (mg, n, co))
        for s in range(2 * PRE_SWEEPS - 1):
            block_pass(t, nt, emulate, barrier, nq, colour_at, (mg, n, fo, co, h2, (s + 1) % 2))
        block_pass(t, nt, emulate, barrier, NC, restrict_at, (mg, n, fo, co, r, N, cb))
    if t == 0:
        coarse_solve(mg, L, singular, 1)
    if ti.static(barrier):
        ti.simt.block.sync()
    for q in range(L - m):
        l = L - 1 - q
        n, fo, co, nc, h2, nq, r, N, cb, _ = level_pair(mg, l, act)
        block_pass(t, nt, emulate, barrier, nq, prolong_black_at, (mg, n, fo, co, h2, r, N, cb))
        for s in range(1, 2 * POST_SWEEPS):
            block_pass(t, nt, emulate, barrier, nq, colour_at, (mg, n, fo, co, h2, (s + 1) % 2))


@kernel
def k_coarse_cycle(mg: Multigrid, m: ti.i32, L: ti.i32, singular: ti.i32, threads: ti.template(),
                   emulate: ti.template(), barrier: ti.template()):
    """Levels m..L (L the coarsest) of a V-cycle whose level m's right-hand side the launch before restricted.
    ``barrier`` (CUDA): one block of ``threads`` threads; else one thread (``emulate``: taking the shares of
    ``threads`` threads in turn, the division of the cells a block makes)."""
    one_block(threads, emulate, barrier, 1, _cycle, (mg, m, L, singular))


@ti.func
def _coarsen_levels(t, nt: ti.template(), emulate: ti.template(), barrier: ti.template(), mg: ti.template(), m, L):
    """Levels m+1..L from level m down, one after the other (``multigrid._coarsen`` of each: the x, y and z faces,
    then the diagonal, which reads them)."""
    for l in range(m, L):
        Lc, r, N, nfx, nfy, nfz, mx, my, mz, co, nc = coarsen_constants(mg, l)
        block_pass(t, nt, emulate, barrier, mx, coarsen_face_at, (mg, l, Lc, r, N, nfx, 0))
        block_pass(t, nt, emulate, barrier, my, coarsen_face_at, (mg, l, Lc, r, N, nfy, 1))
        block_pass(t, nt, emulate, barrier, mz, coarsen_face_at, (mg, l, Lc, r, N, nfz, 2))
        block_pass(t, nt, emulate, barrier, nc, diag_at, (mg, Lc, N, co))


@kernel
def k_coarsen_levels(mg: Hierarchy, m: ti.i32, L: ti.i32, threads: ti.template(), emulate: ti.template(),
                     barrier: ti.template()):
    """The multigrid set-up's coarsenings from level m to the coarsest L in one launch (``multigrid.k_coarsen`` a
    level, the same per-face and per-cell functions): one block of ``threads`` threads with ``barrier`` (CUDA),
    else one thread (``emulate``: the shares of ``threads`` threads in turn), as :func:`k_coarse_cycle`."""
    one_block(threads, emulate, barrier, 1, _coarsen_levels, (mg, m, L))
