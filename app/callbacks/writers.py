"""Writers: what a run puts into its output folder while it steps, each on its own schedule.

``Series`` (a row of /series in run.h5), ``GrainSnapshots`` and ``GasFields`` (frames in run.h5),
``Checkpoints`` (checkpoint.h5 and the ParaView indexes) on simulated time, ``WallCheckpoints`` on
the wall clock, and ``FinalOutputs`` (the last of each, bed.h5, run.h5 closed) when the run ends.
Every writer is attached behind the guard (``Guard.guarded``): nothing non-finite reaches a file.
Device data is copied to the host once per write, as whole arrays; the series' rows are recorded on the
device every series step and read back in blocks (``Simulation.record_diagnostics``), each through the
guard before it is written.
"""
from __future__ import annotations

import pathlib
import time as wallclock

import numpy as np

from ..io import store, xdmf
from ..io.store import SPLIT_KEY
from ..sim.simulation import Unstable
from .progress import log

DEM_SERIES = ("kinetic_energy", "kinetic_energy_rotational", "max_overlap", "max_speed", "grains_alive",
              "grains_removed", "bed_height")
GAS_SERIES = ("gas_max_speed", "gas_cfl", "pressure_iterations", "pressure_residual", "divergence_residual",
              "clipped_cells", "pressure_drop")


def open_run_file(path: pathlib.Path, name: str, sim, scene, resume: bool = False) -> store.RunFile:
    """run.h5 (appended to when resuming), with the gas grid that run.xdmf draws the gas fields on."""
    runfile = store.RunFile(path, name, resume_time=sim.time if resume else None)
    if sim.flow is not None:
        runfile.grid(scene.flow.shape, scene.flow.h, scene.flow.origin, sim.flow.fields.vol_frac.to_numpy())
    return runfile


class Series:
    """Rows of run.h5's /series: each series step's diagnostics (and, coupled, the pressure drop across the bed).

    A series step records its row on the device and reads nothing (``Simulation.record_diagnostics``); the
    rows come back in blocks to ``row`` (a diagnostics sink, after the guard) and are appended in step order.
    A row already read when its step fires (a writer or the guard asked for it) is appended at once."""

    def __init__(self, runfile, bed=None):
        self.runfile, self.bed = runfile, bed
        self._wanted: set[int] = set()  # steps whose rows are recorded and not yet written

    def attach(self, sim, interval: float, finish=None) -> None:
        sim.diagnostics_sinks.append(self.row)
        sim.add(self, interval, at_start=True, finish=finish)

    def __call__(self, sim) -> None:
        if sim.diagnostics_read(sim.step_count):
            self._append(sim.diagnostics())
        else:
            self._wanted.add(sim.step_count)
            sim.record_diagnostics()

    def row(self, d: dict) -> None:
        if d["step"] in self._wanted:
            self._wanted.discard(d["step"])
            self._append(d)

    def _append(self, d: dict) -> None:
        if self.bed is not None and "end_layer_pressures" in d:
            d["pressure_drop"] = self.bed.pressure_drop_of(*d["end_layer_pressures"])
        row = {"time": d["time"]}
        row.update({k: d[k] for k in DEM_SERIES + GAS_SERIES if k in d})
        row.update({k: v for k, v in d.items() if k.startswith("wall_force_z_")})
        row["wall_time"] = d["wall_time"]
        self.runfile.append(row)


class GrainSnapshots:
    """The grains' positions, velocities and radii as a frame of run.h5 (once per step at most)."""

    def __init__(self, runfile, dem):
        self.runfile, self.dem, self.last = runfile, dem, -1

    def __call__(self, sim) -> None:
        if self.last != sim.step_count:
            self.runfile.snapshot(sim.time, self.dem.read("position"), self.dem.read("velocity"), self.dem.radii())
            self.last = sim.step_count


class GasFields:
    """The gas's cell velocity, pressure and gas fraction as a frame of run.h5 (once per step at most)."""

    def __init__(self, runfile, flow):
        self.runfile, self.flow, self.last = runfile, flow, -1

    def __call__(self, sim) -> None:
        if self.last != sim.step_count:
            f = self.flow
            self.runfile.gas_fields(sim.time, f.cell_velocity(), f.pressure(), f.fields.eps.to_numpy())
            self.last = sim.step_count


def write_xdmf(out_dir: pathlib.Path, runfile=None) -> None:
    """run.xdmf (and particles.xdmf, checkpoint.xdmf) for ParaView: small XML files that point into the HDF5
    files, at every checkpoint (``runfile``: run.h5 open for writing) and, with bed.xdmf, at the end; a failure
    here costs only them."""
    try:
        if runfile is not None:
            xdmf.write_run(runfile.path, runfile.f)
            xdmf.write_state(out_dir / "checkpoint.h5")
        else:
            xdmf.write_all(out_dir)
    except store.DiskFull as err:
        log(f"fbed: run.xdmf not written: {err}")
    except Exception as err:  # noqa: BLE001 - a viewer's index must never lose the run's outputs
        log(f"fbed: run.xdmf not written ({type(err).__name__}: {err})")


