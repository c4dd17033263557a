"""Each wall's vertical force on the grains (a diagnostics column, ``wall_force_z_<wall>``, in run.h5's series):
a bed at rest stands on its walls, so their forces add up to its weight; without side walls (a laterally
periodic box) the floor alone carries it."""
import math

import numpy as np
import pytest

from dem_helpers import make

pytestmark = pytest.mark.verification

G = 9.81


def settled(**changes):
    """About 600 grains of 2 mm poured from the scene's lattice and left to settle for 0.25 s (friction 0.5),
    float64: the kinetic energy is then ~1e-9 of the potential energy the pour released."""
    scene, dem = make(particles={"count": 600}, domain={"lo": [-0.008, -0.008, 0.0], "hi": [0.008, 0.008, 0.06],
                                                         "gravity": [0.0, 0.0, -G]},
                      contact={"friction": 0.5}, **changes)
    dem.advance(int(round(0.25 / scene.model.dt)))
    weight = float(np.sum(dem.masses())) * G
    return scene, dem.diagnostics(), weight


def test_a_bed_at_rest_stands_on_the_floor_and_the_wall():
    """In a cylinder the floor and the wall carry the bed together: their vertical forces sum to its weight
    within 1% (the rest is the bed's residual vibration: the instantaneous balance holds to ~0.1% in the
    settle preset), and the rough wall takes a share by friction (Janssen's effect) while it pushes down on
    nothing: its force is upward and under a third of the weight."""
    scene, d, weight = settled(vessel={"shape": "cylinder", "radius": 0.008})
    assert d["grains_removed"] == 0
    assert [w.name for w in scene.model.walls] == ["cylinder", "floor"]
    floor, wall = d["wall_force_z_floor"], d["wall_force_z_cylinder"]
    assert floor + wall == pytest.approx(weight, rel=0.01)
    assert 0 < wall < weight / 3


def test_without_side_walls_the_floor_carries_the_whole_bed():
    periodic = {f"{a}{s}": {"kind": "periodic"} for a in "xy" for s in "-+"}
    scene, d, weight = settled(vessel={"shape": "box"}, boundary=periodic)
    assert [w.name for w in scene.model.walls] == ["floor"]
    assert d["wall_force_z_floor"] == pytest.approx(weight, rel=0.01)
    assert math.isfinite(d["bed_height"]) and d["grains_removed"] == 0
