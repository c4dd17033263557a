"""Gas solver of fbed: volume-averaged incompressible gas on a uniform staggered grid.

Owns: the gas flow set-up (:class:`FlowConfig`, boundary conditions :class:`BC`), the solver
(:class:`FlowSolver`: one fractional step per call of :meth:`FlowSolver.step`), the arrays
shared with the coupling code (:class:`GasFields`). (The lid-driven cavity, a verification
scene, is set up with the accuracy cases, :mod:`app.accuracy.gas_cases`.) It knows nothing
about particles: the coupling code writes the gas fraction, its rate of change and the drag
coefficients into those arrays.

Equations (u = interstitial gas velocity, eps = gas volume fraction, m = 1 for the
"shared" pressure form, Model A, and m = 0 for the "gas" form, Model B)::

    d(eps)/dt + div(eps u) = 0
    rho eps (du/dt + u.grad u) = -eps^m grad p + div(eps mu grad u) + rho eps g
                                 + beta (u_s - u) + f

This is the non-conservative (advective) form: it equals the conservative form
d(rho eps u)/dt + div(rho eps u u) minus u times continuity, so it needs no time
derivative of eps and keeps the momentum predictor a plain per-face update, whatever eps
does. Simplification (documented as agreed): the viscous stress is the eps-weighted
Laplacian div(eps mu grad u); the transpose and dilatational parts of the volume-averaged
stress, which vanish for uniform eps, are dropped. p is the full (gauge) pressure, gas
weight included. With "shared" the grains must also feel -V_p grad p (``GasFields.grad_p``);
with "gas" they must not.

Discretisation
--------------
* MAC grid (:mod:`app.sim.gas.grid`): u, v, w on faces, p and eps on cells; z vertical.
  Face values of eps, u_s and f are the means of the two cells; the face drag coefficient is
  beta_f = eps_f^(m+1) * mean(beta/eps^(m+1)), the series resistance of the two half-cells, so
  the pressure drop of a 1-D flow through any eps/beta layering is exact.
* Convection: semi-Lagrangian back-tracing (RK2 midpoint trajectory, trilinear
  interpolation of each MAC component, ghost values across domain faces), optionally with
  the MacCormack correction clamped to the values of the interpolation stencil (Selle et
  al. 2008): unconditionally stable (a 50 m/s jet on 6 mm cells at dt = 1e-3 s, CFL ~ 8,
  is fine), second order in smooth flow, first order where clamped. Selectable:
  "maccormack" (default), "semi_lagrangian", "none" (Stokes flow).
  Second-order splitting: dt/2 a is added at the departure point and taken off at the
  arrival face (the plain semi-Lagrangian trace of a, outside the MacCormack correction:
  corrected together with u it fed back on itself and blew up; a is smoothed first, its
  two-cell mode removed, and a path that entered through an inlet or outlet takes none:
  :mod:`app.sim.gas.advection`), where a is the last step's non-advective acceleration
  (u^n - u~^(n-1))/dt weighted by the inertial share rho eps/(rho eps + beta dt) of the
  face. This is the trapezoidal rule for the forces along the path; without it the
  pressure impulse integrated along a curved trajectory is not a gradient and the
  projection leaves an O(dt) error (Taylor-Green energy decayed 10% too fast at CFL 0.4).
  The weight switches it off where drag balances the pressure gradient (bed surfaces).
* Predictor (per face, backward Euler, incremental pressure)::

      (rho eps/dt + beta) u* - div(eps mu grad u*) = rho eps/dt u~ - eps^m grad p^n
                                                     + rho eps g + f + beta u_s

  solved in place by red-black Gauss-Seidel sweeps (the viscous stencil couples a face
  only to faces of the other parity) from the last step's predictor increment as initial
  iterate (exact in a steady state), until the change is below 1e-6 of the velocity scale
  (at most ``max_viscous_sweeps``). beta and every wall term sit on the diagonal, so huge
  beta (packed beds) is stable and drives u* to u_s.
* Projection (incremental): u = u* - kappa grad phi, p^(n+1) = p^n + phi, with
  kappa = eps^m / (rho eps/dt + beta) on faces. Cell continuity
  theta d(eps)/dt + (1/h) sum_faces (+-) a eps_f u_f = 0 (a = face aperture, theta = open
  volume fraction) gives the variable-coefficient Poisson equation
  sum T_f (phi_c - phi_nb) = -div(eps u*) - theta d(eps)/dt, T_f = a eps_f kappa_f / h^2,
  solved by :class:`app.sim.gas.linsolve.MGPCG` (multigrid-preconditioned CG) to ``tol``.
  The incremental form keeps a fluid at rest in hydrostatic balance (no splitting error at
  no-slip walls) and makes steady states independent of dt. The very first step is taken
  twice: once from p = 0 to find a consistent pressure (its velocity is discarded), then
  for real (skip with :meth:`FlowSolver.set_pressure`). At a pressure outlet the predicted
  velocity is the first interior face's with its pressure push swapped for the outlet
  face's own, so a steady state extrapolates p linearly to the outlet value.
* Divergence after projection: max_c |theta eps_t + (1/h) sum a eps_f u_f| <= tol * S,
  where S is the largest gross face-flux rate of a cell, (1/h) sum a eps_f |u_f| +
  theta |eps_t|, over the predicted or the corrected field (whichever is larger).
  :meth:`FlowSolver.divergence_residual` returns that ratio.

Boundary conditions (per domain face: x-, x+, y-, y+, z-, z+; aliases bottom = z-,
top = z+; a face not given is a no-slip wall)
------------------------------------------------------------------------------
* ``wall``: zero normal velocity; tangential ghost value -u (zero at the face).
* ``moving_wall(U)``: as wall, tangential ghost 2U - u (for the lid-driven cavity).
* ``free_slip``: zero normal velocity, tangential ghost u (zero shear).
* ``velocity_inlet(U)``: U is a superficial velocity vector (flux per unit open area);
  the face carries U_n/eps. A per-cell profile (n1, n2) or (n1, n2, 3) can replace it at
  any step (:meth:`FlowSolver.set_inlet_profile`): that is how a jet is injected.
  Tangential ghost 2 U_t/eps - u.
* ``pressure_outlet(p)``: p fixed half a cell outside the last cell centre (Dirichlet in
  the pressure equation), zero-gradient velocity (the predicted normal velocity is
  copied from the first interior face, then corrected by the pressure gradient; backflow
  is allowed), tangential ghost u.
* ``periodic``: must pair x-/x+ (etc.); the first and last faces are one face.

Vessel walls (cut cells)
------------------------
Apertures, open volume fractions and active cells come from the vessel SDF
(:func:`app.sim.gas.grid.cut_cells`). Closed faces carry zero velocity; cells with no open
volume are not solved. In the viscous stencil a neighbour face that lies in the wall
(clearance < 0 at its centre, or closed) is replaced by the ghost value
u_G = -u_P (1 - t)/t, where t = c_P/(c_P - c_Q) is where the wall crosses the segment
between the two face centres (clearances c; t clamped to [0.05, 1]): linear extrapolation
to u = 0 on the true wall, put on the diagonal. Where a vessel wall cuts the cell next to a
domain face and lies closer than that face, it takes precedence over the domain ghost (its
clearance is extrapolated linearly across the boundary). Accuracy: the no-slip velocity is second
order away from the wall (first-order local truncation at the ghost, as usual for
ghost-cell immersed boundaries); the pressure flux through a cut face uses the full cell
distance and the aperture, first order near the wall; mass conservation is exact
(to ``tol``) on the cut geometry. Back-traced convection near an immersed wall sees the
closed faces as zero velocity (first order there).

Units are SI throughout. The solver never prints or writes files.

Modules (each kernel a function over named bundles, :mod:`.layout`; inputs first, outputs last)
--------------------------------------------------------------------------------------------
* :mod:`.config`: :class:`BC`, :class:`FlowConfig` (the preset's [gas] keys), :class:`StepInfo`.
* :mod:`.grid`: the MAC grid and its cut cells (numpy); :mod:`.layout`: the bundles and index functions.
* :mod:`.boundary`: boundary conditions and inlets; :mod:`.advection`; :mod:`.predictor`;
  :mod:`.projection`; the linear solver :mod:`.linsolve` (:mod:`.multigrid`, :mod:`.pcg`).
* :mod:`.fields`: the bundle shared with the coupling; :mod:`.solver` and :mod:`.outputs`: the solver object.

Implementation note: all solver state lives in bundles of Taichi ndarrays and the kernels are
module-level, so they compile once per process for any grid; only the two copy kernels between the
:class:`GasFields` bundle and the solver's bundles are compiled per solver. A step does not wait on
the device: the viscous sweeps and the pressure iterations are launched in batches sized from the last
step's counts whose stopping tests run on the device (a launch past convergence does nothing), and the
host reads one record per step (:func:`app.sim.gas.projection.k_record`), a second only when the pressure
solve outran its batch, the viscous sweeps outran theirs (that projection is void and is redone) or a float32
refinement round is due.

Two compiled forms of every step kernel (a compile-time ``serial`` argument, :attr:`FlowSolver.serial`, set from
:func:`app.sim.runtime.serial` at construction): on CUDA and several CPU threads each loop over faces or cells is a
top-level, parallel loop of its kernel; on one CPU thread (Taichi 1.7.4 makes each top-level loop a task of its own,
~70 us even when empty) the kernel's loops are nested in one serial loop, one task a launch, and walk the grid as
nested loops over (axis,) i, j, k instead of decoding a flat index by division (:func:`.layout.each_face`,
:func:`.layout.each_cell`). Both compute the same step up to the order of float sums (tests/test_gas_serial.py).
In the parallel form a run of statements between two loops is a task too (one thread): the kernels launched many
times a step (the V-cycle's levels, the viscous sweeps) compute their constants at their head and run their loops
back to back through functions with template arguments (``passes.level_pair``). Every max and sum of the step
accumulates in a kernel-scope variable (thread-local, then one atomic per warp on CUDA), never with an atomic per
cell into an array element (``layout.face_max_into``).
"""
from .config import (ALIASES, BC, CONVECTION, EPS_MIN, FACES, GAS_KEYS, INLET, KIND_ALIASES, KINDS, MOVING, OUTLET,
                     PERIODIC, PRESSURE_FORMS, SLIP, THETA_MIN, VISCOUS_REDUCTION, WALL, FlowConfig, StepInfo,
                     free_slip, moving_wall, periodic, pressure_outlet, velocity_inlet, wall)
from .fields import GasFields
from .grid import CutCells, MacGrid, cut_cells
from .linsolve import MGPCG, SolveInfo, plan_levels
from .solver import FlowSolver

__all__ = ["ALIASES", "BC", "CONVECTION", "EPS_MIN", "FACES", "GAS_KEYS", "INLET", "KIND_ALIASES", "KINDS", "MOVING",
           "OUTLET", "PERIODIC", "PRESSURE_FORMS", "SLIP", "THETA_MIN", "VISCOUS_REDUCTION", "WALL", "FlowConfig",
           "StepInfo", "free_slip", "moving_wall", "periodic", "pressure_outlet", "velocity_inlet", "wall",
           "GasFields", "CutCells", "MacGrid", "cut_cells", "MGPCG", "SolveInfo", "plan_levels", "FlowSolver"]
