"""From a Config to a ready Simulation: decide what this scene needs and allocate only that.

Owns: building the vessel walls, the number and sizes of grains, the initial placement
(lattice filler or an earlier run's bed), and the compile-time ``DemModel`` (friction or
not, rolling model, mono- or polydisperse): the ``Scene`` (plain numpy, no Taichi memory).
Then ``build_simulation(scene)``, the one assembly of the solvers: the DEM solver when the
scene has grains, the gas solver when it has gas, the coupler when it has both, the inlet
schedule, and the Simulation that steps them in the one coupling order (``Simulation.step``).
Everything that runs a scene (``fbed run``, ``fbed view``, the benches, the validation
scripts, the tests of more than one solver) builds it here. The physics lives in ``app.sim``;
this module only assembles it.
"""
from __future__ import annotations

import math
import pathlib

import numpy as np

from .beds import load_bed
from .config import ConfigError, resolve_path
from .config.derived import Derived, derive, gas_shape, periodic_axes, smoothing_passes
from .config.schema import Config
from .io.store import available_memory
from .schedule import InletSchedule
from .sim import coupling, drag, geometry, runtime
from .sim.gas import BC, FlowConfig, FlowSolver
from .sim.dem import DemSolver
from .sim.fields import HISTORY_SLOTS, ROLL_CONSTANT, ROLL_EPSD, DemModel, bytes_per_grain, slots_bound
from .sim.simulation import Simulation

ROLLING = {"none": 0, "constant_torque": ROLL_CONSTANT, "epsd": ROLL_EPSD}
CELLS_PER_GRAIN = 4  # cap on the cell list's size (4 bytes per cell)
LAYER_POINTS = 1_000_000  # lattice points of one fill layer beyond which only a centred patch is made


def build_walls(cfg: Config) -> list:
    """The vessel's walls (geometry dataclasses), from [vessel] and [domain]. The floor plane holds the grains
    up: a scene without grains gets one only where vessel.floor is given (its gas is bounded below by the
    domain's bottom face and its [boundary] condition; a floor there would be a second, no-slip, wall on
    that face and would close a periodic z axis)."""
    v, d = cfg.vessel, cfg.domain
    floor = d.lo[2] if v.floor is None else v.floor
    walls: list = []
    if v.shape == "none":
        return walls
    if v.shape == "cylinder":
        walls.append(geometry.CylinderWall(tuple(v.center), v.radius, name="cylinder"))
    elif v.shape == "box":  # side walls on the faces that are not periodic
        walls += geometry.box_walls(d.lo, d.hi, faces=tuple(ax + s for ax, p in zip("xy", periodic_axes(cfg))
                                                             if not p for s in "-+"))
    elif v.shape == "sampled":
        walls.append(sampled_wall(resolve_path(cfg, v.sdf_file)))
        return walls  # a sampled vessel carries its own floor (the faces it seals: geometry.sealed_faces)
    if cfg.particles is not None or v.floor is not None:
        walls.append(geometry.PlaneWall((0.0, 0.0, floor), (0.0, 0.0, 1.0), name="floor"))
    if v.lid is not None:
        walls.append(geometry.PlaneWall((0.0, 0.0, v.lid), (0.0, 0.0, -1.0), name="lid"))
    return walls


