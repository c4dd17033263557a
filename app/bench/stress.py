"""`fbed bench stress`: hostile scenes that must end cleanly or stop with a clear message.

Owns: the stress scenes (a small coupled bed made hostile one way at a time), running each as
an ordinary `fbed run` in its own process with a wall-clock limit (so a hang is caught), and
judging the outcome. Each scene either
- finishes with finite series in run.h5, no grain outside the vessel's walls (grains may leave
  through the open top only), and the gas's discrete divergence small (mass conserved), or
- stops early with exit 3 and a message that names the setting to change, with run.h5
  readable and finite and the last good checkpoint kept.
Never a NaN written, never a traceback, never a hang. The table goes to benchmarks/STRESS.md
(or --out DIR/STRESS.md).

    fbed bench stress [--out DIR] [--scenes NAME ...] [--arch cpu|cuda]
"""
from __future__ import annotations

import dataclasses
import datetime
import json
import math
import os
import pathlib
import subprocess
import sys
import time

import h5py
import numpy as np

from ..config import load
from ..config.derived import derive
from ..io import store
from ..outputs import out_folder

BASE = """
[run]
duration = {duration}
step = 1.0e-3
name = "{name}"
[domain]
lo = [-0.016, -0.016, 0.0]
hi = [0.016, 0.016, 0.096]
gravity = [0.0, 0.0, -9.81]
[vessel]
shape = "cylinder"
radius = 0.015
[particles]
{grains}
diameter = 2.0e-3
density = 1000.0
[contact]
model = "hertz_mindlin"
youngs_modulus = 5.0e6
restitution = {restitution}
friction = 0.3
[gas]
cell_size = {cell}
pressure_form = "shared"
max_iterations = {max_iter}
[coupling]
drag = "wen_yu"
smoothing_width = 2.0e-3
[boundary]
bottom = {{ kind = "velocity_inlet", velocity = [0.0, 0.0, {u}], {inlet_extra} }}
top = {{ kind = "pressure_outlet" }}
[output]
series_interval = 2.0e-3
checkpoint_interval = 1.0e-2
checkpoint_wall_interval = 0.0
save_bed = false
[guard]
interval = 2.0e-3
"""
DEFAULTS = dict(duration=0.1, grains="count = 1200", restitution=0.9, cell=4.0e-3, max_iter=200, u=0.4,
                inlet_extra="start = 0.0")


@dataclasses.dataclass(frozen=True)
class Scene:
    name: str
    what: str
    expect: str                  # "finish", "stop" or "either"
    params: dict = dataclasses.field(default_factory=dict)
    overrides: tuple = ()
    bed: str = ""                # "overlapping" or "compacted": an initial_state written for the scene
    gas: bool = True
    knobs: tuple = ()            # a stop message must name one of these settings


SCENES = (
    Scene("jet_100", "a 100 m/s jet through the central bottom cells into the settled bed", "either",
          dict(inlet_extra="jet_velocity = [0.0, 0.0, 100.0], jet_radius = 0.003, jet_start = 0.02, "
                           "jet_duration = 0.03, jet_ramp = 0.002"),
          knobs=("run.step", "guard.max_gas_speed", "dem.impact_speed", "guard.max_speed")),
    Scene("restitution_099", "restitution 0.99 in a deep bed (3000 grains, no gas)", "finish",
          dict(restitution=0.99, grains="count = 3000", u=0.0), gas=False),
    Scene("dt_twice_stable", "a DEM step at twice the stability limit of the explicit update (2 x 2/omega = "
          "1.27 collision times), forced", "stop", dict(dt_factor=4.0 / math.pi), knobs=("dem.dt",)),
    Scene("blowout_20umf", "gas at about 20 U_mf: grains are blown out of the top", "either",
          dict(u=8.0), knobs=("run.step", "guard.max_gas_speed", "guard.max_speed")),
    Scene("overlap_20pct", "grains overlapping by 20% of a diameter at the start", "either",
          bed="overlapping", knobs=("contact.youngs_modulus", "dem.impact_speed", "dem.dt_fraction")),
    Scene("compacted", "a bed compacted below eps_min (touching FCC, solids 0.74)", "either",
          bed="compacted", knobs=("contact.youngs_modulus", "dem.impact_speed")),
    Scene("empty_vessel", "an empty vessel: gas only", "finish", dict(grains=""), gas=True),
    Scene("grain_as_cell", "grains as large as a gas cell (2 mm grains, 2 mm cells)", "either",
          dict(cell=2.0e-3), knobs=("gas.cell_size", "coupling.smoothing_width", "run.step")),
    Scene("starved_pressure", "a pressure solver starved of iterations (gas.max_iterations = 1)", "either",
          dict(max_iter=1, u=1.0), knobs=("gas.max_iterations", "run.step")),
)


