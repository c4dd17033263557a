"""Values derived from a Config, computed in one place: grain sizes and masses, contact
constants, damping from restitution, collision times and the DEM step.

Owns: every number the kernels use that is not written in the preset. Plain Python
(numpy/scipy), so it can be unit-tested against hand values.

Damping from restitution is solved exactly, not by a fitted formula: with the normal
force clamped at zero (no attraction), the restitution of a linear spring-dashpot depends
only on the damping ratio zeta, and that of a Hertz spring with damping
``alpha * sqrt(m* k_n) * delta^(1/4) * d(delta)/dt`` depends only on alpha (Antypov &
Elliott 2011, EPL 94:50004, scale invariance). We integrate the dimensionless contact
ODE once and invert it with a root finder, so the set restitution is what the DEM
produces up to its time-step error.
"""
from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from .errors import ConfigError
from .schema import DT_FRACTION_MIN, Config

FOUR_THIRDS_PI = 4.0 / 3.0 * math.pi


def run_steps(duration: float, step: float) -> int:
    """Coupling steps a run takes to reach ``duration`` [s] in steps of ``step`` [s]: the next whole step at or
    after it (a duration that is not a whole number of steps ends up to one step late; `fbed run` says so)."""
    return int(math.ceil(duration / step - 1e-9))


def interval_steps(interval: float, step: float) -> int:
    """Steps between the records of an interval of simulated time [s] in steps of ``step`` [s]: the nearest whole
    number, at least 1 (an interval that is no whole number of steps is taken as that many; `fbed run` says so)."""
    return max(1, int(round(interval / step)))


#: the fewest frames `fbed rcfd` works on (a recurrence needs a state, its successor and one more)
RCFD_MIN_FRAMES = 3


def rcfd_frames(span: float, interval: float) -> int:
    """Whole rCFD frames of ``interval`` [s] recorded over ``span`` [s] (none for a span of 0 or less)."""
    return max(0, math.floor(span / interval + 1e-9))


SMOOTH_ALPHA = 1.0 / 7.0  # explicit diffusion weight per pass of the coupling's smoothing (stable below 1/6 in 3-D)
#: the most smoothing passes a fluid step may take: coupling.smoothing_width = 10 m on fluidize's 5 mm cells was
#: 1.4e7 passes, still in its first step after 15 minutes (a SIGTERM waits for the step); the presets take 1 or 2
MAX_SMOOTHING_PASSES = 1000


def smoothing_passes(width: float, h: float) -> int:
    """Passes giving a Gaussian spread of standard deviation ``width`` [m] (each adds 2 alpha h^2 per axis)."""
    if width <= 0:
        return 0
    return int(math.ceil(width ** 2 / (2 * SMOOTH_ALPHA * h * h)))


#: the most gas cells a preset may ask for: a petabyte at a byte a cell. The memory check (app/scene.py) names the
#: real limit, far below it; this bound only keeps absurd values from the arithmetic of the checks before it
#: (1e-300 m cells: 1e896 cells, and a ZeroDivisionError traceback from the smoothing's passes)
MAX_GAS_CELLS = 10 ** 15

#: the most pixels of one synthetic MRI image, 1024 x 1024 (4 MB a frame in run.h5): 0.25 mm pixels over the poppy
#: bed's 96 mm x 600 mm are 921,600 (the MRI's are 4 mm x 8 mm, 1,800); 1 um pixels in fluidize's column asked Taichi
#: for an array beyond int32 indices, and the host's memory ran out
MRI_MAX_PIXELS = 1 << 20


def mri_pixels(cfg: Config) -> tuple[int, int, float, float, float]:
    """The synthetic MRI's pixel grid: (nx, nz) pixels of probes.mri_pixel over the vessel's width (its diameter,
    or the domain's x extent) and from its floor to its lid (or the domain's top), the vessel's x centre and
    axis y, and the floor z."""
    d, v = cfg.domain, cfg.vessel
    dx, dz = (float(a) for a in cfg.probes.mri_pixel)
    floor = v.floor if v.floor is not None else d.lo[2]
    top = v.lid if v.lid is not None else d.hi[2]
    if v.shape == "cylinder":
        (xc, yc), half_x = v.center, v.radius
    else:
        xc, yc, half_x = 0.5 * (d.lo[0] + d.hi[0]), 0.5 * (d.lo[1] + d.hi[1]), 0.5 * (d.hi[0] - d.lo[0])
    return (int(math.ceil(2.0 * half_x / dx - 1e-9)), int(math.ceil((top - floor) / dz - 1e-9)), float(xc),
            float(yc), float(floor))


