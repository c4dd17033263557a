"""Multigrid-preconditioned CG (app.sim.gas.linsolve): convergence to the requested tolerance,
checked against an independent scipy residual, and grid-independent iteration counts."""
import numpy as np
import pytest
import scipy.sparse.linalg as spla

from app.bench.poisson import cell_operator
from app.sim.gas.linsolve import MGPCG, plan_levels

pytestmark = pytest.mark.verification


def _system(shape, periodic=(False, False, False), dirichlet_faces=("z+",), coef=None):
    """Face transmissibilities of a cell-centred Laplacian: 1 inside, 2 on Dirichlet faces (half-cell
    distance), 0 on Neumann faces; ``coef(axis, face_centres_in_cell_units)`` scales them."""
    ts = []
    for a in range(3):
        fs = list(shape)
        fs[a] += 1
        t = np.ones(fs)
        if coef is not None:
            t = t * coef(a, fs)
        first = [slice(None)] * 3
        last = [slice(None)] * 3
        first[a], last[a] = 0, -1
        if periodic[a]:
            t[tuple(last)] = t[tuple(first)]
        else:
            ax = "xyz"[a]
            t[tuple(first)] *= 2.0 if ax + "-" in dirichlet_faces else 0.0
            t[tuple(last)] *= 2.0 if ax + "+" in dirichlet_faces else 0.0
        ts.append(t)
    return ts


def _solve(shape, tol, periodic=(False, False, False), dirichlet_faces=("z+",), coef=None, seed=0, singular=False):
    rng = np.random.default_rng(seed)
    ts = _system(shape, periodic, dirichlet_faces, coef)
    b = rng.standard_normal(shape)
    if singular:
        b -= b.mean()
    mg = MGPCG(shape, periodic)
    mg.set_system(*ts, b=b, x0=0.0)
    info = mg.solve(tol, 200, singular=singular)
    return mg, info, ts, b


def test_iterations_flat_under_refinement():
    """Constant-coefficient Poisson, Dirichlet top, Neumann elsewhere: outer iterations to 1e-8
    at 16^3, 32^3, 64^3 stay within a factor 2 (measured 7, 8, 8), and the residual recomputed
    with scipy meets the tolerance."""
    its = []
    for n in (16, 32, 64):
        shape = (n, n, n)
        mg, info, ts, b = _solve(shape, 1e-8)
        assert info.converged
        A = cell_operator(shape, ts, (False, False, False))
        r = b.ravel() - A @ mg.solution().ravel()
        assert np.max(np.abs(r)) <= 1e-8 * np.max(np.abs(b))
        its.append(info.iterations)
    assert max(its) / min(its) < 2.0, its
    assert max(its) <= 15, its


def test_coefficient_jump_matches_direct_solve():
    """Coefficient contrast 1e3 (a packed bed under a freeboard): PCG solution equals scipy's direct
    solution to ~tol, and the iteration count stays modest (measured 12 at 24^3)."""
    shape = (24, 24, 24)

    def coef(a, fs):
        zc = (np.arange(fs[2]) + (0.5 if a != 2 else 0.0)) / shape[2]
        return np.where(zc < 0.5, 1e-3, 1.0)[None, None, :] * np.ones(fs)

    mg, info, ts, b = _solve(shape, 1e-10, coef=coef, dirichlet_faces=("z+", "x-"))
    assert info.converged and info.iterations <= 25
    A = cell_operator(shape, ts, (False, False, False))
    x = spla.spsolve(A.tocsc(), b.ravel())
    assert np.max(np.abs(mg.solution().ravel() - x)) <= 1e-6 * np.max(np.abs(x))


def test_singular_periodic_and_semicoarsening():
    """Pure Neumann/periodic system (singular): converges, zero-mean solution; a 16x16x58 grid
    coarsens semi-wise to a 1x1x29 line and still converges in few iterations."""
    shape = (16, 16, 16)
    per = (True, True, False)
    mg, info, ts, b = _solve(shape, 1e-9, periodic=per, dirichlet_faces=(), singular=True)
    assert info.converged
    x = mg.solution()
    assert abs(x.mean()) < 1e-10 * np.abs(x).max()
    A = cell_operator(shape, ts, per)
    r = b.ravel() - A @ x.ravel()
    assert np.max(np.abs(r)) <= 1e-9 * np.max(np.abs(b))

    shape = (16, 16, 58)
    levels = [lv["shape"] for lv in plan_levels(shape)]
    assert levels[-1] == (1, 1, 29)
    mg, info, ts, b = _solve(shape, 1e-8)
    assert info.converged and info.iterations <= 15


