"""Set-up of the gas solver: boundary conditions (:class:`BC`), :class:`FlowConfig`, :class:`StepInfo`.

:class:`FlowConfig` is built from the preset's ``[gas]`` keys: its defaults, units and ranges are the
schema's (app/config/schema.py, ``GasConfig``), read through :data:`GAS_KEYS`, so none can drift from it.
The equations, the discretisation and the meaning of every boundary kind are in :mod:`app.sim.gas`.
"""
import dataclasses
from typing import Mapping, Sequence

import numpy as np

from ...config.schema import GasConfig
from .grid import MacGrid

FACES = ("x-", "x+", "y-", "y+", "z-", "z+")
ALIASES = {"bottom": "z-", "top": "z+"}
WALL, MOVING, SLIP, INLET, OUTLET, PERIODIC = range(6)
KINDS = {"wall": WALL, "moving_wall": MOVING, "free_slip": SLIP, "velocity_inlet": INLET,
         "pressure_outlet": OUTLET, "periodic": PERIODIC}
KIND_ALIASES = {"no_slip": "wall", "inlet": "velocity_inlet", "outlet": "pressure_outlet", "slip": "free_slip",
                "moving": "moving_wall"}
CONVECTION = {"none": 0, "semi_lagrangian": 1, "maccormack": 2}
PRESSURE_FORMS = {"gas": 0, "shared": 1}
THETA_MIN = 0.05  # smallest wall fraction used by the no-slip ghost values
EPS_MIN = 1e-3  # the solver reads eps clamped to [EPS_MIN, 1] (it divides by eps)
VISCOUS_REDUCTION = 1e-6  # viscous sweeps stop at this estimated error relative to the velocity scale


# ============================================================================ set-up
@dataclasses.dataclass(frozen=True)
class BC:
    """Boundary condition of one domain face. ``kind``: wall | moving_wall | free_slip |
    velocity_inlet | pressure_outlet | periodic. ``velocity`` [m/s]: wall velocity (moving
    wall, tangential) or superficial inlet velocity vector; ``pressure`` [Pa]: outlet pressure."""

    kind: str = "wall"
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    pressure: float = 0.0


def wall() -> BC:
    return BC("wall")


def moving_wall(velocity: Sequence[float]) -> BC:
    return BC("moving_wall", tuple(float(v) for v in velocity))


def free_slip() -> BC:
    return BC("free_slip")


def velocity_inlet(velocity: Sequence[float]) -> BC:
    return BC("velocity_inlet", tuple(float(v) for v in velocity))


def pressure_outlet(pressure: float = 0.0) -> BC:
    return BC("pressure_outlet", pressure=float(pressure))


def periodic() -> BC:
    return BC("periodic")


def _finite(x) -> bool:
    return bool(np.all(np.isfinite(np.asarray(x, float))))


# FlowConfig field -> the preset's [gas] key: the defaults, units and ranges are the schema's
# (app/config/schema.py, GasConfig), so a scene built here and one built from a preset agree
GAS_KEYS = {"rho": "density", "mu": "viscosity", "pressure_form": "pressure_form", "convection": "convection",
            "tol": "tolerance", "max_iter": "max_iterations", "aperture_samples": "aperture_samples",
            "min_open_fraction": "min_open_fraction", "max_viscous_sweeps": "max_viscous_sweeps",
            "trace_forces": "trace_forces"}


def _gas_default(field: str):
    return GasConfig.__dataclass_fields__[GAS_KEYS[field]].default


