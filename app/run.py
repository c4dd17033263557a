"""`fbed run`: build a scene, attach writers, progress, checkpoints and the guard, run it.

Owns: the output folder (config.toml, run.h5, checkpoint.h5, bed.h5, summary.json), the
resume logic, and signal handling (Ctrl-C / SIGTERM stop cleanly with a checkpoint).
Exit codes: 0 finished, 2 bad input, 3 stopped by the guard, 130 interrupted.
"""
from __future__ import annotations

import dataclasses
import pathlib
import signal
import sys
import time as wallclock

import numpy as np

from . import config as cfgmod
from .config import ConfigError
from .io import store
from .schedule import InletSchedule

STANDARD_GRAVITY = 9.80665  # [m/s^2]: the guard's energy floor is set in standard g, whatever the scene's gravity

EXIT_OK, EXIT_INPUT, EXIT_UNSTABLE, EXIT_INTERRUPTED = 0, 2, 3, 130


class BedMeasures:
    """Bed-scale figures of a coupled run: pressure drop across the domain (gas hydrostatics removed),
    bed weight per area, and their time means."""

    def __init__(self, scene, flow, dem=None):
        self.flow = flow
        self.dem = dem
        g = scene.cfg.gas
        gz = abs(scene.cfg.domain.gravity[2])
        height = scene.flow.shape[2] * g.cell_size
        self.hydro = g.density * gz * height
        # open cross-section: the bottom layer's open volume fractions (the pressure drop's weights too)
        self.area = float(flow.fields.vol_frac.to_numpy()[:, :, 0].sum()) * g.cell_size ** 2
        self.weight_factor = gz * (1.0 - g.density / scene.cfg.particles.density)  # buoyant weight per kg
        radius = scene.initial["radius"]
        self._initial_mass = float(np.sum(scene.cfg.particles.density * 4.0 / 3.0 * np.pi * radius ** 3))

    @property
    def weight_per_area(self) -> float:
        """Buoyant weight of the grains still in the domain over the open cross-section [Pa]."""
        mass = self._initial_mass
        if self.dem is not None:
            mass = float(np.sum(self.dem.masses() * self.dem.state.alive.to_numpy()))
        return mass * self.weight_factor / self.area if self.area > 0 else float("nan")

    def pressure_drop(self) -> float:
        """Pressure at the bottom face of the domain minus the top face [Pa], gas weight removed: the
        open-area means of the first two (last two) cell layers, extrapolated half a cell to the face,
        so the grains in the lowest half cell count too."""
        p0, p1, p_second_last, p_last = self.flow.end_layer_pressures()  # reduced on the device
        pb = 1.5 * p0 - 0.5 * p1
        pt = 1.5 * p_last - 0.5 * p_second_last
        return pb - pt - self.hydro

    def summary(self, runfile, cfg) -> dict:
        series = store.read_series(runfile)
        t = series["time"]
        t0 = cfg.output.average_from if cfg.output.average_from >= 0 else 0.5 * t[-1]
        sel = t >= t0 - 1e-12
        wpa = self.weight_per_area
        out = {"bed_weight_per_area": wpa, "average_from": float(t0)}
        if sel.any():
            dp = float(np.nanmean(series["pressure_drop"][sel]))
            out.update(mean_pressure_drop=dp, mean_bed_height=float(np.nanmean(series["bed_height"][sel])),
                       pressure_drop_over_weight=dp / wpa)
        return out


