"""Accuracy cases of the DEM alone: restitution of a Hertz pair against the DEM step.

Owns: the two-grain scenes and their measures. Costs here are DEM steps per contact: a bed's DEM
wall time is proportional to it, while a two-grain run's own wall time measures kernel launches.
"""
from __future__ import annotations

import time

import numpy as np

from . import Case

PAIR = """
[run]
duration = 1.0
step = 1.0e-3
precision = "{precision}"
[domain]
lo = [-0.01, -0.01, -0.01]
hi = [0.01, 0.01, 0.01]
gravity = [0.0, 0.0, 0.0]
[vessel]
shape = "none"
[particles]
count = 2
diameter = 2.0e-3
density = 2500.0
[contact]
model = "hertz_mindlin"
youngs_modulus = {E}
restitution = {e}
friction = 0.0
[dem]
dt_fraction = {f}
max_dt_fraction = 0.5
force_dt = true
impact_speed = {v}
"""
DT_FRACTIONS = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2)


def pair_collision(dt_fraction: float, e: float = 0.9, v: float = 0.5, precision: str = "float32",
                   youngs_modulus: float = 5.0e6) -> dict:
    """A head-on Hertz pair at v [m/s]: the measured restitution against the one set (the damping is
    solved exactly from it in app.config.derived, so the error is the time integration's), the steps
    the contact took, and the wall time of the substeps (one thread)."""
    from ..config import load_text
    from ..scene import Scene
    from ..sim.dem import DemSolver

    text = PAIR.format(precision=precision, e=e, f=dt_fraction, v=v, E=youngs_modulus)
    scene = Scene(load_text(text, "pair.toml"), "pair.toml")
    dem = DemSolver(scene.model)
    r, gap = 1.0e-3, 1.0e-9
    dem.set_grains(np.array([[-r - gap, 0, 0], [r + gap, 0, 0]]), np.array([[v / 2, 0, 0], [-v / 2, 0, 0]]),
                   np.full(2, r))
    dt = scene.derived.dt
    steps, touching_steps = 0, 0
    t0 = time.perf_counter()
    while steps < 200000:
        dem.advance(1)
        steps += 1
        x = dem.state.x.to_numpy()
        sep = x[1, 0] - x[0, 0]
        if sep < 2 * r:
            touching_steps += 1
        elif touching_steps:
            break
    wall = time.perf_counter() - t0
    vel = dem.state.v.to_numpy()
    e_measured = (vel[1, 0] - vel[0, 0]) / v
    return {"dt_fraction": dt_fraction, "dt": dt, "steps_per_contact": touching_steps,
            "restitution_error": abs(e_measured - e) / e, "wall_ms": 1e3 * wall,
            "collision_time": scene.derived.collision_time}


def _restitution(settings: dict, size: str) -> dict:
    row = pair_collision(settings["dt_fraction"], precision=settings["precision"])
    return {"error": row["restitution_error"], "cost": row["steps_per_contact"]}


CASES = [
    Case("restitution", "head-on Hertz pair (2 mm, E = 5 MPa, e = 0.9, 0.5 m/s): rebound speed ratio against e",
         "relative error of e", "DEM steps per contact",
         knobs={"dt_fraction": DT_FRACTIONS, "precision": ("float32", "float64")},
         defaults={"dt_fraction": 0.05, "precision": "float32"}, tolerance=0.01, measure=_restitution,
         note="symplectic Euler: error O(dt / t_c)"),
]
