"""Progress: a bar on a terminal, short log lines otherwise; and the run's log itself (stderr)."""
from __future__ import annotations

import pathlib
import re
import sys
import time as wallclock

from rich.progress import BarColumn, Progress as RichProgress, TextColumn

from ..config.derived import RCFD_MIN_FRAMES, interval_steps, rcfd_frames, run_steps


def log(msg: str) -> None:
    """The run's log: one line on stderr (solvers never print; they are given this as ``notify``)."""
    print(msg, file=sys.stderr, flush=True)


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _fastest_cell(text: str) -> str:
    """The short form of Simulation.gas_fastest_cell's description: cell, open volume and gas fraction."""
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
            # that later blows up, or carries a wall channel, shows where its gas was racing (two device reads
            # per line, every output.log_interval of wall time). Read from the gas itself, not as a diagnostics
            # row: a row would reach the guard, whose verdict must not depend on the wall clock
            gas = ""
            if s.flow is not None:
                gas = f"  gas {s.flow.gas_extremes()[0]:.3g} m/s{_fastest_cell(s.gas_fastest_cell())}"
            eta_text = f"ETA {_duration(eta)}" if eta is not None else "ETA ..."
            rate_text = f"{rate:.3g} st/s" if rate > 0 else "... st/s"
            log(f"t {s.time:.4g}/{s.duration:g} s  step {s.step_count}/{s.total_steps}  {rate_text}  "
                f"{eta_text}{gas}")

    def finish(self, sim, reason):
        if self.bar:
            self(sim)
            self.bar.stop()


# GPU-sized scenes on the CPU: the time is estimated from a measured CPU rate (verma_small: 14,000 grains x 52
# substeps x 1000 steps stepped in 90 s on 2 idle CPU cores, gas included; 2026-12-06, benchmarks/RESULTS.md), so a
# run of hours says so before it starts. A million grains outgrow the CPU's caches: read it as a lower bound
CPU_PARTICLE_SUBSTEPS_PER_S = 8.0e6
LONG_ON_CPU = 3600.0  # s
GPU_SIZED_GRAINS = 100_000  # fewer grains than this in a long run: the note blames the steps, not the scene's size


def cpu_estimate_note(preset_path: pathlib.Path, n: int, substeps: int, steps: int) -> str | None:
    est = n * substeps * steps / CPU_PARTICLE_SUBSTEPS_PER_S
    if est < LONG_ON_CPU:
        return None
    if n < GPU_SIZED_GRAINS:  # few grains: the time is in the steps (a small DEM step, a long duration)
        return (f"fbed: note: this run takes roughly {_duration(est)} on the CPU ({n:,} grains x {substeps:,} DEM "
                f"substeps a step x {steps:,} steps, at verma_small's rate on 2 cores): dem.dt, "
                "contact.youngs_modulus and run.duration set it")
    small = preset_path.with_name(preset_path.stem + "_small.toml")
    alt = f"; its small variant runs in minutes: fbed run {small}" if small.exists() else ""
    return (f"fbed: note: this is a GPU-sized scene ({n:,} grains): on the CPU it takes roughly "
            f"{_duration(est)} (estimated from verma_small's rate on 2 cores){alt}")


def announce(sim, scene, name: str, arch: str, out_dir) -> None:
    """The run's first log lines: what it holds, where it runs, where its outputs go."""
    cfg, der, what = scene.cfg, scene.derived, []
    if sim.dem is not None:
        what.append(f"{scene.n} grains, DEM step {der.dt:.3g} s x {der.substeps} per {cfg.run.step:g} s step")
        wrapped = [a for a, p in zip("xyz", der.periodic) if p]
        if wrapped:
            what[-1] += f", periodic in {' and '.join(wrapped)}"
    if sim.flow is not None:
        what.append(f"gas on {'x'.join(map(str, scene.flow.shape))} cells of {cfg.gas.cell_size:g} m, "
                    f"fluid step {cfg.run.step:g} s")
    log(f"fbed: {name}: {'; '.join(what)}; {arch}, {cfg.run.precision}; output in {out_dir}")
    if sim.step_count < sim.total_steps:
        log("fbed: compiling kernels (up to a few minutes the first time; Taichi's offline cache in "
            "~/.cache/taichi makes later starts of the same scene faster)")


def cpu_note(scene, preset_path: pathlib.Path, start_step: int, threads: int) -> None:
    """On the CPU: log run.threads cut to the ``threads`` available, and how long a GPU-sized scene will take there
    (see cpu_estimate_note)."""
    if scene.cfg.run.threads > threads:
        log(f"fbed: note: run.threads = {scene.cfg.run.threads} is more than the {threads} CPUs this process may use: "
            f"it runs on {threads} (more threads than CPUs only take turns)")
    if scene.derived is None:
        return
    steps_left = run_steps(scene.cfg.run.duration, scene.cfg.run.step) - start_step
    note = cpu_estimate_note(preset_path, scene.n, scene.derived.substeps, max(0, steps_left))
    if note:
        log(note)


