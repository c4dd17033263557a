"""Accuracy cases of the gas solver and of the gas-grain coupling: a grain settling to its terminal
velocity, a frozen packed bed against Ergun, laminar pipe flow against Hagen-Poiseuille and the
lid-driven cavity against Ghia et al. (1982).

Owns: these scenes, their exact or published answers and their measures. Costs are wall seconds
of the timed steps, read after ``runtime.sync()`` and after one warm-up step (the first step
compiles the kernels and, for the gas, solves a throw-away step for a consistent pressure).
"""
from __future__ import annotations

import json
import math
import os
import pathlib
import time

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from ..config import load
from ..config.derived import grain_mass, grain_volume
from ..config.loader import build
from ..scene import Scene, build_simulation
from ..sim import runtime
from .cases import Case, Unavailable

MU, RHO_G, G = 1.8e-5, 1.2, 9.81  # air [Pa s], [kg/m^3]; gravity [m/s^2]
TOLERANCES = (1e-3, 1e-6, 1e-8)  # pressure-solve tolerances swept (1e-6: the schema's default)


def _timed_steps(step, n: int) -> float:
    """Wall seconds of steps 2..n of ``step()`` (the first, the warm-up, is left off the clock)."""
    step()
    runtime.sync()
    t0 = time.perf_counter()
    for _ in range(n - 1):
        step()
    runtime.sync()
    return time.perf_counter() - t0


def _coupled(sections: dict, positions: np.ndarray, radius: float, frozen: bool = False):
    """The Simulation of a coupled scene given as preset sections, grains placed at rest (``frozen``: they feel
    the drag but never move); ``sim.step()`` is one fluid step of run.step."""
    radii = np.full(len(positions), radius)
    grains = {"position": positions, "velocity": np.zeros_like(positions), "radius": radii}
    return build_simulation(Scene(build(sections, "<accuracy>"), "<accuracy>", initial=grains), frozen=frozen)


# ------------------------------------------------------------------------------------ terminal velocity
SETTLE_RHO, SETTLE_SECONDS = 2500.0, 0.2  # kg/m^3: glass in air; s: ~4 relaxation times of the 0.1 mm grain


def _settling_force(v: float, d: float, rho_p: float) -> float:
    """Net downward force [N] on a grain falling at v [m/s]: weight less buoyancy less Schiller-Naumann drag
    (C_D = 24/Re (1 + 0.15 Re^0.687), so F_drag = 3 pi mu d v (1 + 0.15 Re^0.687))."""
    re = RHO_G * d * v / MU
    return (rho_p - RHO_G) * grain_volume(d / 2) * G - 3 * math.pi * MU * d * v * (1 + 0.15 * re ** 0.687)


def schiller_naumann_terminal(d: float, rho_p: float) -> float:
    """Terminal speed [m/s]: where the net force vanishes (brentq, as tests/test_fluidization.py)."""
    return brentq(_settling_force, 1e-9, 100.0, args=(d, rho_p), xtol=1e-14, rtol=1e-12)


def schiller_naumann_speed(d: float, rho_p: float, t: float) -> float:
    """Falling speed [m/s] at time t [s] of a grain released at rest: m dv/dt = the net force above,
    integrated to 1e-10 (what the coupled run must reproduce: it has no added mass or history force)."""
    mass = grain_mass(d / 2, rho_p)
    sol = solve_ivp(lambda _, v: [_settling_force(max(v[0], 0.0), d, rho_p) / mass], (0.0, t), [0.0],
                    method="LSODA", rtol=1e-10, atol=1e-12)
    return float(sol.y[0, -1])


