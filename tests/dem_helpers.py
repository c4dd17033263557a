"""Small DEM scenes built in-process for tests (CPU, float64 from conftest)."""
import numpy as np

from app.config import load_text
from app.scene import Scene
from app.sim.dem import DemSolver

BASE = {
    "run": {"duration": 0.01, "step": 1e-3},
    "domain": {"lo": [-0.05, -0.05, -0.05], "hi": [0.05, 0.05, 0.05], "gravity": [0.0, 0.0, 0.0]},
    "vessel": {"shape": "none"},
    "particles": {"diameter": 2e-3, "density": 2500.0, "count": 2},
    "contact": {"model": "hertz_mindlin", "youngs_modulus": 5e6, "restitution": 0.9, "friction": 0.0},
}


def toml_text(sections: dict) -> str:
    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(v)

    def inline(v):
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {val(x)}" for k, x in v.items()) + " }"
        return val(v)

    out = []
    for name, table in sections.items():
        out.append(f"[{name}]")
        out += [f'"{k}" = {inline(v)}' if name == "boundary" else f"{k} = {val(v)}" for k, v in table.items()]
    return "\n".join(out) + "\n"


def merged(**changes) -> dict:
    cfg = {k: dict(v) for k, v in BASE.items()}
    for section, table in changes.items():
        cfg.setdefault(section, {}).update(table)
    return cfg


def scene_of(initial=None, serial=False, **changes) -> Scene:
    """The Scene of BASE updated with ``changes``; ``initial``: its grains (position, radius, velocity ...);
    ``serial``: its kernels as on one CPU thread (``Scene``'s)."""
    return Scene(load_text(toml_text(merged(**changes)), "test.toml"), "test.toml", initial=initial, serial=serial)


def grains(position, radius, velocity=None) -> dict:
    """Initial grains for ``scene_of``: positions [m] and radii [m] (one radius for all, or one each)."""
    position = np.asarray(position, float)
    out = {"position": position, "radius": np.broadcast_to(np.asarray(radius, float), len(position)).copy()}
    if velocity is not None:
        out["velocity"] = np.asarray(velocity, float)
    return out


def make(positions=None, velocities=None, omega=None, radius=None, **changes):
    """Build (scene, dem) from BASE updated with ``changes``; optionally place the grains."""
    scene = Scene(load_text(toml_text(merged(**changes)), "test.toml"))
    dem = DemSolver(scene.model)
    if positions is None:
        dem.set_grains(scene.initial["position"], radius=scene.initial["radius"])
    else:
        positions = np.asarray(positions, float)
        r = np.full(len(positions), scene.model.radius) if radius is None else radius
        dem.set_grains(positions, velocities, r, omega)
    return scene, dem
