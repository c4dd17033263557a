"""The guard: stops a run that went wrong before it writes garbage, and says which setting to change."""
from __future__ import annotations

import math

import numpy as np

from ..config.derived import gas_shape, inlet_peak_speeds
from ..schedule import FACE_AXES, jet_cells
from ..sim.drag import terminal_slip
from ..sim.simulation import Simulation, Unstable

#: the share of the inlets' flow that may go unbalanced without a pressure outlet (rounding of the face sums)
INFLOW_IMBALANCE = 1e-6
STANDARD_GRAVITY = 9.80665  # [m/s^2]: the energy floor is set in standard g, whatever the scene's gravity


def carried_speed(cfg, derived, radii) -> np.ndarray:
    """The speed [m/s] at which the gas carries each grain up: the fastest inlet's superficial speed (jets left
    out: they blow through a few cells) less the grain's terminal slip by the run's drag law, or 0. A 10 um powder
    in 1.1 m/s gas moves at 1.1 m/s within a millisecond, real energy 1e4 times that of a fall through its own
    diameter; a 2 mm grain in the same gas (terminal slip about 7 m/s) is carried at 0 and keeps that floor."""
    radii = np.asarray(radii, float)
    if getattr(cfg, "gas", None) is None or not radii.size:
        return np.zeros_like(radii)
    speed = max([inlet_peak_speeds(face)[0] for _, face in cfg.boundary] or [0.0])
    if speed == 0.0:
        return np.zeros_like(radii)
    sizes, which = np.unique(radii, return_inverse=True)
    slip = terminal_slip(cfg.coupling.drag, 2.0 * sizes, derived.density, cfg.gas.density, cfg.gas.viscosity,
                         float(np.linalg.norm(cfg.domain.gravity)))
    return np.maximum(speed - slip, 0.0)[which.reshape(-1)]


def jet_floors(cfg, derived, radii, masses) -> list[tuple[float, float, float]]:
    """The energy [J] each inlet jet adds to the floor, and the times [s] it counts from and to:
    ``(from, to, energy)``, from the jet's opening to two guard intervals after it closes (the reference is one to
    two intervals back). The smaller of two floors, each enough alone for the jet's growth to stay under
    guard.max_energy_growth = G:
    - the jet's work: its mechanical power (the face pressure under the bed's weight and its dynamic pressure,
      times its flow) over two intervals, / (G - 1): the grains cannot take more than the jet gives;
    - its column: the grains at the jet's speed less their terminal slip, times the share of the face the jet
      blows through (its face cells): all the grains at that speed are 1 / share times it, under G for any jet
      wider than 1 / G of the face (the Boyce jet: a 460th).
    The first binds in a bed (a 100 m/s jet into 1,200 grains of 2 mm: 1.6e-4 J), the second in a powder light
    beside the gas (20 m/s into 10 um grains: 2e-10 J, stopped as a blow-up at 4.8e3x without it)."""
    gas, g = getattr(cfg, "gas", None), cfg.guard
    radii, masses = np.asarray(radii, float), np.asarray(masses, float)
    if gas is None or not radii.size:
        return []
    d, h, shape = cfg.domain, gas.cell_size, gas_shape(cfg)
    sizes, which = np.unique(radii, return_inverse=True)
    gravity = float(np.linalg.norm(d.gravity))
    floors = []
    for name, face in cfg.boundary:
        jet = inlet_peak_speeds(face)[1]
        if jet == 0.0:
            continue
        others = [k for k in range(3) if k != FACE_AXES[name[0]]]
        area = float(np.prod([d.hi[k] - d.lo[k] for k in others]))  # [m^2] the face (the cylinder's where round)
        if cfg.vessel.shape == "cylinder" and name[0] == "z":
            area = min(area, math.pi * cfg.vessel.radius ** 2)
        jet_area = max(int(jet_cells(name, face, shape, h, d.lo).sum()), 1) * h * h  # [m^2]
        pressure = float(masses.sum()) * gravity / area + 0.5 * gas.density * jet ** 2  # [Pa]
        work = jet_area * jet * pressure * 2.0 * g.interval / (g.max_energy_growth - 1.0)  # [J]
        slip = terminal_slip(cfg.coupling.drag, 2.0 * sizes, derived.density, gas.density, gas.viscosity, gravity)
        speed = np.maximum(jet - slip, 0.0)[which.reshape(-1)]
        column = 0.5 * min(1.0, jet_area / area) * float(np.sum(masses * speed ** 2))  # [J]
        end = face.jet_start + face.jet_duration + 2.0 * g.interval if face.jet_duration > 0 else math.inf
        floors.append((face.jet_start, end, min(work, column)))
    return floors