def _gas_check(field: str, value) -> None:
    """ValueError unless ``value`` fits the schema's range or choices of the [gas] key behind ``field``."""
    key = GAS_KEYS[field]
    meta = GasConfig.__dataclass_fields__[key].metadata
    choices = meta.get("choices")
    if choices:
        if value not in choices:
            raise ValueError(f"flow: {field} (gas.{key}) must be one of {list(choices)}, got {value!r}")
        return
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        if GasConfig.__dataclass_fields__[key].type in (bool, "bool"):
            return
        raise ValueError(f"flow: {field} (gas.{key}) must be a number, got {value!r}")
    lo, hi, unit = meta.get("lo"), meta.get("hi"), meta.get("unit", "-")
    u = "" if unit == "-" else f" {unit}"
    bad = not np.isfinite(value)
    if lo is not None and (value < lo or (meta.get("lo_open") and value <= lo)):
        bad = True
    if hi is not None and value > hi:
        bad = True
    if bad:
        rng = f"{'>' if meta.get('lo_open') else '>='} {lo:g}" if lo is not None else ""
        if hi is not None:
            rng += (" and " if rng else "") + f"<= {hi:g}"
        raise ValueError(f"flow: {field} (gas.{key}) must be {rng}{u}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class FlowConfig:
    """Everything the gas solver needs to be built (validated on construction).

    shape (nx, ny, nz) cells of size h [m] from origin [m]; rho [kg/m3]; mu [Pa s];
    gravity [m/s2]; bcs: face name -> :class:`BC` (missing faces are no-slip walls);
    walls: vessel walls (:mod:`app.sim.geometry`) for cut cells; pressure_form "gas" (Model
    B) or "shared" (Model A); convection "maccormack" | "semi_lagrangian" | "none"; tol:
    pressure-solve tolerance (relative divergence, see module doc); max_iter: outer PCG
    iterations; aperture_samples: sub-samples per face edge for cut cells; min_open_fraction:
    cut cells with at most this open volume fraction are closed (small-cell removal);
    max_viscous_sweeps: cap on red-black Gauss-Seidel sweeps of the implicit viscous predictor.
    These gas fields are the preset's [gas] keys (:data:`GAS_KEYS`): their defaults, units and
    ranges are read from the schema (app/config/schema.py), so none can drift from it.
    """

    shape: tuple[int, int, int]
    h: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rho: float = _gas_default("rho")
    mu: float = _gas_default("mu")
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    bcs: Mapping[str, BC] = dataclasses.field(default_factory=dict)
    walls: tuple = ()
    pressure_form: str = _gas_default("pressure_form")
    convection: str = _gas_default("convection")
    tol: float = _gas_default("tol")
    max_iter: int = _gas_default("max_iter")
    aperture_samples: int = _gas_default("aperture_samples")
    min_open_fraction: float = _gas_default("min_open_fraction")
    max_viscous_sweeps: int = _gas_default("max_viscous_sweeps")
    trace_forces: bool = _gas_default("trace_forces")

    def __post_init__(self):
        bad = ValueError
        try:
            shape = tuple(int(n) for n in self.shape)
        except (TypeError, ValueError):
            raise bad(f"flow: shape must be three positive integers, got {self.shape!r}") from None
        if len(shape) != 3 or min(shape) < 1 or any(int(n) != n for n in self.shape):
            raise bad(f"flow: shape must be three positive integers, got {self.shape!r}")
        object.__setattr__(self, "shape", shape)
        if not (np.isfinite(self.h) and self.h > 0):
            raise bad(f"flow: cell size h must be a positive number of metres, got {self.h!r}")
        for name in ("origin", "gravity"):
            v = getattr(self, name)
            if len(tuple(v)) != 3 or not _finite(v):
                raise bad(f"flow: {name} must be three finite numbers, got {v!r}")
            object.__setattr__(self, name, tuple(float(x) for x in v))
        for name in GAS_KEYS:  # the schema's ranges and choices of the [gas] keys
            _gas_check(name, getattr(self, name))
        norm = {}
        for face, bc in dict(self.bcs).items():
            f = ALIASES.get(face, face)
            if f not in FACES:
                raise bad(f"flow: unknown boundary face {face!r}; use one of {list(FACES) + list(ALIASES)}")
            if f in norm:
                raise bad(f"flow: boundary face {f!r} given twice (through an alias)")
            if isinstance(bc, str):
                bc = BC(bc)
            if not isinstance(bc, BC):
                raise bad(f"flow: boundary condition of {face!r} must be a BC, got {bc!r}")
            kind = KIND_ALIASES.get(bc.kind, bc.kind)
            if kind not in KINDS:
                raise bad(f"flow: unknown boundary kind {bc.kind!r} on {face!r}; use one of {sorted(KINDS)}")
            vel = tuple(float(x) for x in bc.velocity)
            if len(vel) != 3 or not _finite(vel) or not np.isfinite(bc.pressure):
                raise bad(f"flow: boundary {face!r} needs a finite 3-vector velocity and finite pressure")
            axis = "xyz".index(f[0])
            if kind == "moving_wall" and vel[axis] != 0.0:
                raise bad(f"flow: moving wall {f!r} velocity must be tangential (its {f[0]} component must be 0)")
            norm[f] = BC(kind, vel, float(bc.pressure))
        for a, ax in enumerate("xyz"):
            lo = norm.get(ax + "-", BC()).kind == "periodic"
            hi = norm.get(ax + "+", BC()).kind == "periodic"
            if lo != hi:
                raise bad(f"flow: periodic boundaries must pair {ax}- with {ax}+")
        object.__setattr__(self, "bcs", norm)
        object.__setattr__(self, "walls", tuple(self.walls))
        for w in self.walls:
            if not hasattr(w, "clearance"):
                raise bad(f"flow: walls must be geometry walls with a clearance(), got {w!r}")

    def bc(self, face: str) -> BC:
        """Boundary condition of ``face`` (aliases allowed); no-slip wall when not given."""
        return self.bcs.get(ALIASES.get(face, face), BC())

    @property
    def grid(self) -> MacGrid:
        return MacGrid(self.shape, float(self.h), self.origin)

    @property
    def periodic(self) -> tuple[bool, bool, bool]:
        return tuple(self.bc(ax + "-").kind == "periodic" for ax in "xyz")


@dataclasses.dataclass(frozen=True)
class StepInfo:
    """What one fluid step did: CFL = max|u| dt/h (old or new velocity, whichever is larger),
    diffusion number mu dt/(rho h^2), red-black Gauss-Seidel sweeps of the viscous predictor,
    pressure iterations (all refinement rounds), pressure_residual = divergence = the relative
    continuity residual of the final field (see module doc), converged = divergence <= tol."""

    dt: float
    cfl: float
    diffusion_number: float
    viscous_sweeps: int
    pressure_iterations: int
    pressure_residual: float
    converged: bool
    divergence: float