def prepared_state(cfg, preset_path: pathlib.Path, arch: str, chain: tuple = ()) -> pathlib.Path:
    """The checkpoint of ``run.start_from``'s preparation preset: reused from the cache
    (runs/prepared/<name>-<hash of its resolved config>/) when it holds a finished run,
    else run there now. The hash covers the preparation's own chain, so editing any stage
    reruns it and everything after it."""
    import hashlib

    prep = cfgmod.resolve_path(cfg, cfg.run.start_from)
    if not prep.exists():
        raise ConfigError("preparation preset not found", str(prep), "run.start_from",
                          hint=f"a path relative to {preset_path.name}'s folder")
    if prep.resolve() in chain:
        raise ConfigError("run.start_from chain loops back on itself", str(prep), "run.start_from")
    prep_cfg = cfgmod.load(prep, [])
    text = cfgmod.dump(prep_cfg)
    if prep_cfg.run.start_from:  # its own preparation's identity is part of its identity
        text += str(prepared_state(prep_cfg, prep, arch, chain + (prep.resolve(),)))
    key = hashlib.sha1(text.encode()).hexdigest()[:10]
    cache = pathlib.Path("runs") / "prepared" / f"{prep.stem}-{key}"
    summary = cache / "summary.json"
    if summary.exists() and (cache / "checkpoint.h5").exists():
        import json

        if json.loads(summary.read_text()).get("status") == "finished":
            log(f"fbed: starting from the prepared state in {cache} ({prep.name}, reused)")
            return cache / "checkpoint.h5"
    log(f"fbed: preparing {prep.name} first (cached in {cache} for later runs)")
    rc = run(str(prep), [], out=str(cache), arch=arch, overwrite=True)
    if rc != EXIT_OK:
        raise ConfigError(f"the preparation run did not finish (exit {rc}); see {cache}", str(prep), "run.start_from")
    return cache / "checkpoint.h5"


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def pick_out_dir(preset: pathlib.Path, out: str | None, overwrite: bool) -> pathlib.Path:
    if out:
        d = pathlib.Path(out)
        if d.exists() and any(d.iterdir()) and (d / "run.h5").exists() and not overwrite:
            raise ConfigError("already holds a run", str(d), "--out",
                              hint="pass --overwrite to replace it, --resume to continue it, or another --out")
        return d
    base = pathlib.Path("runs") / preset.stem
    d, k = base, 1
    while d.exists() and any(d.iterdir()):
        k += 1
        d = base.with_name(f"{base.name}-{k}")
    return d


class Progress:
    """A rich progress bar on a terminal, a log line every few seconds otherwise."""

    def __init__(self, sim, name: str, log_interval: float):
        self.sim = sim
        self.tty = sys.stderr.isatty()
        self.bar = None
        self.t0 = wallclock.perf_counter()
        self.step0 = sim.step_count
        self.interval = log_interval
        if self.tty:
            from rich.progress import BarColumn, Progress as RichProgress, TextColumn, TimeRemainingColumn

            self.bar = RichProgress(TextColumn(f"[bold]{name}"), BarColumn(),
                                    TextColumn("{task.fields[simt]}"), TextColumn("{task.fields[rate]}"),
                                    TimeRemainingColumn(), transient=False)
            self.task = self.bar.add_task(name, total=sim.total_steps, completed=sim.step_count, simt="", rate="")
            self.bar.start()

    def text(self):
        s = self.sim
        dt = max(wallclock.perf_counter() - self.t0, 1e-9)
        rate = (s.step_count - self.step0) / dt
        eta = (s.total_steps - s.step_count) / rate if rate > 0 else float("inf")
        return s, rate, eta

    def __call__(self, sim):
        s, rate, eta = self.text()
        if self.bar:
            self.bar.update(self.task, completed=s.step_count, simt=f"t = {s.time:.4g}/{s.duration:g} s",
                            rate=f"{rate:.1f} steps/s")
        else:
            # log lines are what a long headless (GPU) run leaves: with gas, where its fastest cell is, so a run
            # that later blows up, or carries a wall channel, shows where its gas was racing (one device read
            # per line, every output.log_interval of wall time)
            gas = ""
            if s.flow is not None:
                gas = f"  gas max {s.diagnostics()['gas_max_speed']:.3g} m/s{s.gas_fastest_cell()}"
            log(f"t = {s.time:.5g}/{s.duration:g} s  step {s.step_count}/{s.total_steps}  {rate:.2f} steps/s  "
                f"ETA {eta:.0f} s{gas}")

    def finish(self, sim, reason):
        if self.bar:
            self(sim)
            self.bar.stop()


def restore_gas(flow, coupler, gas_arrays: dict) -> None:
    """Load a checkpoint's gas group: the gas solver's arrays and, under the coupling_ prefix, the coupler's."""
    flow.load_state_arrays(gas_arrays)
    if coupler is not None:
        coupler.load_state_arrays({k[len("coupling_"):]: v for k, v in gas_arrays.items()
                                   if k.startswith("coupling_")})


