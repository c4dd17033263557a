"""Rules that involve more than one key (each names the key to change)."""
from __future__ import annotations

import pathlib

from .derived import (MAX_GAS_CELLS, MAX_SMOOTHING_PASSES, MRI_MAX_PIXELS, inlet_peak_speeds, mri_pixels,
                      periodic_axes, plane_name, smoothing_passes)
from .errors import ConfigError, find_line
from .schema import Config


def check(cfg: Config, file: str, text: str) -> None:
    """Raise ConfigError on the first rule ``cfg`` (read from ``file``, whose ``text`` locates the key's line)
    breaks; the rules are checked in a fixed order (domain and vessel, rCFD, gas and boundaries, grains and
    contacts, output and video, probes), so the same preset always names the same key."""
    def fail(section, key, message, hint=""):
        raise ConfigError(message, file, f"{section}.{key}", find_line(text, section, key), hint)

    _domain_and_vessel(cfg, fail)
    _rcfd(cfg, fail)
    if cfg.particles is None and cfg.gas is None:
        raise ConfigError("nothing to simulate: the preset has neither [particles] nor [gas]", file, "particles",
                          None, "add a [particles] section (grains) and/or a [gas] section (gas flow)")
    _gas_and_boundaries(cfg, fail)
    _particles_and_contact(cfg, fail)
    _output_and_video(cfg, fail)
    _probes(cfg, fail)


def _domain_and_vessel(cfg: Config, fail) -> None:
    d = cfg.domain
    for a, (lo, hi) in enumerate(zip(d.lo, d.hi)):
        if hi <= lo:
            fail("domain", "hi", f"upper corner must exceed the lower one along {'xyz'[a]} "
                 f"({hi:g} m <= {lo:g} m)", "swap or correct domain.lo / domain.hi")
    v = cfg.vessel
    if v.shape == "cylinder":
        if v.radius <= 0:
            fail("vessel", "radius", "a cylinder vessel needs a radius > 0 m", "set vessel.radius in metres")
        cx, cy = v.center
        if cx - v.radius < d.lo[0] - 1e-12 or cx + v.radius > d.hi[0] + 1e-12 or \
           cy - v.radius < d.lo[1] - 1e-12 or cy + v.radius > d.hi[1] + 1e-12:
            fail("vessel", "radius", f"the cylinder (radius {v.radius:g} m at {v.center}) does not fit in the domain "
                 f"x {d.lo[0]:g}..{d.hi[0]:g} m, y {d.lo[1]:g}..{d.hi[1]:g} m", "enlarge the domain or reduce the radius")
    if v.shape == "sampled" and not v.sdf_file:
        fail("vessel", "sdf_file", "shape = 'sampled' needs an sdf_file (.npz)")
    for key in ("floor", "lid"):
        z = getattr(v, key)
        if z is not None and not (d.lo[2] <= z <= d.hi[2]):
            fail("vessel", key, f"{z:g} m lies outside the domain's z range {d.lo[2]:g}..{d.hi[2]:g} m")
    if v.floor is not None and v.lid is not None and v.lid <= v.floor:
        fail("vessel", "lid", f"the lid ({v.lid:g} m) must be above the floor ({v.floor:g} m)")


def _rcfd(cfg: Config, fail) -> None:
    pr = cfg.probes
    if pr.rcfd_from >= 0:
        from ..rcfd.database import parse_tag  # h5py and scipy.sparse: only for rCFD scenes

        try:
            axis, _, value = parse_tag(pr.rcfd_tag)
        except ValueError as err:
            fail("probes", "rcfd_tag", str(err))
        lo, hi = cfg.domain.lo[axis], cfg.domain.hi[axis]
        if not lo < value < hi:  # 'z>100' tagged no grain: every rCFD index NaN (validate: after all its runs)
            fail("probes", "rcfd_tag", f"the tag {pr.rcfd_tag!r} tags all or none of the domain "
                 f"({'xyz'[axis]} {lo:g}..{hi:g} m)", "give a value inside it, e.g. 'x<0' for the half x < 0")
        if cfg.gas is None or cfg.particles is None:
            fail("probes", "rcfd_from", "rCFD frames need both grains and gas", "set probes.rcfd_from = -1")
        if pr.rcfd_interval < cfg.run.step * (1 - 1e-9):  # (0.5 ms in 1 ms steps had made 1 ms frames, silently)
            fail("probes", "rcfd_interval", f"shorter than run.step ({cfg.run.step:g} s): a frame is a whole number "
                 "of fluid steps", f"probes.rcfd_interval a multiple of {cfg.run.step:g} s (the default: 0.005)")


