"""The pressure solver object: :class:`MGPCG` (method in :mod:`app.sim.gas.pcg`).

It allocates the two bundles of the solve from the level plan, launches the set-up, the V-cycles and
the outer iterations, and reads one record per batch. Callers that fill the system inside their own
kernels take :attr:`MGPCG.mg` (transmissibilities of level 0 at ``trans[face(mg, 0, a, I)]``, the control
scalars ``ctrl``) and :attr:`MGPCG.ks` (right-hand side ``rhs[c]``, solution / initial guess ``sol[c]``,
cell c = (i*ny + j)*nz + k); :meth:`MGPCG.set_system` and :meth:`MGPCG.solution` do the same from numpy.
"""
import math
from typing import Sequence

import numpy as np
import taichi as ti

from .. import runtime
from . import multigrid as mgm
from . import coarse, coarse_cycle, pcg, vcycle
from .pcg import SolveInfo, plan_levels
from ..launch import view

__all__ = ["MGPCG", "SolveInfo", "plan_levels"]


def _zeros(n):
    a = ti.ndarray(float, shape=(max(int(n), 1),))
    a.fill(0.0)
    return a


class MGPCG:
    """Multigrid-preconditioned CG on a (nx, ny, nz) cell grid (state in the bundles ``mg`` and ``ks``)."""

    def __init__(self, shape: Sequence[int], periodic: Sequence[bool] = (False, False, False), *,
                 min_coarse_cells: int = 8, max_levels: int = 16, coarse_iterations: int | None = None,
                 serial: bool | None = None, coarse_block: bool | None = None):
        self.shape = tuple(int(n) for n in shape)
        if len(self.shape) != 3 or min(self.shape) < 1:
            raise ValueError(f"grid shape must be three positive ints, got {shape!r}")
        self.periodic = tuple(bool(p) for p in periodic)
        # compile-time: each kernel's loops nested in one serial loop (one task a launch) when Taichi runs
        # on one CPU thread, where each top-level loop costs a task (~70 us); else parallel top-level loops
        self.serial = runtime.serial() if serial is None else bool(serial)
        plan = plan_levels(self.shape, int(min_coarse_cells), int(max_levels))
        self.nlevels = len(plan)
        self.level_shapes = [lv["shape"] for lv in plan]
        self.level_jacobi = [any(self.periodic[a] and s[a] > 1 and s[a] % 2 == 1 for a in range(3))
                             for s in self.level_shapes]
        lev, nfaces, ncells_all = mgm.level_table(plan)
        n0 = int(np.prod(self.shape))
        ncoarse = int(np.prod(plan[-1]["shape"]))
        if coarse_iterations is None:
            coarse_iterations = min(ncoarse, max(8, 3 * max(plan[-1]["shape"])), 100)
        self.coarse_iterations = int(coarse_iterations)
        # a coarsest grid too large for one thread (dimensions that do not halve, e.g. 33^3) is
        # smoothed in parallel instead; the outer CG then needs more iterations (choose grid
        # dimensions with factors of 2 for multigrid efficiency)
        self.coarse_parallel = ncoarse > mgm.COARSE_SERIAL_MAX
        # the small red-black levels above the coarsest in one launch (coarse_cycle.py): in the parallel form
        # (CUDA: one block; several CPU threads: one thread), not on one CPU thread, where a launch is one task
        # anyway; ``coarse_block`` False keeps a launch down and up per level (A/B, or a device whose start-up
        # check of the cycle failed: cycle_check.coarse_block), True asks for it in either form
        use = (not self.serial) if coarse_block is None else bool(coarse_block)
        self.block_from = self._block_from() if use else None
        #: the first level the set-up coarsens in one launch (coarse_cycle.k_coarsen_levels), with the cycle's block
        self.coarsen_from = self._coarsen_from() if use else None
        cuda = runtime.on_cuda()
        #: (threads, emulate, barrier) of coarse_cycle.k_coarse_cycle and k_coarsen_levels: one block on CUDA, else
        #: one thread
        self.block_mode = (coarse_cycle.BLOCK_THREADS, False, True) if cuda else (1, False, False)
        self._lev = ti.ndarray(ti.i32, shape=lev.shape)
        self._lev.from_numpy(lev)
        self._dval = _zeros(6)
        self._sc = _zeros(mgm.NSCAL)
        self.mg = mgm.Multigrid(lev=self._lev, trans=_zeros(nfaces), diag=_zeros(ncells_all),
                                xs=_zeros(ncells_all), bs=_zeros(ncells_all), rs=_zeros(ncells_all),
                                cg_p=_zeros(ncoarse), cg_ap=_zeros(ncoarse), dirichlet=self._dval, ctrl=self._sc,
                                periodic=ti.Vector([int(p) for p in self.periodic], ti.i32), ncell0=n0,
                                coarse_iters=self.coarse_iterations,
                                coarse_axis=mgm.line_axis(plan[-1]["shape"], self.periodic))
        self.vc = view(mgm.VCycle, self.mg)
        self._x, self._b0 = _zeros(n0), _zeros(n0)
        self.ks = pcg.Krylov(sol=self._x, res=_zeros(n0), prec=_zeros(n0), prec_old=_zeros(n0),
                             dirn=_zeros(n0), a_dirn=_zeros(n0), rhs=self._b0)
        # the outer CG's fused kernels take views of the bundles with only the members they read (vcycle.py)
        self._mg_iter = view(vcycle.IterMultigrid, self.mg)
        self._mg_setup = view(mgm.Hierarchy, self.mg)
        self._begin_args = (view(pcg.BeginMultigrid, self.mg), view(pcg.BeginKrylov, self.ks))
        self._finish_args = (view(pcg.FinishMultigrid, self.mg), view(pcg.FinishKrylov, self.ks))
        self._ks_down = view(vcycle.IterDownKrylov, self.ks)
        self._ks_up = view(vcycle.UpFromKrylov, self.ks)
        self.last: SolveInfo | None = None
        self._singular = False
        self._max_iter = 0
        self._launched = 0

    def _block_from(self) -> int | None:
        """The first level of the one-launch coarse cycle: the finest level m >= 1 such that levels m..L-1 are
        red-black with at most ``coarse_cycle.max_cells()`` cells, and the coarsest L is solved on one thread; None
        if there is none (a coarsest level smoothed in parallel, no such level, or a Jacobi level just above
        the coarsest)."""
        L = self.nlevels - 1
        if L < 2 or self.coarse_parallel:
            return None
        m = None
        limit = coarse_cycle.max_cells()
        for l in range(L - 1, 0, -1):
            if self.level_jacobi[l] or int(np.prod(self.level_shapes[l])) > limit:
                break
            m = l
        return m

    def _coarsen_from(self) -> int | None:
        """The finest level l whose coarsening into l+1 and every one after it the set-up makes in one launch: the
        levels l+1..L each have at most ``coarse_cycle.max_cells()`` cells (the faces of a pass about as many);
        None if the coarsest has more, or there is one level only."""
        limit = coarse_cycle.max_cells()
        m = None
        for l in range(self.nlevels - 2, -1, -1):
            if int(np.prod(self.level_shapes[l + 1])) > limit:
                break
            m = l
        return m

    # ---------------------------------------------------------------- host helpers
    def set_system(self, tx=None, ty=None, tz=None, b=None, x0=None) -> None:
        """Copy level-0 transmissibilities / right-hand side / initial guess from numpy."""
        for a, t in enumerate((tx, ty, tz)):
            if t is not None:
                fs = list(self.shape)
                fs[a] += 1
                t = np.ascontiguousarray(t, dtype=np.float64)
                if t.shape != tuple(fs):
                    raise ValueError(f"transmissibility of axis {a} must have shape {tuple(fs)}, got {t.shape}")
                pcg.k_set_faces(self.mg, a, t)
        for vec, v in ((self._b0, b), (self._x, x0)):
            if v is not None:
                v = np.ascontiguousarray(np.broadcast_to(np.asarray(v, np.float64), self.shape))
                pcg.k_cells_in(vec, v)

    def _cells(self, vec) -> np.ndarray:
        out = np.zeros(self.shape)
        pcg.k_cells_out(vec, out)
        return out

    def solution(self) -> np.ndarray:
        return self._cells(self._x)

    def rhs(self) -> np.ndarray:
        return self._cells(self._b0)

    def transmissibility(self, a: int) -> np.ndarray:
        fs = list(self.shape)
        fs[a] += 1
        out = np.zeros(fs)
        pcg.k_get_faces(self.mg, a, out)
        return out

    def set_dirichlet(self, values: Sequence[float]) -> None:
        """Outside value of each domain face (x-, x+, y-, y+, z-, z+) where its T > 0."""
        dv = np.asarray(values, np.float64)
        if dv.shape != (6,):
            raise ValueError(f"dirichlet needs 6 values (x-, x+, y-, y+, z-, z+), got shape {dv.shape}")
        self._dval.from_numpy(np.ascontiguousarray(dv, dtype=self._dval.to_numpy().dtype))

    # ---------------------------------------------------------------- solve
    def _precondition(self, iterate: bool = False) -> None:
        """(``iterate``: an outer CG iteration, then) z = one V-cycle of the residual, then the outer CG's
        new direction: a launch down and one up per level above the coarsest; the iteration rides on the
        first launch down, the coarsest solve on the last (when it is the one-thread solve after a
        red-black level), the new direction on the last launch up, where those levels are red-black. With a
        coarse cycle (``block_from`` m), levels m..L are one launch (:func:`.coarse_cycle.k_coarse_cycle`)."""
        mg, vc = self.mg, self.vc
        L = self.nlevels - 1
        sg = int(self._singular)
        ser = self.serial
        m = self.block_from
        top = L if m is None else m  # the levels launched one by one
        fused = m is None and L > 0 and not self.coarse_parallel and not self.level_jacobi[L - 1]
        first = L > 1 and not self.level_jacobi[0]  # level 0 red-black and not the last: k_iter_down
        if iterate and not first:
            pcg.k_pcg_iter(mg, self.ks, self._max_iter, ser)
        for l in range(top):
            if self.level_jacobi[l]:
                vcycle.k_down_j(mg, l, ser)
            elif fused and l == L - 1:
                vcycle.k_down_coarse(mg, l, sg, ser)
            elif iterate and first and l == 0:
                vcycle.k_iter_down(self._mg_iter, self._ks_down, self._max_iter, ser)
            else:
                vcycle.k_down(vc, l, ser)
        if m is not None:
            coarse_cycle.k_coarse_cycle(mg, m, L, sg, *self.block_mode)
        elif self.coarse_parallel:
            for k in range(mgm.COARSE_SMOOTH_SWEEPS):
                vcycle.k_coarse_smooth(mg, L, int(k == 0), ser)
        elif not fused:
            coarse.k_coarse(mg, L, sg)
        for l in reversed(range(top)):
            if self.level_jacobi[l]:
                vcycle.k_up_j(mg, l, ser)
            elif l == 0:
                vcycle.k_up_from(self._mg_iter, self._ks_up, sg, ser)
            else:
                vcycle.k_up(vc, l, ser)
        if L == 0 or self.level_jacobi[0]:
            pcg.k_pcg_from(mg, self.ks, sg, ser)

    def begin(self, tol: float, max_iter: int, *, singular: bool = False, scale: float | None = None,
              device_scale: bool = False, same_matrix: bool = False) -> None:
        """Start a solve of A x = b (level-0 T, b, x already in the bundles) from the current x; launches
        only (nothing is read back). ``scale``: see :meth:`solve`; ``device_scale``: a caller's kernel has
        written the scale into the solver's scalars (``mg.ctrl[S_SCALE]``); ``same_matrix``: the level-0
        transmissibilities are those of the last solve (a refinement round), so the coarse levels and the
        diagonals built for it still hold and are not built again."""
        if not (tol > 0.0):
            raise ValueError(f"tolerance must be > 0, got {tol}")
        self._singular = bool(singular)
        self._max_iter = int(max_iter)
        self._launched = 0
        if not same_matrix:
            top = self.nlevels - 1 if self.coarsen_from is None else self.coarsen_from
            if top == 0:  # level 0's diagonal rides on the first k_coarsen where there is one
                mgm.k_diag(self._mg_setup, 0, self.serial)
            for l in range(top):
                mgm.k_coarsen(self._mg_setup, l, self.serial)
            if self.coarsen_from is not None:
                coarse_cycle.k_coarsen_levels(self._mg_setup, top, self.nlevels - 1, *self.block_mode)
        mode = 2 if device_scale else (0 if scale is None else 1)
        pcg.k_pcg_begin(*self._begin_args, int(self._singular), float(tol), mode, float(scale or 0.0), self.serial)
        self._precondition()

    def launch(self, iterations: int) -> None:
        """Queue up to ``iterations`` more outer iterations (each stops itself on the device once the
        solve has converged, stagnated or reached max_iter), then the final zero-mean step (once)."""
        n = max(0, min(int(iterations), self._max_iter - self._launched))
        sg = int(self._singular)
        for _ in range(n):
            self._precondition(iterate=True)
        self._launched += n
        pcg.k_pcg_finish(*self._finish_args, sg, self.serial)

    @property
    def exhausted(self) -> bool:
        """Every iteration up to max_iter has been launched."""
        return self._launched >= self._max_iter

    #: iterations launched past the last solve's count before the first look, and in each further batch
    MARGIN = 1
    BATCH = 2

    def budget(self, last: int | None = None) -> int:
        """Iterations to launch before the first look: the last solve's count and ``MARGIN`` more. A launch
        past convergence does nothing on the device but still costs its host time and its (empty) tasks, about
        a tenth of a V-cycle's launches each (10 a V-cycle on the Verma grid), while a solve that needs more
        gets further batches of ``BATCH`` (:meth:`more`), each with one more read of a few numbers: on the
        flow_throughput bed the count moves by 1-2 between steps, so a small margin wastes least. ``last``:
        the count to start from instead of the last solve's."""
        if last is None:
            last = self.last.iterations if self.last is not None else 8
        return max(2, last + self.MARGIN)

    def more(self) -> int:
        """Iterations of a further batch, when the last look found the solve still going."""
        return self.BATCH

    def info_from(self, rec) -> SolveInfo:
        """A :class:`SolveInfo` from a record (:func:`app.sim.gas.pcg.solve_record`) read from the device."""
        it, rinf, conv, scale, r0 = (float(x) for x in rec[:5])
        if scale > 0:
            rel, rel0 = rinf / scale, r0 / scale
        else:
            rel, rel0 = (0.0 if rinf == 0 else math.inf), (0.0 if r0 == 0 else math.inf)
        info = SolveInfo(int(round(it)), rel, bool(conv > 0.5), scale, rel0)
        self.last = info
        return info

    def solve(self, tol: float = 1e-6, max_iter: int = 200, *, singular: bool = False,
              scale: float | None = None) -> SolveInfo:
        """Solve A x = b (level-0 T, b, x already in the bundles) from the current x.

        Stops when ``max|b - A x| <= tol * scale``; ``scale`` defaults to ``max|b|`` (after the
        zero-mean projection when ``singular``). ``singular``: no Dirichlet face at all (pure
        Neumann/periodic): b is projected onto zero mean and x returned with zero mean.
        The iterations are launched in batches (:meth:`budget`) and their convergence is decided on
        the device; the host reads one record per batch (one in all when the budget suffices).
        Returns a :class:`SolveInfo` (also kept as ``last``).
        """
        self.begin(tol, max_iter, singular=singular, scale=scale)
        n = self.budget()
        while True:
            self.launch(n)
            rec = pcg.k_record(self.mg)
            if rec[5] > 0.5 or self.exhausted:
                break
            n = self.more()
        return self.info_from(rec)
