"""`fbed run`: build a scene, attach writers, progress, checkpoints and the guard, run it.

Owns: the output folder (config.toml, run.h5, checkpoint.h5, bed.h5, summary.json, the .xdmf indexes),
its protection (RUN_OUTPUTS), the resume logic and its checks (same scene, readable files), signal
handling (Ctrl-C / SIGTERM stop cleanly with a checkpoint; a second one waits for it) and the stop on
a full disk (store.DiskFull: exit 3, the last good checkpoint kept).
Exit codes: 0 finished, 2 bad input, 3 stopped by the guard or a full disk, 130 interrupted.
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
            mass = float(np.sum(self.dem.masses() * self.dem.read("alive")))
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
    # one process prepares at a time (sweep cases start together): the others wait for it, then reuse its result
    import fcntl

    locks = cache.parent / ".locks"
    locks.mkdir(parents=True, exist_ok=True)
    with open(locks / (cache.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return _prepare(prep, cache, arch)


def _prepare(prep: pathlib.Path, cache: pathlib.Path, arch: str) -> pathlib.Path:
    summary = cache / "summary.json"
    status = None  # of the cached preparation: None when there is none to go on from
    if (cache / "checkpoint.h5").exists() and (cache / "config.toml").exists():
        import json

        try:  # no summary: the preparation was killed after a checkpoint
            status = json.loads(summary.read_text()).get("status") if summary.exists() else "killed"
        except ValueError:
            status = "killed"
    if status == "finished":
        log(f"fbed: starting from the prepared state in {cache} ({prep.name}, reused)")
        return cache / "checkpoint.h5"
    if status in ("interrupted", "killed"):  # a stopped preparation goes on from its checkpoint
        log(f"fbed: resuming the preparation {prep.name} in {cache} (it was {status})")
        rc = run(None, [], arch=arch, resume=str(cache))
    else:
        log(f"fbed: preparing {prep.name} first (cached in {cache} for later runs)")
        rc = run(str(prep), [], out=str(cache), arch=arch, overwrite=True)
    if rc != EXIT_OK:
        raise ConfigError(f"the preparation run did not finish (exit {rc}); see {cache}", str(prep), "run.start_from")
    return cache / "checkpoint.h5"


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# every file and folder `fbed run` writes into its output folder (the video under its configured name too):
# a folder holding any of them holds a run; --overwrite removes exactly these before the new run writes
RUN_OUTPUTS = ("run.h5", "run.xdmf", "particles.xdmf", "checkpoint.h5", "checkpoint.xdmf", "bed.h5", "bed.xdmf",
               "config.toml", "summary.json", "summary_units.json", "video.mp4", "analysis")
RUN_OUTPUT_PATTERNS = ("*.tmp", "screenshot-*.png")


def run_outputs(d: pathlib.Path, video_file: str = "") -> list[pathlib.Path]:
    """The fbed outputs present in folder ``d``."""
    names = set(RUN_OUTPUTS) | ({video_file} if video_file else set())
    found = [d / n for n in sorted(names) if (d / n).exists()]
    for pat in RUN_OUTPUT_PATTERNS:
        found += sorted(p for p in d.glob(pat) if p not in found)
    return found


def pick_out_dir(preset: pathlib.Path, out: str | None, overwrite: bool, video_file: str = "") -> pathlib.Path:
    if out:
        d = pathlib.Path(out)
        if d.exists() and not d.is_dir():
            raise ConfigError("is a file, not a folder", str(d), "--out", hint="name a folder (new or holding a run)")
        if d.exists():
            held = run_outputs(d, video_file)
            if held and not overwrite:
                raise ConfigError(f"already holds a run ({', '.join(p.name for p in held[:4])}"
                                  f"{', ...' if len(held) > 4 else ''})", str(d), "--out",
                                  hint="pass --overwrite to replace it, --resume to continue it, or another --out")
        return d
    base = pathlib.Path("runs") / preset.stem
    d, k = base, 1
    while d.exists() and any(d.iterdir()):
        k += 1
        d = base.with_name(f"{base.name}-{k}")
    return d


def remove_outputs(d: pathlib.Path, video_file: str = "") -> None:
    """--overwrite: the old run's files go before the new run writes, so none of them is left beside it."""
    import shutil

    for p in run_outputs(d, video_file):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink()


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _fastest_cell(text: str) -> str:
    """The short form of Simulation.gas_fastest_cell's description: cell, open volume and gas fraction."""
    import re

    m = re.search(r"cell \(([^)]*)\).*open volume fraction ([\d.]+), gas fraction ([\d.]+)", text)
    return f" in {m.group(1).replace(' ', '')} open {m.group(2)} eps {m.group(3)}" if m else ""