def _gas_and_boundaries(cfg: Config, fail) -> None:
    d = cfg.domain
    g = cfg.gas
    if g is not None and cfg.particles is not None and g.viscosity == 0:  # (a gas alone may be inviscid)
        fail("gas", "viscosity", "0 Pa s makes the grains' Reynolds number rho |w| d / mu infinite, on which every "
             "drag law is written (di_felice, beetstra, tang and koch_hill drag came out NaN; stokes gave none)",
             "give the gas's viscosity, e.g. 1.8e-5 Pa s for air at 20 C")
    if g is not None:
        cells = 1
        for a in range(3):
            n = (d.hi[a] - d.lo[a]) / g.cell_size
            if abs(n - round(n)) > 1e-6 * max(1.0, n) or round(n) < 1:
                fail("gas", "cell_size", f"the domain's {'xyz'[a]} extent {d.hi[a] - d.lo[a]:g} m is not a whole "
                     f"number of {g.cell_size:g} m cells ({n:.4g})", "adjust gas.cell_size or domain.lo / domain.hi")
            cells *= round(n)
        if cells > MAX_GAS_CELLS:
            fail("gas", "cell_size", f"{g.cell_size:g} m cells make more than {MAX_GAS_CELLS:.0e} gas cells, beyond "
                 "any machine's memory", "cells of a few grain diameters (the presets: 3-10 mm)")
        if g.tolerance > cfg.guard.max_divergence:  # (the guard blamed gas.max_iterations at the first check)
            fail("gas", "tolerance", f"the pressure solve stops at a relative divergence of {g.tolerance:g}, above "
                 f"guard.max_divergence = {cfg.guard.max_divergence:g}, for which the guard stops the run",
                 f"gas.tolerance at most {cfg.guard.max_divergence:g} (default 1e-6), or raise guard.max_divergence")
        _periodic_pairs(cfg, fail)
        _smoothing(cfg, fail)
        for face, b in dict(cfg.boundary).items():
            _boundary_face(face, b, fail)
            _inlet_speed(face, b, cfg.guard.max_gas_speed, fail)
        _gas_way_out(dict(cfg.boundary), fail)
    else:
        for face, b in cfg.boundary:  # without gas only periodic faces mean something (the grains wrap)
            if b.kind != "periodic":
                fail("boundary", face, f"a {b.kind} boundary needs a [gas] section",
                     "add [gas], or keep only periodic faces (they wrap the grains)")
        _periodic_pairs(cfg, fail)


def _smoothing(cfg: Config, fail) -> None:
    """More than MAX_SMOOTHING_PASSES passes a fluid step: the width is blamed when it is beyond three grain
    diameters (the usual width is one or two), else the cells (1e-5 m cells under fluidize's 3 mm width)."""
    width, h, p = cfg.coupling.smoothing_width, cfg.gas.cell_size, cfg.particles
    passes = smoothing_passes(width, h)
    if p is None or passes <= MAX_SMOOTHING_PASSES:
        return
    what = (f"coupling.smoothing_width = {width:g} m on gas.cell_size = {h:g} m cells is {passes:.3g} smoothing passes "
            f"a fluid step (at most {MAX_SMOOTHING_PASSES}; each pass sweeps the grid)")
    if width > 3 * max(p.diameters or [p.diameter]):
        fail("coupling", "smoothing_width", what, "a grain diameter or two (the presets: 1.5-4 mm, 1 or 2 passes)")
    fail("gas", "cell_size", what, "unresolved CFD-DEM wants cells of a few grain diameters")


