"""The gas solver object: :class:`FlowSolver` (equations and method in :mod:`app.sim.gas`).

It allocates the bundles (:mod:`.layout`) from the :class:`~app.sim.gas.config.FlowConfig`, fills the
constant ones, and launches one fractional step per :meth:`FlowSolver.step`: advection
(:mod:`.advection`), boundary values (:mod:`.boundary`), the predictor (:mod:`.predictor`), the
projection (:mod:`.projection`) with :class:`~app.sim.gas.linsolve.MGPCG`. Outputs and checkpoints are
in :class:`~app.sim.gas.outputs.SolverOutputs`.
"""
import numpy as np
import taichi as ti
from taichi.lang.util import to_numpy_type

from .. import runtime
from . import advection, boundary, cycle_check, layout, predictor, projection
from .config import CONVECTION, FACES, INLET, KINDS, MOVING, OUTLET, PRESSURE_FORMS, THETA_MIN, VISCOUS_REDUCTION
from .config import ALIASES, FlowConfig, StepInfo
from .fields import GasFields, _as_cell_array, _load
from .grid import cut_cells
from .layout import NPAR, NSC, P_G, P_H, P_MU, P_POUT, P_RHO, P_THMIN, P_TRACE, k_copy
from .linsolve import MGPCG
from .outputs import SolverOutputs
from ..launch import view


def _zeros(n: int):
    a = ti.ndarray(float, shape=(max(int(n), 1),))
    a.fill(0.0)
    return a