def load_prepared(cfg, sim, dem, flow, coupler, arrays, gas_arrays, meta) -> None:
    """Start from a prepared state: its grains (full contact state when the models match),
    its gas (when it has one) and its clock."""
    t = float(meta["time"])
    steps = t / cfg.run.step
    if abs(steps - round(steps)) > 1e-6:
        raise ConfigError(f"the prepared state's time {t:g} s is not a whole number of steps of {cfg.run.step:g} s",
                          cfg.source or "", "run.step", hint="use the preparation preset's run.step")
    if dem is not None and arrays is not None:
        try:
            dem.load_state_arrays(arrays)
        except (KeyError, ValueError):  # other contact model: positions and velocities carry over, history restarts
            dem.set_grains(arrays["position"], arrays["velocity"], arrays["radius"], None, arrays.get("alive"))
    if flow is not None and gas_arrays is not None:
        restore_gas(flow, coupler, gas_arrays)
    sim.step_count = int(round(steps))
    if sim.step_count >= sim.total_steps:
        raise ConfigError(f"the prepared state is at t = {t:g} s, past run.duration = {cfg.run.duration:g} s",
                          cfg.source or "", "run.duration", hint="run.duration is the end time: raise it")


def post_process(analysis: str, out_dir: pathlib.Path) -> dict:
    """Run the preset's analysis on the finished run's files; its key figures go into summary.json."""
    import importlib

    try:
        mod = importlib.import_module(f".analysis.{analysis}", __package__)
        figures = mod.summarize(out_dir)
        log(f"fbed: {analysis} analysis written to {out_dir / 'analysis'}")
        return figures
    except Exception as err:  # noqa: BLE001 - an analysis failure must not lose the run's outputs
        log(f"fbed: the {analysis} analysis failed ({type(err).__name__}: {err}); rerun it with "
            f"`fbed analyze {out_dir}`")
        return {"analysis_error": f"{type(err).__name__}: {err}"}


def analyze(run_dir: str, kind: str | None = None) -> int:
    """`fbed analyze RUN_DIR`: the run's analysis (probes.analysis, or ``kind``) into RUN_DIR/analysis."""
    import json

    d = pathlib.Path(run_dir)
    if (d / "sweep.csv").exists() and not (d / "run.h5").exists():
        return analyze_sweep(d, kind)
    if not (d / "run.h5").exists() or not (d / "config.toml").exists():
        raise ConfigError("not a run folder (no run.h5 / config.toml)", str(d), "RUN_DIR",
                          hint="give the output folder of an fbed run")
    cfg = cfgmod.load(d / "config.toml")
    kind = kind or cfg.probes.analysis
    if kind == "none":
        raise ConfigError("the run names no analysis", str(d / "config.toml"), "probes.analysis",
                          hint="pass --kind boyce or --kind verma")
    figures = post_process(kind, d)
    summary_path = d / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    summary.update(figures)
    store.write_json(summary_path, summary)
    for k, v in figures.items():
        print(f"{k} = {v:.6g}" if isinstance(v, float) else f"{k} = {v}")
    return EXIT_OK if "analysis_error" not in figures else EXIT_INPUT


def analyze_sweep(d: pathlib.Path, kind: str | None = None) -> int:
    """`fbed analyze SWEEP_DIR`: each case's analysis where it is missing, then the cases side by side
    (SWEEP_DIR/mri_compare.{csv,md,png} or umf_compare.{md,png})."""
    import csv

    with open(d / "sweep.csv", newline="") as f:
        cases = [r["case"] for r in csv.DictReader(f)]
    kinds = set()
    for c in cases:
        cd = d / c
        if (cd / "config.toml").exists():
            kinds.add(kind or cfgmod.load(cd / "config.toml").probes.analysis)
    if len(kinds) != 1 or next(iter(kinds)) not in ("mri", "umf"):
        raise ConfigError(f"side-by-side comparison is written for the mri and umf analyses, not {sorted(kinds)}",
                          str(d), "probes.analysis", hint="analyze each case folder on its own: fbed analyze DIR/case-000")
    which = next(iter(kinds))
    for c in cases:
        cd = d / c
        if (cd / "run.h5").exists() and not (cd / "analysis" / f"{which}.json").exists():
            analyze(str(cd), which)
    import importlib

    print(importlib.import_module(f".analysis.{which}", __package__).compare(d).read_text())
    return EXIT_OK


