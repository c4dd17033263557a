"""Accuracy cases of the DEM alone: restitution and contact duration of a Hertz pair against the DEM step.

Owns: the two-grain scenes and their measures. Costs here are DEM steps per contact: a bed's DEM
wall time is proportional to it, while a two-grain run's own wall time measures kernel launches.
"""
from __future__ import annotations

import time

import numpy as np
from scipy.special import beta

from ..config import load_text
from ..config.derived import grain_mass
from ..scene import Scene, build_simulation
from .cases import Case

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
    the contact took, the wall time of the substeps (one thread), and the touching interval
    interpolated between steps [s] (contact_duration) with the exact elastic Hertz one (hertz_duration:
    the reference when e = 1)."""
    text = PAIR.format(precision=precision, e=e, f=dt_fraction, v=v, E=youngs_modulus)
    r, gap = 1.0e-3, 1.0e-9
    grains = {"position": np.array([[-r - gap, 0, 0], [r + gap, 0, 0]]),
              "velocity": np.array([[v / 2, 0, 0], [-v / 2, 0, 0]]), "radius": np.full(2, r)}
    scene = Scene(load_text(text, "pair.toml"), "pair.toml", initial=grains)
    dem = build_simulation(scene).dem   # stepped one DEM step at a time: the contact is resolved step by step
    dt = scene.derived.dt
    steps, touching_steps = 0, 0
    sep_before = 2 * (r + gap)
    t_in = t_out = float("nan")
    t0 = time.perf_counter()
    while steps < 200000:
        dem.advance(1)
        steps += 1
        x = dem.read("position")
        sep = float(x[1, 0] - x[0, 0])
        # within a step the grains move at the step's end velocity (symplectic Euler), so the
        # separation is linear in time between two steps: interpolating its crossings of 2r is exact
        if sep < 2 * r <= sep_before:
            t_in = (steps - 1 + (sep_before - 2 * r) / (sep_before - sep)) * dt
        if sep < 2 * r:
            touching_steps += 1
        elif touching_steps:
            t_out = (steps - 1 + (2 * r - sep_before) / (sep - sep_before)) * dt
            break
        sep_before = sep
    wall = time.perf_counter() - t0
    vel = dem.read("velocity")
    e_measured = (vel[1, 0] - vel[0, 0]) / v
    return {"dt_fraction": dt_fraction, "dt": dt, "steps_per_contact": touching_steps,
            "restitution_error": abs(e_measured - e) / e, "wall_ms": 1e3 * wall,
            "collision_time": scene.derived.collision_time, "contact_duration": t_out - t_in,
            "hertz_duration": hertz_duration_exact(scene.cfg, r, v)}


def hertz_duration_exact(cfg, radius: float, speed: float) -> float:
    """Elastic Hertz contact duration [s] of two equal grains of ``radius`` [m] meeting at ``speed``
    [m/s], with the exact coefficient (4/5) (15/16)^(2/5) B(2/5, 1/2) = 2.86827 (app.config.derived
    rounds it to 2.868 to pick the step; the reference must not carry that rounding)."""
    c = cfg.contact
    m_eff = grain_mass(radius, cfg.particles.density) / 2
    e_star = c.youngs_modulus / (2 * (1 - c.poisson_ratio ** 2))
    coeff = 0.8 * (15.0 / 16.0) ** 0.4 * beta(0.4, 0.5)
    return coeff * (m_eff ** 2 / ((radius / 2) * e_star ** 2 * speed)) ** 0.2


def _restitution(settings: dict, size: str) -> dict:
    row = pair_collision(settings["dt_fraction"], precision=settings["precision"])
    return {"error": row["restitution_error"], "cost": row["steps_per_contact"]}


def _contact_time(settings: dict, size: str) -> dict:
    speeds = (0.2, 0.5, 2.0) if size == "full" else (0.5,)
    rows = [pair_collision(settings["dt_fraction"], e=1.0, v=v, precision=settings["precision"]) for v in speeds]
    errors = [abs(r["contact_duration"] / r["hertz_duration"] - 1.0) for r in rows]
    return {"error": max(errors), "cost": rows[0]["steps_per_contact"],
            "contact_duration": rows[0]["contact_duration"], "hertz_duration": rows[0]["hertz_duration"]}


CASES = [
    Case("restitution", "head-on Hertz pair (2 mm, E = 5 MPa, e = 0.9, 0.5 m/s): rebound speed ratio against e",
         "relative error of e", "DEM steps per contact",
         knobs={"dt_fraction": DT_FRACTIONS, "precision": ("float32", "float64")},
         defaults={"dt_fraction": 0.05, "precision": "float32"}, tolerance=0.01, measure=_restitution,
         note="symplectic Euler: error O(dt / t_c)"),
    Case("contact_time", "head-on elastic Hertz pair (2 mm, E = 5 MPa, e = 1, 0.5 m/s; 'full': also 0.2 and 2 m/s): "
         "contact duration against Hertz's 2.868 (m*^2 / (R* E*^2 v))^(1/5)",
         "relative error of the contact duration", "DEM steps per contact",
         knobs={"dt_fraction": DT_FRACTIONS, "precision": ("float32", "float64")},
         defaults={"dt_fraction": 0.05, "precision": "float32"}, tolerance=0.01, measure=_contact_time,
         note="the reference is exact (Hertz's closed form); the touching interval is interpolated between steps, "
              "so the error is the integration's, not the sampling's. Tolerance 1%: the duration sets the DEM step "
              "and the stress relaxation of a bed, and 1% is below every other error of a bed run"),
]
