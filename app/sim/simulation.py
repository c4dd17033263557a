"""The Simulation: owns the clock and the step loop; everything else attaches as a callback.

Owns: simulated time, the step counter, the schedules on which callbacks fire and the stop
request (from a signal handler). The callbacks themselves (writers, the guard that stops an
unstable run by raising ``Unstable``, progress, checkpoints) live in ``app.callbacks``. One step is
``run.step`` seconds: the gas step (when the scene has gas), then the DEM substeps it
holds (when it has grains). A scene without one of them allocates nothing for it.

Schedules count steps, not floating-point seconds, so a run resumed from a checkpoint
fires its callbacks on exactly the same steps as an uninterrupted run.

Diagnostics rows: ``record_diagnostics`` writes the step's DEM, gas and coupler figures into a row of a
device ring (``app.sim.diagnostics``) and reads nothing; ``flush_diagnostics`` copies the recorded rows in one
read and hands each, in step order, to the ``diagnostics_sinks`` (in a run: the guard, then the series). The
block is read every ``diag_rows`` steps, or at once when someone needs the current figures (``diagnostics()``:
the guard before a write, progress, the summary); so the series costs the host no wait per step.

Adaptive fluid step: when the gas's CFL number (max|u| dt / h) passes ``max_gas_cfl``, the next
steps split into ``gas_split`` pieces, each a whole number of DEM substeps with its own
deposit -> drag -> gas step -> DEM substeps; the clock and the schedules still count whole
``run.step`` steps, so outputs land where they would have. The split halves again once the CFL
of the pieces is back below a quarter of the limit. Each change is reported through ``notify``.
"""
from __future__ import annotations

import dataclasses
import math
import time as wallclock
from typing import Callable

from ..config.derived import interval_steps, run_steps


DIAG_ROWS = 50  # steps of diagnostics held on the device between reads (Simulation.diag_rows)


class Unstable(RuntimeError):
    """Raised by the guard: the message says what went wrong and which setting to change."""


@dataclasses.dataclass
class Hook:
    """A callback and when it fires: every ``every`` steps and/or every ``wall`` seconds of wall time."""

    fn: Callable
    every: int = 0
    wall: float = 0.0
    at_start: bool = False
    finish: Callable | None = None  # called once with (sim, reason) when the run ends
    _last_wall: float = dataclasses.field(default=0.0, repr=False)