def settling_grain(d: float, fluid_step: float, cell_size: float, precision: str, seconds: float) -> dict:
    """One grain released at rest in still air (a closed 40 x 40 x 240 mm box, pressure outlet on top)
    and followed for ``seconds``: its final falling speed and the wall time per simulated second."""
    sections = {
        "run": {"duration": seconds, "step": fluid_step, "precision": precision},
        "domain": {"lo": [-0.02, -0.02, 0.0], "hi": [0.02, 0.02, 0.24], "gravity": [0.0, 0.0, -G]},
        "vessel": {"shape": "box"},
        "particles": {"diameter": d, "density": SETTLE_RHO, "count": 1},
        # the grain touches nothing: the softest contact, and one DEM step per fluid step
        "contact": {"youngs_modulus": 1.0e3, "friction": 0.0},
        "dem": {"dt": fluid_step, "force_dt": True},
        "gas": {"cell_size": cell_size, "viscosity": MU, "density": RHO_G, "pressure_form": "shared"},
        "coupling": {"drag": "schiller_naumann"},
        "boundary": {"top": "pressure_outlet"},
    }
    sim = _coupled(sections, np.array([[0.004, 0.004, 0.22]]), d / 2)
    n = max(2, round(seconds / fluid_step))
    wall = _timed_steps(sim.step, n)
    return {"speed": float(-sim.dem.read("velocity")[0, 2]), "cost": wall / ((n - 1) * fluid_step)}


def _terminal_velocity(settings: dict, size: str) -> dict:
    # 'full' adds coarser grains (Re ~ 11 and ~ 31 at terminal speed) to the 0.1 mm one (Re ~ 3.7)
    diameters = (1.0e-4, 1.6e-4, 2.5e-4) if size == "full" else (1.0e-4,)
    errors, costs, speeds = [], [], []
    for d in diameters:
        run = settling_grain(d, settings["fluid_step"], settings["cell_size"], settings["precision"], SETTLE_SECONDS)
        v_t = schiller_naumann_terminal(d, SETTLE_RHO)
        errors.append(abs(run["speed"] - schiller_naumann_speed(d, SETTLE_RHO, SETTLE_SECONDS)) / v_t)
        costs.append(run["cost"])
        speeds.append(run["speed"] / v_t)
    return {"error": max(errors), "cost": float(np.mean(costs)), "speed_over_terminal": speeds[0]}


# ------------------------------------------------------------------------------------ Ergun
ERGUN_D, ERGUN_LAYERS = 2.0e-3, 40  # m; a cubic lattice of 6 x 6 x 40 grains (80 mm deep)


def ergun_gradient(U: float, eps: float, d: float) -> float:
    """Ergun's pressure gradient [Pa/m] at superficial velocity U [m/s] through a bed of gas fraction eps."""
    phi = 1 - eps
    return 150 * MU * U * phi ** 2 / (eps ** 3 * d ** 2) + 1.75 * RHO_G * U ** 2 * phi / (eps ** 3 * d)


def frozen_bed(cell_size: float, tolerance: float, precision: str, velocities, steps: int) -> dict:
    """Grains frozen on a cubic lattice (eps = 1 - pi/6) in a 12 mm square box with free-slip sides;
    the gas enters at each superficial velocity in turn for ``steps`` fluid steps of 1 ms. The
    pressure drop across the bed (gas hydrostatics removed) over Ergun's, per velocity."""
    d, width, z0 = ERGUN_D, 0.012, 0.02
    xs = (np.arange(round(width / d)) + 0.5) * d - width / 2
    zs = z0 + (np.arange(ERGUN_LAYERS) + 0.5) * d
    X, Y, Z = np.meshgrid(xs, xs, zs, indexing="ij")
    pos = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    side = {"kind": "free_slip"}
    sections = {
        "run": {"duration": 1.0, "step": 1e-3, "precision": precision},
        "domain": {"lo": [-width / 2, -width / 2, 0.0], "hi": [width / 2, width / 2, 0.12],
                   "gravity": [0.0, 0.0, -G]},
        "vessel": {"shape": "box"},
        "particles": {"diameter": d, "density": 2500.0, "count": len(pos)},
        "contact": {"youngs_modulus": 5.0e6, "friction": 0.0},
        "gas": {"cell_size": cell_size, "pressure_form": "shared", "viscosity": MU, "density": RHO_G,
                "tolerance": tolerance},
        # Gidaspow's law is Ergun's below eps = 0.8: the answer is the drag law's own
        "coupling": {"drag": "gidaspow", "eps_min": 0.3},
        "boundary": {"bottom": {"kind": "velocity_inlet", "velocity": [0.0, 0.0, velocities[0]]},
                     "top": "pressure_outlet", "x-": side, "x+": side, "y-": side, "y+": side},
    }
    sim = _coupled(sections, pos, d / 2, frozen=True)
    eps = 1 - math.pi / 6
    nx, ny, _ = sim.flow.config.shape
    ratios, wall = [], 0.0
    for U in velocities:
        sim.flow.set_inlet_profile("bottom", np.full((nx, ny), U))
        wall += _timed_steps(sim.step, steps)
        p = sim.flow.pressure()
        dp = p[:, :, 0].mean() - p[:, :, -1].mean() - RHO_G * G * (p.shape[2] - 1) * cell_size
        ratios.append(dp / (ergun_gradient(U, eps, d) * ERGUN_LAYERS * d))
    return {"ratios": ratios, "cost": wall / (len(velocities) * (steps - 1))}