def odd_intervals(cfg) -> list[tuple[str, float, int]]:
    """The record intervals in use that are no whole number of run.step, each with the steps it is taken as
    (``interval_steps``; at least a step: output.particles_interval and the probes' are refused below one): boyce's
    probes.slab_interval = 2.5 ms in 1 ms steps recorded the slab every 2 ms, and its notes said 2.5."""
    o, pr, step = cfg.output, cfg.probes, cfg.run.step
    used = {"output.series_interval": o.series_interval, "output.particles_interval": o.particles_interval,
            "output.checkpoint_interval": o.checkpoint_interval,
            "video.interval": cfg.video.interval if cfg.video.enabled else 0.0,
            **{f"probes.{k}": getattr(pr, k) for k in ("slab_interval", "planes_interval", "volume_interval",
                                                       "mri_interval")},
            "probes.rcfd_interval": pr.rcfd_interval if pr.rcfd_from >= 0 else 0.0,
            "gas.fields_interval": cfg.gas.fields_interval if cfg.gas is not None else 0.0}
    odd = []
    for key, v in used.items():
        n = interval_steps(v, step)
        if v >= step * (1 - 1e-9) and abs(n * step - v) > 1e-9 * v:
            odd.append((key, v, n))
    return odd


def window_notes(cfg) -> list[str]:
    """Notes at the start where the run or a recorded window does not fit what was asked (a preset shortened with
    --set, say), which otherwise shows only at its end: run.duration not a whole number of run.step (the run ends at
    the next whole step, up to one step late); output.average_from not before run.duration (the time means, and the
    analysis that reads that window, would find nothing); probes.rcfd_from leaving fewer than the 3 frames that
    `fbed rcfd` needs; an inlet or a jet that opens after the end; a video of fewer than two frames; record
    intervals that are no whole number of steps."""
    notes, end = [], cfg.run.duration
    steps = run_steps(end, cfg.run.step)
    if abs(steps * cfg.run.step - end) > 1e-9 * max(end, cfg.run.step):
        notes.append(f"fbed: note: run.duration = {end:g} s is not a whole number of run.step = {cfg.run.step:g} s: "
                     f"the run ends at t = {steps * cfg.run.step:g} s, after {steps} step{'s' * (steps != 1)} "
                     "(make run.duration a multiple of run.step to end on it)")
    t0 = cfg.output.average_from
    if t0 >= 0 and t0 >= end:
        what = "" if cfg.probes.analysis == "none" else f", and the {cfg.probes.analysis} analysis nothing to analyse"
        notes.append(f"fbed: note: output.average_from = {t0:g} s is not before run.duration = {end:g} s: "
                     f"summary.json will have no time means{what} (set output.average_from below it, or -1: the "
                     "second half)")
    pr = cfg.probes
    if pr.rcfd_from >= 0:
        frames = rcfd_frames(end - pr.rcfd_from, pr.rcfd_interval)
        if frames < RCFD_MIN_FRAMES:
            notes.append(f"fbed: note: rCFD frames from probes.rcfd_from = {pr.rcfd_from:g} s to run.duration = "
                         f"{end:g} s: {frames} of probes.rcfd_interval = {pr.rcfd_interval:g} s, and `fbed rcfd` "
                         f"needs at least {RCFD_MIN_FRAMES} (record from earlier, or run longer)")
    for face, b in cfg.boundary:  # an inlet or jet that opens after the end (a preset shortened with --set)
        if b.kind != "velocity_inlet":
            continue
        if b.start >= end and not b.schedule and any(b.velocity):
            notes.append(f"fbed: note: boundary.{face}.start = {b.start:g} s is not before run.duration = {end:g} s: "
                         "the inlet blows nothing in this run")
        if b.jet_radius > 0 and any(b.jet_velocity) and b.jet_start >= end:
            notes.append(f"fbed: note: boundary.{face}.jet_start = {b.jet_start:g} s is not before run.duration = "
                         f"{end:g} s: the jet never opens in this run")
    if odd := odd_intervals(cfg):
        notes.append(f"fbed: note: records come every whole number of run.step = {cfg.run.step:g} s: "
                     + ", ".join(f"{k} = {v:g} s is taken as {n * cfg.run.step:g} s ({n} step{'s' * (n != 1)})"
                                 for k, v, n in odd) + " (make them multiples of run.step)")
    vid = cfg.video
    if vid.enabled:  # frames as the Simulation fires them: every interval_steps steps, and at t = 0 only without
        # gas (with gas the first frame waits for the first step: before it no void fraction is deposited)
        frames = steps // interval_steps(vid.interval, cfg.run.step) + (cfg.gas is None)
        if frames < 2:
            what = "no video will be written" if frames == 0 else "the video will hold one frame, a still"
            notes.append(f"fbed: note: video.interval = {vid.interval:g} s and run.duration = {end:g} s: {what} "
                         "(lower video.interval)")
    return notes