class Checkpoints:
    """checkpoint.h5: the full state of the grains, the gas and the coupler, from which a resumed run continues
    bit for bit; every row of the series up to it is flushed first, and the ParaView indexes rewritten."""

    def __init__(self, out_dir: pathlib.Path, runfile, config_text: str):
        self.out_dir, self.runfile, self.config_text = out_dir, runfile, config_text
        self.parts: dict = {}  # name -> saved(sim): a recorder's own state, written under /parts/<name>

    @staticmethod
    def state(sim) -> tuple[dict | None, dict | None]:
        """(grains, gas) arrays of the simulation: the DEM's, and the gas's with the coupler's under coupling_ and
        the adaptive fluid step's state (pieces, peak, changes: a resumed run splits its steps as the run did)."""
        gas = None
        if sim.flow is not None:
            gas = sim.flow.state_arrays()
            if sim.coupler is not None:
                gas.update({"coupling_" + k: v for k, v in sim.coupler.state_arrays().items()})
            gas[SPLIT_KEY] = np.array([sim.gas_split, sim.gas_split_peak, sim.gas_split_changes], np.int64)
        return (sim.dem.state_arrays() if sim.dem is not None else None, gas)

    def __call__(self, sim) -> dict | None:
        """Write one; returns the grains' arrays it wrote (the run's end writes bed.h5 from them)."""
        sim.flush_diagnostics()  # the rows recorded on the device, through the guard into the series
        self.runfile.flush()  # every row up to the checkpoint is on disk: a resumed run continues the series
        grains, gas = self.state(sim)
        parts = {name: saved(sim) for name, saved in self.parts.items()}
        store.write_checkpoint(self.out_dir / "checkpoint.h5", grains, gas, sim.time, sim.step_count,
                               self.config_text, {k: v for k, v in parts.items() if v})
        write_xdmf(self.out_dir, self.runfile)  # a run killed later still opens in ParaView up to here
        return grains


class WallCheckpoints:
    """Checkpoints on the wall clock: the first after FIRST seconds (a run killed in its first minute leaves
    something to resume, compilation included), then at doubling intervals up to ``longest``
    (output.checkpoint_wall_interval), so a long run pays for a checkpoint every ``longest`` seconds only."""

    FIRST = 30.0  # s
    CHECK = 1.0   # s: how often the clock is looked at (a hook on the wall clock)

    def __init__(self, write, longest: float):
        self.write, self.longest = write, longest
        self.interval = min(self.FIRST, longest)
        self.last = wallclock.perf_counter()

    def __call__(self, sim):
        now = wallclock.perf_counter()
        if now - self.last >= self.interval:
            self.write(sim)
            self.last = wallclock.perf_counter()
            self.interval = min(2 * self.interval, self.longest)


class FinalOutputs:
    """When the run ends finished or interrupted with a good state (the guard checks it): the last series row
    (unless this step had one), snapshot, gas fields and checkpoint, and bed.h5 (output.save_bed, finished
    only); then run.h5 is closed. A full disk here keeps the last good checkpoint: the DiskFull is kept in
    ``disk_full`` for the run to report."""

    def __init__(self, guard, writers: list, series, series_every: int, checkpoints: Checkpoints, save_bed: bool):
        self.guard, self.writers, self.series, self.series_every = guard, writers, series, series_every
        self.checkpoints, self.save_bed = checkpoints, save_bed
        self.disk_full: list = []
        self.unstable = ""  # why the end state failed the guard (the run then ends unstable, not finished)

    def finish(self, sim, reason: str) -> None:
        if reason in ("finished", "interrupted"):
            try:
                self.guard(sim)
            except Unstable as err:  # the last steps went bad: keep the last good files
                reason = "unstable"
                self.unstable = f"{err} (the final state was not written)"
        ck = self.checkpoints
        try:
            if reason in ("finished", "interrupted"):
                if sim.step_count % self.series_every:
                    self.series(sim)
                for write in self.writers:
                    write(sim)
                grains = ck(sim)
                # bed.h5 from the checkpoint's grains, not read again (a million-grain run's end on a CPU: 20.7 ->
                # 19.3 s, RESULTS.md)
                if reason == "finished" and self.save_bed and sim.dem is not None:
                    store.write_checkpoint(ck.out_dir / "bed.h5", grains, None, sim.time, sim.step_count,
                                           ck.config_text)
            else:  # the rows recorded before the error or the guard's stop: the good ones reach the series
                try:
                    sim.flush_diagnostics()
                except Unstable:
                    pass
        except store.DiskFull as err:  # the last good checkpoint stays; nothing half-written is left
            self.disk_full.append(err)
        sim.diagnostics_sinks.clear()  # a later read (the summary's) neither checks nor appends to the closed file
        try:
            ck.runfile.close()
        except store.DiskFull as err:
            self.disk_full.append(err)
