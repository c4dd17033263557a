"""`fbed run`: the output folder, resume, signals, the callbacks attached, exit codes.

The solvers come from ``app.scene.build_simulation``; what a run writes and checks while it steps are the
callbacks of ``app.callbacks``; the config and the output folder, and their rules, are ``app.outputs``, going on
from an earlier state ``app.resume``; how Ctrl-C and SIGTERM stop it ``app.stopping`` (cleanly, with a checkpoint;
a third quits at once). A full disk stops with the last good checkpoint kept. Exit codes: 0 finished, 2 bad
input, 3 stopped by the guard or a full disk, 130 interrupted."""
from __future__ import annotations

import time as wallclock

from . import config as cfgmod, outputs
from .callbacks.bed import BedMeasures
from .callbacks.guard import Guard
from .callbacks.probes import attach_probes
from .callbacks.progress import Progress, announce, cpu_note, log
from .callbacks.summary import Summary
from .callbacks.video import VideoFrames, renderer_for
from .callbacks.writers import (Checkpoints, FinalOutputs, GasFields, GrainSnapshots, Series, WallCheckpoints,
                                open_run_file)
from .io import store
from .outputs import configure, remove_outputs, stop_disk_full
from .resume import prepared_state, restore, resume_free
from .scene import Scene, build_simulation
from .sim import runtime
from .sim.dem import NeighborOverflow
from .sim.simulation import Unstable
from .stopping import EXIT_INTERRUPTED, StopOnSignals, watch_parent

EXIT_OK, EXIT_INPUT, EXIT_UNSTABLE = 0, 2, 3


def run(preset: str | None, overrides: list[str], out: str | None = None, arch: str = "auto",
        resume: str | None = None, overwrite: bool = False, viewer=None) -> int:
    """Run a preset (or resume DIR). ``viewer``: a callable ``viewer(renderer, schedule, out_dir)``
    returning a controller for ``Simulation.run`` (``fbed view``); None runs headless.
    A full disk before the run steps (its first files) stops it too, and after them (the analysis): exit 3."""
    held = outputs.held_folders()  # an outer run's folder (this one prepares its start) stays held
    try:
        return _run(preset, overrides, out, arch, resume, overwrite, viewer)
    except (store.DiskFull, OSError) as err:  # OSError: a full disk in a write outside the store (the analysis)
        if (what := store.disk_full_text(err)) is None:
            raise
        log(f"fbed: {what}; free some space or give another --out")
        return EXIT_UNSTABLE
    finally:
        outputs.release_folders(keep=held)


def _attach(sim, scene, name, out_dir, runfile, config_text, renderer, viewer, resume):
    """The run's callbacks, in the order they fire: guard, series, snapshots, gas fields, probes, video,
    checkpoints (simulated and wall time), progress. Returns (final outputs, series' bed measures, video frames)."""
    cfg, o, dem, flow = scene.cfg, scene.cfg.output, sim.dem, sim.flow
    grains = (dem.masses(), dem.radii()) if dem is not None else (None, None)  # [kg], [m]: the energy floor
    guard = Guard.of(cfg, scene.derived, *grains)
    series = Series(runfile, BedMeasures(scene, flow, dem) if sim.coupler is not None else None)
    writers = [(GrainSnapshots(runfile, dem), o.particles_interval)] if dem is not None else []
    writers += [(GasFields(runfile, flow), cfg.gas.fields_interval)] if flow is not None else []
    checkpoints = Checkpoints(out_dir, runfile, config_text)
    final = FinalOutputs(guard, [w for w, _ in writers], series, sim.every(o.series_interval), checkpoints,
                         o.save_bed)
    guard.attach(sim, cfg.guard.interval)  # every diagnostics row passes the guard before the series gets it
    series.attach(sim, o.series_interval, finish=final.finish)
    for writer, interval in writers:  # interval 0: at the start and the end only
        sim.add(guard.guarded(writer), interval, at_start=True)
    attach_probes(sim, cfg, runfile, out_dir, guard, sim.time if resume else None, log, checkpoints,
                  store.read_parts(out_dir / "checkpoint.h5") if resume else {})
    # the video before the checkpoints: a checkpoint's flush of run.h5 then holds the record of its step's frame
    video = VideoFrames.attach(sim, cfg, renderer, out_dir, runfile, guard, close_renderer=viewer is None)
    if o.checkpoint_interval:
        sim.add(guard.guarded(checkpoints), o.checkpoint_interval)
    if o.checkpoint_wall_interval:  # the clock is looked at every second; the guard runs only before a write
        sim.add(WallCheckpoints(guard.guarded(checkpoints), o.checkpoint_wall_interval), wall=WallCheckpoints.CHECK)
    progress = Progress(sim, name, o.log_interval)
    sim.add(progress, wall=0.25 if progress.tty else o.log_interval, finish=progress.finish)
    return final, series.bed, video