def _periodic_pairs(cfg: Config, fail) -> None:
    faces = dict(cfg.boundary)
    for ax in "xyz":
        lo_p = faces.get(ax + "-") is not None and faces[ax + "-"].kind == "periodic"
        hi_p = faces.get(ax + "+") is not None and faces[ax + "+"].kind == "periodic"
        if lo_p != hi_p:
            fail("boundary", ax + "-", f"periodic boundaries come in pairs: set both {ax}- and {ax}+ periodic")


def _gas_way_out(faces: dict, fail) -> None:
    """Gas blown in through velocity inlets needs a way out: with no pressure outlet, inlets that only blow inwards
    left the incompressible solve without a solution, and the guard stopped the first step blaming the solver's
    iterations. Inlets of mixed sign may balance (one blowing in, one drawing out), and are left to the guard."""
    if any(b.kind == "pressure_outlet" for b in faces.values()):
        return
    inlets = {f: b for f, b in faces.items() if b.kind == "velocity_inlet"}

    def into(f: str, v) -> float:  # v's component into the domain through face f
        return (1.0 if f[1] == "-" else -1.0) * v["xyz".index(f[0])]
    inward = {f: into(f, b.velocity) for f, b in inlets.items()}
    jets = {f: into(f, b.jet_velocity) for f, b in inlets.items()}
    fractions = [r[1] for b in inlets.values() for r in b.schedule]
    if (all(v >= 0 for v in (*inward.values(), *jets.values(), *fractions))
            and any(v > 0 for v in (*inward.values(), *jets.values()))):
        face = next(f for f in inlets if inward[f] > 0 or jets[f] > 0)
        fail("boundary", face, "gas is blown in through velocity inlets and let out nowhere: no face is a "
             "pressure_outlet, and the incompressible gas has no solution",
             "add one, e.g. top = { kind = \"pressure_outlet\" } (0 Pa: the atmosphere)")


def _inlet_speed(face: str, b, most: float, fail) -> None:
    """An inlet or jet faster than guard.max_gas_speed: the guard would stop the run as it opens, blaming the gas
    step (inlets of 1e6 m/s, a schedule's fraction of 1e9, a 1e5 m/s jet: found by running the keys at their edges).
    The gas there moves at least at the superficial speed given."""
    uniform, jet = inlet_peak_speeds(b)  # (0, 0) for a face that blows nothing
    scaled = " x the schedule's largest fraction" if b.schedule else ""
    speed, what = max((uniform, "velocity" + scaled), (jet, "jet_velocity"))
    if speed > most:
        fail("boundary", face, f"its {what} blows at {speed:.4g} m/s, above guard.max_gas_speed = {most:g} m/s: the "
             "guard would stop the run as the inlet opens", "correct the inlet, or raise guard.max_gas_speed above "
             "it if such speeds are meant (the default 300 m/s serves jets of 50-100 m/s)")


def _boundary_face(face: str, b, fail) -> None:
    axis = "xyz".index(face[0])
    inlet_only = [k for k in ("schedule", "jet_radius", "jet_duration", "jet_ramp", "jet_start")
                  if getattr(b, k)] + (["jet_velocity"] if any(b.jet_velocity) else [])
    if inlet_only and b.kind != "velocity_inlet":
        fail("boundary", face, f"{inlet_only[0]} applies to a velocity_inlet, not to a {b.kind}")
    if b.schedule:
        rows = b.schedule
        ok = all(isinstance(r, list) and len(r) == 2 and all(isinstance(v, (int, float)) and
                                                               not isinstance(v, bool) for v in r) for r in rows)
        if not ok:
            fail("boundary", face, "schedule must be a list of [time (s), fraction] pairs",
                 "e.g. schedule = [[0.0, 0.0], [0.3, 0.0], [0.35, 1.0]]")
        times = [r[0] for r in rows]
        if any(t1 <= t0 for t0, t1 in zip(times, times[1:])):
            fail("boundary", face, "schedule times must increase", "sort the [time, fraction] pairs by time")
        if b.start or b.ramp:
            fail("boundary", face, "give either schedule or start/ramp, not both")
    if any(b.jet_velocity) and b.jet_radius <= 0:
        fail("boundary", face, "a jet needs jet_radius > 0 m (the face cells within it blow)")
    if b.jet_duration and b.jet_duration < 2 * b.jet_ramp:
        fail("boundary", face, f"jet_duration ({b.jet_duration:g} s) is shorter than its two ramps "
             f"(2 x {b.jet_ramp:g} s)")
    if b.kind == "moving_wall" and b.velocity[axis] != 0:
        fail("boundary", face, f"a moving wall slides along itself: its {face[0]} velocity must be 0")