class FlowSolver(SolverOutputs):
    """Fractional-step gas solver on a MAC grid (see :mod:`app.sim.gas` for the equations).

    ``FlowSolver(config)``; then set the coupling inputs (or write them in ``fields``) and
    call :meth:`step` (dt) repeatedly. Reads return numpy copies. ``serial``: run every step kernel's loops
    nested in one serial loop (default: :func:`app.sim.runtime.serial`, Taichi on one CPU thread).
    """

    def __init__(self, config: FlowConfig, *, serial: bool | None = None):
        if not isinstance(config, FlowConfig):
            raise ValueError(f"flow: FlowSolver needs a FlowConfig, got {type(config).__name__}")
        self.config = cfg = config
        self.grid = grid = cfg.grid
        nx, ny, nz = self.shape = cfg.shape
        self.h = float(cfg.h)
        per = cfg.periodic
        self.cut = cut = cut_cells(grid, cfg.walls, int(cfg.aperture_samples), per, float(cfg.min_open_fraction))
        self.fields = GasFields(grid, cut, per)
        self._reduced = _zeros(6)  # device-side reductions (diagnostics, end-layer pressures)
        # compile-time choice of every step kernel: its loops nested in one serial loop when Taichi runs on
        # one CPU thread (each top-level loop is then a task of ~70 us), parallel top-level loops otherwise
        self.serial = runtime.serial() if serial is None else bool(serial)
        # on CUDA the one-launch coarse cycle once checked on the device first (cycle_check.py)
        self.mg = MGPCG(cfg.shape, per, serial=self.serial, coarse_block=cycle_check.coarse_block(self.serial))
        kinds = [KINDS[cfg.bc(f).kind] for f in FACES]
        self._kinds = kinds
        self._singular = OUTLET not in kinds
        self._fshapes = [grid.face_shape(a) for a in range(3)]
        fsz = [int(np.prod(s)) for s in self._fshapes]
        self._face_off = [0, fsz[0], fsz[0] + fsz[1]]
        nf = sum(fsz)
        nc = nx * ny * nz
        self._nf, self._nc = nf, nc
        self._flux_sum = None  # the face-flux sum of add_face_flux (the rCFD probe), allocated on first use
        has_walls = len(cfg.walls) > 0
        # ---- boundary-value blocks, component-major [comp][t1][t2] per face
        self._bcv_dims, bcv_off, off = [], [], 0
        for fi in range(6):
            b = fi // 2
            t = [a for a in range(3) if a != b]
            dims = (cfg.shape[t[0]], cfg.shape[t[1]])
            self._bcv_dims.append(dims)
            bcv_off.append(off)
            off += 3 * dims[0] * dims[1]
        self._bcv_off = bcv_off
        # ---- the bundles
        self._aperture = _zeros(nf)
        self._clear = _zeros(nf) if has_walls else self._aperture
        self._par = _zeros(NPAR)
        self._bcv = _zeros(off)
        self.g = layout.Grid(dims=ti.Vector(list(cfg.shape), ti.i32), wrap=ti.Vector([int(p) for p in per], ti.i32),
                             bc_kind=ti.Vector(kinds, ti.i32), bcv_off=ti.Vector(bcv_off, ti.i32),
                             face_off=ti.Vector(self._face_off, ti.i32), scheme=CONVECTION[cfg.convection],
                             form=PRESSURE_FORMS[cfg.pressure_form], has_walls=int(has_walls), nfaces=nf, ncells=nc,
                             aperture=self._aperture, clear=self._clear, open_vol=self.fields.vol_frac, par=self._par,
                             bcv=self._bcv)
        self.inp = self.fields.inputs  # the coupling's arrays themselves: nothing is copied in
        sa = {k: _zeros(nf) for k in ("vel", "vel_old", "vel_adv", "vel_tmp", "accel", "dpred", "eps_f", "beta_f",
                                      "vel_save")}
        if cfg.convection == "maccormack":
            sa["vel_lo"], sa["vel_hi"] = _zeros(nf), _zeros(nf)
        else:  # the clamps are never touched without the MacCormack correction; vel_lo is the predictor's
            sa["vel_lo"], sa["vel_hi"] = _zeros(nf), sa["vel_tmp"]
        sa["gsc"] = _zeros(NSC)
        self._st = sa
        self.st = layout.State(**sa)
        fl = self.fields
        self._div_cell = ti.ndarray(float, shape=cfg.shape)
        self._div_cell.fill(0.0)
        self.cl = layout.Cells(pres=fl.p, u_cell=fl.u_gas, gradp_cell=fl.grad_p, div_cell=self._div_cell)
        self._make_views()
        self._load_constants(cfg, cut, kinds, has_walls)
        # ---- bookkeeping
        self._ncoupled = sum(1 for a in range(3) if not (per[a] and cfg.shape[a] == 1))
        self.time = 0.0
        self.steps = 0
        self.last: StepInfo | None = None
        self._s_pred = 0.0
        self._div = (0.0, 0.0)
        self._p_init_pending = True
        self._refine_iters = 1  # outer iterations the last refinement round of the pressure solve took
        self._viscous_last: int | None = None  # viscous sweeps the last step took
        self.viscous_retries = 0  # steps whose viscous sweeps outran their launches (a void projection each)
        self._face_coefficients()

    def _make_views(self) -> None:
        """Views of the bundles with only the members each step kernel reads (:func:`app.sim.launch.view`:
        the same arrays, nothing copied; Taichi 1.7.4 sets every ndarray member of a pack at each launch)."""
        self._visc_args = (view(predictor.ViscInputs, self.inp), view(predictor.ViscCells, self.cl),
                           view(predictor.ViscState, self.st))
        self._sweep_args = (view(predictor.SweepGrid, self.g), view(predictor.SweepState, self.st))
        self._advect_args = (view(layout.EpsInputs, self.inp), view(advection.AdvectState, self.st))
        self._finish_args = (view(layout.EpsInputs, self.inp), view(advection.CorrectionState, self.st))
        self._bc_args = (view(layout.EpsInputs, self.inp), view(boundary.BcState, self.st))
        self._face_args = (view(predictor.FaceInputs, self.inp), view(predictor.FaceState, self.st))
        m, ks = self.mg.mg, self.mg.ks
        P = projection
        self._build_args = (view(P.RateInputs, self.inp), view(P.PresCells, self.cl), view(P.BuildState, self.st),
                            view(P.BuildMultigrid, m), view(P.BuildKrylov, ks))
        self._correct_args = (view(P.RateInputs, self.inp), view(P.CtrlMultigrid, m), view(P.SolKrylov, ks),
                              view(P.CorrectState, self.st), self.cl)
        self._record_args = (view(P.RecordState, self.st), view(P.CtrlMultigrid, m))

    def _load_constants(self, cfg: FlowConfig, cut, kinds: list, has_walls: bool) -> None:
        """The fixed data of the bundles: parameters, apertures and clearances, boundary velocities."""
        # the open boundary faces of each domain face (aperture x area) and each inlet's volume flow into the
        # domain [m^3/s], on the host from what _set_bcv writes: with no outlet they must sum to zero
        self._bc_area = [np.take(cut.apertures[fi // 2], 0 if fi % 2 == 0 else -1, axis=fi // 2) * self.h ** 2
                         for fi in range(6)]
        self._inflow = [0.0] * 6
        par = np.zeros(NPAR)
        par[P_RHO], par[P_MU], par[P_H] = cfg.rho, cfg.mu, cfg.h
        par[P_G:P_G + 3] = cfg.gravity
        par[P_POUT:P_POUT + 6] = [cfg.bc(f).pressure if kinds[i] == OUTLET else 0.0 for i, f in enumerate(FACES)]
        par[P_THMIN] = THETA_MIN
        par[P_TRACE] = 1.0 if cfg.trace_forces else 0.0
        self._put(self._par, par)
        self._put(self._aperture, np.concatenate([ap.ravel() for ap in cut.apertures]))
        if has_walls:
            self._put(self._clear, np.concatenate([np.minimum(c, 1e30).ravel() for c in cut.clearance]))
        for fi, face in enumerate(FACES):
            if kinds[fi] in (INLET, MOVING):
                self._set_bcv(fi, np.broadcast_to(np.asarray(cfg.bc(face).velocity, float),
                                                  self._bcv_dims[fi] + (3,)))
        self.mg.set_dirichlet(np.zeros(6))  # the solve is for the increment
        self._bc_speeds = [float(np.linalg.norm(cfg.bc(f).velocity)) if kinds[i] in (INLET, MOVING) else 0.0
                           for i, f in enumerate(FACES)]

    def _face_coefficients(self) -> None:
        """Face gas fraction and drag coefficient from the current inputs."""
        predictor.k_face_coef(self.g, *self._face_args, self.serial)

    # ------------------------------------------------------------------ host <-> bundle arrays
    @staticmethod
    def _put(arr, values, off: int = 0) -> None:
        # in the array's own precision: a float64 source into float32 made Taichi warn "Assign may lose
        # precision" at every float32 start (the rounding is the same either side of the copy)
        layout.k_write(arr, int(off), np.ascontiguousarray(np.asarray(values, to_numpy_type(arr.dtype)).ravel()))

    @staticmethod
    def _get(arr, n: int, off: int = 0) -> np.ndarray:
        out = np.zeros(int(n))
        layout.k_read(arr, int(off), out)
        return out

    def _set_bcv(self, fi: int, vec: np.ndarray) -> None:
        vec = np.asarray(vec, np.float64)
        self._put(self._bcv, np.moveaxis(vec, -1, 0), self._bcv_off[fi])
        if self._kinds[fi] == INLET:  # superficial velocity x open area, into the domain
            self._inflow[fi] = (1.0 if fi % 2 == 0 else -1.0) * float(np.sum(vec[..., fi // 2] * self._bc_area[fi]))

    def inflow_imbalance(self) -> tuple[float, float]:
        """With no pressure outlet: the velocity inlets' net volume flow into the domain [m^3/s] and the share of
        their gross flow it is (an incompressible gas then has no solution unless it is zero; the divergence
        residual, a per-cell ratio, hardly sees a net flow spread over the grid: 9% read 1e-4). (0, 0) with an
        outlet."""
        if not self._singular:
            return 0.0, 0.0
        net, gross = sum(self._inflow), sum(abs(q) for q in self._inflow)
        return net, (abs(net) / gross if gross > 0 else 0.0)

    # ------------------------------------------------------------------ inputs
    def set_eps(self, eps) -> None:
        """Gas volume fraction (scalar or (nx, ny, nz)), each in (0, 1]."""
        a = _as_cell_array(eps, self.shape, "eps")
        if np.any(a <= 0.0) or np.any(a > 1.0):
            raise ValueError("flow: eps must lie in (0, 1]")
        _load(self.fields.eps, a)

    def set_deps_dt(self, deps) -> None:
        """d(eps)/dt [1/s] (scalar or (nx, ny, nz))."""
        _load(self.fields.deps_dt, _as_cell_array(deps, self.shape, "deps_dt"))

    def set_beta(self, beta) -> None:
        """Implicit drag coefficient [kg m^-3 s^-1] (scalar or (nx, ny, nz)), >= 0."""
        a = _as_cell_array(beta, self.shape, "beta")
        if np.any(a < 0.0):
            raise ValueError("flow: beta must be >= 0")
        _load(self.fields.beta, a)

    def set_solid_velocity(self, us) -> None:
        """Solid velocity [m/s] (3-vector or (nx, ny, nz, 3)) that beta pulls the gas toward."""
        _load(self.fields.us, _as_cell_array(us, self.shape, "solid velocity", vector=True))

    def set_explicit_source(self, f) -> None:
        """Explicit momentum source on the gas [N/m^3] (3-vector or (nx, ny, nz, 3))."""
        _load(self.fields.f_exp, _as_cell_array(f, self.shape, "explicit source", vector=True))

    def set_inlet_profile(self, face: str, profile) -> None:
        """Superficial inlet velocity of a velocity-inlet ``face`` per boundary cell.

        ``profile``: (n1, n2) normal component (into the domain for a positive value on the
        '-' faces, so use the sign of the global axis) or (n1, n2, 3) full vectors, where
        (n1, n2) are the cell counts along the face's two other axes in x, y, z order.
        Takes effect from the next step; may change every step.
        """
        f = ALIASES.get(face, face)
        if f not in FACES:
            raise ValueError(f"flow: unknown face {face!r}")
        fi = FACES.index(f)
        if self._kinds[fi] != INLET:
            raise ValueError(f"flow: face {f!r} is not a velocity inlet")
        dims = self._bcv_dims[fi]
        a = np.asarray(profile, np.float64)
        if a.shape == dims:
            vec = np.zeros(dims + (3,))
            vec[..., fi // 2] = a
        elif a.shape == dims + (3,):
            vec = a
        else:
            raise ValueError(f"flow: inlet profile of {f!r} must have shape {dims} or {dims + (3,)}, got {a.shape}")
        if not np.all(np.isfinite(vec)):
            raise ValueError("flow: inlet profile must be finite")
        self._set_bcv(fi, vec)
        self._bc_speeds[fi] = float(np.max(np.linalg.norm(vec, axis=-1))) if vec.size else 0.0

    @property
    def _bc_speed(self) -> float:
        return max(self._bc_speeds)

    def set_face_velocity(self, u=None, v=None, w=None) -> None:
        """Set face velocities [m/s] (arrays of the face shapes; None keeps a component).
        Closed faces are zeroed and periodic duplicates made consistent."""
        for a, arr in enumerate((u, v, w)):
            if arr is None:
                continue
            arr = np.asarray(arr, np.float64)
            if arr.shape != self._fshapes[a]:
                raise ValueError(f"flow: face velocity {'uvw'[a]} must have shape {self._fshapes[a]}, got {arr.shape}")
            self._put(self._st["vel"], arr, self._face_off[a])
        boundary.k_periodic_copy(self.g, self.st)

    def set_pressure(self, p) -> None:
        """Set the pressure [Pa] (scalar or (nx, ny, nz)); it is the starting point of the
        incremental projection. Without it, the first :meth:`step` first computes a consistent
        pressure by a throw-away step from the initial velocity."""
        _load(self.fields.p, _as_cell_array(p, self.shape, "pressure"))
        self._p_init_pending = False

    # ------------------------------------------------------------------ the step
    def _jacobi_factor(self, dt: float) -> float:
        """Upper bound of the Jacobi contraction factor of the viscous predictor (eps = 1, beta = 0)."""
        cfg = self.config
        d = cfg.mu * dt / (cfg.rho * self.h ** 2)
        k = 2 * max(self._ncoupled, 1)
        return k * d / (1.0 + k * d)

    def step(self, dt: float) -> StepInfo:
        """Advance the gas by dt [s]: convection, implicit-drag/viscous predictor, projection."""
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"flow: dt must be a positive number of seconds, got {dt!r}")
        if self._p_init_pending:
            # the incremental projection needs a pressure that balances the forces; a step from
            # p = 0 would leave an O(dt) splitting error at no-slip walls. Take one step, keep its
            # pressure, and restart from the initial velocity.
            self._p_init_pending = False
            s = self._st
            k_copy(s["vel"], s["vel_save"], 0)
            t, n = self.time, self.steps
            self._step(dt)
            self.time, self.steps = t, n
            k_copy(s["vel_save"], s["vel"], 0)
            k_copy(s["vel"], s["accel"], 1)
            k_copy(s["vel"], s["dpred"], 1)
        return self._step(dt)

    def _step(self, dt: float) -> StepInfo:
        """One fractional step. Every kernel is launched without waiting on the device: the viscous
        sweeps and the pressure iterations stop themselves there (launches sized from the last step's
        counts, each doing nothing once done), and the host reads one record at the end. It reads again
        only when the pressure solve needed more iterations than the last step's count and one more
        (:meth:`MGPCG.budget`), the viscous sweeps more than :meth:`_viscous_budget` launched (that
        projection was void and is redone), or a refinement round is due (float32 at its precision floor)."""
        cfg = self.config
        g = self.g
        self._face_coefficients()
        advection.k_advect(g, *self._advect_args, dt, self.serial)
        advection.k_advect_finish(g, *self._finish_args, dt, self.serial)
        boundary.k_bc_prep(g, *self._bc_args, self.serial)
        # red-black Gauss-Seidel sweeps until the estimated error, change * r/(1-r) with r the
        # contraction factor at this diffusion number, and the change itself (a first sweep from a
        # poor initial iterate leaves red and black faces with different errors: a checkerboard)
        # are below VISCOUS_REDUCTION of the velocity scale (decided on the device)
        r = self._jacobi_factor(dt) ** 2
        factor = VISCOUS_REDUCTION * min(1.0, (1.0 - r) / max(r, 1e-30))
        nmax = int(cfg.max_viscous_sweeps)
        predictor.k_visc(g, *self._visc_args, dt, 1, factor, self._bc_speed, nmax, self.serial)
        n_all = -(-max(nmax - predictor.VISCOUS_CHUNK, 0) // predictor.VISCOUS_CHUNK_MORE)  # launches for nmax
        n_more = min(n_all, self._viscous_budget())
        for _ in range(n_more):
            predictor.k_visc_more(*self._sweep_args, nmax, self.serial)
        max_iter = int(cfg.max_iter)
        rec = self._project(dt, 0, max_iter)
        while rec[12] > 0.5 and n_more < n_all:
            # the sweeps outran the launches: that round was void (k_build), the predictor goes on where it
            # stopped, and the projection starts again, as if every launch had been made at first. The launches
            # double each round, not all up to the cap at once (gas.max_viscous_sweeps = 1e9 had the host launch
            # 2.5e8 empty kernels on the first step: a run that never ended)
            self.viscous_retries += 1
            extra = min(n_all - n_more, max(n_more, self.FIRST_LAUNCHES))
            for _ in range(extra):
                predictor.k_visc_more(*self._sweep_args, nmax, self.serial)
            n_more += extra
            rec = self._project(dt, 0, max_iter)
        first = self.mg.info_from(rec[7:])
        iters = first.iterations
        for _ in range(2):
            # refinement: where the solve stopped at its precision floor (float32 with a large
            # pressure increment), project the remaining, much smaller divergence once more
            dmax, s_ref = float(rec[3]), float(rec[5])
            if dmax <= cfg.tol * s_ref or iters >= max_iter:
                break
            rec = self._project(dt, 1, max_iter - iters)
            self._refine_iters = self.mg.info_from(rec[7:]).iterations
            iters += self._refine_iters
        self.mg.last = first  # the next step's iteration budget follows the main solve
        uold, umax, nsw, dmax, smax, s_ref = (float(x) for x in rec[:6])
        self._viscous_last = int(round(nsw))
        self._s_pred = s_ref
        self._div = (dmax, smax)
        div = dmax / s_ref if s_ref > 0 else 0.0
        self.time += dt
        self.steps += 1
        self.last = StepInfo(dt=dt, cfl=max(uold, umax) * dt / self.h,
                             diffusion_number=cfg.mu * dt / (cfg.rho * self.h ** 2), viscous_sweeps=int(round(nsw)),
                             pressure_iterations=iters, pressure_residual=div,
                             converged=div <= cfg.tol, divergence=div)
        return self.last

    #: viscous sweeps launched past the last step's count before the first look (the launches come in chunks of
    #: predictor.VISCOUS_CHUNK_MORE sweeps; None: every launch up to gas.max_viscous_sweeps, the sweeps stopping
    #: themselves on the device)
    VISCOUS_MARGIN: int | None = 2
    #: launches of ``k_visc_more`` on the first step (no count yet), and the fewest added when a step's sweeps outrun
    #: their launches: 16 reach 68 sweeps, past the default cap of 40 (so a default run launches every chunk at once)
    FIRST_LAUNCHES = 16

    def _viscous_budget(self) -> int:
        """Launches of ``k_visc_more`` before the first look: enough for the last step's sweeps and
        ``VISCOUS_MARGIN`` more (``FIRST_LAUNCHES`` on the first step). A launch past the sweeps' end does nothing
        on the device but costs its host time and tasks (13 on CUDA); a step whose sweeps outrun the budget finds out
        at its one read (the record), and launches more and projects again (``viscous_retries``): the same result,
        at the cost of a void projection. The Verma grid: ~3 sweeps a step against a cap of 40, 9 launches."""
        if self.VISCOUS_MARGIN is None:
            return 1 << 62
        if self._viscous_last is None:
            return self.FIRST_LAUNCHES
        want = self._viscous_last + self.VISCOUS_MARGIN - predictor.VISCOUS_CHUNK
        return max(0, -(-want // predictor.VISCOUS_CHUNK_MORE))

    def _project(self, dt: float, again: int, max_iter: int):
        """Pressure system, solve and correction (round ``again``); returns the step record (one read,
        more only when the solve outran its budget)."""
        g, mg = self.g, self.mg
        projection.k_build(g, *self._build_args, dt, again, self.serial)
        # a refinement round's k_build leaves the first round's transmissibilities in place (eps, beta and dt are
        # unchanged), so the hierarchy built from them still holds
        mg.begin(self.config.tol, max_iter, singular=self._singular, device_scale=True, same_matrix=bool(again))
        # a refinement round projects a much smaller remainder: its own last count (1 on the Verma grid in
        # float32), not the main solve's, sets its budget
        n = mg.budget(self._refine_iters if again else None)
        while True:
            mg.launch(n)
            projection.k_correct(g, *self._correct_args, dt, again, self.serial)
            rec = projection.k_record(*self._record_args)
            if rec[6] > 0.5 or rec[12] > 0.5 or mg.exhausted:  # corrected, void (the sweeps go on) or out of iterations
                return rec
            n = mg.more()