def _ergun(settings: dict, size: str) -> dict:
    velocities = (0.05, 0.1, 0.2) if size == "full" else (0.1,)  # all below U_mf ~ 1 m/s
    run = frozen_bed(settings["cell_size"], settings["tolerance"], settings["precision"], velocities, steps=12)
    return {"error": float(max(abs(r - 1.0) for r in run["ratios"])), "cost": run["cost"]}


# ------------------------------------------------------------------------------------ pipe
PIPE_MU, PIPE_FORCE, PIPE_SECONDS, PIPE_DT = 0.1, 1.0, 2.0, 0.05  # Pa s, N/m^3, s, s (rho = 1, D = 1 m)


def pipe_flow(cells_across: int, tolerance: float, axis_offset: float = 0.0) -> dict:
    """Hagen-Poiseuille flow in a cut-cell cylinder of diameter 1 m, ``cells_across`` cells, periodic
    along z (one cell: the flow does not vary along it), driven by a body force G. It starts from the
    exact profile G (R^2 - r^2) / (4 mu) and runs 2 s (4.6 viscous times R^2 / (5.78 nu)): the discrete
    steady state does not depend on the start, and its O(h^2) distance from the exact one has decayed
    to 1% by then (from rest it would take three times as long). ``axis_offset`` [cells] shifts the
    axis off a cell centre. Returns the RMS error of the axial velocity over the open faces, relative
    to the exact centreline value."""
    h = 1.0 / cells_across
    c = (cells_across / 2 + 1.5 + axis_offset) * h
    side = (cells_across + 3) * h
    sections = {
        "run": {"duration": PIPE_SECONDS, "step": PIPE_DT, "precision": runtime.current()[1]},
        "domain": {"lo": [0.0, 0.0, 0.0], "hi": [side, side, h], "gravity": [0.0, 0.0, 0.0]},
        "vessel": {"shape": "cylinder", "center": [c, c], "radius": 0.5},  # no grains: no floor (scene.build_walls)
        "gas": {"cell_size": h, "density": 1.0, "viscosity": PIPE_MU, "tolerance": tolerance, "max_split": 1},
        "boundary": {"z-": "periodic", "z+": "periodic"},  # the sides are the cut-cell cylinder
    }
    sim = build_simulation(Scene(build(sections, "<accuracy>"), "<accuracy>"))
    s = sim.flow
    xyz = s.grid.face_centres(2)
    r2 = (xyz[..., 0] - c) ** 2 + (xyz[..., 1] - c) ** 2
    u_exact = np.maximum(PIPE_FORCE / (4 * PIPE_MU) * (0.25 - r2), 0.0)
    s.set_face_velocity(np.zeros(s.grid.face_shape(0)), np.zeros(s.grid.face_shape(1)), u_exact)
    s.set_explicit_source((0.0, 0.0, PIPE_FORCE))
    n = round(PIPE_SECONDS / PIPE_DT)
    wall = _timed_steps(sim.step, n)
    r2, u_exact = r2[:, :, 0], u_exact[:, :, 0]
    inside = (s.cut.apertures[2][:, :, 0] > 0) & (r2 < 0.25)
    w = s.face_velocity(2)[:, :, 0]
    rms = float(np.sqrt(np.mean((w - u_exact)[inside] ** 2)))
    return {"error": rms / (PIPE_FORCE * 0.25 / (4 * PIPE_MU)), "cost": wall / ((n - 1) * PIPE_DT)}