def _particles_and_contact(cfg: Config, fail) -> None:
    d = cfg.domain
    p = cfg.particles
    if p is None:
        return
    if p.diameters:
        if p.diameter:
            fail("particles", "diameter", "give either diameter (monodisperse) or diameters (a size distribution), not both")
        if len(p.fractions) != len(p.diameters):
            fail("particles", "fractions", f"{len(p.fractions)} fractions for {len(p.diameters)} diameters",
                 "give one fraction per diameter")
        if any(not isinstance(x, float) or x <= 0 for x in p.diameters):
            fail("particles", "diameters", "every diameter must be a number > 0 (m)")
        if any(not isinstance(x, float) or x < 0 for x in p.fractions) or sum(p.fractions) <= 0:
            fail("particles", "fractions", "fractions must be numbers >= 0 with a positive sum")
    elif p.diameter <= 0:
        fail("particles", "diameter", "grains need a diameter > 0 m", "set particles.diameter (m) or particles.diameters")
    dmax = max(p.diameters) if p.diameters else p.diameter
    width = min(h - l for l, h in zip(d.lo, d.hi))
    if dmax >= width:
        fail("particles", "diameter", f"grains of {dmax:g} m do not fit in a domain {width:g} m wide")
    far = max(abs(v) for v in (*d.lo, *d.hi))
    rmin = 0.5 * min(p.diameters or [p.diameter])
    if cfg.run.precision == "float32" and far * 2.0 ** -23 > 0.01 * rmin:  # 1e6 m: grains on one float32 point
        fail("domain", "hi" if far in map(abs, d.hi) else "lo", f"in float32 positions {far:g} m from the origin "
             f"are {far * 2.0 ** -23:.2g} m apart, more than 1% of the smallest grain's radius ({rmin:g} m): the "
             "grains cannot move in such steps",
             "a smaller domain, or one placed about the origin, or run.precision = 'float64'")
    sources = sum([p.count > 0, p.bed_height > 0, bool(p.initial_state)])
    if sources == 0:
        fail("particles", "count", "say how many grains: count, bed_height (m) or initial_state (a bed.h5)")
    if sources > 1:
        fail("particles", "count", "give only one of count, bed_height and initial_state")
    periodic = [ax for ax, p in zip("xyz", periodic_axes(cfg)) if p]  # pairs checked above (_periodic_pairs)
    if "z" in periodic:
        fail("boundary", "z-", "grains cannot wrap vertically: the floor holds the bed up",
             "close z- / z+ (e.g. a velocity_inlet below and a pressure_outlet on top)")
    if periodic and cfg.vessel.shape not in ("box", "none"):
        fail("vessel", "shape", f"a periodic {periodic[0]} axis needs vessel.shape = 'box' (walls on the closed "
             f"faces only) or 'none', not '{cfg.vessel.shape}'", "set vessel.shape = 'box', or close the "
             f"{periodic[0]} faces")
    c = cfg.contact
    if c.model == "linear" and c.normal_stiffness <= 0:
        fail("contact", "normal_stiffness", "the linear model needs normal_stiffness > 0 N/m")
    rolling = c.rolling_friction > 0 or (c.wall_rolling_friction or 0) > 0
    if rolling and c.rolling_model == "none":
        fail("contact", "rolling_model", "rolling_friction is set but rolling_model = 'none'",
             "choose 'constant_torque' or 'epsd', or set rolling_friction = 0")
    if c.rolling_model != "none" and not rolling:
        fail("contact", "rolling_friction", f"rolling_model = '{c.rolling_model}' needs rolling_friction > 0")
    if c.rolling_model != "none" and c.friction == 0 and (c.wall_friction or 0) == 0:
        fail("contact", "friction", "rolling resistance needs friction > 0 (grains must be able to roll)")


