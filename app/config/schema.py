"""The preset schema: every section and key a preset may hold, with its SI unit and range.

Owns: the frozen dataclasses a preset loads into. Each field's metadata gives its unit,
a one-line doc, and the range or choices the loader checks; ``fbed`` never reads a key
that is not declared here, and an undeclared key in a preset is an error.

Plain Python (no Taichi): the CLI, analysis and tests read configs without a GPU.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Optional

#: the shortest DEM step taken, as a fraction of the collision time: below it a step buys no accuracy (0.05 keeps
#: restitution within 0.3%) and costs its number of substeps (dem.dt = 1e-12 s in settle.toml: 2e9 substeps a step,
#: a step that no Ctrl-C interrupts)
DT_FRACTION_MIN = 1e-4


def spec(default=dataclasses.MISSING, *, unit: str = "-", doc: str, lo=None, hi=None, lo_open=False,
         choices=None, length=None):
    """A schema field: ``unit`` (SI), ``doc``, inclusive range [lo, hi] (``lo_open`` makes lo exclusive)."""
    meta = dict(unit=unit, doc=doc, lo=lo, hi=hi, lo_open=lo_open, choices=choices, length=length)
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda d=default: type(d)(d), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class RunConfig:
    duration: float = spec(unit="s", doc="simulated time at which the run ends (counted from t = 0, so a resumed run "
                       "or one that starts from a prepared state runs up to it; rounded up to a whole number of "
                       "run.step, with a note)", lo=0.0, lo_open=True)
    step: float = spec(1.0e-3, unit="s", doc="coupling step: the fluid step when the scene has gas; in DEM-only "
                       "scenes the interval at which callbacks (output, guard, progress) are checked (at least 1e-12 "
                       "s: float32 kernels then hold the gas's 1/dt; 1e-300 s made the gas non-finite at its first "
                       "step)", lo=1.0e-12, hi=1.0)
    name: str = spec("", doc="run name stamped on outputs (default: the preset file's name)")
    seed: int = spec(0, doc="random seed for filling and size sampling", lo=0)
    start_from: str = spec("", doc="a preparation preset (path relative to this one): it is run first, or its "
                           "cached result reused, and this run starts from its final state (grains, gas and clock; "
                           "run.duration is then the end time)")
    precision: str = spec("float32", doc="floating-point precision of the kernels", choices=("float32", "float64"))
    threads: int = spec(0, doc="CPU threads (0 = automatic: one thread on machines with 2 cores or fewer, where "
                        "one thread without atomics is as fast as two with them, else all cores; at most the CPUs "
                        "available, with a note); 1 makes CPU runs bit-reproducible", lo=0)


@dataclass(frozen=True)
class DomainConfig:
    lo: tuple[float, float, float] = spec(unit="m", doc="lower corner of the simulation box (x, y, z)", length=3)
    hi: tuple[float, float, float] = spec(unit="m", doc="upper corner of the simulation box (x, y, z); "
                                          "grains that leave it are removed and counted", length=3)
    gravity: tuple[float, float, float] = spec((0.0, 0.0, -9.81), unit="m/s^2", doc="gravitational acceleration", length=3)


@dataclass(frozen=True)
class VesselConfig:
    shape: str = spec("cylinder", doc="vessel walls: a vertical cylinder, the domain box (side walls on its faces "
                      "that are not periodic), a sampled SDF, or none",
                      choices=("cylinder", "box", "sampled", "none"))
    radius: float = spec(0.0, unit="m", doc="cylinder radius", lo=0.0)
    center: tuple[float, float] = spec((0.0, 0.0), unit="m", doc="cylinder axis position (x, y)", length=2)
    floor: Optional[float] = spec(None, unit="m", doc="height of the floor plane (default: the domain's lower z; "
                                   "a scene without grains has a floor only where this is given)")
    lid: Optional[float] = spec(None, unit="m", doc="height of a lid plane (default: no lid, open top)")
    sdf_file: str = spec("", doc="for shape = 'sampled': .npz with 'values' (clearance at nodes, m, positive "
                         "inside the vessel), 'origin' (m, 3) and 'spacing' (m); relative to the preset")


@dataclass(frozen=True)
class ParticlesConfig:
    density: float = spec(unit="kg/m^3", doc="grain material density", lo=1.0, hi=3.0e4)
    diameter: float = spec(0.0, unit="m", doc="grain diameter (monodisperse)", lo=0.0, hi=1.0)
    diameters: list = spec([], unit="m", doc="grain diameters of a discrete size distribution (polydisperse)")
    fractions: list = spec([], doc="fraction of each diameter in `diameters`; normalised to sum 1")
    fractions_by: str = spec("mass", doc="whether `fractions` are mass (volume) or number fractions",
                             choices=("mass", "number"))
    count: int = spec(0, doc="number of grains to place (or give bed_height)", lo=0)
    bed_height: float = spec(0.0, unit="m", doc="fill to about this settled bed height instead of a count", lo=0.0)
    fill_solid_fraction: float = spec(0.6, doc="solid fraction assumed when converting bed_height to a count",
                                      lo=0.1, hi=0.74)
    fill_spacing: float = spec(1.05, doc="lattice spacing of the filler over the largest diameter", lo=1.0, hi=3.0)
    initial_state: str = spec("", doc="start from the grains of an earlier run (its bed.h5 or checkpoint.h5) "
                              "instead of filling; relative to the preset")


@dataclass(frozen=True)
class ContactConfig:
    model: str = spec("hertz_mindlin", doc="normal/tangential contact law", choices=("hertz_mindlin", "linear"))
    youngs_modulus: float = spec(5.0e6, unit="Pa", doc="Young's modulus of the grains (hertz_mindlin); "
                                 "softer than the real material to allow a larger DEM step", lo=1.0e3, hi=1.0e12)
    poisson_ratio: float = spec(0.3, doc="Poisson's ratio (hertz_mindlin)", lo=0.0, hi=0.5)
    normal_stiffness: float = spec(0.0, unit="N/m", doc="spring constant of the linear model", lo=0.0)
    tangential_stiffness_ratio: float = spec(2.0 / 7.0, doc="k_t / k_n of the linear model", lo=0.0, hi=1.0)
    restitution: float = spec(0.9, doc="grain-grain normal coefficient of restitution", lo=0.01, hi=1.0)
    friction: float = spec(0.5, doc="grain-grain Coulomb friction coefficient (0: frictionless, no history kept)", lo=0.0, hi=10.0)
    rolling_friction: float = spec(0.0, doc="grain-grain rolling friction coefficient (dimensionless)", lo=0.0, hi=1.0)
    rolling_model: str = spec("none", doc="rolling resistance: none, constant_torque, or epsd "
                              "(elastic-plastic spring-dashpot, LIGGGHTS' rolling_model epsd)",
                              choices=("none", "constant_torque", "epsd"))
    rolling_damping: float = spec(0.3, doc="grain-grain viscous damping ratio of the epsd rolling mode (dimensionless; "
                                  "C_r = ratio x 2 sqrt(I_r k_r), 1 is critical; LIGGGHTS' "
                                  "coefficientRollingViscousDamping, which has no default there)", lo=0.0, hi=1.0)
    wall_restitution: Optional[float] = spec(None, doc="grain-wall restitution (default: restitution)", lo=0.01, hi=1.0)
    wall_friction: Optional[float] = spec(None, doc="grain-wall friction (default: friction)", lo=0.0, hi=10.0)
    wall_rolling_friction: Optional[float] = spec(None, doc="grain-wall rolling friction (default: rolling_friction)",
                                                  lo=0.0, hi=1.0)
    wall_rolling_damping: Optional[float] = spec(None, doc="grain-wall epsd rolling damping ratio (dimensionless; "
                                                 "default: rolling_damping)", lo=0.0, hi=1.0)
    wall_youngs_modulus: Optional[float] = spec(None, unit="Pa", doc="Young's modulus of the walls "
                                                "(default: the grains')", lo=1.0e3, hi=1.0e12)
    wall_poisson_ratio: Optional[float] = spec(None, doc="Poisson's ratio of the walls (default: the grains')", lo=0.0, hi=0.5)


@dataclass(frozen=True)
class DemConfig:
    dt: float = spec(0.0, unit="s", doc="DEM step; 0 picks dt_fraction x the shortest collision time", lo=0.0)
    dt_fraction: float = spec(0.05, doc="automatic DEM step as a fraction of the collision time (0.05: restitution "
                              "within 0.3%, contact time within 0.13%; benchmarks/ACCURACY.md)", lo=DT_FRACTION_MIN, hi=0.2)
    max_dt_fraction: float = spec(0.1, doc="largest DEM step allowed, as a fraction of the collision time "
                                  "(10 steps per contact); larger steps are refused unless force_dt", lo=1e-3, hi=0.5)
    force_dt: bool = spec(False, doc="accept a dt above the stability limit (for stress tests)")
    impact_speed: float = spec(1.0, unit="m/s", doc="impact speed at which the Hertz collision time sets the step "
                               "(faster impacts are shorter)", lo=1e-4, hi=1e3)
    skin: float = spec(0.0, unit="m", doc="Verlet neighbour-list skin; 0 = 0.15 x largest diameter", lo=0.0)
    max_neighbors: int = spec(0, doc="neighbour slots per grain (half list); 0 = automatic", lo=0, hi=256)


@dataclass(frozen=True)
class OutputConfig:
    series_interval: float = spec(1.0e-3, unit="s", doc="interval of the time series in run.h5", lo=0.0, lo_open=True)
    particles_interval: float = spec(0.0, unit="s", doc="interval of particle snapshots in run.h5 (0: first and last only)", lo=0.0)
    checkpoint_interval: float = spec(0.0, unit="s", doc="simulated-time interval of checkpoints (0: only at the end "
                                      "and on interruption)", lo=0.0)
    checkpoint_wall_interval: float = spec(300.0, unit="s", doc="wall-clock interval of checkpoints (0: off)", lo=0.0)
    save_bed: bool = spec(True, doc="write bed.h5 (the final grains, reusable as particles.initial_state)")
    log_interval: float = spec(5.0, unit="s", doc="wall-clock interval of log lines when not on a terminal", lo=0.1)
    average_from: float = spec(-1.0, unit="s", doc="start of the time means in summary.json and of the window the "
                               "mri and verma analyses read (negative: the second half of the run)")


@dataclass(frozen=True)
class VideoConfig:
    enabled: bool = spec(False, doc="write a video of the run (also switched on by `fbed run --video`)")
    file: str = spec("", doc="video file, an .mp4 (default: video.mp4 in the output folder); relative to the output folder")
    width: int = spec(1280, unit="px", doc="frame width of the 3-D view (the void-fraction panel is added beside it)",
                      lo=64, hi=7680)
    height: int = spec(720, unit="px", doc="frame height", lo=64, hi=4320)
    interval: float = spec(0.01, unit="s", doc="simulated time between frames", lo=0.0, lo_open=True)
    fps: float = spec(30.0, unit="1/s", doc="frames per second of the video file (playback rate)", lo=1.0, hi=240.0)
    view: str = spec("perspective", doc="'perspective': the whole bed from the camera below; 'slab': the grains with "
                     "|y - y_centre| < slab_width/2 seen from the side (orthographic), where bubbles show",
                     choices=("perspective", "slab"))
    color: str = spec("speed", doc="grain colouring: speed [m/s], height [m], void_fraction (the local one) [-], size (the "
                      "radius) [m], or tracer (bands of initial height)",
                      choices=("speed", "height", "void_fraction", "size", "tracer"))
    color_range: tuple[float, float] = spec((0.0, 0.0), unit="unit of the colouring", doc="values mapped to the "
                                            "ends of the colour map; (0, 0): automatic", length=2)
    slab_width: float = spec(0.0, unit="m", doc="thickness of the central slab (0: automatic, the larger of 3 grain "
                             "diameters and 5% of the domain's y extent)", lo=0.0)
    void_panel: bool = spec(True, doc="add the void fraction on the central vertical plane beside the view "
                            "(scenes with gas)")
    camera_azimuth: float = spec(-60.0, unit="deg", doc="perspective camera: angle about the vertical axis from -y")
    camera_elevation: float = spec(20.0, unit="deg", doc="perspective camera: angle above the horizontal", lo=-89.0,
                                   hi=89.0)
    camera_distance: float = spec(0.0, unit="m", doc="perspective camera: distance from the domain centre (0: "
                                  "automatic, the whole domain in view)", lo=0.0)


@dataclass(frozen=True)
class ProbesConfig:
    slab_interval: float = spec(0.0, unit="s", doc="interval of the void fraction on the central vertical slab (x-z, "
                                "averaged over the cells within slab_width of the mid-plane y) in run.h5 /slab (0: off)",
                                lo=0.0)
    slab_width: float = spec(0.01, unit="m", doc="thickness of the central slab (the MRI slice: 10 mm); at least the "
                             "cells that straddle the mid-plane are used", lo=0.0)
    planes: list = spec([], unit="m", doc="heights of horizontal planes whose void fraction (linear between cell "
                        "layers) is recorded in run.h5 /planes; pairs of (lower, upper) planes give rise velocities")
    planes_interval: float = spec(0.0, unit="s", doc="interval of the plane records (0: off)", lo=0.0)
    volume_interval: float = spec(0.0, unit="s", doc="interval of the full 3-D void fraction in run.h5 /porosity3d "
                                  "(0: off)", lo=0.0)
    rcfd_from: float = spec(-1.0, unit="s", doc="record rCFD frames into rcfd.h5 from this time on (negative: "
                            "off): void fraction at frame boundaries, frame-mean gas face fluxes, the grains' "
                            "cell-to-cell volume shifts (`fbed rcfd`)")
    rcfd_interval: float = spec(5.0e-3, unit="s", doc="rCFD frame interval (a whole number of run.step); checked "
                                "against the void fraction's Taylor time, logged and in rcfd.h5", lo=0.0,
                                lo_open=True)
    rcfd_z_max: float = spec(0.0, unit="m", doc="record only the cells below this height (grains above it count "
                             "in the top layer; 0: the whole domain)", lo=0.0)
    rcfd_tag: str = spec("x<0", doc="grains tagged at the first rCFD frame, whose volume per cell is recorded (the "
                         "real grains' tracer): AXIS OP VALUE with AXIS x, y or z, OP <, <=, > or >=, VALUE in m")
    rcfd_grain_cells: bool = spec(True, doc="also record each grain's cell and its octant within "
                                  "the cell at every frame boundary (5 bytes per grain per frame), so that shift operators over several frames can be built "
                                  "(`fbed rcfd ... --lag`)")
    rcfd_fluxes: bool = spec(True, doc="also record the frame-mean gas face fluxes (summed on the device, read once per frame)")
    mri_interval: float = spec(0.0, unit="s", doc="interval of the synthetic MRI in run.h5 /mri: the grains' volume "
                               "within the central slab (slab_width thick, through the vessel's axis, normal to y) "
                               "binned by centre onto mri_pixel pixels, as void fraction (0: off; the MRI's 4 ms: 0.004)",
                               lo=0.0)
    mri_pixel: tuple[float, float] = spec((0.004, 0.008), unit="m", doc="synthetic MRI pixel (horizontal x, "
                                          "vertical z): the MRI's 4 mm x 8 mm; finer pixels resolve smaller bubbles",
                                          length=2)
    mri_static_height: float = spec(0.130, unit="m", doc="static bed height of the MRI analysis (expansion ratio, "
                                    "the radial profile below the static bed, the void-fraction spectrum)",
                                    lo=0.0, lo_open=True)
    analysis: str = spec("none", doc="post-processing run when the run ends (and by `fbed analyze DIR`): 'boyce' "
                         "(single bubble on the slab), 'verma' (bubble statistics on the planes), 'mri' (the MRI "
                         "study's bubble, bed-height and radial statistics on /mri and /slab), 'umf' (the pressure drop of "
                         "each hold of the inlet schedule and the U_mf read off it)",
                         choices=("none", "boyce", "verma", "mri", "umf"))


@dataclass(frozen=True)
class GuardConfig:
    interval: float = spec(1.0e-3, unit="s", doc="how often the NaN / overlap / speed checks run", lo=0.0, lo_open=True)
    max_overlap: float = spec(0.2, doc="stop when a grain overlaps by more than this fraction of its diameter", lo=0.0, lo_open=True)
    max_speed: float = spec(100.0, unit="m/s", doc="stop when a grain moves faster than this", lo=0.0, lo_open=True)
    max_divergence: float = spec(1.0e-3, doc="stop when the gas's relative divergence residual after the pressure "
                                 "solve exceeds this (gas mass not conserved: the solve did not converge)", lo=0.0,
                                 lo_open=True)
    max_energy_growth: float = spec(1.0e3, doc="stop when the grains' kinetic energy grows more than this factor "
                                    "from one guard check to the next (measured from at least the energy of every "
                                    "grain moving at sqrt(g d), or at the speed the inlet's gas carries it, its "
                                    "superficial speed less the grain's terminal slip, where faster: from rest any "
                                    "factor is physical; while a jet blows, plus the smaller of its work over two "
                                    "checks / (this - 1) and its column of grains at its speed). Measured per check: "
                                    "forced DEM-step blow-ups 2.4e3-9.3e4x, a 100 m/s jet into a bed 7.3x (it runs "
                                    "on), grains started at 20% overlap 2.4e3x (stopped)", lo=1.0, lo_open=True)
    max_gas_speed: float = spec(300.0, unit="m/s", doc="stop when the gas moves faster than this anywhere (a gas "
                                "step going unstable; jets of 50-100 m/s stay below it)", lo=0.0, lo_open=True)


@dataclass(frozen=True)
class GasConfig:
    cell_size: float = spec(unit="m", doc="gas cell size h (the domain must be a whole number of cells)",
                            lo=0.0, lo_open=True)
    density: float = spec(1.2, unit="kg/m^3", doc="gas density (at least 1e-6: float32 kernels lose a lighter gas; "
                          "1e-300 made it non-finite at the first step)", lo=1.0e-6, hi=1.0e4)
    viscosity: float = spec(1.8e-5, unit="Pa s", doc="gas dynamic viscosity (0, inviscid, only "
                            "without grains: the drag laws divide by it; at most 1e6, a pitch: 1e30 overflowed "
                            "float32)", lo=0.0, hi=1.0e6)
    pressure_form: str = spec("gas", doc="who carries the pressure gradient: 'gas' (Model B) or 'shared' "
                              "(Model A: grains feel -V grad p too)", choices=("gas", "shared"))
    convection: str = spec("maccormack", doc="convection scheme (semi-Lagrangian, with the MacCormack "
                           "correction by default; 'none' for Stokes flow)", choices=("maccormack", "semi_lagrangian", "none"))
    tolerance: float = spec(1.0e-6, doc="pressure solve: relative divergence tolerance", lo=0.0, lo_open=True, hi=0.1)
    max_iterations: int = spec(200, doc="pressure solve: most conjugate-gradient iterations per step", lo=1)
    aperture_samples: int = spec(4, doc="sub-samples per face edge when cutting cells with the vessel walls", lo=1, hi=64)
    min_open_fraction: float = spec(0.1, doc="cut cells whose open volume fraction is at most this are closed to the "
                                    "gas (small-cell removal: a sliver between wall and grid has no resolved wall "
                                    "shear and would be a frictionless bypass)", lo=0.0, hi=0.9)
    max_viscous_sweeps: int = spec(40, doc="most Gauss-Seidel sweeps of the implicit viscous predictor", lo=1)
    trace_forces: bool = spec(True, doc="carry the last step's forces along the convection trajectory (second order "
                              "in time: without it Taylor-Green vortices decay 10% too fast at CFL 0.5, 37% at CFL "
                              "2); off is first order and the most robust: with MacCormack the trace fed a gas blow-up "
                              "in the freeboard of the million-grain bed, cured since (its acceleration smoothed, "
                              "benchmarks/gust_stability.py) yet with spikes left near a pressure outlet")
    max_cfl: float = spec(8.0, doc="adaptive fluid step: above this gas CFL number (largest gas speed x dt / h) the next fluid "
                          "steps split into pieces (each with its deposit, drag and DEM substeps) until the CFL is "
                          "back under it; the convection scheme is tested stable at 8", lo=0.0, lo_open=True)
    max_split: int = spec(16, doc="most pieces a fluid step may split into (1 turns the adaptive step off)",
                          lo=1, hi=1024)
    fields_interval: float = spec(0.0, unit="s", doc="interval of gas-field snapshots in run.h5 "
                                  "(0: first and last only)", lo=0.0)


@dataclass(frozen=True)
class CouplingConfig:
    drag: str = spec("wen_yu", doc="drag law (Model-A coefficient; see app/sim/drag.py for each law's source)",
                     choices=("stokes", "schiller_naumann", "wen_yu", "gidaspow", "di_felice", "beetstra", "tang",
                              "koch_hill"))
    eps_min: float = spec(0.4, doc="lowest gas fraction a cell may take (denser deposits are clipped and counted)",
                          lo=0.05, hi=0.95)
    smoothing_width: float = spec(0.0, unit="m", doc="standard deviation of the Gaussian-like smoothing of the "
                                  "deposited grain volume (0: plain cloud-in-cell)", lo=0.0)


@dataclass(frozen=True)
class BoundarySpec:
    kind: str = spec("wall", doc="boundary condition of a domain face; periodic faces come in pairs (x-/x+, y-/y+) "
                     "and wrap the grains too (a grains-only scene may have those alone)",
                     choices=("wall", "moving_wall", "free_slip", "velocity_inlet", "pressure_outlet", "periodic"))
    velocity: tuple[float, float, float] = spec((0.0, 0.0, 0.0), unit="m/s", doc="inlet superficial velocity, or "
                                                "the tangential velocity of a moving wall", length=3)
    pressure: float = spec(0.0, unit="Pa", doc="gauge pressure of a pressure outlet (0: the atmosphere; the gas is "
                           "incompressible, so only differences between outlets matter, and beyond 1e6 Pa float32 "
                           "loses the bed's pressure drop: fluidize's read 5.1 Pa at 1e7 Pa for 11.9 at 0)",
                           lo=-1.0e6, hi=1.0e6)
    start: float = spec(0.0, unit="s", doc="an inlet blows nothing before this time", lo=0.0)
    ramp: float = spec(0.0, unit="s", doc="an inlet then rises linearly to its velocity over this time", lo=0.0)
    schedule: list = spec([], unit="[s, -]", doc="inlet: [[time, fraction], ...]: the velocity is scaled by the "
                          "fraction, interpolated linearly in time (constant beyond the ends); replaces start/ramp")
    jet_velocity: tuple[float, float, float] = spec((0.0, 0.0, 0.0), unit="m/s", doc="inlet: velocity of a jet "
                                                    "(nozzle) blowing through the cells near jet_center", length=3)
    jet_center: tuple[float, float] = spec((0.0, 0.0), unit="m", doc="inlet: jet axis on the face (the two other "
                                           "coordinates in x, y, z order: (x, y) on the bottom)", length=2)
    jet_radius: float = spec(0.0, unit="m", doc="inlet: face cells whose centres lie within this distance of "
                             "jet_center blow at jet_velocity instead of the inlet velocity", lo=0.0)
    jet_start: float = spec(0.0, unit="s", doc="inlet: time the jet opens", lo=0.0)
    jet_duration: float = spec(0.0, unit="s", doc="inlet: how long the jet blows (0: until the end), ramps included",
                               lo=0.0)
    jet_ramp: float = spec(0.0, unit="s", doc="inlet: the jet opens and closes linearly over this time (an abrupt "
                           "50 m/s start is a pressure shock of one fluid step)", lo=0.0)


@dataclass(frozen=True)
class Config:
    run: RunConfig
    domain: DomainConfig
    particles: Optional[ParticlesConfig] = None
    vessel: VesselConfig = field(default_factory=VesselConfig)
    contact: ContactConfig = field(default_factory=ContactConfig)
    dem: DemConfig = field(default_factory=DemConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    guard: GuardConfig = field(default_factory=GuardConfig)
    video: VideoConfig = field(default_factory=VideoConfig)
    probes: ProbesConfig = field(default_factory=ProbesConfig)
    gas: Optional[GasConfig] = None
    coupling: CouplingConfig = field(default_factory=CouplingConfig)
    # [boundary]: face name (x-, x+, y-, y+, z-, z+, bottom, top) -> BoundarySpec; faces not given are walls
    boundary: tuple = ()
    # where the preset came from: relative paths inside it resolve against this folder
    source: str = field(default="", compare=False, metadata=dict(internal=True))