class Simulation:
    def __init__(self, dem, step: float, substeps: int, duration: float, flow=None, coupler=None, inlets=None,
                 max_gas_cfl: float = float("inf"), max_gas_split: int = 1, notify: Callable | None = None,
                 timing: bool = False):
        """``inlets``: a before-step hook setting the inlet profiles (app.schedule.InletSchedule, whose live
        controls the viewer uses), or None; the rest as the attributes of the same names below."""
        self.dem = dem
        self.flow = flow
        self.coupler = coupler
        self.inlets = inlets
        self.before_step: list[Callable] = [inlets] if inlets is not None else []  # called before each step
        self.flow_info = None  # StepInfo of the last gas step
        self.step_dt = step
        self.substeps = substeps
        self.duration = duration
        self.step_count = 0
        self.hooks: list[Hook] = []
        self.stop_requested: str | None = None
        self.wall_elapsed = 0.0  # wall seconds spent stepping, this process
        self._diag_cache: tuple[int, dict] | None = None  # (step, figures) of the last row read
        self.diag_rows = DIAG_ROWS  # steps recorded on the device between reads of the diagnostics ring
        self._diag_ring = None  # app.sim.diagnostics.DiagnosticsRing, made at the first record
        self._pending: list[tuple[int, dict]] = []  # (step, host figures) of the rows recorded, not yet read
        self.diagnostics_sinks: list[Callable[[dict], None]] = []  # each read row, in step order (guard, series)
        # whether the at-start callbacks fire (None: when starting at step 0; a run started from a
        # prepared state at a later step is fresh too, a resumed one is not)
        self.fresh: bool | None = None
        self.timing = timing  # per-phase wall times (coupling, gas, dem, callbacks) into phase_seconds
        self.timing_every = 25  # ... measured on every 25th step only (see _lap)
        self._timed = False
        self._lap_start = 0.0  # wall clock at the start of the current phase (sampled steps)
        self.phase_seconds: dict[str, float] = {}  # summed over the sampled steps
        self.callback_seconds = 0.0  # summed over every step
        self.steps_timed = 0
        self.steps_sampled = 0
        self.max_gas_cfl = max_gas_cfl      # adapt above this CFL (gas.max_cfl)
        self.max_gas_split = max_gas_split  # most pieces a step may split into (gas.max_split)
        self.gas_split = 1              # pieces of the current step
        self.gas_split_peak = 1
        self.gas_split_changes = 0
        self.notify: Callable[[str], None] | None = notify  # the run's log (solvers never print)

    def wall_split(self) -> dict[str, float]:
        """Estimated wall seconds per phase over the timed steps: coupling, gas and DEM scaled up
        from the sampled steps, callbacks as measured."""
        if not self.steps_sampled:
            return {}
        scale = self.steps_timed / self.steps_sampled
        out = {k: v * scale for k, v in self.phase_seconds.items()}
        out["callbacks"] = self.callback_seconds
        return out

    @property
    def time(self) -> float:
        return self.step_count * self.step_dt

    @property
    def total_steps(self) -> int:
        return run_steps(self.duration, self.step_dt)

    def every(self, interval: float) -> int:
        """Steps between firings for an interval of simulated time [s] (at least 1)."""
        return interval_steps(interval, self.step_dt)

    def add(self, fn, interval: float = 0.0, wall: float = 0.0, at_start: bool = False, finish=None) -> Hook:
        h = Hook(fn, self.every(interval) if interval > 0 else 0, wall, at_start, finish)
        h._last_wall = wallclock.perf_counter()
        self.hooks.append(h)
        return h

    def record_diagnostics(self) -> None:
        """Record this step's diagnostics on the device (once per step) and read nothing. The block is read
        (``flush_diagnostics``) when ``diag_rows`` rows are pending or the oldest is ``diag_rows`` - 1 steps old,
        so every sink (the guard among them) sees each row within ``diag_rows`` steps."""
        step = self.step_count
        if (self._pending and self._pending[-1][0] == step) or self.diagnostics_read(step):
            return
        if self._diag_ring is None:
            from .diagnostics import DiagnosticsRing

            self._diag_ring = DiagnosticsRing(self.dem, self.flow, self.coupler, self.diag_rows)
        self._diag_ring.record(len(self._pending))
        self._pending.append((step, self._host_figures()))
        if len(self._pending) >= self.diag_rows or step - self._pending[0][0] >= self.diag_rows - 1:
            self.flush_diagnostics()

    def diagnostics_read(self, step: int) -> bool:
        """Whether the row of ``step`` has been read back (``diagnostics()`` then costs nothing)."""
        return self._diag_cache is not None and self._diag_cache[0] == step

    def flush_diagnostics(self) -> None:
        """Read the recorded rows in one block (one host read) and hand each, in step order, to every sink."""
        if not self._pending:
            return
        pending, self._pending = self._pending, []
        for (step, host), d in zip(pending, self._diag_ring.read(len(pending))):
            d.update(host)
            self._diag_cache = (step, d)
            for sink in self.diagnostics_sinks:
                sink(d)

    def diagnostics(self) -> dict:
        """Diagnostics of the current step (recorded and read once per step, shared by callbacks); the rows
        recorded before it are read with it and reach the sinks first."""
        if not self.diagnostics_read(self.step_count):
            self.record_diagnostics()
            self.flush_diagnostics()
        return self._diag_cache[1]

    def _host_figures(self) -> dict:
        """What a row holds that the host already has: step, time, wall time, the last gas step's figures."""
        d = {"step": self.step_count, "time": self.time, "wall_time": self.wall_elapsed}
        if self.flow is not None:
            info = self.flow_info
            d.update(gas_cfl=info.cfl if info else 0.0,
                     pressure_iterations=info.pressure_iterations if info else 0,
                     pressure_residual=info.pressure_residual if info else 0.0,
                     pressure_converged=bool(info.converged) if info else True,
                     divergence_residual=info.divergence if info else 0.0)
        return d

    def gas_fastest_cell(self) -> str:
        """Where the gas is fastest (cell, position, open volume and gas fraction), for a guard's message and
        the headless log lines; read then only, not every step."""
        import numpy as np

        u = self.flow.cell_velocity()
        speed = np.sqrt((u ** 2).sum(-1))
        if not speed.size or not np.isfinite(speed).all():
            return ""
        c = np.unravel_index(int(np.argmax(speed)), speed.shape)
        g = self.flow.config.grid
        x = ", ".join(f"{o + (i + 0.5) * g.h:.4g}" for o, i in zip(g.origin, c))
        return (f"; fastest in cell {tuple(int(i) for i in c)} at ({x}) m, open volume fraction "
                f"{float(self.flow.cut.volume[c]):.2f}, gas fraction {float(self.flow.fields.eps[c]):.2f}")

    def step(self) -> None:
        # sampled steps skip the first ones (kernel compilation would dominate them)
        self._timed = self.timing and self.step_count >= 2 * self.timing_every and \
            self.step_count % self.timing_every == 0
        if self._timed:
            import taichi as ti

            ti.sync()
            self._lap_start = wallclock.perf_counter()
        for fn in self.before_step:
            fn(self)
        pieces = min(self.gas_split, self.substeps) if self.dem is not None else self.gas_split
        for k in self._piece_substeps(pieces):
            dt = self.step_dt * k / self.substeps if self.dem is not None else self.step_dt / pieces
            # one coupling order per fluid step: deposit eps -> drag -> gas step -> DEM substeps
            if self.coupler is not None:
                self.coupler.step(dt)
                self._lap("coupling")
            if self.flow is not None:
                self.flow_info = self.flow.step(dt)
                self._lap("gas")
            if self.dem is not None:
                self.dem.advance(k)
                self._lap("dem")
        self.step_count += 1
        if self.flow_info is not None and self.max_gas_split > 1:
            self._adapt(self.flow_info.cfl, pieces)

    def _piece_substeps(self, pieces: int) -> list[int]:
        """DEM substeps in each piece of a split step (whole numbers summing to ``substeps``)."""
        if pieces <= 1:
            return [self.substeps]
        base, extra = divmod(self.substeps, pieces)
        return [base + (i < extra) for i in range(pieces)]

    def _adapt(self, cfl: float, pieces: int) -> None:
        """Choose the next step's split from the CFL of this step's pieces."""
        limit = self.max_gas_cfl
        if cfl > limit and pieces < self.max_gas_split:
            new = min(self.max_gas_split, pieces * math.ceil(cfl / (0.8 * limit)))
            why = f"gas CFL {cfl:.3g} > gas.max_cfl = {limit:g}"
        elif pieces > 1 and 2 * cfl < 0.5 * limit:
            new = max(1, pieces // 2)
            why = f"gas CFL back to {cfl:.3g}"
        else:
            return
        if new == pieces:
            return
        self.gas_split = new
        self.gas_split_peak = max(self.gas_split_peak, new)
        self.gas_split_changes += 1
        if self.notify:
            self.notify(f"fbed: t = {self.time:.6g} s: {why}: the fluid step is now {self.step_dt / new:.3g} s "
                        f"(run.step / {new})" + ("; raise gas.max_split or lower run.step if this persists"
                                                 if new == self.max_gas_split and cfl > limit else ""))

    def _lap(self, phase: str) -> None:
        """Wall time of each phase [s], summed over the sampled steps (``timing`` on: every
        ``timing_every``-th step synchronises the device at each phase's end, so the split is honest
        on a GPU. Only a sample of steps pays for it: a sync per phase stops the host from queueing
        the next phase's kernels while the device still runs the last one)."""
        if not self._timed:
            return
        import taichi as ti

        ti.sync()
        now = wallclock.perf_counter()
        self.phase_seconds[phase] = self.phase_seconds.get(phase, 0.0) + now - self._lap_start
        self._lap_start = now

    def _fire(self, start: bool = False) -> None:
        now = wallclock.perf_counter()
        for h in self.hooks:
            due = (start and h.at_start) or (not start and h.every and self.step_count % h.every == 0)
            if not due and h.wall and not start and now - h._last_wall >= h.wall:
                due = True
            if due:
                h._last_wall = now
                h.fn(self)

    def advance(self) -> None:
        """One step, timed, then the callbacks that are due."""
        t0 = wallclock.perf_counter()
        self.step()
        t1 = wallclock.perf_counter()
        self.wall_elapsed += t1 - t0
        self._fire()
        if self.timing:  # host code (it syncs where it reads the device): timed on every step
            if self.step_count > 2 * self.timing_every:
                self.callback_seconds += wallclock.perf_counter() - t1
                self.steps_timed += 1
                self.steps_sampled += int(self._timed)

    def run(self, controller=None) -> str:
        """Step until the duration is reached, a stop is requested, or the guard trips.

        ``controller`` (interactive runs): called before every step with the simulation;
        returns 'step' (advance one step), 'wait' (do not step now: paused, or past the end)
        or 'stop' (the window was closed). Without one, the run steps to the end.
        Returns 'finished' or 'interrupted'; raises Unstable after the finish hooks ran."""
        reason = "finished"
        try:
            if self.fresh if self.fresh is not None else self.step_count == 0:
                self._fire(start=True)
            while True:
                if self.stop_requested:
                    reason = "interrupted"
                    break
                if controller is None:
                    if self.step_count >= self.total_steps:
                        break
                    self.advance()
                    continue
                action = controller(self)
                if action == "stop":
                    reason = "interrupted" if self.step_count < self.total_steps else "finished"
                    break
                if action == "step" and self.step_count < self.total_steps:
                    self.advance()
            self.flush_diagnostics()  # the rows still on the device reach the guard while it can stop the run
        except Unstable:
            self._finish("unstable")
            raise
        except BaseException:
            self._finish("error")
            raise
        self._finish(reason)
        return reason

    def _finish(self, reason: str) -> None:
        for h in self.hooks:
            if h.finish:
                h.finish(self, reason)