def test_rejects_bad_input():
    with pytest.raises(ValueError):
        MGPCG((0, 4, 4))
    mg = MGPCG((4, 4, 4))
    with pytest.raises(ValueError):
        mg.set_system(tx=np.ones((4, 4, 4)))
    with pytest.raises(ValueError):
        mg.solve(0.0)


def test_odd_dimensions_fall_back_and_converge():
    """Dimensions that do not halve (27^3: no coarsening at all) leave a large coarsest grid,
    smoothed in parallel instead of the one-thread CG: slower, but converges to tol."""
    shape = (27, 27, 27)
    mg, info, ts, b = _solve(shape, 1e-8)
    assert mg.nlevels == 1 and mg.coarse_parallel
    assert info.converged
    A = cell_operator(shape, ts, (False, False, False))
    r = b.ravel() - A @ mg.solution().ravel()
    assert np.max(np.abs(r)) <= 1e-8 * np.max(np.abs(b))


# one grid per way the V-cycle's launches are arranged (app.sim.gas.linsolve.MGPCG._precondition): no level
# above the coarsest, serial or parallel coarsest; one level above it, fused with the one-thread CG or followed
# by the parallel smoother (the arrangement that once ran the outer CG iteration twice: 9x9x50 is the
# fluidize preset's grid); several red-black levels; Jacobi levels of a periodic odd grid
_ARRANGEMENTS = [((2, 2, 2), (False,) * 3), ((33, 33, 33), (False,) * 3), ((6, 6, 6), (False,) * 3),
                 ((9, 9, 50), (False,) * 3), ((16, 16, 16), (False,) * 3), ((9, 9, 16), (True, True, False))]


def test_every_launch_arrangement_of_the_v_cycle_solves_the_system():
    """Each arrangement converges to 1e-8 with the residual recomputed by scipy within 1e-8 of max|b|, and
    together they cover L = 0, L = 1 (serial and parallel coarsest), L > 1 and Jacobi levels."""
    seen = set()
    for shape, periodic in _ARRANGEMENTS:
        mg, info, ts, b = _solve(shape, 1e-8, periodic=periodic)
        L = mg.nlevels - 1
        seen.add((min(L, 2), mg.coarse_parallel, mg.level_jacobi[0]))
        assert info.converged, (shape, info)
        r = b.ravel() - cell_operator(shape, ts, periodic) @ mg.solution().ravel()
        assert np.max(np.abs(r)) <= 1e-8 * np.max(np.abs(b)), shape
    assert {(0, False, False), (0, True, False), (1, False, False), (1, True, False), (2, False, False),
            (2, False, True)} <= seen, seen


def test_a_line_of_cells_is_solved_exactly_by_the_coarse_sweep():
    """A coarsest level that is one line of cells (here the only level: 1 x 1 x 7, coefficients varying 100x)
    is solved by the tridiagonal sweep, an exact inverse: the outer CG converges in one iteration, to scipy's
    direct solution within 1e-9 (float64 roundoff of a 7-cell system, far below the 1e-10 asked). A line with
    a part that touches no Dirichlet face (an inactive cell cuts it; a right-hand side there that sums to zero,
    so the system is consistent) gives the sweep a zero pivot; the solve still converges to 1e-10 with finite
    values (the sweep hands such a level to the coarse CG)."""
    rng = np.random.default_rng(4)
    shape = (1, 1, 7)
    ts = _system(shape, dirichlet_faces=("z-", "z+"), coef=lambda a, fs: 10.0 ** rng.uniform(-1, 1, fs))
    b = rng.standard_normal(shape)
    mg = MGPCG(shape)
    assert mg.nlevels == 1 and int(mg.mg["coarse_axis"]) == 2
    mg.set_system(*ts, b=b, x0=0.0)
    info = mg.solve(1e-10, 50)
    x = spla.spsolve(cell_operator(shape, ts, (False,) * 3).tocsc(), b.ravel())
    assert info.converged and info.iterations == 1, info
    assert np.max(np.abs(mg.solution().ravel() - x)) <= 1e-9 * np.max(np.abs(x))

    ts = _system(shape, dirichlet_faces=("z-",))
    ts[2][0, 0, 3:5] = 0.0  # cell 3 closed: cells 4-6 touch no Dirichlet face
    b = rng.standard_normal(shape)
    b[0, 0, 3:] = [0.0, 1.0, -2.0, 1.0]
    mg = MGPCG(shape)
    mg.set_system(*ts, b=b, x0=0.0)
    info = mg.solve(1e-10, 50)
    x = mg.solution()
    assert info.converged and np.all(np.isfinite(x))
    r = b.ravel() - cell_operator(shape, ts, (False,) * 3) @ x.ravel()
    assert np.max(np.abs(r)) <= 1e-10 * np.max(np.abs(b))


