"""A scene pays only for what it uses, and the optional models do what they claim."""
import math

import numpy as np
import pytest

from app.sim.fields import bytes_per_grain

from dem_helpers import make

pytestmark = pytest.mark.verification

R = 1e-3


def test_frictionless_monodisperse_scene_allocates_no_history_radius_or_spin():
    scene, dem = make(contact={"friction": 0.0})
    assert not hasattr(dem.state, "omega") and not hasattr(dem.state, "torque")
    assert not hasattr(dem.history, "tangential") and not hasattr(dem.history, "rolling")
    assert not hasattr(dem.fixed, "radius") and not hasattr(dem.fixed, "mass")
    assert not hasattr(dem.state, "external_force") and not hasattr(dem.state, "drag_coeff")  # DEM-only: no gas
    lean = bytes_per_grain(scene.model)
    scene2, dem2 = make(contact={"friction": 0.5})
    assert hasattr(dem2.history, "tangential") and not hasattr(dem2.history, "rolling")
    # springs are kept per history slot (the contacts a grain owns), not per neighbour slot
    assert bytes_per_grain(scene2.model) > lean + 12 * scene2.model.history_slots


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
    v1 = dem.read("velocity")[0, 0]
    n = int(0.04 / dem.m.dt)
    dem.advance(n)
    a = (dem.read("velocity")[0, 0] - v1) / (n * dem.m.dt)
    assert a == pytest.approx(-5 / 7 * mu_r * g, rel=0.05)


def test_grain_leaving_the_domain_is_counted_not_lost_silently():
    _, dem = make(positions=[[0, 0, 0.045], [0, 0, -0.04]], velocities=[[0, 0, 2.0], [0, 0, 0]],
                  vessel={"shape": "box"}, domain={"gravity": [0.0, 0.0, -9.81]})
    dem.advance(int(0.01 / dem.m.dt))
    d = dem.diagnostics()
    assert d["grains_removed"] == 1 and d["grains_alive"] == 1 and d["non_finite"] == 0
    assert list(dem.read("alive")) == [0, 1]


def test_sampled_sdf_wall_matches_the_analytic_cylinder(tmp_path):
    """A cylinder sampled on a 0.5 mm grid returns a grain like the analytic cylinder wall."""
    radius, h = 0.02, 5e-4
    ax = np.arange(-0.025, 0.025 + h / 2, h)
    zs = np.arange(-0.05, 0.05 + h / 2, h)
    X, Y, Z = np.meshgrid(ax, ax, zs, indexing="ij")
    values = np.minimum(radius - np.hypot(X, Y), Z + 0.05)  # cylinder side and floor at z = -0.05
    np.savez(tmp_path / "cyl.npz", values=values, origin=[ax[0], ax[0], zs[0]], spacing=h)
    outcomes = []
    for vessel in ({"shape": "cylinder", "radius": radius}, {"shape": "sampled", "sdf_file": str(tmp_path / "cyl.npz")}):
        _, dem = make(positions=[[radius - R - 1e-6, 0, 0]], velocities=[[0.5, 0, 0]], particles={"count": 1},
                      vessel=vessel, contact={"restitution": 0.3, "wall_restitution": 0.8, "friction": 0.0},
                      dem={"impact_speed": 0.5})
        dem.advance(int(0.003 / dem.m.dt))
        outcomes.append(dem.read("velocity")[0, 0])
    assert outcomes[0] == pytest.approx(-0.8 * 0.5, rel=0.02)
    assert outcomes[1] == pytest.approx(outcomes[0], rel=0.01)  # trilinear SDF is exact for planes, close here


def test_bed_height_sets_the_count_from_the_assumed_solid_fraction():
    scene, _ = make(domain={"lo": [-0.01, -0.01, 0.0], "hi": [0.01, 0.01, 0.1]},
                    vessel={"shape": "cylinder", "radius": 0.01},
                    particles={"count": 0, "bed_height": 0.02, "fill_solid_fraction": 0.6})
    expected = 0.6 * math.pi * 0.01 ** 2 * 0.02 / (math.pi / 6 * 2e-3 ** 3)
    assert scene.n == round(expected)