class Progress:
    """A rich progress bar on a terminal, a log line every few seconds otherwise (under 100 characters).

    The first step compiles the kernels: its wall time is not counted in the rate, and the ETA is shown only
    once ETA_AFTER seconds of stepping after it have been measured (before that it would be hours off)."""

    ETA_AFTER = 10.0  # s of wall time after the first step

    def __init__(self, sim, name: str, log_interval: float):
        self.sim = sim
        self.tty = sys.stderr.isatty()
        self.bar = None
        self.t0 = wallclock.perf_counter()
        self.step0 = sim.step_count
        self.first = None  # (wall clock, step) when the first step (the compilation) was done
        self.interval = log_interval
        if self.tty:
            from rich.progress import BarColumn, Progress as RichProgress, TextColumn

            self.bar = RichProgress(TextColumn(f"[bold]{name}"), BarColumn(),
                                    TextColumn("{task.fields[simt]}"), TextColumn("{task.fields[rate]}"),
                                    TextColumn("{task.fields[eta]}"), transient=False)
            self.task = self.bar.add_task(name, total=sim.total_steps, completed=sim.step_count, simt="",
                                          rate="compiling kernels", eta="")
            self.bar.start()

    def text(self):
        s = self.sim
        now = wallclock.perf_counter()
        if self.first is None and s.step_count > self.step0:
            self.first = (now, s.step_count)
            if not self.tty:
                log(f"fbed: kernels ready after {now - self.t0:.0f} s")
        if self.first is None:
            return s, 0.0, None
        dt = now - self.first[0]
        rate = (s.step_count - self.first[1]) / dt if dt > 0 else 0.0
        eta = (s.total_steps - s.step_count) / rate if rate > 0 and dt >= self.ETA_AFTER else None
        return s, rate, eta

    def __call__(self, sim):
        s, rate, eta = self.text()
        if self.bar:
            self.bar.update(self.task, completed=s.step_count, simt=f"t = {s.time:.4g}/{s.duration:g} s",
                            rate=f"{rate:.1f} steps/s" if self.first else "compiling kernels",
                            eta=f"ETA {_duration(eta)}" if eta is not None else "")
        elif self.first is not None:
            # log lines are what a long headless (GPU) run leaves: with gas, where its fastest cell is, so a run
            # that later blows up, or carries a wall channel, shows where its gas was racing (one device read
            # per line, every output.log_interval of wall time)
            gas = ""
            if s.flow is not None:
                gas = f"  gas {s.diagnostics()['gas_max_speed']:.3g} m/s{_fastest_cell(s.gas_fastest_cell())}"
            eta_text = f"ETA {_duration(eta)}" if eta is not None else "ETA ..."
            rate_text = f"{rate:.3g} st/s" if rate > 0 else "... st/s"
            log(f"t {s.time:.4g}/{s.duration:g} s  step {s.step_count}/{s.total_steps}  {rate_text}  "
                f"{eta_text}{gas}")

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


def load_prepared(cfg, sim, flow, coupler, gas_arrays, meta) -> None:
    """Start from a prepared state: its gas (when it has one) and its clock (its grains, with their full contact
    state when the models match, were placed by build_simulation from the Scene's initial grains)."""
    t = float(meta["time"])
    steps = t / cfg.run.step
    if abs(steps - round(steps)) > 1e-6:
        raise ConfigError(f"the prepared state's time {t:g} s is not a whole number of steps of {cfg.run.step:g} s",
                          cfg.source or "", "run.step", hint="use the preparation preset's run.step")
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


# what a resumed run may change: its end, its outputs, its checks and its machine; everything else (the vessel,
# the grains, the contact model, the gas grid, the step) must be the run's own, or the checkpoint means nothing
RESUME_FREE = {"run": {"duration", "name", "threads", "precision", "start_from"}, "output": None, "video": None,
               "guard": None, "probes": None, "boundary": None}


def _flat(cfg) -> dict:
    out = {}
    for name, section in cfgmod.loader.sections_of(cfg).items():
        free = RESUME_FREE.get(name, set())
        if free is None:
            continue
        out[f"[{name}]"] = "absent" if section is None else "present"
        if section is None:
            continue
        for f in dataclasses.fields(section):
            if f.name in free:
                continue
            v = getattr(section, f.name)
            if f.name in ("initial_state", "sdf_file") and v:
                v = str(cfgmod.resolve_path(cfg, v).resolve())
            out[f"{name}.{f.name}"] = v
    return out