def plane_name(z: float) -> str:
    """The run.h5 group of the plane at height ``z`` [m] (to the mm: heights within it are one plane)."""
    return f"z{z:.3f}"


def grain_volume(radius):
    """Volume [m^3] of a grain (a sphere) of ``radius`` [m]: 4/3 pi r^3. One formula for a number, a numpy
    array and a Taichi kernel (``app.sim.coupling.grain_volume_func`` is this function as a ti.func):
    products only, so the three agree to rounding."""
    return FOUR_THIRDS_PI * radius * radius * radius


def grain_mass(radius, density):
    """Mass [kg] of a grain of ``radius`` [m] and ``density`` [kg/m^3]: density times ``grain_volume``."""
    return density * grain_volume(radius)


HERTZ_DURATION_COEFF = 2.868  # t_c = 2.868 (m*^2 / (R* E*^2 v))^(1/5), undamped Hertz impact


# ---------------------------------------------------------------------------- restitution

def _rebound(model: str, c: float) -> float:
    """Restitution of the dimensionless contact with damping parameter c (zeta or alpha)."""
    if c <= 0.0:
        return 1.0

    def rhs(_, y):
        x, v = y
        xp = max(x, 0.0)
        if model == "linear":
            f = xp + 2.0 * c * v
        else:
            f = xp ** 1.5 + c * xp ** 0.25 * v
        return [v, -max(f, 0.0)]

    def back_at_zero(_, y):
        return y[0]

    back_at_zero.terminal, back_at_zero.direction = True, -1
    sol = solve_ivp(rhs, (0.0, 100.0), [1e-12, 1.0], events=back_at_zero, rtol=1e-10, atol=1e-12, max_step=0.01)
    return float(-sol.y_events[0][0][1]) if sol.t_events[0].size else 0.0


@functools.lru_cache(maxsize=64)
def damping_from_restitution(model: str, restitution: float) -> float:
    """Damping parameter giving ``restitution``: zeta (linear) or alpha (hertz_mindlin)."""
    if restitution >= 1.0:
        return 0.0
    hi = 1.0 if model == "linear" else 4.0
    while _rebound(model, hi) > restitution:
        hi *= 2.0
    return float(brentq(lambda c: _rebound(model, c) - restitution, 0.0, hi, xtol=1e-12, rtol=1e-10))


# ---------------------------------------------------------------------------- materials

def effective_moduli(e1: float, nu1: float, e2: float, nu2: float) -> tuple[float, float]:
    """Hertz E* and Mindlin G* [Pa] of two materials."""
    e_star = 1.0 / ((1 - nu1 ** 2) / e1 + (1 - nu2 ** 2) / e2)
    g1, g2 = e1 / (2 * (1 + nu1)), e2 / (2 * (1 + nu2))
    g_star = 1.0 / ((2 - nu1) / g1 + (2 - nu2) / g2)
    return e_star, g_star


def hertz_duration(m_eff: float, r_eff: float, e_star: float, speed: float) -> float:
    """Undamped Hertz contact duration [s] for an impact at ``speed`` [m/s]."""
    return HERTZ_DURATION_COEFF * (m_eff ** 2 / (r_eff * e_star ** 2 * speed)) ** 0.2


def rayleigh_time(radius: float, density: float, youngs: float, poisson: float) -> float:
    """Rayleigh-wave time [s] across a grain (the other common DEM step estimate)."""
    g = youngs / (2 * (1 + poisson))
    return math.pi * radius * math.sqrt(density / g) / (0.1631 * poisson + 0.8766)


@dataclasses.dataclass(frozen=True)
class ContactPair:
    """Constants of one kind of contact (grain-grain or grain-wall), read by the kernels."""

    model: str            # 'hertz_mindlin' | 'linear'
    e_star: float         # [Pa] effective Young's modulus (hertz)
    g_star: float         # [Pa] effective shear modulus (hertz)
    kn: float             # [N/m] normal stiffness (linear)
    kt: float             # [N/m] tangential stiffness (linear)
    damping: float        # zeta (linear) or alpha (hertz), from the restitution
    restitution: float
    friction: float
    rolling_friction: float
    rolling_damping: float  # eta_r of the elastic-plastic rolling model


