"""A scene pays only for what it uses, and the optional models do what they claim."""
import math

import numpy as np
import pytest

from app.sim.fields import bytes_per_grain

from dem_helpers import make

R = 1e-3


def test_frictionless_monodisperse_scene_allocates_no_history_radius_or_spin():
    scene, dem = make(contact={"friction": 0.0})
    assert not hasattr(dem.state, "omega") and not hasattr(dem.state, "torque")
    assert not hasattr(dem.history, "tangential") and not hasattr(dem.history, "rolling")
    assert not hasattr(dem.fixed, "radius") and not hasattr(dem.fixed, "mass")
    assert not hasattr(dem.state, "external_force")  # DEM-only: nothing for a gas
    lean = bytes_per_grain(scene.model)
    scene2, dem2 = make(contact={"friction": 0.5})
    assert hasattr(dem2.history, "tangential") and not hasattr(dem2.history, "rolling")
    assert bytes_per_grain(scene2.model) > lean + 12 * scene2.model.slots


def test_polydisperse_bed_reads_per_grain_radius_and_keeps_fractions():
    scene, dem = make(
        run={"step": 1e-3},
        domain={"lo": [-0.01, -0.01, 0.0], "hi": [0.01, 0.01, 0.06], "gravity": [0.0, 0.0, -9.81]},
        vessel={"shape": "cylinder", "radius": 0.01},
        particles={"diameter": 0.0, "diameters": [1.5e-3, 2.5e-3], "fractions": [0.5, 0.5],
                   "fractions_by": "number", "count": 400},
        contact={"friction": 0.3, "youngs_modulus": 2e7})
    assert hasattr(dem.fixed, "radius")
    r = dem.radii()
    assert np.sum(np.isclose(r, 0.75e-3)) == 200 and np.sum(np.isclose(r, 1.25e-3)) == 200
    for _ in range(30):
        dem.advance(scene.derived.substeps)
    d = dem.diagnostics()
    assert d["grains_removed"] == 0 and d["non_finite"] == 0 and d["max_overlap"] < 0.05
    assert d["bed_height"] < 0.06


@pytest.mark.parametrize("model", ["constant_torque", "epsd"])
def test_rolling_resistance_decelerates_a_rolling_ball(model):
    """A ball rolling on a floor with rolling friction mu_r decelerates at (5/7) mu_r g (rolling, no slip)."""
    mu_r, g, v0 = 0.05, 9.81, 0.3
    _, dem = make(positions=[[-0.04, 0, -0.05 + R * 0.9995]], velocities=[[v0, 0, 0]], omega=[[0, v0 / R, 0]],
                  particles={"count": 1}, domain={"gravity": [0.0, 0.0, -g]}, vessel={"shape": "box"},
                  contact={"friction": 0.5, "rolling_friction": mu_r, "rolling_model": model, "restitution": 0.5})
    dem.advance(int(0.005 / dem.m.dt))
    v1 = dem.state.v.to_numpy()[0, 0]
    n = int(0.04 / dem.m.dt)
    dem.advance(n)
    a = (dem.state.v.to_numpy()[0, 0] - v1) / (n * dem.m.dt)
    assert a == pytest.approx(-5 / 7 * mu_r * g, rel=0.05)