def _pipe(settings: dict, size: str) -> dict:
    # 'full' also puts the axis on a cell corner and at an arbitrary offset: the cut cells differ
    offsets = (0.0, 0.5, 0.3) if size == "full" else (0.0,)
    runs = [pipe_flow(settings["cells_across"], settings["tolerance"], o) for o in offsets]
    return {"error": max(r["error"] for r in runs), "cost": float(np.mean([r["cost"] for r in runs]))}


# ------------------------------------------------------------------------------------ cavity
CAVITY_LID_CFL = {"small": 2.56, "full": 1.28}  # 'full': the preset's 0.02 s step at 64 cells


def ghia_reference() -> dict:
    """Ghia et al. (1982) Re = 100 centrelines from $FBED_REFERENCE or ../shared/reference."""
    root = pathlib.Path(__file__).resolve().parents[2]
    folder = pathlib.Path(os.environ.get("FBED_REFERENCE", root.parent / "shared" / "reference"))
    path = folder / "ghia1982_re100.json"
    if not path.is_file():
        raise Unavailable(f"Ghia et al. 1982 centrelines not found at {path}; set FBED_REFERENCE to the folder "
                          "holding ghia1982_re100.json")
    return json.loads(path.read_text())


CAVITY_PRESET = pathlib.Path(__file__).resolve().parents[2] / "presets" / "validation" / "cavity.toml"


def cavity_scene(cells: int, tolerance: float, convection: str, dt: float, seconds: float) -> Scene:
    """The shipped Re = 100 cavity (presets/validation/cavity.toml: the unit square in the x-z plane, one periodic
    cell in y, the lid sliding at 1 m/s along x) at ``cells`` cells a side, run for ``seconds`` at steps of ``dt``
    [s] with the pressure ``tolerance`` and the ``convection`` scheme, in Taichi's current precision."""
    h = 1.0 / cells
    overrides = [f"domain.hi=[1.0, {h!r}, 1.0]", f"gas.cell_size={h!r}", f"gas.tolerance={tolerance!r}",
                 f'gas.convection="{convection}"', f"run.step={dt!r}", f"run.duration={seconds!r}",
                 f'run.precision="{runtime.current()[1]}"']
    return Scene(load(CAVITY_PRESET, overrides), str(CAVITY_PRESET))