def sampled_wall(path: pathlib.Path) -> "geometry.SampledWall":
    """vessel.sdf_file's wall, its arrays checked: a ConfigError naming the file and what is wrong (a file that is
    no .npz, a missing array, NaN clearances, a spacing that is no positive number were tracebacks or a vessel
    that "fits 0 grains")."""
    import zipfile

    def bad(what: str):
        return ConfigError(f"cannot read the sampled SDF: {what}", str(path), "vessel.sdf_file",
                           hint="an .npz (numpy.savez) with arrays 'values' (nx, ny, nz clearances at the nodes, m, "
                           "positive inside), 'origin' (3, m) and 'spacing' (one number, m)")
    try:
        if path.is_file() and not zipfile.is_zipfile(path):
            raise bad("not an .npz archive")
        with np.load(path, allow_pickle=False) as data:
            values, origin, spacing = (np.asarray(data[k], float) for k in ("values", "origin", "spacing"))
    except KeyError as err:
        raise bad(f"no array {str(err.args[0]).split()[0]!r} in the file") from None
    except OSError as err:
        raise bad(err.strerror or str(err)) from None
    except (ValueError, TypeError) as err:
        raise bad(str(err)) from None
    if values.ndim != 3 or min(values.shape) < 2 or not np.isfinite(values).all():
        raise bad(f"'values' must be a 3-D array of finite clearances, at least 2 nodes an axis (got shape "
                  f"{values.shape}, {int((~np.isfinite(values)).sum())} not finite)")
    if origin.shape != (3,) or not np.isfinite(origin).all():
        raise bad(f"'origin' must be 3 finite numbers (got {origin.tolist()})")
    if spacing.size != 1 or not np.isfinite(spacing).all() or float(spacing.ravel()[0]) <= 0:
        raise bad(f"'spacing' must be one number > 0 (got {spacing.tolist()})")
    return geometry.SampledWall(values, tuple(map(float, origin)), float(spacing.ravel()[0]), name=path.stem)


def open_area(cfg: Config, walls: list, z: float) -> float:
    """Open cross-section of the vessel at height z [m^2] (sampled on a 256x256 grid)."""
    d = cfg.domain
    if cfg.vessel.shape == "cylinder":
        return math.pi * cfg.vessel.radius ** 2
    xs = np.linspace(d.lo[0], d.hi[0], 257)
    ys = np.linspace(d.lo[1], d.hi[1], 257)
    xc, yc = 0.5 * (xs[1:] + xs[:-1]), 0.5 * (ys[1:] + ys[:-1])
    X, Y = np.meshgrid(xc, yc, indexing="ij")
    pts = np.stack([X, Y, np.full_like(X, z)], -1)
    frac = np.mean(geometry.vessel_clearance(walls, pts) > 0) if walls else 1.0
    return float(frac * (d.hi[0] - d.lo[0]) * (d.hi[1] - d.lo[1]))


def check_bed(cfg: Config, walls: list, d: Derived, bed: dict, path: pathlib.Path) -> None:
    """A bed file's grains must be this preset's sizes (smaller ones would break its neighbour list sizing, larger
    ones its cells; the relative 1e-6 absorbs float32 storage) and fit its vessel: a grain that overlaps a wall by
    more than guard.max_overlap (a bed from a wider vessel) is refused here, where the guard stopped the run at
    t = 0 blaming the contact stiffness."""
    n = len(bed["position"])
    if not n:
        return
    r = np.asarray(bed["radius"], float)
    rmin, rmax = float(r.min()), float(r.max())
    if rmax > d.radius_max * (1 + 1e-6) or rmin < d.radius_min * (1 - 1e-6):
        def sizes(lo, hi):
            return f"{2 * lo:g} m" if hi <= lo * (1 + 1e-6) else f"{2 * lo:g} to {2 * hi:g} m"

        raise ConfigError(f"the bed's grains have diameters {sizes(rmin, rmax)}, the preset's "
                          f"{sizes(d.radius_min, d.radius_max)}", str(path), "particles.initial_state",
                          hint="set particles.diameter to the bed's, or use a bed made with this preset's sizes")
    if not walls:
        return
    overlap = (r - geometry.vessel_clearance(walls, bed["position"])) / (2 * r)  # of the diameter
    deep = overlap > cfg.guard.max_overlap
    if deep.any():
        worst = int(np.argmax(overlap))
        raise ConfigError(f"{int(deep.sum())} of the bed's {n} grains overlap the vessel's walls by more than "
                          f"guard.max_overlap = {cfg.guard.max_overlap:g} of a diameter (the most: grain {worst}, "
                          f"{overlap[worst]:.3g}): the bed does not fit this vessel", str(path),
                          "particles.initial_state", hint="use a bed made in this preset's vessel, or give the "
                          "[vessel] of the run that made it")