def _step(sim, start, final, out_dir) -> tuple[str, str, float]:
    """Run with Ctrl-C / SIGTERM stopping it (app.stopping), ``start()`` announcing it; (status, message, wall s)."""
    with StopOnSignals(sim, out_dir):
        watch_parent(sim)
        return _stepped(sim, start, final)


def _stepped(sim, start, final) -> tuple[str, str, float]:
    t_start = wallclock.perf_counter()
    status, message = "finished", ""
    try:
        status = sim.run(start())
    except (Unstable, NeighborOverflow) as err:
        status, message = "unstable", str(err)
    except store.DiskFull as err:
        final.disk_full.append(err)
    except store.FolderGone as err:  # nothing more can be written there: summary.json included
        status, message = "folder_gone", str(err)
    if final.unstable:  # the end state failed the guard: it said "done", exit 0, with its final files unwritten
        status, message = "unstable", final.unstable
    if final.disk_full:
        status, message = "disk_full", str(final.disk_full[0])
    return status, message, wallclock.perf_counter() - t_start


def _run(preset, overrides, out, arch, resume, overwrite, viewer) -> int:
    cfg, preset_path, out_dir, name = configure(preset, overrides, out, resume, overwrite)
    used_arch = runtime.init(arch, cfg.run.precision, cfg.run.threads or None)
    arrays = gas_arrays = meta = None
    if resume:
        arrays, gas_arrays, meta = store.read_checkpoint(out_dir / "checkpoint.h5")
    elif cfg.run.start_from:
        arrays, gas_arrays, meta = store.read_checkpoint(prepared_state(cfg, preset_path, arch, run))
    threads = runtime.cpu_threads(cfg.run.threads or None)
    scene = Scene(cfg, str(preset_path), initial=arrays, serial=used_arch == "cpu" and threads == 1)
    if used_arch == "cpu":
        cpu_note(scene, preset_path, int(meta["step"]) if resume else 0, threads)
    if outside := scene.outside_domain():
        log(f"fbed: note: {outside} of the {scene.n} grains lie outside the domain (domain.lo, domain.hi): they are "
            "removed at the first step")
    sim = build_simulation(scene, notify=log, timing=True)  # the grains placed from the checkpoint when resuming
    restore(sim, scene, arrays, gas_arrays, meta, bool(cfg.run.start_from) and not resume, out_dir if resume else None)
    renderer = renderer_for(sim, scene, name, viewer)
    if overwrite and not resume and out_dir.is_dir():
        remove_outputs(out_dir, cfg.video.file)
    out_dir.mkdir(parents=True, exist_ok=True)
    outputs.hold_folder(out_dir, "--out")  # a new folder: held from now on
    config_text = cfgmod.dump(cfg)
    store.write_text(out_dir / "config.toml", config_text)
    runfile = open_run_file(out_dir / "run.h5", name, sim, scene, resume=bool(resume))
    final, bed, video = _attach(sim, scene, name, out_dir, runfile, config_text, renderer, viewer, resume)
    def start():
        announce(sim, scene, name, used_arch, out_dir)
        return viewer(renderer, sim.inlets, out_dir) if viewer is not None else None

    status, message, wall = _step(sim, start, final, out_dir)
    if status == "folder_gone":
        log(f"fbed: stopped at t = {sim.time:.6g} s: {message}; run it again (a folder that was moved holds the "
            "run up to its last checkpoint: resume it there)")
        return EXIT_UNSTABLE
    summary = Summary(scene, name, used_arch, out_dir, int(meta["step"]) if meta else 0, renderer, video, bed)
    figures = summary.figures(sim, status, message, wall)
    figures.update(final.guard.stop_times() if status == "unstable" else {})  # when it went wrong, not where it got
    if status == "disk_full":
        return stop_disk_full(out_dir, figures, final.disk_full[0])
    summary.write(figures, analyze=status in ("finished", "interrupted"))
    return _exit(sim, status, message, wall, out_dir, figures.get("grains_removed", 0))


def _exit(sim, status, message, wall, out_dir, removed: int) -> int:
    if status == "unstable":
        log(f"fbed: stopped at t = {sim.time:.6g} s: {message}")
        kept = (out_dir / "checkpoint.h5").exists()
        log(f"fbed: outputs kept in {out_dir}" + (" (last good checkpoint: checkpoint.h5); go on from it with the "
                                                  f"knob turned: fbed run --resume {out_dir} --set KEY=VALUE, for "
                                                  f"a KEY a resume may change ({resume_free()}); others need a new "
                                                  "run" if kept else ""))
        return EXIT_UNSTABLE
    if status == "interrupted":
        log(f"fbed: stopped by {sim.stop_requested} at t = {sim.time:.6g} s; checkpoint written.\n"
            f"      resume with: fbed run --resume {out_dir}")
        return EXIT_INTERRUPTED
    gone = f"; {removed} grain{'s' * (removed != 1)} left the domain and were removed" if removed else ""
    log(f"fbed: done: t = {sim.time:g} s in {wall:.1f} s wall{gone}; outputs in {out_dir}")
    return EXIT_OK