def cavity_centrelines(solver):
    """(z, u on x = L/2) and (x, w on z = L/2) of a cavity's gas solver (:func:`cavity_scene`, n even),
    wall values included, both coordinates scaled by the cavity size."""
    n = solver.config.shape[0]
    h = solver.config.h
    L = n * h
    u = solver.face_velocity(0)[n // 2, 0, :]
    w = solver.face_velocity(2)[:, 0, n // 2]
    lid = solver.config.bc("z+").velocity[0]
    zc = np.concatenate([[0.0], (np.arange(n) + 0.5) * h, [L]]) / L
    uc = np.concatenate([[0.0], u, [lid]])
    xc = np.concatenate([[0.0], (np.arange(n) + 0.5) * h, [L]]) / L
    wc = np.concatenate([[0.0], w, [0.0]])
    return (zc, uc), (xc, wc)


def cavity_flow(cells: int, tolerance: float, convection: str, lid_cfl: float, ref: dict,
                seconds: float = 10.0) -> dict:
    """Re = 100 lid-driven unit cavity (lid 1 m/s) from rest to ``seconds`` at steps of ``lid_cfl`` cells
    per step at the lid: RMS difference from Ghia's centreline velocities (u on x = 1/2, w on z = 1/2,
    all their points). 10 s, as the preset: the flow then drifts by ~1e-3 per second."""
    dt = lid_cfl / cells
    sim = build_simulation(cavity_scene(cells, tolerance, convection, dt, seconds))
    n = round(seconds / dt)
    wall = _timed_steps(sim.step, n)
    (zc, uc), (xc, wc) = cavity_centrelines(sim.flow)
    ru, rv = ref["u_on_vertical_centreline"], ref["v_on_horizontal_centreline"]
    diff = np.concatenate([np.interp(ru["y"], zc, uc) - ru["u"], np.interp(rv["x"], xc, wc) - rv["v"]])
    return {"error": float(np.sqrt(np.mean(diff ** 2))), "cost": wall / ((n - 1) * dt)}


def _cavity(settings: dict, size: str) -> dict:
    # 'small' takes twice the preset's step (lid CFL 2.6): the t = 10 s error moves by 4e-5 at 64 cells
    return cavity_flow(settings["cells"], settings["tolerance"], settings["advection"], CAVITY_LID_CFL[size],
                       ghia_reference())


# ------------------------------------------------------------------------------------ registry
CASES = [
    Case("terminal_velocity", "0.1 mm glass grain released in still air ('full': also 0.16 and 0.25 mm), falling "
         "speed at t = 0.2 s (~4 relaxation times, 98% of terminal) against the Schiller-Naumann equation of motion",
         "error of the speed / terminal speed", "wall s per simulated s",
         knobs={"fluid_step": (1e-3, 2e-3, 4e-3, 8e-3), "cell_size": (4e-3, 8e-3, 2e-2),
                "precision": ("float32", "float64")},
         defaults={"fluid_step": 1e-3, "cell_size": 8e-3, "precision": "float32"}, tolerance=0.02,
         measure=_terminal_velocity,
         note="the drag law is Schiller-Naumann itself and the reference integrates the same equation of motion "
              "(terminal speed by brentq), so the error is numerical: the drag's implicit step and the gas the "
              "grain drags along. One DEM step per fluid step (the grain touches nothing). Tolerance 2%, as "
              "tests/test_fluidization.py. A bed's fluid step is bounded by its jets and bubbles, not by this "
              "grain. The 20 mm cells test float32's dilute limit: the grain fills 6e-8 of a cell, so eps rounds "
              "to 1; the laws are coded as beta / phi, so the grain keeps its single-sphere drag (when the "
              "coupling divided beta by phi = 1 - eps, the error was 38%)"),
    Case("ergun", "frozen cubic packed bed (2 mm, eps = 0.476, 80 mm deep) at U = 0.1 m/s ('full': 0.05, 0.1, "
         "0.2 m/s): pressure drop against Ergun",
         "relative error of the pressure drop", "wall s per fluid step",
         knobs={"cell_size": (2e-3, 3e-3, 4e-3, 6e-3), "tolerance": TOLERANCES, "precision": ("float32", "float64")},
         defaults={"cell_size": 4e-3, "tolerance": 1e-6, "precision": "float32"}, tolerance=0.05,
         measure=_ergun,
         note="the drag law (Gidaspow) is Ergun's own below eps = 0.8, so the correlation's +-15-20% scatter does "
              "not enter: the error is numerical, mostly the bed's top and bottom smeared over a cell (about h over "
              "the bed depth, the drag being strongly nonlinear in eps). Tolerance 5%, as "
              "tests/test_fluidization.py: it moves U_mf by as much. Default h = 2 d as the boyce presets"),
    Case("pipe", "laminar flow in a cut-cell cylinder, periodic along its axis ('full': three axis placements "
         "against the grid): axial velocity profile against Hagen-Poiseuille",
         "RMS velocity error / exact centreline velocity", "wall s per simulated s",
         knobs={"cells_across": (8, 16, 32), "tolerance": TOLERANCES, "precision": ("float32", "float64")},
         defaults={"cells_across": 32, "tolerance": 1e-6, "precision": "float32"}, tolerance=0.01,
         measure=_pipe,
         note="exact answer. Default 32 cells across the vessel, as the verma and boyce presets. Tolerance 1%: "
              "the wall shear of a bed's vessel is a small part of its momentum balance"),
    Case("cavity", "lid-driven square cavity at Re = 100 (presets/validation/cavity.toml) at t = 10 s, lid CFL 2.6 "
         "('full': the preset's 1.3): centreline velocities against Ghia, Ghia & Shin 1982",
         "RMS error / lid speed", "wall s per simulated s",
         knobs={"cells": (16, 32, 64), "tolerance": (1e-3, 1e-6), "advection": ("maccormack", "semi_lagrangian"),
                "precision": ("float32", "float64")},
         defaults={"cells": 64, "tolerance": 1e-6, "advection": "maccormack", "precision": "float32"},
         tolerance=0.01, measure=_cavity,
         note="Ghia's values differ from grid-converged solutions by up to ~0.009 (reference README): below 0.01 "
              "the comparison cannot tell. Default 64 cells, as the preset. Tolerance 1e-8 is left out here (10 s "
              "of CPU per 64-cell point): the pipe and ergun cases show its cost"),
]