def grain_count(cfg: Config, walls: list, der: Derived) -> int:
    p = cfg.particles
    if p.count:
        return p.count
    floor = cfg.domain.lo[2] if cfg.vessel.floor is None else cfg.vessel.floor
    d = np.asarray(der.diameters)
    mean_volume = float(np.sum(np.asarray(der.number_fractions) * der.volume(d)))
    area = open_area(cfg, walls, floor + 0.5 * p.bed_height)
    return max(1, int(round(p.fill_solid_fraction * area * p.bed_height / mean_volume)))


def sample_radii(n: int, der: Derived, rng: np.random.Generator) -> np.ndarray:
    """Radii of n grains with the number fractions of the size distribution (largest remainder)."""
    frac = np.asarray(der.number_fractions)
    counts = np.floor(frac * n).astype(int)
    rest = n - counts.sum()
    counts[np.argsort(-(frac * n - counts))[:rest]] += 1
    r = np.repeat(np.asarray(der.diameters) / 2, counts)
    rng.shuffle(r)
    return r


def _layer_axes(spans: list, s: float, n: int) -> list:
    """The x and y lattice lines of a fill layer, np.arange(lo, hi, s) for each (lo, hi) of ``spans``; where the
    layer would be far larger than the n grains need, a centred patch of about 4n points: a 1e6 m domain with
    vessel.shape = 'none' asked numpy for 1.57 EiB. The presets' layers are thousands of points, far under
    LAYER_POINTS."""
    nx, ny = (max(0, math.ceil((hi - lo) / s)) for lo, hi in spans)
    if nx * ny <= LAYER_POINTS + 4 * n:
        return [np.arange(lo, hi, s) for lo, hi in spans]
    wy = min(ny, math.isqrt(4 * n) + 1)
    wx = min(nx, -(-4 * n // wy) + 1)
    wy = min(ny, -(-4 * n // wx) + 1)
    return [lo + (np.arange(w) + (c - w) // 2) * s for (lo, _), c, w in zip(spans, (nx, ny), (wx, wy))]


def lattice_fill(cfg: Config, walls: list, n: int, radius_max: float, rng: np.random.Generator,
                 file: str = "<preset>") -> np.ndarray:
    """n non-overlapping centres on a jittered cubic lattice, lowest first, inside the vessel."""
    d = cfg.domain
    s = cfg.particles.fill_spacing * 2 * radius_max
    floor = d.lo[2] if cfg.vessel.floor is None else cfg.vessel.floor
    top = d.hi[2] if cfg.vessel.lid is None else cfg.vessel.lid
    gap = s - 2 * radius_max
    margin = radius_max + 0.5 * gap + 1e-9
    axes = _layer_axes([(d.lo[a] + margin, d.hi[a] - margin + 1e-12) for a in range(2)], s, n)
    z0, z1 = max(floor, d.lo[2]) + margin, min(top, d.hi[2]) - margin + 1e-12
    dz = (z0 + s) - z0  # np.arange(z0, z1, s)'s heights to the bit (its step is this difference), made as needed
    zs = (z0 + k * dz for k in range(max(0, math.ceil((z1 - z0) / s))))
    X, Y = np.meshgrid(axes[0], axes[1], indexing="ij")
    layer = np.stack([X.ravel(), Y.ravel()], -1)
    pts = []
    have = 0
    for z in zs:
        q = np.column_stack([layer, np.full(len(layer), z)])
        if walls:
            q = q[geometry.vessel_clearance(walls, q) >= margin]
        pts.append(q)
        have += len(q)
        if have >= n:
            break
    if have < n:
        raise ConfigError(f"only {have} grains fit in the vessel at a spacing of {s:g} m, {n} asked for",
                          file, "particles.count",
                          hint="raise domain.hi (z), lower particles.count / bed_height, or lower particles.fill_spacing")
    pos = np.concatenate(pts)[:n]
    # jitter within the lattice gap so the pour is not a perfect crystal; never overlaps
    pos = pos + rng.uniform(-1, 1, pos.shape) * 0.45 * gap / math.sqrt(3)
    return pos


def dem_model(cfg: Config, der: Derived, n: int, walls: list, coupled: bool = False,
              serial: bool = False) -> DemModel:
    d = cfg.domain
    # cells at least one cut-off wide, and no more than CELLS_PER_GRAIN per grain: a sparse scene
    # (few small grains in a tall column) gets larger cells instead of a huge, empty cell list
    lo, hi = tuple(d.lo), tuple(d.hi)
    volume = float(np.prod([hi[a] - lo[a] for a in range(3)]))
    cut = max(2 * der.radius_max + der.skin, (volume / (CELLS_PER_GRAIN * max(n, 1024))) ** (1 / 3))
    # along a periodic axis at least 3 cells (``derive`` checks that 3 cut-offs fit in the period), so the
    # 27 cells around a grain are distinct
    cells = tuple(max(3 if der.periodic[a] else 1, int((hi[a] - lo[a]) // cut)) for a in range(3))
    cell = tuple((hi[a] - lo[a]) / cells[a] for a in range(3))
    slots = cfg.dem.max_neighbors
    # springs per grain: the kissing number (contacts with grains at least its size), or one per
    # neighbour slot when the list is sized by hand (dem.max_neighbors: the way out of a shortage)
    history = min(slots, HISTORY_SLOTS) if not slots else slots
    if not slots:
        slots = slots_bound(der.radius_min, der.skin)
        history = min(slots, HISTORY_SLOTS)
    r = der.diameters[0] / 2
    pc, wc = der.pair, der.wall
    return DemModel(
        n=n, slots=slots, polydisperse=der.polydisperse, radius=r, mass=float(der.mass(2 * r)),
        density=der.density, hertz=pc.model == "hertz_mindlin", friction=der.friction, rolling=ROLLING[der.rolling],
        e_star=pc.e_star, g_star=pc.g_star, kn=pc.kn, kt=pc.kt, damping=pc.damping, mu=pc.friction,
        mu_roll=pc.rolling_friction, w_e_star=wc.e_star, w_g_star=wc.g_star, w_damping=wc.damping, w_mu=wc.friction,
        w_mu_roll=wc.rolling_friction, walls=tuple(walls), gravity=tuple(d.gravity), dt=der.dt, skin=der.skin,
        lo=lo, hi=hi, cell=cell, cells=cells, periodic=der.periodic, sealed=geometry.sealed_faces(walls, lo, hi),
        coupled=coupled, serial=serial,
        history_slots=history, roll_damping=pc.rolling_damping, w_roll_damping=wc.rolling_damping)


def flow_config(cfg: Config, walls: list):
    """The gas solver's set-up from [gas], [boundary], [domain] and the vessel walls."""
    g, d = cfg.gas, cfg.domain
    shape = gas_shape(cfg)
    bcs = {face: BC(b.kind, tuple(b.velocity), b.pressure) for face, b in cfg.boundary}
    return FlowConfig(shape=shape, h=g.cell_size, origin=tuple(d.lo), rho=g.density, mu=g.viscosity,
                           gravity=tuple(d.gravity), bcs=bcs, walls=tuple(walls), pressure_form=g.pressure_form,
                           convection=g.convection, tol=g.tolerance, max_iter=g.max_iterations,
                           aperture_samples=g.aperture_samples, max_viscous_sweeps=g.max_viscous_sweeps,
                           trace_forces=g.trace_forces,
                           min_open_fraction=g.min_open_fraction)


def coupling_model(cfg: Config, serial: bool = False):
    c = cfg.coupling
    return coupling.CouplingModel(law=drag.law_of(c.drag), model_b=cfg.gas.pressure_form == "gas",
                                  eps_min=c.eps_min, gas_density=cfg.gas.density, gas_viscosity=cfg.gas.viscosity,
                                  gravity=tuple(cfg.domain.gravity),
                                  smoothing_passes=smoothing_passes(c.smoothing_width, cfg.gas.cell_size),
                                  serial=serial)


class Scene:
    """What a run needs, decided from the Config (no Taichi memory yet).

    ``model`` (the DEM's compile-time description) is None for a gas-only scene and
    ``flow`` (the gas solver's set-up) is None for a grains-only scene."""

    def __init__(self, cfg: Config, file: str = "<preset>", initial: dict | None = None, serial: bool = False):
        """``initial``: the grains given (a checkpoint's full DEM state, or position, radius and optionally
        velocity, omega, alive); their number replaces particles.count. ``serial``: kernels run on one CPU
        thread (plain adds instead of atomics)."""
        self.cfg = cfg
        self.file = file
        self.walls = build_walls(cfg)
        self.flow = flow_config(cfg, self.walls) if cfg.gas is not None else None
        self.derived, self.model, self.n, self.initial, self.coupling = None, None, 0, None, None
        if cfg.particles is None:
            check_memory(self)  # the gas grid's
            return
        self.derived = derive(cfg, file)
        rng = np.random.default_rng(cfg.run.seed)
        if initial is not None:  # resuming (the checkpoint supplies the grains), or grains placed by the caller
            self.initial = initial
            n = len(initial["position"])
        elif cfg.particles.initial_state:
            path = resolve_path(cfg, cfg.particles.initial_state)
            if not path.exists():
                raise ConfigError("file not found", str(path), "particles.initial_state",
                                  hint="run the preset that writes it first (e.g. fbed run presets/settle.toml)")
            self.initial = load_bed(path)
            n = len(self.initial["position"])
            check_bed(cfg, self.walls, self.derived, self.initial, path)
        else:
            n = grain_count(cfg, self.walls, self.derived)
        self.n = n
        self.model = dem_model(cfg, self.derived, n, self.walls, coupled=cfg.gas is not None, serial=serial)
        check_memory(self)  # before the grains are made: a scene too large for the CPU's memory is refused
        if self.initial is None:
            radius = sample_radii(n, self.derived, rng)
            pos = lattice_fill(cfg, self.walls, n, self.derived.radius_max, rng, file)
            self.initial = {"position": pos, "velocity": np.zeros_like(pos), "radius": radius}
        self.coupling = coupling_model(cfg, serial) if cfg.gas is not None else None

    def outside_domain(self) -> int:
        """Live grains given to this scene (a bed file, a checkpoint) whose centres lie outside the domain box along
        an axis that is not periodic: the DEM removes them at its first substep."""
        g, d = self.initial, self.cfg.domain
        if not g or not len(g["position"]):
            return 0
        x, walled = np.asarray(g["position"]), ~np.asarray(periodic_axes(self.cfg))
        out = ((x < np.asarray(d.lo)) | (x > np.asarray(d.hi)))[:, walled].any(axis=1)
        if "alive" in g:
            out &= np.asarray(g["alive"]).astype(bool)
        return int(out.sum())


#: a CPU run's memory: its peak resident size measured 2026-12-06 (AMD EPYC, float32, presets/verma.toml for one
#: step with 1e5, 3e5 and 9.65e5 grains: 0.465, 0.707 and 1.449 GB) is this much plus ~3 x the DEM's own
#: bytes_per_grain a grain (397 B there: the host's float64 copies at the fill, the checkpoint and bed.h5 add
#: the rest), within 1% at all three sizes; with 1.9e7 grains in a 3 m column it peaked at 16.6 GB through a
#: checkpoint where this says 19.7: on the safe side
CPU_BASE_BYTES = 350e6
CPU_BYTES_PER_DEVICE_BYTE = 3.0
#: and a gas cell's: the peak resident size of a gas-only box for one step (a velocity inlet, 5 x 10^4 to
#: 2.0 x 10^6 cells, AMD EPYC, 2026-12-06) grew by 478-514 B a cell in float32 and 771 B in float64 (the solver's
#: fields and the host's cut-cell geometry, field snapshots and checkpoint); on top of the base above, which
#: already held the Verma grid's 1.2 x 10^5 cells: on the safe side
CPU_BYTES_PER_GAS_CELL = {"float32": 520.0, "float64": 780.0}


#: a gas cell's device memory [B]: the gas solver's ndarrays (runtime.ndarray_bytes over gas-only boxes of 1.6 x
#: 10^4 to 6.4 x 10^4 cells, 2026-12-06: 300.5 B a cell in float32, the same with 1 and 2 threads, and 597 B in
#: float64) and the coupling's per-cell fields (4 scalars and 2 vectors: 40 B, 80 B)
GAS_DEVICE_BYTES_PER_CELL = {"float32": 341.0, "float64": 677.0}


def device_bytes(scene: "Scene") -> float:
    """The memory a scene's fields take on the device [B]: the DEM's bytes_per_grain a grain and
    :data:`GAS_DEVICE_BYTES_PER_CELL` a gas cell (Taichi's own buffers not counted)."""
    fp = 8 if scene.cfg.run.precision == "float64" else 4
    grains = 0.0 if scene.model is None else scene.n * bytes_per_grain(scene.model, fp)
    cells = 0 if scene.flow is None else math.prod(scene.flow.shape)
    return grains + cells * GAS_DEVICE_BYTES_PER_CELL[scene.cfg.run.precision]


def check_memory(scene: "Scene") -> None:
    """Refuse, before anything is allocated, a scene whose estimated peak memory exceeds what is there: past it the
    kernel's out-of-memory killer would end a CPU run mid-start-up without a word, and on a GPU Taichi would fail
    with a traceback (its pool, :data:`runtime.CUDA_MEMORY_FRACTION` of the GPU's memory, full). On CUDA both the
    GPU's memory (the DEM's bytes_per_grain and :data:`GAS_DEVICE_BYTES_PER_CELL`; Taichi's own buffers are not
    counted, so a scene just under the pool may still fail there) and the host's (the CPU estimate, whose share of
    device arrays lives on the GPU there: on the safe side) are checked."""
    cur = runtime.current()
    if cur is None or (scene.model is None and scene.flow is None):
        return
    fp = 8 if scene.cfg.run.precision == "float64" else 4
    bpg = 0.0 if scene.model is None else bytes_per_grain(scene.model, fp)
    if cur[0] == "cuda":
        total = runtime.cuda_memory()
        if total is not None:
            _refuse_beyond(scene, "of the GPU's memory", bpg, GAS_DEVICE_BYTES_PER_CELL[scene.cfg.run.precision],
                           0.0, runtime.CUDA_MEMORY_FRACTION * total,
                           f"Taichi's pool ({runtime.CUDA_MEMORY_FRACTION:g} of the GPU's {total / 1e9:.3g} GB)")
    have = available_memory()
    if have is not None:
        _refuse_beyond(scene, "of memory on the CPU", CPU_BYTES_PER_DEVICE_BYTE * bpg,
                       CPU_BYTES_PER_GAS_CELL[scene.cfg.run.precision], CPU_BASE_BYTES, have, "available")


def _refuse_beyond(scene: "Scene", where: str, per_grain: float, per_cell: float, base: float, have: float,
                   what: str) -> None:
    """A ConfigError naming the key to change (gas.cell_size where the gas needs the more) when ``base`` + the
    grains x ``per_grain`` + the gas cells x ``per_cell`` [B] exceed ``have`` [B]."""
    cells = 0 if scene.flow is None else math.prod(scene.flow.shape)
    grains, gas = scene.n * per_grain, cells * per_cell
    if base + grains + gas <= have:
        return
    need = f"about {(base + grains + gas) / 1e9:.3g} GB {where}"
    gpu = "GPU" in where
    if gas > grains:
        raise ConfigError(f"{cells:,} gas cells ({' x '.join(map(str, scene.flow.shape))}) need {need} (about "
                          f"{per_cell:.0f} B a cell), and {have / 1e9:.3g} GB is {what}", scene.file,
                          "gas.cell_size", hint="larger gas cells (each doubling divides the cells by 8), a smaller "
                          "domain, or a machine with more memory")
    key = "particles.initial_state" if scene.cfg.particles.initial_state else "particles.count"
    raise ConfigError(f"{scene.n:,} grains need {need} ({per_grain:.0f} B a grain), and {have / 1e9:.3g} GB is "
                      f"{what}", scene.file, key, hint="fewer grains (particles.count or particles.bed_height), "
                      + ("a GPU with more memory, or --arch cpu on a machine with more" if gpu else
                         "a machine with more memory, or a GPU (--arch cuda)"))


def place_grains(dem: DemSolver, initial: dict) -> None:
    """Put a scene's initial grains into the DEM: a full state (a checkpoint's) exactly, contact springs and
    neighbour list included; from another contact model, or given as plain arrays, positions, velocities,
    radii (and omega, alive) with the contact history restarted."""
    omega = initial.get("omega")
    if "nl_partner" in initial:
        try:
            dem.load_state_arrays(initial)
            return
        except (KeyError, ValueError):  # another contact model: positions and velocities carry over, history
            omega = None                # (spins included) restarts
    dem.set_grains(initial["position"], initial.get("velocity"), initial["radius"], omega, initial.get("alive"))


def build_simulation(scene: Scene, frozen: bool = False, notify=None, timing: bool = False) -> Simulation:
    """The one assembly of a scene's solvers into a Simulation (after ``runtime.init``).

    Allocates what the scene needs and nothing else: the DEM solver with the scene's initial grains placed
    (grains only), the gas solver (gas only), the coupler (both), the inlet schedule (scheduled inlets, a
    before-step hook: ``sim.inlets``); the clock is ``run.step`` x ``run.duration`` with the DEM's substeps, and
    the adaptive fluid step is set from gas.max_cfl / gas.max_split. ``frozen``: the grains are deposited and
    feel the drag every step but never move (the Simulation holds no DEM to advance: a fixed bed; the DEM
    solver is ``sim.coupler.dem``). ``notify``: the run's log for the Simulation's notes; ``timing``: the
    sampled per-phase wall time (``Simulation.wall_split``). A gas set-up the solver refuses is a ConfigError
    naming [gas] or [boundary]."""
    cfg, der = scene.cfg, scene.derived
    dem = None
    if scene.model is not None:
        dem = DemSolver(scene.model)
        place_grains(dem, scene.initial)
    gas = inlets = coupler = None
    if scene.flow is not None:
        try:
            gas = FlowSolver(scene.flow)
        except ValueError as err:
            raise ConfigError(str(err), scene.file, "gas", hint="check [gas] and [boundary]") from None
        try:
            inlets = InletSchedule(cfg.boundary, scene.flow.shape, scene.flow.h, scene.flow.origin)
        except ValueError as err:
            raise ConfigError(str(err), scene.file, "boundary") from None
        if not inlets.faces:
            inlets = None
    if dem is not None and gas is not None:
        coupler = coupling.Coupler(scene.coupling, dem, gas)
    split = dict(max_gas_cfl=cfg.gas.max_cfl, max_gas_split=cfg.gas.max_split) if gas is not None else {}
    return Simulation(None if frozen else dem, cfg.run.step, der.substeps if der else 0, cfg.run.duration,
                      flow=gas, coupler=coupler, inlets=inlets, notify=notify, timing=timing, **split)