def lattice(kind: str, n_target: int, d: float, radius: float, z0: float = 0.0) -> np.ndarray:
    """Grain centres in the cylinder: 'overlapping' a simple cubic lattice at 0.8 d spacing (20% overlap),
    'compacted' a touching face-centred cubic packing (solids 0.74)."""
    a = 0.8 * d if kind == "overlapping" else d * math.sqrt(2.0)
    pts = []
    n = int(2 * radius / a) + 2
    base = [(0.0, 0.0, 0.0)] if kind == "overlapping" else [(0, 0, 0), (0.5, 0.5, 0), (0.5, 0, 0.5), (0, 0.5, 0.5)]
    k = 0
    while len(pts) < n_target and k < 400:
        for i in range(-n, n + 1):
            for j in range(-n, n + 1):
                for b in base:
                    p = ((i + b[0]) * a, (j + b[1]) * a, z0 + d / 2 + (k + b[2]) * a)
                    if math.hypot(p[0], p[1]) < radius - d / 2:
                        pts.append(p)
        k += 1
    return np.asarray(pts[:n_target])


def write_bed(path: pathlib.Path, kind: str, n: int = 1200) -> None:
    pos = lattice(kind, n, 2.0e-3, 0.015)
    grains = {"position": pos, "velocity": np.zeros_like(pos), "radius": np.full(len(pos), 1.0e-3)}
    store.write_checkpoint(path, grains, None, 0.0, 0, "")


def preset_text(s: Scene, bed_path: str = "") -> str:
    p = {**DEFAULTS, **{k: v for k, v in s.params.items() if k != "dt_factor"}, "name": s.name}
    if s.bed:
        p["grains"] = f'initial_state = "{bed_path}"'
    text = BASE.format(**p)
    if not p["grains"]:  # gas only: no [particles], no [contact]
        text = text[:text.index("[particles]")] + text[text.index("[gas]"):]
    if not s.gas:
        text = text[:text.index("[gas]")] + text[text.index("[output]"):]
    return text


def energy_growth(config: pathlib.Path, series: dict, radii) -> float:
    """The largest growth of the grains' kinetic energy from one guard check to the next, as the guard measures
    it: from the energy of the check before, or from its floor where that is larger (the scenes' series rows
    are the guard's own, both every 2 ms). The figure guard.max_energy_growth's documentation quotes."""
    from ..callbacks.guard import Guard  # the run's own guard, built as `fbed run` builds it

    cfg = load(config)
    derived = derive(cfg, str(config))
    guard = Guard.of(cfg, derived, derived.mass(2.0 * radii), radii)
    t, energy = series["time"], series["kinetic_energy"]
    base = np.maximum(energy[:-1], [guard.floor_at(x) for x in t[1:]])
    return round(float(np.max(energy[1:] / base)), 3)


def judge(s: Scene, rc: int | None, out: pathlib.Path, log: str, wall: float) -> dict:
    """The scene's outcome and whether it meets the contract."""
    row = {"scene": s.name, "what": s.what, "exit": rc, "wall_s": round(wall, 1)}
    problems = []
    if rc is None:
        problems.append("hung (killed at the wall-clock limit)")
    if "Traceback" in log:
        problems.append("traceback")
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() else {}
    row["status"] = summary.get("status", "-")
    row["reached_s"] = summary.get("time")
    row["unstable_at"] = summary.get("unstable_at", "")  # the guard reads rows a few steps behind the run
    row["message"] = summary.get("message", "")
    if (out / "run.h5").exists():
        with h5py.File(out / "run.h5", "r") as f:
            series = {k: f["series"][k][...] for k in f["series"]} if "series" in f else {}
            snaps = f.get("particles")
            last = snaps[str(len(snaps) - 1)]["position"][...] if snaps is not None and len(snaps) else None
            radii = snaps["0"]["radius"][...] if snaps is not None and len(snaps) else None
        bad = [k for k, v in series.items() if not np.all(np.isfinite(v))]
        if bad:
            problems.append(f"non-finite series in run.h5: {bad}")
        if radii is not None and len(series.get("kinetic_energy", ())) > 1:
            row["max_growth"] = energy_growth(out / "config.toml", series, radii)
        if "divergence_residual" in series and len(series["divergence_residual"]):
            row["max_divergence"] = float(np.max(series["divergence_residual"]))
        if last is not None:  # no grain through a wall: inside the cylinder and above the floor
            r = np.hypot(last[:, 0], last[:, 1])
            outside = int(np.sum((r > 0.015 + 1e-3) | (last[:, 2] < -1e-3)))
            row["grains_outside_walls"] = outside
            if outside:
                problems.append(f"{outside} grains outside the walls")
        row["grains_removed_top"] = summary.get("grains_removed", 0)
    elif rc not in (None,):
        problems.append("no run.h5")
    if rc == 0:
        row["outcome"] = "finished"
        if s.expect == "stop":
            problems.append("was expected to stop")
        if row.get("max_divergence", 0.0) > 1e-3:
            problems.append(f"gas divergence {row['max_divergence']:.2g} (mass not conserved)")
    elif rc == 3:
        row["outcome"] = "stopped"
        if s.expect == "finish":
            problems.append("was expected to finish")
        if not any(k in row["message"] for k in s.knobs):
            problems.append(f"message names none of {s.knobs}")
        if not (out / "checkpoint.h5").exists() and (row.get("reached_s") or 0) > 0.01:
            problems.append("no checkpoint kept")
    else:
        row["outcome"] = f"exit {rc}"
        problems.append(f"unexpected exit code {rc}")
    row["ok"] = not problems
    row["problems"] = "; ".join(problems)
    return row