def mp4_name(name: str) -> bool:
    """Whether ``name`` names an .mp4 file (video.file, and `fbed run --video FILE`): the video is H.264 in MP4."""
    return not name.endswith(("/", "\\")) and pathlib.PurePath(name).suffix.lower() == ".mp4"


def _output_and_video(cfg: Config, fail) -> None:
    if cfg.output.particles_interval and cfg.output.particles_interval < cfg.run.step:
        fail("output", "particles_interval", f"shorter than run.step ({cfg.run.step:g} s)")
    vid = cfg.video
    if vid.file and not mp4_name(vid.file):
        fail("video", "file", f"'{vid.file}' is not an .mp4 file's name (the video is H.264 in an MP4 file)",
             "e.g. video.file = 'bubble.mp4' (relative to the output folder), or leave it out for video.mp4")
    if vid.enabled or vid.file:
        if cfg.particles is None:
            fail("video", "enabled", "the renderer draws grains: this scene has none", "remove --video / video.enabled")
        if vid.color == "void_fraction" and cfg.gas is None:
            fail("video", "color", "colouring by void fraction needs a [gas] section",
                 "choose video.color = 'speed', 'height', 'size' or 'tracer'")
        lo, hi = vid.color_range
        if (lo, hi) != (0.0, 0.0) and hi <= lo:
            fail("video", "color_range", f"the upper end ({hi:g}) must exceed the lower end ({lo:g})",
                 "give [low, high], or [0, 0] for automatic")


def _probes(cfg: Config, fail) -> None:
    d = cfg.domain
    pr = cfg.probes
    if (pr.slab_interval or pr.planes_interval or pr.volume_interval) and cfg.gas is None:
        fail("probes", "slab_interval" if pr.slab_interval else "planes_interval" if pr.planes_interval
             else "volume_interval", "void-fraction probes need a [gas] section (the grid they sample)")
    if pr.mri_interval:
        if cfg.gas is None or cfg.particles is None:
            fail("probes", "mri_interval", "the synthetic MRI is recorded in coupled scenes: it needs [particles] "
                 "and [gas]")
        if any(not isinstance(v, float) or v <= 0 for v in pr.mri_pixel):
            fail("probes", "mri_pixel", "pixel sizes must be numbers > 0 (m)", "e.g. mri_pixel = [0.004, 0.008]")
        nx, nz = mri_pixels(cfg)[:2]
        if nx * nz > MRI_MAX_PIXELS:
            fail("probes", "mri_pixel", f"{nx:,} x {nz:,} pixels an image; at most {MRI_MAX_PIXELS:,}",
                 "give a larger pixel (the MRI's: [0.004, 0.008])")
    if pr.analysis == "mri" and not (pr.mri_interval or pr.slab_interval):
        fail("probes", "analysis", "the mri analysis reads /mri or /slab images",
             "set probes.mri_interval and/or probes.slab_interval (the MRI's 4 ms: 0.004)")
    if pr.planes:
        if any(not isinstance(z, float) for z in pr.planes) or not all(d.lo[2] < z < d.hi[2] for z in pr.planes):
            fail("probes", "planes", f"plane heights must be numbers inside the domain ({d.lo[2]:g}..{d.hi[2]:g} m)")
        if not pr.planes_interval:
            fail("probes", "planes_interval", "planes are given but planes_interval = 0", "set it, e.g. 2e-3 s")
        names = [plane_name(z) for z in pr.planes]
        if len(set(names)) < len(names):  # [0.05, 0.05] recorded each frame twice into one group
            same = next(n for n in names if names.count(n) > 1)
            fail("probes", "planes", f"two heights are the same plane, {same[1:]} m (planes are named to the mm)",
                 "give each height once, at least 1 mm apart")
    for key in ("slab_interval", "planes_interval", "volume_interval", "mri_interval"):
        v = getattr(pr, key)
        if v and v < cfg.run.step * (1 - 1e-9):
            fail("probes", key, f"shorter than run.step ({cfg.run.step:g} s)")