@dataclasses.dataclass(frozen=True)
class Derived:
    diameters: tuple[float, ...]        # [m] size classes
    number_fractions: tuple[float, ...]  # by number, sum 1
    density: float                      # [kg/m^3]
    polydisperse: bool
    radius_min: float                   # [m]
    radius_max: float                   # [m]
    mass_min: float                     # [kg]
    pair: ContactPair
    wall: ContactPair
    collision_time: float               # [s] shortest grain-grain contact duration at impact_speed
    wall_collision_time: float          # [s]
    rayleigh_time: float                # [s] of the smallest grain (hertz), else 0
    dt: float                           # [s] DEM step actually used
    dt_limit: float                     # [s] largest step accepted without force_dt
    substeps: int                       # DEM steps per run.step
    skin: float                         # [m] Verlet skin
    friction: bool                      # any tangential force (grain or wall)
    rolling: str                        # 'none' | 'constant_torque' | 'epsd'
    periodic: tuple = (False, False, False)  # axes whose [boundary] faces are periodic (grains wrap there too)

    @staticmethod
    def volume(d):
        """Volume [m^3] of grains of diameter d [m] (a number or an array): ``grain_volume`` of d / 2."""
        return grain_volume(np.asarray(d, float) / 2.0)

    def mass(self, d):
        """Mass [kg] of grains of diameter d [m] (a number or an array): ``grain_mass`` of d / 2."""
        return grain_mass(np.asarray(d, float) / 2.0, self.density)


def periodic_axes(cfg: Config) -> tuple[bool, bool, bool]:
    """Whether each axis has periodic faces: both of its [boundary] faces of kind 'periodic' (the rules check
    that they come in pairs). Grains and gas wrap there alike."""
    faces = dict(cfg.boundary)
    return tuple(all(faces.get(ax + s) is not None and faces[ax + s].kind == "periodic" for s in "-+")
                 for ax in "xyz")


def gas_shape(cfg: Config) -> tuple[int, int, int]:
    """The gas grid's cells along x, y, z: the domain over gas.cell_size (the rules check it divides)."""
    d = cfg.domain
    return tuple(int(round((d.hi[a] - d.lo[a]) / cfg.gas.cell_size)) for a in range(3))


def inlet_peak_speeds(face) -> tuple[float, float]:
    """A [boundary] face's fastest superficial speeds [m/s]: (its uniform velocity times the schedule's largest
    fraction, its jet's); (0, 0) for a face that is not a velocity inlet."""
    if face.kind != "velocity_inlet":
        return 0.0, 0.0
    peak = max([abs(f) for _, f in face.schedule] or [1.0])
    jet = math.hypot(*face.jet_velocity) if face.jet_radius > 0 else 0.0
    return math.hypot(*face.velocity) * peak, jet