def make_renderer(cfg, scene, dem, flow, name: str, show_window: bool = False):
    """The GGUI renderer for this scene, or a clear error when no Vulkan device is present."""
    try:
        from .gui.render import Renderer, ViewSettings

        return Renderer(dem, flow, scene.walls, cfg.domain.lo, cfg.domain.hi, ViewSettings.from_config(cfg.video),
                        title=name, show_window=show_window)
    except RuntimeError as err:
        raise ConfigError(f"the renderer could not start: {str(err).splitlines()[0] if str(err) else err}",
                          "", "--video", hint="it needs a Vulkan driver (a GPU driver, or Debian's "
                          "mesa-vulkan-drivers on the CPU); run without --video / video.enabled") from None


def run(preset: str | None, overrides: list[str], out: str | None = None, arch: str = "auto",
        resume: str | None = None, overwrite: bool = False, viewer=None) -> int:
    """Run a preset (or resume DIR). ``viewer``: a callable ``viewer(renderer, schedule)``
    returning a controller for ``Simulation.run`` (``fbed view``); None runs headless."""
    # -- configuration (errors here lose nothing: no output written yet)
    if resume:
        out_dir = pathlib.Path(resume)
        ckpt = out_dir / "checkpoint.h5"
        if not ckpt.exists():
            raise ConfigError("no checkpoint.h5 to resume from", str(out_dir), "--resume",
                              hint="give the output folder of an earlier run that was stopped or finished")
        base = pathlib.Path(preset) if preset else out_dir / "config.toml"
        cfg = cfgmod.load(base, overrides)
        preset_path = base
    else:
        if not preset:
            raise ConfigError("no preset given", "", "PRESET", hint="fbed run presets/settle.toml")
        preset_path = pathlib.Path(preset)
        cfg = cfgmod.load(preset_path, overrides)
        out_dir = pick_out_dir(preset_path, out, overwrite)
    name = cfg.run.name or preset_path.stem
    if resume and preset_path.name == "config.toml":
        name = cfg.run.name or out_dir.name

    from .sim import runtime

    used_arch = runtime.init(arch, cfg.run.precision, cfg.run.threads or None)
    from .scene import Scene
    from .sim.dem import DemSolver, NeighborOverflow
    from .sim.fields import bytes_per_grain
    from .sim.simulation import Guard, Simulation, Unstable

    arrays = gas_arrays = meta = None
    prepared = False
    if resume:
        arrays, gas_arrays, meta = store.read_checkpoint(ckpt)
    elif cfg.run.start_from:
        arrays, gas_arrays, meta = store.read_checkpoint(prepared_state(cfg, preset_path, arch))
        prepared = True
    serial = used_arch == "cpu" and runtime.cpu_threads(cfg.run.threads or None) == 1
    scene = Scene(cfg, str(preset_path), initial=arrays, serial=serial)
    der = scene.derived
    dem = DemSolver(scene.model) if scene.model is not None else None
    flow = None
    if scene.flow is not None:
        from .sim.flow import FlowSolver

        try:
            flow = FlowSolver(scene.flow)
        except ValueError as err:
            raise ConfigError(str(err), str(preset_path), "gas", hint="check [gas] and [boundary]") from None
    coupler = None
    if dem is not None and flow is not None:
        from .sim.coupling import Coupler

        coupler = Coupler(scene.coupling, dem, flow)
    sim = Simulation(dem, cfg.run.step, der.substeps if der else 0, cfg.run.duration, flow=flow, coupler=coupler)
    sim.timing = True  # the split of the wall time per phase, sampled (see Simulation._lap)
    if flow is not None:
        sim.max_gas_cfl, sim.max_gas_split, sim.notify = cfg.gas.max_cfl, cfg.gas.max_split, log
    if prepared:
        load_prepared(cfg, sim, dem, flow, coupler, arrays, gas_arrays, meta)
        sim.fresh = True
    if resume:
        if dem is not None and (arrays is None or len(arrays["position"]) != scene.n):
            raise ConfigError("the checkpoint does not hold this preset's grains", str(ckpt), "--resume",
                              hint="resume with the run's own config.toml")
        if dem is not None:
            dem.load_state_arrays(arrays)
        if flow is not None:
            if gas_arrays is None:
                raise ConfigError("the checkpoint holds no gas state", str(ckpt), "--resume",
                                  hint="resume with the run's own config.toml")
            restore_gas(flow, coupler, gas_arrays)
        sim.step_count = int(meta["step"])
        if sim.step_count >= sim.total_steps:
            log(f"{out_dir}: already at t = {sim.time:g} s >= run.duration; extend it with --set run.duration=...")
    schedule = None
    if flow is not None:
        try:
            schedule = InletSchedule(cfg.boundary, scene.flow.shape, scene.flow.h, scene.flow.origin)
        except ValueError as err:
            raise ConfigError(str(err), str(preset_path), "boundary") from None
        if schedule.faces:
            sim.before_step.append(schedule)
    renderer = None
    if viewer is not None and dem is None:
        raise ConfigError("the viewer draws grains: this scene has none", str(preset_path), "particles")
    if dem is not None and (cfg.video.enabled or viewer is not None):
        renderer = make_renderer(cfg, scene, dem, flow, name,
                                 show_window=viewer is not None and getattr(viewer, "show_window", True))
    if not resume and not prepared and dem is not None:
        init = scene.initial
        dem.set_grains(init["position"], init.get("velocity"), init["radius"], init.get("omega"))

    out_dir.mkdir(parents=True, exist_ok=True)
    config_text = cfgmod.dump(cfg)
    (out_dir / "config.toml").write_text(config_text)
    runfile = store.RunFile(out_dir / "run.h5", name, resume_time=sim.time if resume else None)
    o = cfg.output
    dem_series = ("kinetic_energy", "kinetic_energy_rotational", "max_overlap", "max_speed", "grains_alive",
                  "grains_removed", "bed_height")
    gas_series = ("gas_max_speed", "gas_cfl", "pressure_iterations", "pressure_residual", "divergence_residual",
                  "clipped_cells", "pressure_drop")
    bed = BedMeasures(scene, flow, dem) if coupler is not None else None

    def record(s):
        d = s.diagnostics()
        if bed is not None:
            d["pressure_drop"] = bed.pressure_drop()
        row = {"time": s.time}
        row.update({k: d[k] for k in dem_series + gas_series if k in d})
        row["wall_time"] = s.wall_elapsed
        runfile.append(row)

    last_snapshot = {"grains": -1, "gas": -1}

    def snapshot(s):
        if dem is not None and last_snapshot["grains"] != s.step_count:
            runfile.snapshot(s.time, dem.state.x.to_numpy(), dem.state.v.to_numpy(), dem.radii())
            last_snapshot["grains"] = s.step_count

    def gas_fields(s):
        if flow is not None and last_snapshot["gas"] != s.step_count:
            runfile.gas_fields(s.time, flow.cell_velocity(), flow.pressure(), flow.fields.eps.to_numpy())
            last_snapshot["gas"] = s.step_count

    def state_of(s):
        gas = None
        if flow is not None:
            gas = flow.state_arrays()
            if coupler is not None:
                gas.update({"coupling_" + k: v for k, v in coupler.state_arrays().items()})
        return (dem.state_arrays() if dem is not None else None, gas)

    def checkpoint(s, path=out_dir / "checkpoint.h5"):
        runfile.flush()  # every row up to the checkpoint is on disk: a resumed run continues the series
        grains, gas = state_of(s)
        store.write_checkpoint(path, grains, gas, s.time, s.step_count, config_text)

    energy_floor = 0.0
    if dem is not None:  # every grain at sqrt(g d), the speed of a fall through one diameter (standard g)
        energy_floor = 0.5 * float(np.sum(dem.masses())) * STANDARD_GRAVITY * 2.0 * der.radius_min
    guard = Guard(cfg.guard.max_overlap, cfg.guard.max_speed, der.dt if der else 0.0,
                  der.dt_limit if der else float("inf"), cfg.guard.max_gas_speed,
                  cfg.guard.max_divergence, cfg.guard.max_energy_growth, energy_floor, cfg.guard.interval)

    def guarded(fn):
        """Writers check the guard first, so nothing non-finite ever reaches a file."""
        def write(s):
            guard(s)
            fn(s)
        return write

    def finish_outputs(s, reason):
        if reason in ("finished", "interrupted"):
            try:
                guard(s)
            except Unstable as err:  # the last steps went bad: keep the last good files
                reason = "unstable"
                log(f"fbed: final state not written: {err}")
        if reason in ("finished", "interrupted"):
            if s.step_count % s.every(o.series_interval):
                record(s)
            snapshot(s)
            gas_fields(s)
            checkpoint(s)
            if reason == "finished" and o.save_bed and dem is not None:
                store.write_checkpoint(out_dir / "bed.h5", dem.state_arrays(), None, s.time, s.step_count,
                                       config_text)
        runfile.close()

    sim.add(guard, cfg.guard.interval, at_start=True)
    sim.add(guarded(record), o.series_interval, at_start=True, finish=finish_outputs)
    if dem is not None:
        sim.add(guarded(snapshot), o.particles_interval, at_start=True) if o.particles_interval else \
            sim.add(guarded(snapshot), at_start=True)
    if flow is not None:
        sim.add(guarded(gas_fields), cfg.gas.fields_interval, at_start=True) if cfg.gas.fields_interval else \
            sim.add(guarded(gas_fields), at_start=True)
    pr = cfg.probes
    if flow is not None and (pr.slab_interval or pr.planes_interval or pr.volume_interval or pr.mri_interval):
        from .probes import Probes

        Probes(cfg, flow, flow.fields.active.to_numpy()).attach(sim, runfile, guarded)
    if coupler is not None and pr.rcfd_from >= 0:
        from .rcfd_probe import RcfdRecorder

        v = cfg.vessel
        axis = v.center if v.shape == "cylinder" else tuple(0.5 * (a + b) for a, b in zip(cfg.domain.lo[:2],
                                                                                         cfg.domain.hi[:2]))
        RcfdRecorder(cfg, axis).attach(sim, out_dir, guarded, sim.time if resume else None, log)
    if o.checkpoint_interval:
        sim.add(guarded(checkpoint), o.checkpoint_interval)
    if o.checkpoint_wall_interval:
        sim.add(guarded(checkpoint), wall=o.checkpoint_wall_interval)
    writer = None
    if renderer is not None and cfg.video.enabled:
        from .gui.video import VideoWriter

        writer = VideoWriter(out_dir / (cfg.video.file or "video.mp4"), cfg.video.fps, notify=log)

        def video_frame(s):
            writer.write(renderer.frame(s.time))

        def video_close(s, reason):
            writer.close()
            if viewer is None:
                renderer.close()

        # with gas, the first frame waits for the first step: before it no void fraction is deposited
        sim.add(guarded(video_frame), cfg.video.interval, at_start=flow is None, finish=video_close)
    progress = Progress(sim, name, o.log_interval)
    sim.add(progress, wall=0.25 if progress.tty else o.log_interval, finish=progress.finish)

    def on_signal(signum, frame):
        if sim.stop_requested:  # second signal: stop hard
            raise KeyboardInterrupt
        sim.stop_requested = signal.Signals(signum).name

    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    what = []
    if dem is not None:
        what.append(f"{scene.n} grains, DEM step {der.dt:.3g} s x {der.substeps} per {cfg.run.step:g} s step")
    if flow is not None:
        what.append(f"gas on {'x'.join(map(str, scene.flow.shape))} cells of {cfg.gas.cell_size:g} m, "
                    f"fluid step {cfg.run.step:g} s")
    log(f"fbed: {name}: {'; '.join(what)}; {used_arch}, {cfg.run.precision}; output in {out_dir}")
    t_start = wallclock.perf_counter()
    status, message = "finished", ""
    try:
        reason = sim.run(viewer(renderer, schedule, out_dir) if viewer is not None else None)
        status = reason
    except Unstable as err:
        status, message = "unstable", str(err)
    except NeighborOverflow as err:
        status, message = "unstable", str(err)
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
    wall = wallclock.perf_counter() - t_start
    d = sim.diagnostics() if status != "unstable" else {}
    steps_here = max(1, sim.step_count - int(meta["step"] if meta else 0))
    summary = {
        "preset": name, "status": status, "message": message, "arch": used_arch, "precision": cfg.run.precision,
        "time": sim.time, "steps": sim.step_count, "duration": cfg.run.duration, "wall_time": wall,
        "steps_per_s": steps_here / max(sim.wall_elapsed, 1e-9),
    }
    if dem is not None:
        summary.update({
            "grains": scene.n, "dem_dt": der.dt, "substeps_per_step": der.substeps,
            "collision_time": der.collision_time, "rayleigh_time": der.rayleigh_time,
            "neighbor_slots": scene.model.slots,
            "bytes_per_grain": bytes_per_grain(scene.model, 8 if cfg.run.precision == "float64" else 4),
            "particle_substeps_per_s": scene.n * der.substeps * steps_here / max(sim.wall_elapsed, 1e-9),
            "neighbor_rebuilds": dem.nlist.builds})
    if flow is not None:
        summary.update({"gas_cells": list(scene.flow.shape), "gas_cell_size": cfg.gas.cell_size,
                        "gas_split_peak": sim.gas_split_peak, "gas_split_changes": sim.gas_split_changes})
    split = sim.wall_split()  # coupling, gas and DEM sampled on every 25th step; callbacks on all
    if split:
        total = sum(split.values())
        summary["wall_split"] = {k: round(v, 3) for k, v in split.items()}
        summary["wall_split_share"] = {k: round(v / total, 4) for k, v in split.items()}
    if renderer is not None:
        summary.update({"frames": renderer.frames, "render_time": renderer.render_seconds,
                        "render_share": renderer.render_seconds / max(wall, 1e-9)})
        if writer is not None:
            summary.update({"video": str(writer.path), "video_encoder": writer.encoder})
    if bed is not None:  # also for a guard stop: `fbed analyze` of its data needs the bed weight
        summary.update(bed.summary(out_dir / "run.h5", cfg))
    summary.update({k: d[k] for k in dem_series + gas_series if k in d})
    if status == "unstable" and (out_dir / "checkpoint.h5").exists():
        summary["last_good_checkpoint"] = str(out_dir / "checkpoint.h5")
    store.write_json(out_dir / "summary.json", summary)
    if cfg.probes.analysis != "none" and status in ("finished", "interrupted"):
        summary.update(post_process(cfg.probes.analysis, out_dir))  # it reads the summary written above
        store.write_json(out_dir / "summary.json", summary)
    units = {"time": "s", "wall_time": "s", "dem_dt": "s", "collision_time": "s", "rayleigh_time": "s",
             "bed_height": "m", "kinetic_energy": "J", "particle_substeps_per_s": "1/s", "bytes_per_grain": "B",
             "gas_cell_size": "m", "gas_max_speed": "m/s", "steps_per_s": "1/s", "bed_weight_per_area": "Pa",
             "mean_pressure_drop": "Pa", "mean_bed_height": "m", "pressure_drop_over_weight": "1", "average_from": "s",
             "render_time": "s", "render_share": "1"}
    store.write_json(out_dir / "summary_units.json", units)
    if status == "unstable":
        log(f"fbed: stopped at t = {sim.time:.6g} s: {message}")
        log(f"fbed: outputs kept in {out_dir}" + (" (last good checkpoint: checkpoint.h5)"
                                                  if (out_dir / 'checkpoint.h5').exists() else ""))
        return EXIT_UNSTABLE
    if status == "interrupted":
        log(f"fbed: stopped by {sim.stop_requested} at t = {sim.time:.6g} s; checkpoint written.\n"
            f"      resume with: fbed run --resume {out_dir}")
        return EXIT_INTERRUPTED
    log(f"fbed: done: t = {sim.time:g} s in {wall:.1f} s wall; outputs in {out_dir}")
    return EXIT_OK