def run_scene(s: Scene, out_dir: pathlib.Path, arch: str, limit: float) -> dict:
    work = out_dir / s.name
    work.mkdir(parents=True, exist_ok=True)
    bed = ""
    if s.bed:
        write_bed(work / "start.h5", s.bed)
        bed = str((work / "start.h5").resolve())
    preset = work / "scene.toml"
    preset.write_text(preset_text(s, bed))
    args = [sys.executable, "-m", "app", "run", str(preset), "--out", str(work / "run"), "--overwrite", "--arch", arch]
    overrides = list(s.overrides)
    if "dt_factor" in s.params:  # a DEM step as a multiple of this scene's collision time
        tc = derive(load(preset), str(preset)).collision_time
        overrides += [f"dem.dt={s.params['dt_factor'] * tc:.6g}", "dem.force_dt=true"]
    for o in overrides:
        args += ["--set", o]
    env = dict(os.environ)
    env["PYTHONPATH"] = str(pathlib.Path(__file__).resolve().parents[2]) + os.pathsep + env.get("PYTHONPATH", "")
    t0 = time.perf_counter()
    try:
        r = subprocess.run(args, capture_output=True, text=True, env=env, timeout=limit)
        rc, log = r.returncode, r.stdout + r.stderr
    except subprocess.TimeoutExpired as err:
        rc, log = None, str(err.stdout or "") + str(err.stderr or "")
    (work / "log.txt").write_text(log)
    return judge(s, rc, work / "run", log, time.perf_counter() - t0)


def table(rows: list[dict]) -> str:
    cols = ["scene", "what", "outcome", "reached_s", "unstable_at", "wall_s", "grains_removed_top", "max_divergence",
            "max_growth", "ok", "message", "problems"]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        vals = []
        for c in cols:
            v = r.get(c, "")
            if isinstance(v, float):
                v = f"{v:.3g}"
            vals.append(str(v).replace("|", "/"))
        lines.append("| " + " | ".join(vals) + " |")
    return "\n".join(lines) + "\n"


def stress(out: str | None = None, names: list[str] | None = None, arch: str = "cpu", limit: float = 600.0) -> int:
    out_dir = out_folder(out, pathlib.Path("runs") / "stress")
    chosen = [s for s in SCENES if not names or s.name in names]
    rows = []
    for s in chosen:
        row = run_scene(s, out_dir, arch, limit)
        rows.append(row)
        print(f"  {s.name}: {row['outcome']}{'' if row['ok'] else '  FAILED: ' + row['problems']}", file=sys.stderr,
              flush=True)
    text = (f"# Stress scenes\n\n{datetime.date.today().isoformat()}, arch {arch}; `fbed bench stress` "
            f"(app/bench/stress.py). Each must finish clean or stop with exit 3 and a message naming the setting to "
            f"change, keeping its checkpoint; never a NaN in run.h5, a traceback or a hang.\n\n" + table(rows))
    (out_dir / "STRESS.md").write_text(text)
    (out_dir / "stress.json").write_text(json.dumps(rows, indent=1, default=str))
    print(text)
    return 0 if all(r["ok"] for r in rows) else 1