def size_distribution(cfg: Config) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Size classes and number fractions; mass fractions are converted (n_k ~ f_k / d_k^3)."""
    p = cfg.particles
    if p.diameters:
        d = np.asarray(p.diameters, float)
        f = np.asarray(p.fractions, float)
        if p.fractions_by == "mass":
            f = f / d ** 3
        f = f / f.sum()
        return tuple(d.tolist()), tuple(f.tolist())
    return (p.diameter,), (1.0,)


def _pair(model, e_star, g_star, kn, kt_ratio, e, mu, mu_r, eta_r) -> ContactPair:
    return ContactPair(model=model, e_star=e_star, g_star=g_star, kn=kn, kt=kt_ratio * kn,
                       damping=damping_from_restitution(model, e), restitution=e, friction=mu, rolling_friction=mu_r,
                       rolling_damping=eta_r)


def derive(cfg: Config, file: str = "<preset>") -> Derived:
    """All derived values of a validated Config (raises ConfigError for a refused DEM step)."""
    c, p = cfg.contact, cfg.particles
    diam, frac = size_distribution(cfg)
    rmin, rmax = min(diam) / 2, max(diam) / 2
    mmin = float(grain_mass(rmin, p.density))
    e_w = c.wall_youngs_modulus if c.wall_youngs_modulus is not None else c.youngs_modulus
    nu_w = c.wall_poisson_ratio if c.wall_poisson_ratio is not None else c.poisson_ratio
    es, gs = effective_moduli(c.youngs_modulus, c.poisson_ratio, c.youngs_modulus, c.poisson_ratio)
    esw, gsw = effective_moduli(c.youngs_modulus, c.poisson_ratio, e_w, nu_w)
    wall_e = c.wall_restitution if c.wall_restitution is not None else c.restitution
    wall_mu = c.wall_friction if c.wall_friction is not None else c.friction
    wall_mur = c.wall_rolling_friction if c.wall_rolling_friction is not None else c.rolling_friction
    wall_etar = c.wall_rolling_damping if c.wall_rolling_damping is not None else c.rolling_damping
    pair = _pair(c.model, es, gs, c.normal_stiffness, c.tangential_stiffness_ratio, c.restitution, c.friction,
                 c.rolling_friction, c.rolling_damping)
    wall = _pair(c.model, esw, gsw, c.normal_stiffness, c.tangential_stiffness_ratio, wall_e, wall_mu, wall_mur,
                 wall_etar)

    v = cfg.dem.impact_speed
    if c.model == "hertz_mindlin":
        tc = hertz_duration(mmin / 2, rmin / 2, es, v)
        tcw = hertz_duration(mmin, rmin, esw, v)
        t_r = rayleigh_time(rmin, p.density, c.youngs_modulus, c.poisson_ratio)
    else:
        tc = math.pi * math.sqrt((mmin / 2) / c.normal_stiffness)
        tcw = math.pi * math.sqrt(mmin / c.normal_stiffness)
        t_r = 0.0
    t_short = min(tc, tcw)
    limit = cfg.dem.max_dt_fraction * t_short
    dt = cfg.dem.dt if cfg.dem.dt > 0 else cfg.dem.dt_fraction * t_short
    if dt > limit and not cfg.dem.force_dt and cfg.dem.dt == 0:  # (the hint had said to lower dem.dt, which was 0)
        raise ConfigError(
            f"dem.dt_fraction = {cfg.dem.dt_fraction:g} of the {t_short:.3g} s collision time (at {v:g} m/s) is above "
            f"dem.max_dt_fraction = {cfg.dem.max_dt_fraction:g}, the stable limit", file, "dem.dt_fraction",
            hint=f"dem.dt_fraction at most {cfg.dem.max_dt_fraction:g} (default 0.05), or set dem.force_dt = true to "
                 "run anyway")
    if dt > limit and not cfg.dem.force_dt:
        raise ConfigError(
            f"{dt:.3g} s is above the stable limit {limit:.3g} s "
            f"({cfg.dem.max_dt_fraction:g} x the {t_short:.3g} s collision time at {v:g} m/s)",
            file, "dem.dt",
            hint="lower dem.dt (0 picks dt_fraction x collision time), soften contact.youngs_modulus, "
                 "or set dem.force_dt = true to run anyway")
    if dt < DT_FRACTION_MIN * t_short:  # (an explicit dem.dt: dt_fraction has this bound)
        raise ConfigError(f"{dt:.3g} s is {t_short / dt:.3g} times shorter than the {t_short:.3g} s collision time: "
                          f"below {DT_FRACTION_MIN:g} of it a step buys no accuracy and costs "
                          f"{math.ceil(cfg.run.step / dt):,} substeps a {cfg.run.step:g} s step", file, "dem.dt",
                          hint="dem.dt = 0: the automatic step, dem.dt_fraction x the collision time")
    substeps = max(1, math.ceil(cfg.run.step / dt - 1e-9))
    dt = cfg.run.step / substeps
    skin = cfg.dem.skin if cfg.dem.skin > 0 else 0.15 * 2 * rmax
    friction = c.friction > 0 or wall_mu > 0
    periodic = periodic_axes(cfg)
    cut = 2 * rmax + skin
    for a, ax in enumerate("xyz"):
        period = cfg.domain.hi[a] - cfg.domain.lo[a]
        if periodic[a] and period < 3 * cut * (1 - 1e-9):
            # the cell list needs 3 cells of at least one cut-off across a period, so the 27 cells around a
            # grain are distinct and a pair meets only its nearest image
            raise ConfigError(f"the periodic {ax} extent ({period:g} m) is under 3 contact cut-offs "
                              f"(3 x (largest diameter + skin) = {3 * cut:g} m)", file, "domain.hi",
                              hint=f"widen the domain along {ax} to at least {3 * cut:g} m, or close the {ax} faces")
    return Derived(diameters=diam, number_fractions=frac, density=p.density, polydisperse=len(diam) > 1,
                   radius_min=rmin, radius_max=rmax, mass_min=mmin, pair=pair, wall=wall,
                   collision_time=tc, wall_collision_time=tcw, rayleigh_time=t_r, dt=dt, dt_limit=limit,
                   substeps=substeps, skin=skin, friction=friction,
                   rolling=c.rolling_model if (c.rolling_friction > 0 or wall_mur > 0) else "none",
                   periodic=periodic)