def check_same_scene(cfg, run_cfg, preset_path: pathlib.Path, out_dir: pathlib.Path) -> None:
    """Refuse to resume a run with a preset (or --set) whose scene differs from the run's config.toml."""
    a, b = _flat(cfg), _flat(run_cfg)
    diff = [k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
    whole = {k[1:-1] for k in diff if k.startswith("[")}  # a section one side lacks: named once, not key by key
    diff = [k for k in diff if k.startswith("[") or k.split(".")[0] not in whole]
    if diff:
        names = ", ".join(diff[:12]) + (f" and {len(diff) - 12} more" if len(diff) > 12 else "")
        values = "; ".join(f"{k}: {a.get(k, 'absent')!s:.30} here, {b.get(k, 'absent')!s:.30} in the run"
                           for k in diff[:3])
        raise ConfigError(f"this preset's scene differs from the run's in {names} ({values})", str(preset_path),
                          "--resume", hint=f"resume with the run's own settings (fbed run --resume {out_dir}); a "
                          "resume may change only run.duration, [output], [video], [guard], [probes] and [boundary]")


def check_readable(out_dir: pathlib.Path) -> None:
    """Refuse a run folder whose checkpoint.h5 or run.h5 cannot be read (a damaged file loses nothing more)."""
    import h5py

    for name, must in (("checkpoint.h5", ("step", "time")), ("run.h5", ())):
        path = out_dir / name
        if not path.exists():
            continue
        try:
            with h5py.File(path, "r") as f:
                missing = [k for k in must if k not in f.attrs]
                if name == "run.h5" and "series" in f:
                    f["series"]["time"][...] if "time" in f["series"] else None
        except Exception as err:  # noqa: BLE001 - h5py raises OSError, KeyError or RuntimeError on damage
            raise ConfigError(f"{name} is damaged and cannot be read ({str(err).splitlines()[0][:80]})", str(path),
                              "--resume", hint="move it aside and resume (run.h5: its series restart; "
                              "checkpoint.h5: nothing to resume), or start again with --overwrite") from None
        if missing:
            raise ConfigError(f"{name} lacks {', '.join(missing)}: not an fbed checkpoint", str(path), "--resume")


# GPU-sized scenes on the CPU: the time is estimated from a measured CPU rate (verma_small: 14,000 grains x 52
# substeps x 1000 steps in 3.0 min on 2 CPU cores, gas included), so a run of hours says so before it starts
CPU_PARTICLE_SUBSTEPS_PER_S = 4.0e6
LONG_ON_CPU = 3600.0  # s


def cpu_estimate_note(preset_path: pathlib.Path, n: int, substeps: int, steps: int) -> str | None:
    est = n * substeps * steps / CPU_PARTICLE_SUBSTEPS_PER_S
    if est < LONG_ON_CPU:
        return None
    small = preset_path.with_name(preset_path.stem + "_small.toml")
    alt = f"; its small variant runs in minutes: fbed run {small}" if small.exists() else ""
    return (f"fbed: note: this is a GPU-sized scene ({n:,} grains): on the CPU it takes roughly "
            f"{_duration(est)} (estimated from verma_small's rate on 2 cores){alt}")


def watch_parent(sim) -> None:
    """With FBED_STOP_WITH_PARENT = the pid of the process that started this run (set by `fbed sweep` on a Dask
    worker), stop cleanly, with a checkpoint, once that process is gone (a worker killed): the case is rerun
    elsewhere, and this run must not go on writing into its folder."""
    import os
    import threading

    try:  # the pid of the process that started this one (read here, it may already be gone)
        parent = int(os.environ.get("FBED_STOP_WITH_PARENT", ""))
    except ValueError:
        return

    def watch():
        while not sim.stop_requested:
            if os.getppid() != parent:
                log("fbed: the process that started this run is gone: stopping with a checkpoint")
                sim.stop_requested = "parent gone"
                return
            wallclock.sleep(1.0)

    threading.Thread(target=watch, daemon=True).start()


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


def write_xdmf(out_dir: pathlib.Path, runfile=None) -> None:
    """run.xdmf (and particles.xdmf, checkpoint.xdmf) for ParaView: small XML files that point into the HDF5
    files, at every checkpoint (``runfile``: run.h5 open for writing) and, with bed.xdmf, at the end; a failure
    here costs only them."""
    from .io import xdmf

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


def stop_disk_full(out_dir: pathlib.Path, summary: dict, err) -> int:
    """The run stopped on a full disk: say what it needed, keep what was written, and how to go on."""
    ckpt = out_dir / "checkpoint.h5"
    try:
        store.write_json(out_dir / "summary.json", summary)
    except store.DiskFull:
        log("fbed: summary.json not written either (no space)")
    for tmp in out_dir.glob("*.tmp"):
        tmp.unlink(missing_ok=True)
    log(f"fbed: stopped: {err}")
    if ckpt.exists():
        import h5py

        with h5py.File(ckpt, "r") as f:
            t = float(f.attrs["time"])
        log(f"fbed: the last good checkpoint (t = {t:.6g} s) is kept; free some space, then resume with: "
            f"fbed run --resume {out_dir}")
    else:
        log(f"fbed: no checkpoint was written yet; free some space (or give another --out) and run again")
    return EXIT_UNSTABLE


def run(preset: str | None, overrides: list[str], out: str | None = None, arch: str = "auto",
        resume: str | None = None, overwrite: bool = False, viewer=None) -> int:
    """Run a preset (or resume DIR). ``viewer``: a callable ``viewer(renderer, schedule)``
    returning a controller for ``Simulation.run`` (``fbed view``); None runs headless.
    A full disk before the run steps (its first files) stops it too: exit 3, nothing half-written."""
    try:
        return _run(preset, overrides, out, arch, resume, overwrite, viewer)
    except store.DiskFull as err:
        log(f"fbed: {err}; free some space or give another --out")
        return EXIT_UNSTABLE


def _run(preset, overrides, out, arch, resume, overwrite, viewer) -> int:
    # -- configuration (errors here lose nothing: no output written yet)
    if resume:
        out_dir = pathlib.Path(resume)
        ckpt = out_dir / "checkpoint.h5"
        if not out_dir.is_dir():
            raise ConfigError("not a folder" if out_dir.exists() else "no such folder", str(out_dir), "--resume",
                              hint="give the output folder of an earlier run")
        if not ckpt.exists():
            raise ConfigError("no checkpoint.h5 to resume from", str(out_dir), "--resume",
                              hint="give the output folder of an earlier run that was stopped or finished")
        check_readable(out_dir)
        base = pathlib.Path(preset) if preset else out_dir / "config.toml"
        cfg = cfgmod.load(base, overrides)
        preset_path = base
        if (out_dir / "config.toml").exists():
            check_same_scene(cfg, cfgmod.load(out_dir / "config.toml"), base, out_dir)
    else:
        if not preset:
            raise ConfigError("no preset given", "", "PRESET", hint="fbed run presets/settle.toml")
        preset_path = pathlib.Path(preset)
        cfg = cfgmod.load(preset_path, overrides)
        out_dir = pick_out_dir(preset_path, out, overwrite, cfg.video.file)
    if cfg.run.start_from and overrides and not resume:
        log(f"fbed: note: --set changes this stage only; the preparation {pathlib.Path(cfg.run.start_from).name} "
            "runs as its own preset says (edit it, or copy it and point run.start_from at the copy)")
    name = cfg.run.name or preset_path.stem
    if resume and preset_path.name == "config.toml":
        name = cfg.run.name or out_dir.name

    from .sim import runtime

    used_arch = runtime.init(arch, cfg.run.precision, cfg.run.threads or None)
    from .scene import Scene, build_simulation
    from .sim.dem import NeighborOverflow
    from .sim.fields import bytes_per_grain
    from .sim.simulation import Guard, Unstable

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
    if used_arch == "cpu" and der is not None:
        steps_left = int(np.ceil(cfg.run.duration / cfg.run.step - 1e-9)) - int(meta["step"] if resume else 0)
        note = cpu_estimate_note(preset_path, scene.n, der.substeps, max(0, steps_left))
        if note:
            log(note)
    if resume and scene.model is not None and arrays is None:
        raise ConfigError("the checkpoint does not hold this preset's grains", str(ckpt), "--resume",
                          hint="resume with the run's own config.toml")
    sim = build_simulation(scene, notify=log, timing=True)  # the grains placed from the checkpoint when resuming
    dem, flow, coupler = sim.dem, sim.flow, sim.coupler
    if prepared:
        load_prepared(cfg, sim, flow, coupler, gas_arrays, meta)
        sim.fresh = True
    if resume:
        if flow is not None:
            if gas_arrays is None:
                raise ConfigError("the checkpoint holds no gas state", str(ckpt), "--resume",
                                  hint="resume with the run's own config.toml")
            restore_gas(flow, coupler, gas_arrays)
        sim.step_count = int(meta["step"])
        sim.fresh = False  # its start was recorded by the run it continues (even one stopped at step 0)
        if sim.step_count >= sim.total_steps:
            log(f"{out_dir}: already at t = {sim.time:g} s >= run.duration; extend it with --set run.duration=...")
    schedule = sim.inlets
    renderer = None
    if viewer is not None and dem is None:
        raise ConfigError("the viewer draws grains: this scene has none", str(preset_path), "particles")
    if dem is not None and (cfg.video.enabled or viewer is not None):
        renderer = make_renderer(cfg, scene, dem, flow, name,
                                 show_window=viewer is not None and getattr(viewer, "show_window", True))

    if overwrite and not resume and out_dir.is_dir():
        remove_outputs(out_dir, cfg.video.file)
    out_dir.mkdir(parents=True, exist_ok=True)
    config_text = cfgmod.dump(cfg)
    store.write_text(out_dir / "config.toml", config_text)
    runfile = store.RunFile(out_dir / "run.h5", name, resume_time=sim.time if resume else None)
    if flow is not None:  # the grid run.xdmf draws the gas fields on (once)
        runfile.grid(scene.flow.shape, scene.flow.h, scene.flow.origin, flow.fields.vol_frac.to_numpy())
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
            runfile.snapshot(s.time, dem.read("position"), dem.read("velocity"), dem.radii())
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
        write_xdmf(out_dir, runfile)  # a run killed later still opens in ParaView up to here

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

    disk_full: list = []  # the DiskFull that stopped the final outputs

    def finish_outputs(s, reason):
        if reason in ("finished", "interrupted"):
            try:
                guard(s)
            except Unstable as err:  # the last steps went bad: keep the last good files
                reason = "unstable"
                log(f"fbed: final state not written: {err}")
        try:
            if reason in ("finished", "interrupted"):
                if s.step_count % s.every(o.series_interval):
                    record(s)
                snapshot(s)
                gas_fields(s)
                checkpoint(s)
                if reason == "finished" and o.save_bed and dem is not None:
                    store.write_checkpoint(out_dir / "bed.h5", dem.state_arrays(), None, s.time, s.step_count,
                                           config_text)
        except store.DiskFull as err:  # the last good checkpoint stays; nothing half-written is left
            disk_full.append(err)
        try:
            runfile.close()
        except store.DiskFull as err:
            disk_full.append(err)

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
        # the clock is looked at every second; the guard runs only before a checkpoint is written
        sim.add(WallCheckpoints(guarded(checkpoint), o.checkpoint_wall_interval), wall=WallCheckpoints.CHECK)
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
        if sim.stop_requested:  # a second signal: the checkpoint is being written, and it must be finished
            log("fbed: already stopping: the checkpoint is being written (kill -9 would lose the steps since "
                "the last one)")
            return
        sim.stop_requested = signal.Signals(signum).name
        log(f"fbed: {sim.stop_requested}: stopping after this step and writing a checkpoint")

    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    watch_parent(sim)
    what = []
    if dem is not None:
        what.append(f"{scene.n} grains, DEM step {der.dt:.3g} s x {der.substeps} per {cfg.run.step:g} s step")
    if flow is not None:
        what.append(f"gas on {'x'.join(map(str, scene.flow.shape))} cells of {cfg.gas.cell_size:g} m, "
                    f"fluid step {cfg.run.step:g} s")
    log(f"fbed: {name}: {'; '.join(what)}; {used_arch}, {cfg.run.precision}; output in {out_dir}")
    if sim.step_count < sim.total_steps:
        log("fbed: compiling kernels (up to a few minutes the first time; Taichi's offline cache in "
            "~/.cache/taichi makes later starts of the same scene faster)")
    t_start = wallclock.perf_counter()
    status, message = "finished", ""
    try:
        reason = sim.run(viewer(renderer, schedule, out_dir) if viewer is not None else None)
        status = reason
    except Unstable as err:
        status, message = "unstable", str(err)
    except NeighborOverflow as err:
        status, message = "unstable", str(err)
    except store.DiskFull as err:
        disk_full.append(err)
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
    if disk_full:
        status, message = "disk_full", str(disk_full[0])
    wall = wallclock.perf_counter() - t_start
    d = sim.diagnostics() if status not in ("unstable", "disk_full") else {}
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
    if status in ("unstable", "disk_full") and (out_dir / "checkpoint.h5").exists():
        summary["last_good_checkpoint"] = str(out_dir / "checkpoint.h5")
    if status == "disk_full":
        return stop_disk_full(out_dir, summary, disk_full[0])
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
    write_xdmf(out_dir)
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