class Guard:
    """Stops a run that went wrong (NaN/inf, runaway overlap, speed or kinetic energy growth; a gas step going
    unstable or a pressure solve that did not converge) before it writes garbage.

    Its message names the setting to change: a DEM step above the stable limit (forced with
    dem.force_dt) is the first suspect; otherwise contacts too soft for the impacts."""

    def __init__(self, max_overlap: float, max_speed: float, dt: float = 0.0, dt_limit: float = float("inf"),
                 max_gas_speed: float = float("inf"), max_divergence: float = float("inf"),
                 max_energy_growth: float = float("inf"), energy_floor: float = 0.0, interval: float = 0.0,
                 trace_forces: bool = False, jet_floors: tuple = ()):
        # energy growth: the grains' kinetic energy against the one of the check an interval before, measured
        # from at least energy_floor [J] (from rest any factor is physical: a bed starting to move)
        self.max_energy_growth = max_energy_growth
        self.energy_floor = energy_floor
        self.jet_floors = tuple(jet_floors)  # (from [s], to [s], energy [J]): added to the floor while a jet blows
        self.interval = interval
        self._energy_ref: tuple[float, float] | None = None   # (time [s], kinetic energy [J])
        self.max_gas_speed = max_gas_speed
        # the gas carries its forces along the convection paths with MacCormack convection: the one gas set-up
        # known to run away by itself (benchmarks/RESULTS.md, the gust case), so its knob is named first
        self.trace_forces = trace_forces
        self.max_divergence = max_divergence
        self.max_overlap = max_overlap
        self.max_speed = max_speed
        self.dt = dt
        self.dt_limit = dt_limit
        self.last_good_time = 0.0  # [s]
        self.failed_time: float | None = None  # [s] of the row that failed: the run reads rows a few steps behind
        self._checked = -1  # the step of the last row that passed
        self._every = 1  # steps between the guard's own rows (attach): only those move the energy reference

    def attach(self, sim: Simulation, interval: float) -> None:
        """In a run: every diagnostics row read back passes the guard before any other sink (the series) gets
        it, and on its own schedule the guard only records the step's row (``Simulation.record_diagnostics``:
        the ring is read within ``sim.diag_rows`` steps, and at once before any guarded write)."""
        sim.diagnostics_sinks.insert(0, lambda d: self.check(d, sim))
        sim.add(lambda s: s.record_diagnostics(), interval, at_start=True)
        self._every = sim.every(interval) if interval > 0 else 1

    @classmethod
    def of(cls, cfg, derived, masses=None, radii=None) -> "Guard":
        """The guard of a run from [guard] and the derived DEM step; ``masses`` [kg] and ``radii`` [m]: the grains'
        (the energy floor: every grain at sqrt(g d), the speed of a fall through one diameter, in standard g, or at
        the speed the gas carries it, ``carried_speed``, where that is faster; and while a jet blows, the energy
        it may give, ``jet_floors``)."""
        g = cfg.guard
        floor, jets = 0.0, []
        if masses is not None:
            speed2 = STANDARD_GRAVITY * 2.0 * derived.radius_min
            if radii is not None:
                speed2 = np.maximum(speed2, carried_speed(cfg, derived, radii) ** 2)
            floor = 0.5 * float(np.sum(np.asarray(masses) * speed2))
            if radii is not None:
                jets = jet_floors(cfg, derived, radii, masses)
        gas = getattr(cfg, "gas", None)
        trace = bool(gas is not None and gas.trace_forces and gas.convection == "maccormack")
        return cls(g.max_overlap, g.max_speed, derived.dt if derived else 0.0,
                   derived.dt_limit if derived else float("inf"), g.max_gas_speed, g.max_divergence,
                   g.max_energy_growth, floor, g.interval, trace, jets)

    def _gas_knobs(self, usual: str) -> str:
        """The settings a gas that runs away should change: the force trace first where it is on."""
        if self.trace_forces:
            return ("set gas.trace_forces = false (the force trace with MacCormack convection can feed grid-scale "
                    "corrections back on themselves, near pressure outlets most: first order in time without it), "
                    "or " + usual)
        return usual

    def guarded(self, write):
        """A writer that checks the guard first, so nothing non-finite ever reaches a file."""
        def checked(sim):
            self(sim)
            write(sim)
        return checked

    def _gas_check(self, sim: Simulation, d: dict, t: float) -> None:
        if "gas_non_finite" not in d:
            return
        if d["gas_non_finite"]:
            raise Unstable(f"non-finite gas velocity or pressure at t = {t:.6g} s (gas CFL {d['gas_cfl']:.3g}): "
                           + self._gas_knobs("lower run.step (the fluid step), raise gas.max_iterations, or check "
                                             "[boundary]"))
        net, share = sim.flow.inflow_imbalance()  # (0, 0) where a face is a pressure outlet
        if share > INFLOW_IMBALANCE:
            raise Unstable(f"the velocity inlets blow {net:.3g} m^3/s more into the domain than they draw out "
                           f"({100 * share:.3g}% of their flow) at t = {t:.6g} s, and no face is a "
                           "pressure_outlet: the incompressible gas has no solution: add a pressure_outlet, or "
                           "balance the inlets (in as much as out, at every instant)")
        if d["divergence_residual"] > self.max_divergence:
            raise Unstable(f"the gas's divergence residual is {d['divergence_residual']:.3g} at t = {t:.6g} s "
                           f"(guard.max_divergence = {self.max_divergence:g}; {d['pressure_iterations']} pressure "
                           "iterations): the pressure solve did not converge, so gas mass is not conserved: raise "
                           "gas.max_iterations, or lower run.step")
        if d["gas_max_speed"] > self.max_gas_speed:
            raise Unstable(f"the gas moves at {d['gas_max_speed']:.3g} m/s at t = {t:.6g} s (guard.max_gas_speed = "
                           f"{self.max_gas_speed:g} m/s; gas CFL {d['gas_cfl']:.3g}{sim.gas_fastest_cell()}): the gas step is going unstable: "
                           + self._gas_knobs("lower run.step (the fluid step) or raise coupling.smoothing_width")
                           + "; raise guard.max_gas_speed if such speeds are real")

    def _advice(self) -> str:
        if self.dt > self.dt_limit:
            return (f"the DEM step {self.dt:.3g} s is above the stable limit {self.dt_limit:.3g} s (forced with "
                    "dem.force_dt): lower dem.dt or set it to 0 (automatic)")
        return ("contacts are too soft or the step too long for these impacts: raise dem.impact_speed (the step "
                "is then set for faster impacts) or lower dem.dt_fraction; raising contact.youngs_modulus cuts "
                "overlaps (at a smaller step)")

    def __call__(self, sim: Simulation) -> None:
        """Check the current step (its row and those recorded before it are read now)."""
        self.check(sim.diagnostics(), sim)

    def check(self, d: dict, sim: Simulation) -> None:
        """Check one diagnostics row (``d``: its figures, with its step and time); a row that passed is not
        checked again."""
        if d["step"] <= self._checked:
            return
        try:
            self._check_row(d, sim, d["time"])
        except Unstable:
            self.failed_time = d["time"]
            raise
        self._checked = d["step"]
        self.last_good_time = d["time"]

    def stop_times(self) -> dict:
        """For summary.json after a stop: the time of the row that failed and of the last that passed [s] (the run
        itself went on to its next read of the rows, up to Simulation.diag_rows steps later)."""
        if self.failed_time is None:
            return {}
        return {"unstable_at": self.failed_time, "last_good_time": self.last_good_time}

    def _check_row(self, d: dict, sim: Simulation, t: float) -> None:
        self._gas_check(sim, d, t)
        if "non_finite" not in d:  # no grains in this scene
            return
        if d["non_finite"] or not math.isfinite(d["kinetic_energy"]):
            raise Unstable(f"non-finite grain positions or velocities at t = {t:.6g} s: {self._advice()}")
        if d["max_overlap"] > self.max_overlap:
            raise Unstable(f"grains overlap by {100 * d['max_overlap']:.1f}% of a diameter at t = {t:.6g} s "
                           f"(guard.max_overlap = {100 * self.max_overlap:g}%): {self._advice()}")
        if d["max_speed"] > self.max_speed:
            raise Unstable(f"a grain moves at {d['max_speed']:.3g} m/s at t = {t:.6g} s (guard.max_speed = "
                           f"{self.max_speed:g} m/s; raise it if such speeds are real): {self._advice()}")
        self._energy_check(d["kinetic_energy"], t, d["step"] % self._every == 0)
        if through := d.get("grains_through_walls", 0):  # counted by the DEM as they leave: never missed
            raise Unstable(f"{through} grain{'s' * (through != 1)} passed through the vessel's walls (its floor, "
                           f"sides or lid) and left the domain by t = {t:.6g} s: {self._advice()}")

    def floor_at(self, t: float) -> float:
        """The energy [J] growth is measured from at time t [s]: the floor, plus each jet's while it counts."""
        return self.energy_floor + sum(e for t0, t1, e in self.jet_floors if t0 <= t <= t1)

    def _energy_check(self, energy: float, t: float, own: bool = True) -> None:
        """Stop when the kinetic energy grew more than max_energy_growth times since the reference check (one
        to two guard intervals back; checks in between, from the writers, compare with the same reference).
        Only the guard's ``own`` rows (on its schedule) become the reference, so which other rows were read (a
        checkpoint on the wall clock's schedule) does not change the verdict."""
        if self._energy_ref is not None:
            t_ref, e_ref = self._energy_ref
            base = max(e_ref, self.floor_at(t))
            if energy > self.max_energy_growth * base:
                raise Unstable(
                    f"the grains' kinetic energy grew {energy / base:.3g}x in {t - t_ref:.3g} s (to {energy:.3g} J) "
                    f"at t = {t:.6g} s (guard.max_energy_growth = {self.max_energy_growth:g}x per guard.interval): "
                    f"{self._advice()}. Grains that start overlapping release their stored energy like this: settle "
                    "the bed with the run's contacts. Raise guard.max_energy_growth if the growth is real")
            if t - t_ref < self.interval * (1.0 - 1e-9):
                return
        if own:
            self._energy_ref = (t, energy)