def test_the_coarse_levels_in_one_launch_give_the_launches_result():
    """The coarse end of the V-cycle in one launch (app/sim/gas/coarse_cycle.py: on CUDA one block, whose threads
    share each pass's cells and meet at a barrier between passes) runs the per-cell functions of the launch-per-
    level V-cycle in the same passes, and a pass's cells do not depend on one another, so the solution is the same
    to the bit, in as many iterations. Checked in the parallel form (the one CUDA runs) on one thread, and with 7
    threads' shares taken in turn (what the barrier guarantees: the division of the cells a block makes, odd so
    that shares end unevenly), on a Dirichlet box, a singular box (the coarsest solved by CG) and a box periodic
    in x and y (wrapped stencils). The levels it takes: from 8x8x29 on the Verma grid, none above a Jacobi level
    or a coarsest level smoothed in parallel, none in the serial form unless asked. The multigrid set-up's
    coarsenings into levels of at most as many cells go with it, one launch too (the hierarchy compared)."""
    cases = [((16, 16, 20), (False,) * 3, ("z+",), False), ((16, 16, 20), (False,) * 3, (), True),
             ((16, 8, 24), (True, True, False), (), True)]
    for shape, per, faces, singular in cases:
        rng = np.random.default_rng(5)
        ts = _system(shape, per, faces, coef=lambda a, fs: 0.1 + rng.random(fs))
        b = rng.standard_normal(shape)
        if singular:
            b -= b.mean()
        out = []
        for block, mode in ((False, None), (True, (1, False, False)), (True, (7, True, False))):
            mg = MGPCG(shape, per, serial=False, coarse_block=block)
            if mode is not None:
                assert mg.block_from == 1, shape
                mg.block_mode = mode
            mg.set_system(*ts, b=b, x0=0.0)
            info = mg.solve(1e-9, 100, singular=singular)
            assert info.converged, (shape, block, mode, info)
            out.append((info.iterations, mg.solution(), mg.mg.trans.to_numpy(), mg.mg.diag.to_numpy()))
        for its, x, trans, diag in out[1:]:
            assert its == out[0][0] and np.array_equal(x, out[0][1]), shape
            # the set-up's coarsenings of the small levels in one launch (coarse_cycle.k_coarsen_levels, with the
            # cycle) build every level's transmissibilities and diagonal to the bit
            assert np.array_equal(trans, out[0][2]) and np.array_equal(diag, out[0][3]), shape
        r = b.ravel() - cell_operator(shape, ts, per) @ out[1][1].ravel()
        assert np.max(np.abs(r)) <= 1e-9 * np.max(np.abs(b)), shape
    assert MGPCG((32, 32, 116), serial=False).block_from == 2  # 8x8x29 (1856 cells) down to the 1x1x29 line
    assert MGPCG((32, 32, 116), serial=False).coarsen_from == 1  # set-up: 16x16x58 into 8x8x29, and on down
    assert MGPCG((16, 16, 20), serial=False).coarsen_from == 0  # 8x8x10 (640 cells) and below
    assert MGPCG((33, 33, 33), serial=False).coarsen_from is None  # a 33^3 coarsest
    assert MGPCG((12, 12, 40), (True, False, False), serial=False).block_from is None  # 3x3x10: Jacobi
    assert MGPCG((33, 33, 33), serial=False).block_from is None  # the coarsest smoothed in parallel
    assert MGPCG((32, 32, 116), serial=True).block_from is None


def test_the_coarse_cycle_can_be_turned_off_from_the_environment(monkeypatch):
    """FBED_COARSE_CELLS (for a device whose check of the CUDA cycle failed, benchmarks/device_run.sh): 0 gives a
    launch down and up per level, a number the largest level the cycle takes, anything else a clear error."""
    from app.config.errors import ConfigError

    monkeypatch.setenv("FBED_COARSE_CELLS", "0")
    assert MGPCG((32, 32, 116), serial=False).block_from is None
    assert MGPCG((32, 32, 116), serial=False).coarsen_from is None
    monkeypatch.setenv("FBED_COARSE_CELLS", "500")  # 4x4x29 (464 cells) and below
    assert MGPCG((32, 32, 116), serial=False).block_from == 3
    assert MGPCG((32, 32, 116), serial=False).coarsen_from == 2
    monkeypatch.setenv("FBED_COARSE_CELLS", "many")
    with pytest.raises(ConfigError, match="FBED_COARSE_CELLS"):
        MGPCG((32, 32, 116), serial=False)


def test_the_coarse_cycle_is_checked_on_the_device_before_a_solver_takes_it(monkeypatch, recwarn):
    """On CUDA the cycle's barrier path runs on no CPU, so the first MGPCG of a process solves a 16x16x20 system both
    ways (app/sim/gas/cycle_check.py) before it takes the cycle. Here on the CPU: the check passes a right cycle (7
    threads' shares taken in turn, what the barrier guarantees: the same to the bit) and fails a wrong one (a block
    of 7 whose thread 0 alone runs: 6/7 of each pass's cells missed, as a block whose barrier or threads misbehave),
    with a warning; the gas solver's MGPCG on CUDA takes the cycle only where the check passed, and none is run in
    the serial form or when FBED_COARSE_CELLS=0 has turned the cycle off."""
    from app.sim import runtime
    from app.sim.gas import cycle_check

    r = cycle_check.compare(*cycle_check.CHECK_SYSTEM, 1e-8, mode=(7, True, False))
    assert (r["block_from"], r["coarsen_from"]) == (1, 0)  # the cycle from 8x8x10, the set-up from level 0
    assert r["iterations"][0] == r["iterations"][1] and r["x_diff"] == 0.0 and r["h_diff"] == 0.0
    assert cycle_check.works(mode=(7, True, False)) and not recwarn.list
    bad = cycle_check.compare(*cycle_check.CHECK_SYSTEM, 1e-8, mode=(7, False, False))
    assert not cycle_check.passes(bad, True, "float64")  # fails CUDA's looser tolerances too (54 iterations, not 9)
    with pytest.warns(RuntimeWarning, match="start-up check"):
        assert not cycle_check.works(mode=(7, False, False))
    monkeypatch.setattr(runtime, "on_cuda", lambda: True)
    monkeypatch.setattr(cycle_check, "works", lambda: False)
    mg = MGPCG((32, 32, 116), serial=False, coarse_block=cycle_check.coarse_block(False))  # as the gas solver makes it
    assert mg.block_from is None and mg.coarsen_from is None
    assert MGPCG((32, 32, 116), serial=False, coarse_block=True).block_from == 2  # asked for (the bench's A/B)
    monkeypatch.setattr(cycle_check, "works", lambda: True)
    assert MGPCG((32, 32, 116), serial=False, coarse_block=cycle_check.coarse_block(False)).block_from == 2

    def no_check():
        raise AssertionError("checked where nothing takes the cycle")

    monkeypatch.setattr(cycle_check, "works", no_check)
    assert cycle_check.coarse_block(True) is None  # one CPU thread: the serial form has no cycle
    monkeypatch.setenv("FBED_COARSE_CELLS", "0")
    assert cycle_check.coarse_block(False) is None
    assert MGPCG((32, 32, 116), serial=False).block_from is None
